"""Skin signals with ground truth, made by the same effects scenes use.

Decoder tests, the decoding benchmark and the reference slips of the
reference-matching decoders (`grasplink.evaluation.decoders`) draw their
signals here, so they exercise exactly the physics a scene would (thesis ch.
4.3 FSR model, ch. 5.3.1 ridge pulses, ch. 5.5.1 speed dips, noise and
drift), at any sample rate, without running nodes or a bus (the signal as the
skin node sends it over CAN: `grasplink.evaluation.scenes`). Every effect only
when asked for.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from grasplink.simulators import harness
from grasplink.simulators.core import Effect
from grasplink.simulators.effects import actuators, kinematics, noise, skin

NOISE_WHITE_N = 0.02  # thesis-like: high-frequency FSR noise
NOISE_DRIFT_N = 0.05  # and slow drift
DRIFT_CORNER_HZ = 0.3
OBJECT_LENGTH_MM = 90.0
LOAD_KG = 0.2  # the object's weight pulling it along the skin (`actuators.ScriptedLoad`)
LEAD_MM = 6.0


@dataclass
class SkinRecording:
    t_s: np.ndarray
    force_n: np.ndarray
    position_mm: np.ndarray  # truth: leading edge
    speed_mm_s: np.ndarray  # truth: signed
    slipping: np.ndarray  # truth: 1/0
    grip_n: np.ndarray  # truth: static grip
    contact_times_s: np.ndarray  # truth: ridge contacts (tips excluded)
    layout_mm: tuple[float, ...]
    fs_hz: int


def slip_recording(
    layout_mm: tuple[float, ...],
    speed_mm_s: float,
    *,
    fs_hz: int = 400,
    reverse: bool = False,
    noise_scale: float = 1.0,
    dips: bool = False,
    tips: float = 0.0,
    onset_s: float = 0.3,
    grip_n: float = 5.0,
    seed: int = 1,
    tail_s: float = 0.3,
) -> SkinRecording:
    """Constant-speed slip across the whole skin (plus ramps of zero speed around it)."""
    if not speed_mm_s > 0:
        raise ValueError(f"slip speed must be > 0 mm/s, got {speed_mm_s} (use static_recording)")
    length = float(sum(layout_mm))
    travel = length + 2 * LEAD_MM
    duration = onset_s + travel / abs(speed_mm_s) + tail_s
    start = length + LEAD_MM if reverse else -LEAD_MM
    profile = [[0.0, 0.0], [onset_s, 0.0], [onset_s + 1e-6, abs(speed_mm_s)]]
    physics: list[tuple[type[Effect], dict[str, object]]] = [
        (
            kinematics.ScriptedObject,
            {
                "speed_mm_s": profile,
                "start_mm": start,
                "direction": "reverse" if reverse else "forward",
            },
        ),
    ]
    if dips:
        physics.append((kinematics.RidgeDips, {}))
    return _record(
        layout_mm,
        fs_hz,
        duration,
        seed,
        physics,
        grip_n=[[0.0, grip_n]],
        noise_scale=noise_scale,
        tips=tips,
        reverse=reverse,
    )


def static_recording(
    layout_mm: tuple[float, ...],
    grip_steps_n: list[list[float]],
    *,
    fs_hz: int = 400,
    duration_s: float = 6.0,
    noise_scale: float = 1.0,
    seed: int = 1,
) -> SkinRecording:
    """A held object (no slip) under grip-force steps: the false-slip test."""
    physics = [
        (kinematics.ScriptedObject, {"speed_mm_s": [[0.0, 0.0]], "start_mm": float(sum(layout_mm))})
    ]
    return _record(
        layout_mm,
        fs_hz,
        duration_s,
        seed,
        physics,
        grip_n=grip_steps_n,
        noise_scale=noise_scale,
        tips=0.0,
        grip_interpolation="linear",
    )


def scripted_recording(
    layout_mm: tuple[float, ...],
    speed_mm_s: list[list[float]],
    *,
    start_mm: float,
    duration_s: float,
    fs_hz: int = 400,
    object_length_mm: float = OBJECT_LENGTH_MM,
    grip_n: list[list[float]] | None = None,
    grip_interpolation: str = "step",
    white_n: float = NOISE_WHITE_N,
    drift_n: float = NOISE_DRIFT_N,
    drift_corner_hz: float = DRIFT_CORNER_HZ,
    full_scale_n: float | None = None,
    dips: bool = False,
    tips: float = 0.0,
    seed: int = 1,
) -> SkinRecording:
    """A slip that changes speed, stops, restarts or reverses: any signed speed profile.

    `speed_mm_s` is `object.scripted`'s [[t_s, mm/s], ...] (signed, linear
    between points) and `start_mm` the leading edge at t = 0. The object
    (`object_length_mm`) leads with the edge its motion points to, so a
    reversal hands the contacts to the other edge (`object_length_mm` of
    `object.scripted`). `grip_n` (default 5 N) may step during the slip;
    `full_scale_n` clips the FSR (`skin.saturation`); noise in N.
    """
    physics: list[tuple[type[Effect], dict[str, object]]] = [
        (
            kinematics.ScriptedObject,
            {
                "speed_mm_s": [list(p) for p in speed_mm_s],
                "start_mm": start_mm,
                "object_length_mm": object_length_mm,
            },
        ),
    ]
    if dips:
        physics.append((kinematics.RidgeDips, {}))
    moving = [v for _, v in speed_mm_s if v != 0]
    return _record(
        layout_mm,
        fs_hz,
        duration_s,
        seed,
        physics,
        grip_n=[list(p) for p in grip_n] if grip_n is not None else [[0.0, 5.0]],
        grip_interpolation=grip_interpolation,
        noise_scale=1.0,
        tips=tips,
        reverse=bool(moving) and moving[0] < 0,
        object_length_mm=object_length_mm,
        white_n=white_n,
        drift_n=drift_n,
        drift_corner_hz=drift_corner_hz,
        full_scale_n=full_scale_n,
    )


def _record(
    layout_mm,
    fs_hz,
    duration_s,
    seed,
    physics,
    *,
    grip_n,
    noise_scale,
    tips,
    grip_interpolation: str = "step",
    reverse: bool = False,
    object_length_mm: float = OBJECT_LENGTH_MM,
    white_n: float | None = None,
    drift_n: float | None = None,
    drift_corner_hz: float = DRIFT_CORNER_HZ,
    full_scale_n: float | None = None,
) -> SkinRecording:
    ctx = harness.context(seed=seed, rate_hz=fs_hz, layout_mm=tuple(layout_mm))
    effects = [harness.make(cls, ctx, **params) for cls, params in physics]
    effects += [
        harness.make(actuators.ScriptedGrip, ctx, grip_n=grip_n, interpolation=grip_interpolation),
        harness.make(actuators.ScriptedLoad, ctx, mass_kg=LOAD_KG),
        harness.make(
            skin.FsrForce,
            ctx,
            object_length_mm=object_length_mm,
            direction="reverse" if reverse else "forward",
        ),
    ]
    contacts = harness.make(skin.RidgeContacts, ctx, tip_probability=tips)
    effects.append(contacts)
    white = NOISE_WHITE_N * noise_scale if white_n is None else white_n
    drift = NOISE_DRIFT_N * noise_scale if drift_n is None else drift_n
    if white > 0 or drift > 0:  # an effect with std 0 draws nothing: as if absent
        effects += [
            harness.make(noise.WhiteNoise, ctx, std=white),
            harness.make(noise.Drift, ctx, std=drift, corner_hz=drift_corner_hz),
        ]
    if full_scale_n is not None:
        effects.append(harness.make(skin.Saturation, ctx, full_scale_n=full_scale_n))
    return run_recording(effects, contacts, layout_mm, fs_hz, duration_s)


def run_recording(
    effects: list, contacts: Any, layout_mm: Sequence[float], fs_hz: int, duration_s: float
) -> SkinRecording:
    """Run `effects` at `fs_hz` for `duration_s` and keep what a decoder is judged on: the
    force, the object's truth and the ridge contacts (`contacts`: the skin.ridge_contacts
    effect among them; its tip contacts are no ridge contacts)."""
    times = harness.sample_times_us(fs_hz, duration_s)
    out = harness.run(effects, times, chunk=4096)
    return SkinRecording(
        times / 1e6,
        out["skin.force_n"],
        out["object.position_mm"],
        out["object.speed_mm_s"],
        out["object.slipping"],
        out["hand.grip_n"],
        np.array([c.time_s for c in contacts.contacts if not c.tip]),
        tuple(layout_mm),
        fs_hz,
    )

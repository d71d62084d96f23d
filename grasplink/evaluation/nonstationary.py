"""Slips that change speed, stop, restart and reverse: the signals and how decoders are judged.

Real slips are not constant (thesis ch. 5.4-5.5: the speed dips at ridges,
objects tip, grips change). This module makes signals of every kind a
decoder meets - accelerating and decelerating slips, stick-slip, reversals,
slips that start with the object already on the skin, grip steps and sensor
saturation during a slip, 10 dB SNR with slow drift, 5-200 mm/s, 100-1000 Hz
with dropped samples, and grip changes without any slip - on several
layouts, seeds and both directions, runs every decoder over them as the
skin node feeds a gateway (3-sample chunks, one TPDO1) and scores them.
The definitions of every figure are in docs/decoding.md ("Non-stationary
slips") and in `score` below; `grasplink bench decode` renders the tables.

Truth is the simulator's (`object.*` signals at the samples); signals come
from `synth.scripted_recording`, so they are exactly what a scene with the
same effects produces.
"""

from __future__ import annotations

import multiprocessing
import os
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from grasplink.decoding.base import SlipEstimate
from grasplink.evaluation.decoders import make_decoder
from grasplink.evaluation.scoring import along_truth
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators.effects.skin import LEAD_IN_MM, SPACING_SCALE_MM
from grasplink.simulators.synth import SkinRecording, scripted_recording

# -- definitions (docs/decoding.md, "Non-stationary slips") ------------------------------
V_MOVING_MM_S = 1.0  # below this the object is at rest (slowest slip: the thesis task's 1.8 mm/s)
V_DIRECTION_MM_S = 5.0  # the direction of a slower truth is not scored
STOP_MIN_S = 0.15  # a standstill shorter than this is a turning point, not a stop
CLEAR_WITHIN_S = 0.3  # the slip flag should clear this soon after the object stops
REST_SETTLED_S = 0.3  # flags later than this into a rest are false slips
CONFIDENT = 0.8  # estimates this confident should point the right way
CONFIDENCE_BINS = (0.0, 0.2, 0.4, 0.6, CONFIDENT, 1.0 + 1e-9)  # the last bin: confident
OFF_SKIN_TOLERANCE_MM = 1.0
CHUNKS = (3, 256)  # the skin node's TPDO1 (3 samples) and a batch reader's 256

# -- the signals --------------------------------------------------------------------------
LAYOUTS = ("alpha0.1", "fibonacci", "alpha0.3", "uniform4")
SYMMETRIC = frozenset(name for name, s in LAYOUTS_MM.items() if tuple(s) == tuple(s)[::-1])
SEEDS = 2
LEAD_MM = 6.0  # the edge starts this far before the first ridge it meets
ONSET_S = 0.3  # at rest before the slip starts
START_S = 0.02  # from rest to the slip speed
STOP_S = 0.03  # from the slip speed to rest
REST_AFTER_S = 0.7  # at rest after the slip: the stop is scored
THESIS_OBJECT_MM = 90.0  # 25 x 45 x 90 mm, slipping along its 90 mm side (ch. 5.4)
SHORT_OBJECT_MM = 25.0  # the same object along its 25 mm side: a reversal stays on the skin
TURN_S = 0.1  # a reversal: from the speed through rest to the speed the other way
SNR_DB = 10.0
FULL_SCALE_N = 5.0  # saturation: the FSR calibrated to 5 N full scale ...
SQUEEZE_N = 12.0  # ... and squeezed from 5 N to this during the slip
PULSE_ALPHA_N = 1.0  # mean contact height of skin.ridge_contacts (alpha_n [0.8, 1.2] N)
PACKET = 3  # samples per skin TPDO1
DROP_PACKETS = 0.02  # share of 3-sample packets lost
DROP_SAMPLES = 0.005  # and of single samples

CATEGORIES: dict[str, str] = {
    "constant": "constant speed 5-200 mm/s",
    "accelerating": "accelerating within one pass (e.g. 20 -> 100 mm/s)",
    "decelerating": "decelerating within one pass (e.g. 100 -> 30 mm/s)",
    "stick-slip": "stick-slip: two stops of 0.2-0.5 s mid-pass",
    "reversal": "reversal mid-slip (25 mm object)",
    "partial-start": "slip from rest with the object already over part of the skin",
    "grip-steps": "grip steps up and down during the slip",
    "saturation": "sensor saturation during the slip",
    "snr10": f"SNR {SNR_DB:g} dB of the ridge-pulse height, slow drift",
    "rates-drops": "100/200/1000 Hz with dropped samples",
    "grip-no-slip": "grip changes without slip",
}
MOVING = tuple(c for c in CATEGORIES if c != "grip-no-slip")

# (variant label, numbers) per category; quick runs take the first of each. Speeds lie off
# the 5 mm/s grids decoders search (the faithful mmse's): a held-out slip is not round.
VARIANTS: dict[str, list[tuple[str, tuple]]] = {
    "constant": [(f"{v} mm/s", (v,)) for v in (57, 6, 22, 118, 197)],
    "accelerating": [(f"{a}->{b} mm/s", (a, b)) for a, b in ((21, 98), (6, 41), (52, 197))],
    "decelerating": [(f"{a}->{b} mm/s", (a, b)) for a, b in ((98, 31), (41, 6), (197, 52))],
    "stick-slip": [(f"{v} mm/s", (v,)) for v in (47, 14, 118)],
    "reversal": [(f"{a}->-{b} mm/s", (a, b)) for a, b in ((41, 39), (22, 58), (97, 52))],
    "partial-start": [(f"{v} mm/s", (v,)) for v in (57, 22, 118)],
    "grip-steps": [(f"{v} mm/s", (v,)) for v in (57, 22, 118)],
    "saturation": [(f"{v} mm/s", (v,)) for v in (57, 22, 118)],
    "snr10": [(f"{v} mm/s", (v, v)) for v in (57, 22, 118)] + [("21->98 mm/s", (21, 98))],
    "rates-drops": [
        ("100 Hz, 21->98 mm/s", (100, "accelerating")),
        ("1000 Hz, stick-slip 47 mm/s", (1000, "stick-slip")),
        ("200 Hz, 21->98 mm/s", (200, "accelerating")),
        ("100 Hz, stick-slip 47 mm/s", (100, "stick-slip")),
        ("1000 Hz, 21->98 mm/s", (1000, "accelerating")),
        ("200 Hz, stick-slip 47 mm/s", (200, "stick-slip")),
    ],
    "grip-no-slip": [
        ("steps 2-5-10-5-2 N, object over the skin", ("full", "steps")),
        ("ramps 3-8-3 N in 0.1 s, object over half the skin", ("half", "ramps")),
        ("steps of 0.5 N every 0.4 s, object over the skin", ("full", "small")),
    ],
}
QUICK_VARIANTS = {"rates-drops": 2, "grip-no-slip": 2}
# quick: each direction on one target layout (the cost of 256-sample chunks on the first)
QUICK_PAIRS = (("alpha0.1", False), ("fibonacci", True))


@dataclass(frozen=True)
class Signal:
    """One signal of the set: a category's variant on a layout, a direction and a seed."""

    category: str
    variant: str
    numbers: tuple
    layout: str
    reverse: bool
    seed: int
    repeat: int = 0  # which of the seeds of this variant, layout and direction

    def make(self) -> Recorded:
        return make_signal(self)


@dataclass
class Recorded:
    """A signal's truth (every sample) and what the decoder gets (samples may be dropped)."""

    truth: SkinRecording
    t_s: np.ndarray
    force_n: np.ndarray
    fs_hz: int


def signals(quick: bool) -> list[Signal]:
    """The whole set, or the quick one (first variants, one seed, one direction per layout)."""
    out: list[Signal] = []
    for c_index, (category, variants) in enumerate(VARIANTS.items()):
        chosen = variants[: QUICK_VARIANTS.get(category, 1)] if quick else variants
        ways = (False,) if category == "grip-no-slip" else (False, True)
        pairs = [(x, r) for x in LAYOUTS for r in ways]
        if quick:
            pairs = [(x, r and category != "grip-no-slip") for x, r in QUICK_PAIRS]
        for v_index, (label, numbers) in enumerate(chosen):
            for layout, reverse in pairs:
                for repeat in range(1 if quick else SEEDS):
                    seed = 7000 + 1000 * c_index + 100 * v_index + 10 * repeat + int(reverse)
                    out.append(Signal(category, label, numbers, layout, reverse, seed, repeat))
    return out


def measures_cost(signal: Signal, quick: bool) -> bool:
    """Whether the signal is also fed in 256-sample chunks (the cost; the output is the same)."""
    if quick:
        return signal.layout == QUICK_PAIRS[0][0]
    return not signal.reverse and signal.repeat == 0


# -- building the signals -----------------------------------------------------------------


class Script:
    """A piecewise-linear speed profile built along the travel, with its exact distance.

    Speeds are magnitudes along the travel direction; `distance_mm` is the
    closed-form integral so far, so a stop or a turn can be placed at a position.
    """

    def __init__(self, rest_s: float = ONSET_S):
        self.knots: list[list[float]] = [[0.0, 0.0], [rest_s, 0.0]]
        self.distance_mm = 0.0

    @property
    def t_s(self) -> float:
        return self.knots[-1][0]

    @property
    def v_mm_s(self) -> float:
        return self.knots[-1][1]

    def ramp(self, speed_mm_s: float, duration_s: float) -> Script:
        """Change the speed linearly to `speed_mm_s` over `duration_s`."""
        self.distance_mm += 0.5 * (self.v_mm_s + speed_mm_s) * duration_s
        self.knots.append([self.t_s + duration_s, speed_mm_s])
        return self

    def reach(self, distance_mm: float, speed_mm_s: float | None = None) -> Script:
        """Travel on to `distance_mm`, the speed changing linearly to `speed_mm_s` (or held)."""
        end = self.v_mm_s if speed_mm_s is None else speed_mm_s
        duration = 2.0 * (distance_mm - self.distance_mm) / (self.v_mm_s + end)
        if duration > 1e-3:
            self.ramp(end, duration)
        return self

    def hold(self, duration_s: float) -> Script:
        return self.ramp(self.v_mm_s, duration_s)

    def signed(self, sign: float) -> list[list[float]]:
        return [[t, sign * v] for t, v in self.knots]


def pulse_height_n(layout_mm: Sequence[float]) -> float:
    """The median ridge-pulse height a slip across the skin makes (skin.ridge_contacts' model).

    Contact height = mean alpha x (1 - exp(-spacing before the ridge / 10 mm)),
    the first ridge met after a 20 mm lead-in (the same set either way): the
    reference of the SNR.
    """
    before = np.array([LEAD_IN_MM, *layout_mm])
    return float(PULSE_ALPHA_N * np.median(1.0 - np.exp(-before / SPACING_SCALE_MM)))


def _finish(script: Script, distance_mm: float) -> Script:
    """On at the speed reached until `distance_mm` along the travel, then stop and rest."""
    return script.reach(distance_mm).ramp(0.0, STOP_S).hold(REST_AFTER_S)


def make_signal(signal: Signal) -> Recorded:
    """Build one signal of the set (deterministic by its seed)."""
    layout = LAYOUTS_MM[signal.layout]
    skin_mm = float(sum(layout))
    rng = np.random.default_rng(signal.seed)
    category, numbers = signal.category, signal.numbers
    fs_hz = 400
    extra: dict = {}
    length = THESIS_OBJECT_MM
    travel_start = -LEAD_MM  # along the travel, from the first ridge met
    if category == "rates-drops":
        fs_hz, category = numbers[0], numbers[1]
        numbers = (20, 100) if category == "accelerating" else (50,)
    if category == "grip-no-slip":
        return _static(signal, layout, rng)
    if category in ("constant", "partial-start", "grip-steps", "saturation"):
        (speed,) = numbers
        if category == "partial-start":
            travel_start = float(rng.uniform(0.25, 0.6)) * skin_mm
        script = Script().ramp(speed, START_S)
        _finish(script, skin_mm + LEAD_MM - travel_start)  # until the edge is off the skin
    elif category in ("accelerating", "decelerating", "snr10"):
        first, last = numbers
        script = Script().ramp(first, START_S).reach(LEAD_MM)  # to the first ridge met
        script.reach(skin_mm + LEAD_MM, last)  # the change spans the pass over the skin
        _finish(script, skin_mm + 2 * LEAD_MM)
    elif category == "stick-slip":
        (speed,) = numbers
        script = Script().ramp(speed, START_S)
        for low, high in ((0.2, 0.45), (0.55, 0.85)):  # stops at these shares of the skin
            at = LEAD_MM + float(rng.uniform(low, high)) * skin_mm
            script.reach(at - 0.5 * speed * STOP_S).ramp(0.0, STOP_S)
            script.hold(float(rng.uniform(0.2, 0.5))).ramp(speed, START_S)
        _finish(script, skin_mm + 2 * LEAD_MM)
    elif category == "reversal":
        there, back = numbers
        length = SHORT_OBJECT_MM
        turn_mm = LEAD_MM + 0.5 * skin_mm + length + float(rng.uniform(-5.0, 10.0))
        script = Script().ramp(there, START_S)
        script.reach(turn_mm - 0.25 * there * TURN_S).ramp(0.0, TURN_S / 2)
        # back: the rear edge leads, from turn_mm - length down to the start (off the skin)
        rear_mm = turn_mm - length - 0.25 * back * TURN_S  # where the turn leaves it
        t = script.t_s + TURN_S / 2
        cruise_s = rear_mm / back
        profile = [
            *script.knots,
            [t, -back],
            [t + cruise_s, -back],
            [t + cruise_s + STOP_S, 0.0],
            [t + cruise_s + STOP_S + REST_AFTER_S, 0.0],
        ]
        return _recorded(signal, layout, profile, travel_start, length, fs_hz, rng, extra)
    else:
        raise ValueError(f"unknown category {signal.category!r}")
    if category == "grip-steps":
        t0, t1 = ONSET_S, script.knots[-2][0]
        up, down = (float(rng.uniform(a, b)) for a, b in ((0.25, 0.4), (0.6, 0.75)))
        extra["grip_n"] = _grip_steps(
            [(t0 + up * (t1 - t0), 8.0), (t0 + down * (t1 - t0), 3.0)], 5.0
        )
        extra["grip_interpolation"] = "linear"
    if category == "saturation":
        t0, t1 = ONSET_S, script.knots[-2][0]
        extra["grip_n"] = _grip_steps(  # a squeeze drives the FSR into its rail
            [(t0 + 0.45 * (t1 - t0), SQUEEZE_N), (t0 + 0.8 * (t1 - t0), 5.0)], 5.0, ramp_s=0.1
        )
        extra["grip_interpolation"] = "linear"
        extra["full_scale_n"] = FULL_SCALE_N
    if signal.category == "snr10":
        height = pulse_height_n(layout)
        extra["white_n"] = height / 10 ** (SNR_DB / 20)
        extra["drift_n"] = height
        extra["drift_corner_hz"] = 0.2
    return _recorded(signal, layout, script.knots, travel_start, length, fs_hz, rng, extra)


def _grip_steps(steps: list[tuple[float, float]], first_n: float, ramp_s: float = 0.05) -> list:
    """A grip profile holding `first_n`, then changing to each value over `ramp_s` at its time."""
    points = [[0.0, first_n]]
    for t, value in steps:
        points += [[t, points[-1][1]], [t + ramp_s, value]]
    return points


def _recorded(signal, layout, profile, travel_start, length, fs_hz, rng, extra) -> Recorded:
    skin_mm = float(sum(layout))
    sign = -1.0 if signal.reverse else 1.0
    start = skin_mm - travel_start if signal.reverse else travel_start
    knots = [[t, sign * v] for t, v in profile]
    duration = knots[-1][0]
    rec = scripted_recording(
        layout,
        knots,
        start_mm=start,
        duration_s=duration,
        fs_hz=fs_hz,
        object_length_mm=length,
        seed=signal.seed,
        **extra,
    )
    if signal.category == "rates-drops":
        keep = kept_samples(len(rec.t_s), rng)
        return Recorded(rec, rec.t_s[keep], rec.force_n[keep], fs_hz)
    return Recorded(rec, rec.t_s, rec.force_n, fs_hz)


def _static(signal: Signal, layout, rng) -> Recorded:
    skin_mm = float(sum(layout))
    cover, pattern = signal.numbers
    start = skin_mm + LEAD_MM if cover == "full" else 0.5 * skin_mm
    if pattern == "steps":
        grip = [[0.0, 2.0], [1.0, 5.0], [2.0, 10.0], [3.0, 5.0], [4.0, 2.0]]
        interpolation = "step"
    elif pattern == "ramps":
        grip = _grip_steps([(1.0, 8.0), (2.0, 3.0), (3.0, 8.0), (4.0, 3.0)], 3.0, ramp_s=0.1)
        interpolation = "linear"
    else:
        levels = 5.0 + 0.5 * np.where(np.arange(12) % 2, 1.0, -1.0)
        grip = [
            [0.4 * (i + 1) + float(rng.uniform(0, 0.05)), float(g)] for i, g in enumerate(levels)
        ]
        grip = [[0.0, 5.0], *grip]
        interpolation = "step"
    rec = scripted_recording(
        layout,
        [[0.0, 0.0]],
        start_mm=start,
        duration_s=5.5,
        grip_n=grip,
        grip_interpolation=interpolation,
        seed=signal.seed,
    )
    return Recorded(rec, rec.t_s, rec.force_n, rec.fs_hz)


def kept_samples(count: int, rng: np.random.Generator) -> np.ndarray:
    """Which samples reach the decoder: 3-sample packets and single samples lost at random.

    The first sample is always kept. Runs of lost packets are rare enough
    (2 % each) that nearly every loss is bridged (up to 8 sample periods).
    """
    packets = rng.random(-(-count // PACKET)) < DROP_PACKETS
    keep = ~np.repeat(packets, PACKET)[:count] & (rng.random(count) >= DROP_SAMPLES)
    keep[0] = True
    return keep


# -- scoring --------------------------------------------------------------------------------


@dataclass
class Score:
    """One decoder on one signal: the raw material of every figure (pooled by `summarise`)."""

    speed_rel_err: np.ndarray  # scored updates with a speed estimate: |v_est - v| / |v|
    speed_mag_err: np.ndarray  # the same, of the magnitudes: | |v_est| - |v| | / |v|
    speed_interval_err: np.ndarray  # against the mean speed over the last ridge interval
    position_err_mm: np.ndarray  # scored updates with a position estimate
    scored: int = 0
    missing: int = 0  # scored updates without a speed estimate
    directed: int = 0  # updates telling a direction while the truth moves >= 5 mm/s
    wrong_direction: int = 0
    confidence_right: np.ndarray = field(default_factory=lambda: np.zeros(5, int))
    confidence_total: np.ndarray = field(default_factory=lambda: np.zeros(5, int))
    positions: int = 0  # updates with a position estimate
    off_skin: int = 0  # of which outside the skin by more than 1 mm
    clear_s: list[float] = field(default_factory=list)  # per stop; inf: not cleared
    stop_on_skin: list[bool] = field(default_factory=list)  # per stop: the edge over the skin
    rest_updates: int = 0  # updates at rest, settled (>= 0.3 s into the rest)
    false_slip: int = 0  # of which flagged slip
    updates: int = 0
    samples: int = 0
    cpu_us: dict[int, float] = field(default_factory=dict)  # chunk -> CPU µs per sample
    chunk_invariant: bool = True  # same estimates in every chunking measured


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index ranges where `mask` holds."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True))


@dataclass
class Motion:
    """The truth's motion, cut into runs (constant sign), stops and rests."""

    runs: list[tuple[float, float, int]]  # (start_s, end_s, sign) of motion >= V_MOVING
    stops: list[tuple[float, float]]  # standstills >= STOP_MIN_S after motion
    rests: list[tuple[float, float]]  # every standstill (the first from the start)


def motion(truth: SkinRecording) -> Motion:
    t, v = truth.t_s, truth.speed_mm_s
    moving = np.abs(v) >= V_MOVING_MM_S
    end_s = float(t[-1]) + 1.0 / truth.fs_hz
    runs = []
    for sign in (1, -1):
        for a, b in _runs(moving & (np.sign(v) == sign)):
            runs.append((float(t[a]), float(t[b]) if b < len(t) else end_s, sign))
    runs.sort()
    rests, stops = [], []
    for a, b in _runs(~moving):
        start, stop = float(t[a]), float(t[b]) if b < len(t) else end_s
        rests.append((start, stop))
        if a > 0 and stop - start >= STOP_MIN_S:
            stops.append((start, stop))
    return Motion(runs, stops, rests)


def scored_windows(truth: SkinRecording, m: Motion) -> list[tuple[float, float]]:
    """Where speed and position are scored: the physical limit of each motion run.

    Within a run of one sign, from the later of (a) the third contact of the
    leg - consecutive runs of the same sign, i.e. since the slip started or
    reversed (position and direction need three contacts) - and (b) the
    second contact of the run itself (after a stop the position is known but
    the new speed needs one ridge interval).
    """
    contacts = np.sort(truth.contact_times_s)
    windows = []
    leg: list[float] = []
    previous_sign = 0
    for start, end, sign in m.runs:
        if sign != previous_sign:
            leg = []
        previous_sign = sign
        mine = contacts[(contacts >= start) & (contacts < end)]
        leg += list(mine)
        if len(leg) < 3 or len(mine) < 2:
            continue
        begin = max(leg[2], mine[1])
        if begin < end:
            windows.append((begin, end))
    return windows


def interval_speed(truth: SkinRecording, t_upd: np.ndarray, runs: list) -> np.ndarray:
    """Mean truth speed over the last ridge interval before each update (NaN if none in its run)."""
    contacts = np.sort(truth.contact_times_s)
    out = np.full(len(t_upd), np.nan)
    for start, end, _ in runs:
        mine = contacts[(contacts >= start) & (contacts < end)]
        if len(mine) < 2:
            continue
        inside = (t_upd >= mine[1]) & (t_upd < end)
        k = np.searchsorted(mine, t_upd[inside], side="right") - 1
        a, b = mine[k - 1], mine[k]
        pa = np.interp(a, truth.t_s, truth.position_mm)
        pb = np.interp(b, truth.t_s, truth.position_mm)
        out[inside] = (pb - pa) / np.maximum(b - a, 1e-9)
    return out


def _nearest(t: np.ndarray, at: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(t, at), 1, len(t) - 1)
    return np.where(np.abs(t[i - 1] - at) <= np.abs(t[i] - at), i - 1, i)


def score(estimates: Sequence[SlipEstimate], rec: Recorded) -> Score:
    """Judge one decoder's estimates on one signal (docs/decoding.md, "Non-stationary slips")."""
    truth = rec.truth
    empty = np.zeros(0)
    out = Score(empty, empty, empty, empty, samples=len(rec.t_s), updates=len(estimates))
    if not estimates:
        return out
    t_upd = np.array([e.t_s for e in estimates])
    x_est = np.array([np.nan if e.position_mm is None else e.position_mm for e in estimates])
    flags = np.array([e.slip for e in estimates])
    confidence = np.array([e.confidence for e in estimates])
    v_true = np.interp(t_upd, truth.t_s, truth.speed_mm_s)
    v_est, direction = along_truth(estimates, v_true)  # no direction: |v|, the truth's way
    x_true = truth.position_mm[_nearest(truth.t_s, t_upd)]  # the edge jumps at a reversal
    m = motion(truth)
    skin_mm = float(sum(truth.layout_mm))

    scored = np.zeros(len(t_upd), bool)
    for begin, end in scored_windows(truth, m):
        scored |= (t_upd >= begin) & (t_upd < end)
    scored &= np.abs(v_true) >= V_MOVING_MM_S
    have_v = scored & np.isfinite(v_est)
    have_x = scored & np.isfinite(x_est)
    speed = np.abs(v_true[have_v])
    out.speed_rel_err = np.abs(v_est[have_v] - v_true[have_v]) / speed
    out.speed_mag_err = np.abs(np.abs(v_est[have_v]) - speed) / speed
    observed = interval_speed(truth, t_upd, m.runs)[have_v]
    usable = np.isfinite(observed) & (np.abs(observed) >= V_MOVING_MM_S)
    out.speed_interval_err = np.abs(v_est[have_v][usable] - observed[usable]) / np.abs(
        observed[usable]
    )
    out.position_err_mm = np.abs(x_est[have_x] - x_true[have_x])
    out.scored = int(scored.sum())
    out.missing = int((scored & ~np.isfinite(v_est)).sum())

    directed = (np.abs(v_true) >= V_DIRECTION_MM_S) & (direction != 0)  # a told direction
    right = direction == np.sign(v_true)
    out.directed = int(directed.sum())
    out.wrong_direction = int((directed & ~right).sum())
    bins = np.clip(np.digitize(confidence, CONFIDENCE_BINS) - 1, 0, len(CONFIDENCE_BINS) - 2)
    out.confidence_total = np.bincount(bins[directed], minlength=5)
    out.confidence_right = np.bincount(bins[directed & right], minlength=5)

    positioned = np.isfinite(x_est)
    out.positions = int(positioned.sum())
    outside = (x_est < -OFF_SKIN_TOLERANCE_MM) | (x_est > skin_mm + OFF_SKIN_TOLERANCE_MM)
    out.off_skin = int((positioned & outside).sum())

    for start, end in m.stops:
        during = (t_upd >= start) & (t_upd < end)
        cleared = np.flatnonzero(during & ~flags)
        out.clear_s.append(float(t_upd[cleared[0]] - start) if len(cleared) else np.inf)
        edge = float(np.interp(start, truth.t_s, truth.position_mm))
        out.stop_on_skin.append(0.0 <= edge <= skin_mm)
    settled = np.zeros(len(t_upd), bool)
    for start, end in m.rests:
        settled |= (t_upd >= start + REST_SETTLED_S) & (t_upd < end)
    out.rest_updates = int(settled.sum())
    out.false_slip = int((settled & flags).sum())
    return out


# -- running ------------------------------------------------------------------------------


def feed(decoder, t_s: np.ndarray, force_n: np.ndarray, chunk: int) -> tuple[list, float]:
    """Estimates and CPU µs per sample, fed `chunk` samples at a time."""
    estimates: list[SlipEstimate] = []
    started = time.process_time()
    for start in range(0, len(t_s), chunk):
        estimates += decoder.feed(t_s[start : start + chunk], force_n[start : start + chunk])
    return estimates, 1e6 * (time.process_time() - started) / max(1, len(t_s))


def signal_job(signal: Signal, decoders: dict[str, dict], chunks: Sequence[int]) -> dict:
    """One signal, in a worker: every decoder fed in each chunking, scored on the first."""
    rec = signal.make()
    scores = {}
    for name, settings in decoders.items():
        runs = {}
        for chunk in chunks:
            decoder = make_decoder(name, rec.truth.layout_mm, rec.fs_hz, **settings)
            runs[chunk] = feed(decoder, rec.t_s, rec.force_n, chunk)
        first = runs[chunks[0]][0]
        result = score(first, rec)
        result.cpu_us = {chunk: cpu for chunk, (_, cpu) in runs.items()}
        result.chunk_invariant = all(runs[c][0] == first for c in chunks)
        scores[name] = result
    return {"signal": signal, "scores": scores}


def warm_worker(signal: Signal, decoders: dict[str, dict]) -> None:
    """Decode `signal` once, unscored, in a fresh worker: numba compiles (or loads from its
    cache) each kernel at its first call, seconds that would land in the µs/sample of
    whichever signal came first, and differ between a cold and a warm cache."""
    signal_job(signal, decoders, CHUNKS[:1])


def run(
    decoders: dict[str, dict],
    quick: bool,
    log: Callable[[str], None] = print,
    workers: int = 2,
) -> dict:
    """Every decoder over the whole set, in at most two worker processes: the figures."""
    started = time.monotonic()
    todo = signals(quick)
    workers = max(1, min(workers, 2, os.cpu_count() or 1, len(todo)))
    with ProcessPoolExecutor(
        workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=warm_worker,
        initargs=(todo[0], decoders),
    ) as pool:
        jobs = [
            pool.submit(signal_job, s, decoders, CHUNKS if measures_cost(s, quick) else CHUNKS[:1])
            for s in todo
        ]
        done = [job.result() for job in jobs]
    results = aggregate(done, decoders)
    results["signals"] = len(todo)
    results["workers"] = workers
    results["quick"] = quick
    log(
        f"non-stationary: {len(todo)} signals x {len(decoders)} decoders in "
        f"{time.monotonic() - started:.1f} s on {workers} workers"
    )
    return results


SCENES = "nonstationary_*.toml"


def scene_job(path: str, controllers_for, decoders: dict[str, dict]) -> dict:
    """One shipped scene, in a worker: run it, decode its CAN log and skin.csv, score both."""
    import tempfile

    from grasplink.evaluation import scenes as sc

    with tempfile.TemporaryDirectory(prefix="grasplink-bench-") as folder:
        signals = sc.record_scene(path, controllers_for, folder)
    scores: dict = {}
    for name, settings in decoders.items():
        for kind, rec in (("can", signals.can), ("csv", signals.csv)):
            recorded = Recorded(rec, rec.t_s, rec.force_n, rec.fs_hz)
            decoder = make_decoder(name, rec.layout_mm, rec.fs_hz, **settings)
            estimates, cpu = feed(decoder, rec.t_s, rec.force_n, CHUNKS[0])
            result = score(estimates, recorded)
            result.cpu_us = {CHUNKS[0]: cpu}
            scores.setdefault(name, {})[kind] = result
    return {"scene": signals.name, "scores": scores}


def scene_path(
    paths: Sequence, controllers_for, decoders: dict[str, dict], workers: int = 2
) -> dict:
    """The shipped non-stationary scenes through the skin node and CAN (and skin.csv): figures."""
    if not paths:
        return {"scenes": []}
    workers = max(1, min(workers, 2, os.cpu_count() or 1, len(paths)))
    warm = signals(quick=True)[0]
    with ProcessPoolExecutor(
        workers,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=warm_worker,
        initargs=(warm, decoders),
    ) as pool:
        jobs = [pool.submit(scene_job, str(p), controllers_for, decoders) for p in paths]
        done = [job.result() for job in jobs]
    return {
        "scenes": [d["scene"] for d in done],
        "figures": {
            name: {
                kind: summarise([d["scores"][name][kind] for d in done]) for kind in ("can", "csv")
            }
            for name in decoders
        },
        "per_scene": {
            d["scene"]: {
                name: {kind: summarise([d["scores"][name][kind]]) for kind in ("can", "csv")}
                for name in decoders
            }
            for d in done
        },
    }


# -- figures ------------------------------------------------------------------------------


def summarise(scores: Sequence[Score]) -> dict:
    """Pooled figures of a set of scores (every update of every signal counts once)."""

    def cat(name):
        parts = [getattr(s, name) for s in scores]
        return np.concatenate(parts) if parts else np.zeros(0)

    rel, mag, interval, pos = (
        cat(n) for n in ("speed_rel_err", "speed_mag_err", "speed_interval_err", "position_err_mm")
    )
    scored = sum(s.scored for s in scores)
    directed = sum(s.directed for s in scores)
    right = sum((s.confidence_right for s in scores), np.zeros(5, int))
    total = sum((s.confidence_total for s in scores), np.zeros(5, int))
    clears = np.array([c for s in scores for c in s.clear_s])
    on_skin = np.array([c for s in scores for c in s.stop_on_skin], bool)
    positions = sum(s.positions for s in scores)
    rest = sum(s.rest_updates for s in scores)
    cost = {}
    for chunk in CHUNKS:
        measured = [s for s in scores if chunk in s.cpu_us]
        samples = sum(s.samples for s in measured)
        cost[chunk] = (
            sum(s.cpu_us[chunk] * s.samples for s in measured) / samples if samples else None
        )
    return {
        "signals": len(scores),
        "speed_median_pct": _pct(rel, 50),
        "speed_p90_pct": _pct(rel, 90),
        "speed_magnitude_median_pct": _pct(mag, 50),
        "speed_vs_last_interval_median_pct": _pct(interval, 50),
        "position_median_mm": _q(pos, 50),
        "position_p90_mm": _q(pos, 90),
        "missing_pct": 100.0 * sum(s.missing for s in scores) / scored if scored else None,
        "wrong_direction_pct": 100.0 * sum(s.wrong_direction for s in scores) / directed
        if directed
        else None,
        "confident_share_pct": 100.0 * total[-1] / directed if directed else None,
        "confident_right_pct": 100.0 * right[-1] / total[-1] if total[-1] else None,
        "confidence_bins": [
            {
                "from": CONFIDENCE_BINS[i],
                "estimates": int(total[i]),
                "right_pct": 100.0 * right[i] / total[i] if total[i] else None,
            }
            for i in range(5)
        ],
        "off_skin_pct": 100.0 * sum(s.off_skin for s in scores) / positions if positions else None,
        "stops": len(clears),
        "cleared_in_time_pct": 100.0 * float(np.mean(clears <= CLEAR_WITHIN_S))
        if len(clears)
        else None,
        "stops_on_skin": int(on_skin.sum()),
        "cleared_in_time_on_skin_pct": 100.0 * float(np.mean(clears[on_skin] <= CLEAR_WITHIN_S))
        if on_skin.any()
        else None,
        "clear_median_s": _q(clears, 50, method="higher"),  # a stop not cleared is inf
        "clear_p90_s": _q(clears, 90, method="higher"),
        "false_slip_pct": 100.0 * sum(s.false_slip for s in scores) / rest if rest else None,
        "cpu_us_per_sample_3": cost[3],
        "cpu_us_per_sample_256": cost[256],
        "chunk_variant_signals": sum(1 for s in scores if not s.chunk_invariant),
    }


def aggregate(done: list[dict], decoders: dict) -> dict:
    """Per decoder: figures per category and overall (asymmetric layouts), per layout."""
    asym = [d for d in done if d["signal"].layout not in SYMMETRIC]
    layouts = list(dict.fromkeys(d["signal"].layout for d in done))
    out: dict = {"categories": {}, "overall": {}, "per_layout": {}, "per_variant": {}}
    for name in decoders:

        def pick(items, name=name):
            return [d["scores"][name] for d in items]

        out["categories"][name] = {
            c: summarise(pick([d for d in asym if d["signal"].category == c])) for c in CATEGORIES
        }
        out["overall"][name] = summarise(pick([d for d in asym if d["signal"].category in MOVING]))
        out["per_layout"][name] = {
            layout: summarise(pick([d for d in done if d["signal"].layout == layout]))
            for layout in layouts
        }
        variants: dict = {}
        for d in asym:
            s = d["signal"]
            variants.setdefault(f"{s.category} | {s.variant}", []).append(d["scores"][name])
        out["per_variant"][name] = {k: summarise(v) for k, v in variants.items()}
    out["layouts"] = layouts
    out["asymmetric_layouts"] = [x for x in layouts if x not in SYMMETRIC]
    return out


def _pct(values: np.ndarray, q: float) -> float | None:
    return float(100 * np.percentile(values, q)) if len(values) else None


def _q(
    values: np.ndarray, q: float, method: Literal["linear", "higher"] = "linear"
) -> float | None:
    """The q-th percentile; None when there is none or it is infinite (never cleared)."""
    if not len(values):
        return None
    value = float(np.percentile(values, q, method=method))
    return value if np.isfinite(value) else None


# -- targets and tables ---------------------------------------------------------------------

#: The issue's targets for the default decoder: (label, where, figure, bound, kind).
TARGETS: list[tuple[str, str, str, float, str]] = [
    ("speed error median, accelerating", "accelerating", "speed_median_pct", 8.0, "max"),
    ("speed error median, decelerating", "decelerating", "speed_median_pct", 8.0, "max"),
    ("speed error median, stick-slip", "stick-slip", "speed_median_pct", 8.0, "max"),
    ("speed error median, reversals", "reversal", "speed_median_pct", 15.0, "max"),
    ("wrong direction, all estimates", "overall", "wrong_direction_pct", 5.0, "max"),
    ("stops with the flag cleared within 0.3 s", "overall", "cleared_in_time_pct", 95.0, "min"),
    ("missing estimates at 10 dB SNR", "snr10", "missing_pct", 20.0, "max"),
    ("false slip on grip changes without slip", "grip-no-slip", "false_slip_pct", 0.0, "max"),
    ("confidence >= 0.8: right direction", "overall", "confident_right_pct", 95.0, "min"),
    ("CPU per sample at 3-sample chunks (µs)", "overall", "cpu_us_per_sample_3", 50.0, "max"),
]
#: "No regression on the constant-speed table": the synthetic target set against the last run.
#: Every figure of the target-set table (lower is better), with its label.
CONSTANT_FIGURES = {
    "speed_median_pct": "speed med %",
    "speed_p90_pct": "speed p90 %",
    "position_median_mm": "pos med mm",
    "position_p90_mm": "pos p90 mm",
    "missing_pct": "missing %",
    "slip_flag_intervals": "slip flag (intervals)",
    "first_good_ratio": "first good / limit",
    "false_slip_pct": "false slip % (static grip steps)",
}


#: Under the targets when a no-regression row is "no": that flag compares with the run the
#: page replaces, so a step traded on purpose shows until the next run; where it is told.
REGRESSION_NOTE = (
    "A **no** in the no-regression rows compares with the previous run only: "
    'docs/decoding.md, "No-regression flags of the constant-speed set", names each commit '
    "that moved that set and what it traded; `benchmarks/constant_target_table.py TREE` "
    "measures the set alone for any checkout (`--bisect` finds the commit)."
)


def target_rows(results: dict, default: str, before: dict | None, now: dict | None) -> list:
    """(label, figure, bound text, met) for the default decoder; None = not measured."""
    rows: list[tuple[str, Any, str, bool | None]] = []
    for label, where, key, bound, kind in TARGETS:
        block = results["overall" if where == "overall" else "categories"].get(default, {})
        figures = block if where == "overall" else block.get(where, {})
        value = figures.get(key)
        met = None if value is None else (value <= bound if kind == "max" else value >= bound)
        rows.append((label, value, f"{'≤' if kind == 'max' else '≥'} {bound:g}", met))
    for key, name in CONSTANT_FIGURES.items():
        old = (before or {}).get(key)
        new = (now or {}).get(key)
        met = None if old is None or new is None else round(new, 2) <= round(old, 2)
        last = f"≤ {old:.2f} (last run)" if old is not None else "≤ last run (none found)"
        rows.append((f"no regression, constant-speed target set: {name}", new, last, met))
    return rows


def _fmt(value, digits: int = 1) -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}f}" if isinstance(value, float) else str(value)


def _cleared(f: dict) -> str:
    if not f.get("stops"):
        return "-"
    return f"{_fmt(f['cleared_in_time_pct'], 0)} / {_fmt(f.get('cleared_in_time_on_skin_pct'), 0)}"


def _clear_p90(f: dict) -> str:
    if not f.get("stops"):
        return "-"
    return "never" if f.get("clear_p90_s") is None else _fmt(f["clear_p90_s"], 2)


def _confidence(f: dict) -> str:
    return f"{_fmt(f.get('confident_right_pct'), 0)} ({_fmt(f.get('confident_share_pct'), 0)})"


def _cost(f: dict) -> str:
    return f"{_fmt(f.get('cpu_us_per_sample_3'))} / {_fmt(f.get('cpu_us_per_sample_256'))}"


MOVING_HEADER = (
    "| decoder | speed med % | speed p90 % | wrong dir % | pos med mm | pos p90 mm | "
    "off skin % | missing % | stops cleared ≤ 0.3 s %: all / on skin | clear p90 s | "
    "conf ≥ 0.8: right dir % (share %) | false slip at rest % | µs/sample 3 / 256 |"
)


def _moving_row(name: str, f: dict) -> str:
    return (
        f"| {name} | {_fmt(f.get('speed_median_pct'))} | {_fmt(f.get('speed_p90_pct'))} | "
        f"{_fmt(f.get('wrong_direction_pct'))} | {_fmt(f.get('position_median_mm'))} | "
        f"{_fmt(f.get('position_p90_mm'))} | {_fmt(f.get('off_skin_pct'))} | "
        f"{_fmt(f.get('missing_pct'))} | {_cleared(f)} | {_clear_p90(f)} | "
        f"{_confidence(f)} | {_fmt(f.get('false_slip_pct'))} | {_cost(f)} |"
    )


PLOT_NAME = "decoding_nonstationary.png"


def _bound(where: str, key: str) -> float:
    """A target's bound, from TARGETS (the table and the plot say the same)."""
    return next(bound for _, w, k, bound, _ in TARGETS if w == where and k == key)


def _not_cleared(figures: dict) -> float | None:
    cleared = figures.get("cleared_in_time_pct")
    return None if cleared is None else 100.0 - cleared


def plot(results: dict, default: str, path: Any) -> None:
    """Left: what accuracy costs in time on the moving categories (speed error median and
    wrong direction against CPU per sample at 3-sample chunks), every decoder. Right: the
    default decoder per category - speed error median, wrong direction, stops not cleared
    within 0.3 s, missing estimates - beside the issue's bounds."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (cost_ax, cat_ax) = plt.subplots(1, 2, figsize=(13, 5), dpi=100)
    for index, (name, figures) in enumerate(results["overall"].items()):
        cost = figures.get("cpu_us_per_sample_3")
        for key, marker in (("speed_median_pct", "o"), ("wrong_direction_pct", "x")):
            value = figures.get(key)
            if cost is None or value is None:
                continue
            shown = max(value, 0.05)  # 0 % on a log axis
            cost_ax.scatter(cost, shown, marker=marker, s=40, color=f"C{index % 10}")
            if marker == "o":
                cost_ax.annotate(
                    name, (cost, shown), xytext=(5, 4), textcoords="offset points", fontsize=8
                )
    budget_us = _bound("overall", "cpu_us_per_sample_3")
    speed_pct = _bound("accelerating", "speed_median_pct")
    direction_pct = _bound("overall", "wrong_direction_pct")
    budget_label = f"cost budget {budget_us:g} µs/sample"
    cost_ax.axvline(budget_us, color="red", lw=0.8, ls=":", label=budget_label)
    speed_label = f"speed median bound {speed_pct:g} %"
    cost_ax.axhline(speed_pct, color="green", lw=0.8, ls=":", label=speed_label)
    direction_label = f"wrong direction bound {direction_pct:g} %"
    cost_ax.axhline(direction_pct, color="purple", lw=0.8, ls="--", label=direction_label)
    cost_ax.scatter([], [], marker="o", color="grey", label="speed error median %")
    cost_ax.scatter([], [], marker="x", color="grey", label="wrong direction %")
    cost_ax.set_xscale("log")
    cost_ax.set_yscale("log")
    cost_ax.set_xlabel("CPU per sample [µs] at 3-sample chunks (this machine)")
    cost_ax.set_ylabel("% over the moving categories (asymmetric layouts)")
    cost_ax.set_title("What accuracy costs in time: non-stationary slips")
    cost_ax.grid(alpha=0.3, which="both")
    cost_ax.legend(fontsize=7)

    categories = [c for c in MOVING if c in results["categories"][default]]
    per = results["categories"][default]
    series = (
        ("speed error median %", lambda f: f.get("speed_median_pct")),
        ("wrong direction %", lambda f: f.get("wrong_direction_pct")),
        ("stops not cleared in 0.3 s %", _not_cleared),
        ("missing estimates %", lambda f: f.get("missing_pct")),
    )
    width = 0.8 / len(series)
    x = np.arange(len(categories))
    for i, (label, get) in enumerate(series):
        values = [get(per[c]) for c in categories]
        heights = [np.nan if v is None else v for v in values]
        cat_ax.bar(x + (i - (len(series) - 1) / 2) * width, heights, width, label=label)
    not_cleared_pct = 100.0 - _bound("overall", "cleared_in_time_pct")
    missing_pct = _bound("snr10", "missing_pct")
    bounds = [(speed_pct, f"speed bound {speed_pct:g} %", "green")]
    if not_cleared_pct == direction_pct:  # one line where the two bounds agree
        bounds.append((direction_pct, f"stops / direction bound {direction_pct:g} %", "purple"))
    else:
        bounds.append((direction_pct, f"direction bound {direction_pct:g} %", "purple"))
        bounds.append((not_cleared_pct, f"stops bound {not_cleared_pct:g} %", "orange"))
    bounds.append((missing_pct, f"missing at 10 dB bound {missing_pct:g} %", "grey"))
    for bound, label, color in bounds:
        cat_ax.axhline(bound, color=color, lw=0.8, ls=":", label=label)
    cat_ax.set_xticks(x, categories, rotation=35, ha="right", fontsize=8)
    cat_ax.set_ylim(0, 100)
    cat_ax.set_ylabel("%")
    cat_ax.set_title(f"`{default}` per category (bounds: see the Targets table)")
    cat_ax.legend(fontsize=7, ncol=2)
    cat_ax.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def render(results: dict, default: str, before: dict | None, now: dict | None) -> list[str]:
    """The "Non-stationary slips" section of decoding.md."""
    decoders = list(results["overall"])
    asym = ", ".join(results["asymmetric_layouts"])
    lines = [
        "## Non-stationary slips",
        "",
        "Slips that speed up, slow down, stop, restart and reverse, start with the object",
        "already on the skin, or meet grip steps, saturation, 10 dB noise, other rates and",
        "lost samples; and grip changes without slip (`grasplink/evaluation/nonstationary.py`,",
        f"{results['signals']} signals: "
        + (
            "each category's first variant, forward on alpha0.1 and reverse on fibonacci, one seed"
            if results["quick"]
            else f"every category's variants on {', '.join(results['layouts'])}, both "
            f"directions, {SEEDS} seeds"
        )
        + "). Every decoder at its default settings, fed 3 samples at a time (one skin",
        "TPDO1) and scored on that output; the same signals fed in 256-sample chunks give",
        "the second cost figure. Truth is compared at each update's time; speed and",
        "position are scored from each motion's physical limit (3 contacts after the slip",
        "starts or reverses, 2 after a restart; a speed without a direction is a speed);",
        f"*wrong dir*: share of told directions that are wrong while the object moves at ≥ "
        f"{V_DIRECTION_MM_S:g} mm/s;",
        f"*stops cleared*: stops (≥ {STOP_MIN_S:g} s below {V_MOVING_MM_S:g} mm/s) whose slip",
        f"flag cleared within {CLEAR_WITHIN_S:g} s, all and those with the leading edge over",
        "the skin; *false slip at rest*: updates flagged slip 0.3 s or more into a rest.",
        'Definitions: docs/decoding.md, "Non-stationary slips". Tables pool the',
        f"asymmetric layouts ({asym}); uniform4 (direction unobservable) is in the per-layout",
        f"table. µs/sample measured in {results['workers']} worker processes at once.",
        "",
        f"### Targets (default decoder `{default}`)",
        "",
        "| target | figure | bound | met |",
        "|---|---:|---|---|",
    ]
    regressed = False
    for label, value, bound, met in target_rows(results, default, before, now):
        mark = "-" if met is None else ("yes" if met else "**no**")
        digits = 2 if label.startswith("no regression") else 1  # as its bound
        lines.append(f"| {label} | {_fmt(value, digits)} | {bound} | {mark} |")
        regressed |= label.startswith("no regression") and met is False
    if regressed:  # a step against the last run only: say where its cause is told
        lines += ["", REGRESSION_NOTE]
    lines += [
        "",
        f"![Non-stationary slips: accuracy against cost per decoder, and `{default}` per "
        f"category against its targets]({PLOT_NAME})",
    ]
    lines += ["", "### All moving categories", "", MOVING_HEADER, "|---|" + "---:|" * 12]
    lines += [_moving_row(name, results["overall"][name]) for name in decoders]
    for category, title in CATEGORIES.items():
        if category == "grip-no-slip":
            continue
        count = results["categories"][decoders[0]][category]["signals"]
        lines += ["", f"### {title} ({count} signals)", "", MOVING_HEADER, "|---|" + "---:|" * 12]
        lines += [_moving_row(name, results["categories"][name][category]) for name in decoders]
    count = results["categories"][decoders[0]]["grip-no-slip"]["signals"]
    lines += [
        "",
        f"### {CATEGORIES['grip-no-slip']} ({count} signals)",
        "",
        "Object at rest over all or half of the skin; grip steps 2-5-10-5-2 N, ramps",
        "3-8-3 N in 0.1 s, steps of 0.5 N every 0.4 s.",
        "",
        "| decoder | false slip % | µs/sample 3 / 256 |",
        "|---|---:|---:|",
    ]
    for name in decoders:
        f = results["categories"][name]["grip-no-slip"]
        lines.append(f"| {name} | {_fmt(f.get('false_slip_pct'))} | {_cost(f)} |")
    layouts = results["layouts"]
    lines += [
        "",
        "### Per layout (every category): |speed| error median % / wrong direction %",
        "",
        "| decoder | " + " | ".join(layouts) + " |",
        "|---|" + "---:|" * len(layouts),
    ]
    for name in decoders:
        cells = [
            f"{_fmt(f.get('speed_magnitude_median_pct'))} / {_fmt(f.get('wrong_direction_pct'))}"
            for f in (results["per_layout"][name][x] for x in layouts)
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    per_variant = results["per_variant"].get(default, {})
    lines += [
        "",
        f"### `{default}` per variant ({asym})",
        "",
        "| category | variant | speed med % | speed p90 % | vs last interval med % | "
        "wrong dir % | missing % | stops cleared ≤ 0.3 s % | false slip at rest % |",
        "|---|---|" + "---:|" * 7,
    ]
    for key, f in per_variant.items():
        category, variant = key.split(" | ", 1)
        lines.append(
            f"| {category} | {variant} | {_fmt(f.get('speed_median_pct'))} | "
            f"{_fmt(f.get('speed_p90_pct'))} | "
            f"{_fmt(f.get('speed_vs_last_interval_median_pct'))} | "
            f"{_fmt(f.get('wrong_direction_pct'))} | {_fmt(f.get('missing_pct'))} | "
            f"{_fmt(f.get('cleared_in_time_pct'), 0)} | {_fmt(f.get('false_slip_pct'))} |"
        )
    lines += render_scenes(results.get("scenes", {}), default)
    variant = sum(
        f.get("chunk_variant_signals", 0)
        for by_layout in results["per_layout"].values()
        for f in by_layout.values()
    )
    lines += [
        "",
        "Chunking: "
        + (
            "every decoder gave the same estimates in 3- and 256-sample chunks."
            if not variant
            else f"{variant} signal(s) decoded differently in 3- and 256-sample chunks "
            "(`chunk_variant_signals` in decoding.json)."
        ),
        "",
    ]
    return lines


def render_scenes(scenes: dict, default: str) -> list[str]:
    """The shipped non-stationary scenes through CAN, beside their skin.csv."""
    if not scenes.get("scenes"):
        return []
    lines = [
        "",
        f"### Shipped scenes through CAN ({len(scenes['scenes'])} `scenes/{SCENES}`)",
        "",
        "Each scene run as `grasplink run` does; its CAN log decoded as `grasplink decode",
        "R/can.asc` does (12-bit ADC, 3 samples per TPDO1, the node's timing), beside the",
        "same run's skin.csv; fed 3 samples at a time, scored as above (all scenes pooled).",
        "",
        "| decoder | signal | speed med % | speed p90 % | wrong dir % | pos p90 mm | "
        "missing % | stops cleared ≤ 0.3 s % | false slip at rest % |",
        "|---|---|" + "---:|" * 7,
    ]
    for name, by_kind in scenes["figures"].items():
        for kind, label in (("can", "CAN (can.asc)"), ("csv", "skin.csv")):
            f = by_kind[kind]
            lines.append(
                f"| {name} | {label} | {_fmt(f.get('speed_median_pct'))} | "
                f"{_fmt(f.get('speed_p90_pct'))} | {_fmt(f.get('wrong_direction_pct'))} | "
                f"{_fmt(f.get('position_p90_mm'))} | {_fmt(f.get('missing_pct'))} | "
                f"{_fmt(f.get('cleared_in_time_pct'), 0)} | {_fmt(f.get('false_slip_pct'))} |"
            )
    lines += [
        "",
        f"`{default}` per scene, CAN / skin.csv: speed median % · wrong direction %",
        "",
        "| scene | speed med % | wrong dir % |",
        "|---|---:|---:|",
    ]
    for scene, by_name in scenes["per_scene"].items():
        f = by_name.get(default)
        if f is None:
            continue
        cells = [
            " / ".join(_fmt(f[kind].get(key)) for kind in ("can", "csv"))
            for key in ("speed_median_pct", "wrong_direction_pct")
        ]
        lines.append(f"| {scene} | " + " | ".join(cells) + " |")
    return lines

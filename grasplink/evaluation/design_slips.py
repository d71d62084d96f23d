"""The slips a candidate skin is judged on, and how one decoded slip is scored.

The thesis scored a layout (ch. 5.3.3) by starting a slip at every ridge that has two more
after it, at every speed of 10-100 mm/s in 5 mm/s steps, and counting a hit when the
decoder told the position within 1/10 of the skin under the three peaks and the speed
within 1/10. Here the same grid is the *design space* of slips - start ridge, speed, both
directions - with three harder kinds beside the constant slip: accelerating, stick-slip
and noisy. A search cannot afford the whole grid per candidate (hundreds of slips), so
`plan_slips` draws a fixed number of them; the plan (kind, speed, direction, where on the
skin) is the same for every candidate of a run (common random numbers: candidates differ
by their skin, not by their luck), while the physics noise is seeded per candidate
(`workers.derive_seed` of the run's seed, the spacings and the slip's index).

Signals come from `synth.scripted_recording` (the skin's effects only: FSR model, ridge
pulses, noise, drift), built with `nonstationary.Script`, the benchmark's speed profiles.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from grasplink.evaluation.decoders import make_decoder
from grasplink.evaluation.nonstationary import SNR_DB, START_S, STOP_S, Script, pulse_height_n
from grasplink.evaluation.workers import derive_seed
from grasplink.simulators.synth import scripted_recording

KINDS = ("constant", "accelerating", "stick-slip", "noisy")
FS_HZ = 400  # the skin node's default rate (ch. 5)
CHUNK = 256  # samples per feed (the estimates do not depend on it)
LEAD_MM = 2.0  # the edge starts this far before the first ridge it meets (spacings >= 3 mm)
ONSET_S = 0.3  # at rest before the slip: the decoder's filters settle
DECIDE_S = 0.17  # the tracker's longest decision delay (slip_reporting.DETECT_ALLOWANCE_S)
TAIL_S = 0.35  # on at speed after the third contact: the decision, then 0.18 s of answers
REST_S = 0.2  # at rest at the end
ACCEL = 1.4  # accelerating: from v / ACCEL at the first ridge to v * ACCEL at the third
STICK_S = (0.2, 0.5)  # stick-slip: one stop this long between the second and third ridge
GOOD_SPEED = 0.10  # a hit: speed within 1/10 of the speed (ch. 5.3.3) ...
GOOD_POSITION = 0.10  # ... and position within 1/10 of the skin under the three peaks
SPEED_ERROR_CAP = 1.0  # a missing speed counts as 100 % wrong
OBJECT_MM = 90.0  # the thesis object's long side (ch. 5.4)


@dataclass(frozen=True)
class SlipPlan:
    """One slip of a plan: kind, speed (mm/s), direction, where it starts (0..1 of the
    start ridges a layout has: the same share on every candidate) and how far before that
    ridge the edge starts (mm, below the 3 mm shortest spacing)."""

    kind: str
    speed_mm_s: float
    reverse: bool
    start_share: float
    lead_mm: float = LEAD_MM


@dataclass(frozen=True)
class SlipScore:
    """One decoded slip: hit share, median speed error (share) and position error (mm) over
    the decoder's updates from a decision's time after the third ridge contact while the
    object slips."""

    hits: float
    speed_error: float
    position_error_mm: float
    updates: int
    samples: int


def plan_slips(
    count: int,
    speeds_mm_s: Sequence[float],
    seed: int,
    kinds: Sequence[str] = KINDS,
    leads_mm: tuple[float, float] | None = None,
) -> tuple[SlipPlan, ...]:
    """`count` slips: kinds and directions in turn, speeds and start shares drawn at random.

    Kinds and directions alternate so that every plan of 2 * len(kinds) slips or more has
    each kind both ways; speeds cycle through a shuffled grid so a plan as long as the grid
    covers every speed. `leads_mm` (low, high): the edge's start before its first ridge is
    drawn from it (a validation set's other start positions), else LEAD_MM.
    """
    rng = np.random.default_rng(derive_seed(seed, "plan", count, tuple(speeds_mm_s)))
    speeds: list[float] = []
    out = []
    for i in range(count):
        if not speeds:
            speeds = [float(v) for v in rng.permutation(np.asarray(speeds_mm_s, dtype=float))]
        kind = kinds[i % len(kinds)]
        reverse = bool((i // len(kinds)) % 2)
        share = float(rng.random())
        lead = LEAD_MM if leads_mm is None else float(rng.uniform(*leads_mm))
        out.append(SlipPlan(kind, speeds.pop(), reverse, share, lead))
    return tuple(out)


def full_plan(speeds_mm_s: Sequence[float], starts: int, kinds: Sequence[str] = KINDS) -> tuple:
    """The thesis's grid: every kind, speed, direction and start ridge (`starts` of them)."""
    return tuple(
        SlipPlan(kind, float(v), reverse, (k + 0.5) / starts)
        for kind in kinds
        for v in speeds_mm_s
        for reverse in (False, True)
        for k in range(starts)
    )


def start_ridges(spacings_mm: Sequence[float]) -> int:
    """How many ridges have two more after them (either way: the same count)."""
    return len(spacings_mm) - 1


def score_layout(
    spacings_mm: Sequence[float],
    plan: Sequence[SlipPlan],
    decoder: str,
    seed: int,
) -> list[SlipScore]:
    """Every slip of `plan` over the skin, decoded by `decoder` and scored."""
    layout = tuple(float(s) for s in spacings_mm)
    return [
        score_slip(layout, slip, decoder, derive_seed(seed, layout, i))
        for i, slip in enumerate(plan)
    ]


def score_slip(layout: tuple[float, ...], slip: SlipPlan, decoder: str, seed: int) -> SlipScore:
    rec, first = simulate(layout, slip, seed)
    est = []
    dec = make_decoder(decoder, layout, FS_HZ)
    for start in range(0, len(rec.t_s), CHUNK):
        est += dec.feed(rec.t_s[start : start + CHUNK], rec.force_n[start : start + CHUNK])
    contacts = rec.contact_times_s
    skin = float(sum(layout))
    if len(contacts) < 3:  # the physics lost a contact: nothing a decoder can be judged on
        return SlipScore(0.0, SPEED_ERROR_CAP, skin / 2, 0, len(rec.t_s))
    t = np.array([e.t_s for e in est]) if est else np.zeros(0)
    slipping = np.interp(t, rec.t_s, rec.slipping) > 0.5
    scored = slipping & (t >= contacts[2] + DECIDE_S)
    if not scored.any():
        return SlipScore(0.0, SPEED_ERROR_CAP, skin / 2, 0, len(rec.t_s))
    v_true = np.abs(np.interp(t[scored], rec.t_s, rec.speed_mm_s))
    x_true = np.interp(t[scored], rec.t_s, rec.position_mm)
    chosen = [e for e, s in zip(est, scored, strict=True) if s]
    v = np.array([math.nan if e.speed_mm_s is None else e.speed_mm_s for e in chosen])
    x = np.array([math.nan if e.position_mm is None else e.position_mm for e in chosen])
    v_err = np.abs(v - v_true) / np.maximum(v_true, 1e-9)
    x_err = np.abs(x - x_true)
    under = _under_three_peaks(layout, first, slip.reverse)
    hit = (v_err <= GOOD_SPEED) & (x_err <= GOOD_POSITION * under)  # NaN: no hit
    return SlipScore(
        hits=float(hit.mean()),
        speed_error=float(
            np.median(np.where(np.isfinite(v_err), v_err, SPEED_ERROR_CAP).clip(0, SPEED_ERROR_CAP))
        ),
        position_error_mm=float(
            np.median(np.where(np.isfinite(x_err), x_err, skin / 2).clip(0, skin / 2))
        ),
        updates=int(scored.sum()),
        samples=len(rec.t_s),
    )


def simulate(layout: tuple[float, ...], slip: SlipPlan, seed: int):
    """The slip's recording and the index of the first ridge it meets (in travel order)."""
    ridges = np.concatenate([[0.0], np.cumsum(layout)])
    skin = float(ridges[-1])
    along = skin - ridges[::-1] if slip.reverse else ridges  # ridges along the travel
    first = min(int(slip.start_share * start_ridges(layout)), start_ridges(layout) - 1)
    start_u = along[first] - slip.lead_mm
    third_u = along[first + 2]
    rng = np.random.default_rng(seed)
    v = slip.speed_mm_s
    extra: dict = {}
    if slip.kind == "accelerating":
        script = Script(ONSET_S).ramp(v / ACCEL, START_S).reach(slip.lead_mm)
        script.reach(third_u - start_u, v * ACCEL)
    elif slip.kind == "stick-slip":
        script = Script(ONSET_S).ramp(v, START_S)
        at = (
            along[first + 1]
            - start_u
            + float(rng.uniform(0.3, 0.7)) * (along[first + 2] - along[first + 1])
        )
        script.reach(at - 0.5 * v * STOP_S).ramp(0.0, STOP_S)
        script.hold(float(rng.uniform(*STICK_S))).ramp(v, START_S)
        script.reach(third_u - start_u)
    elif slip.kind in ("constant", "noisy"):
        script = Script(ONSET_S).ramp(v, START_S).reach(third_u - start_u)
        if slip.kind == "noisy":  # the benchmark's snr10: 10 dB below the pulses, with drift
            height = pulse_height_n(layout)
            extra = {
                "white_n": height / 10 ** (SNR_DB / 20),
                "drift_n": height,
                "drift_corner_hz": 0.2,
            }
    else:
        raise ValueError(f"unknown slip kind {slip.kind!r}; valid: {', '.join(KINDS)}")
    script.hold(TAIL_S).ramp(0.0, STOP_S).hold(REST_S)
    sign = -1.0 if slip.reverse else 1.0
    rec = scripted_recording(
        layout,
        script.signed(sign),
        start_mm=skin - start_u if slip.reverse else start_u,
        duration_s=script.t_s,
        fs_hz=FS_HZ,
        object_length_mm=OBJECT_MM,
        seed=seed % (2**32),
        **extra,
    )
    return rec, first


def _under_three_peaks(layout: tuple[float, ...], first: int, reverse: bool) -> float:
    """The skin between the first and the third ridge met (ch. 5.3.3's position tolerance)."""
    along = layout[::-1] if reverse else layout
    return float(along[first] + along[first + 1])


def summarise(scores: Sequence[SlipScore]) -> dict[str, float]:
    """A layout's figures over its slips: accuracy (mean hit share, the thesis's A), mean
    speed error (%) and mean position error (mm), and the samples simulated."""
    return {
        "accuracy": float(np.mean([s.hits for s in scores])),
        "speed_error_pct": 100.0 * float(np.mean([s.speed_error for s in scores])),
        "position_error_mm": float(np.mean([s.position_error_mm for s in scores])),
        "samples": float(sum(s.samples for s in scores)),
    }

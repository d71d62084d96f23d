"""The silence bound on "slip dropped" (issue 22): how much of the slide any decoder that
reads stops from silence and meets the stop target must report as stopped.

Why: "slip flag down while the object slides <= 1 %" has resisted many sessions, while
"stops cleared within 0.15 s of observable >= 95 %" must hold. A decoder reads a stop
from silence - the next ridge contact due and absent. Up to the moment a stop becomes
observable, a stopped object and one that only slowed (a speed dip, deceleration, the
turn of a reversal, the loop's hysteresis, a ridge the detector misses) leave the same
contact history. So for every update, place a counterfactual stop just after the last
contact known by then: its observable moment follows `slip_reporting.stop_observable_s`
(the speed before it the fastest truth of the 0.2 s before, the next ridge ahead), and a
decoder that clears that stop in time must have the flag down from the last update at or
before its observable moment + `CLEAR_WITHIN_S` (`score` judges the first clean update
against that). Where the true object still slides there, the decoder drops the flag in
the look-alike slide too: the update is *silent past due*. The share of "slip dropped"'s
scored updates that are silent past due is the bound (`score` itself counts it, fed the
silence decoder's flags: `silence_estimates`).

A decoder may read other evidence than contacts: the FSR level moves while the object
covers more or less of the skin (`decoding/level_ramp.py`). `motion_level_move_n` gives,
per update, the noise-free level's move over the preceding window that the object's own
motion made (the grip held at today's: a grip change is no slip evidence, and the loop's
decoder knows its grip commands).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from grasplink.decoding.base import SlipEstimate
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
from grasplink.simulators import harness
from grasplink.simulators import signals as sig
from grasplink.simulators.effects import skin
from grasplink.simulators.effects.actuators import G_M_S2
from grasplink.simulators.synth import LOAD_KG, SkinRecording

AFTER_CONTACT_S = 1e-4  # the counterfactual stop starts this soon after the contact
LEVEL_WINDOW_S = 0.25  # the level's move is read over this time before the update
LEVEL_SIGMAS = 3.0  # ... and counts as evidence beyond this many white-noise sigmas


def run_signs(truth: SkinRecording, times_s: np.ndarray) -> np.ndarray:
    """The sign of the motion run (`nonstationary.motion`) each time falls in; 0 outside."""
    out = np.zeros(len(times_s), int)
    for start, end, sign in ns.motion(truth).runs:
        out[(times_s >= start) & (times_s < end)] = sign
    return out


def stop_due_s(truth: SkinRecording, contact_s: np.ndarray) -> np.ndarray:
    """Per contact: when the report of a stop right after it would be due - its observable
    moment (`stop_observable_s`, the stop placed `AFTER_CONTACT_S` after the contact) +
    `CLEAR_WITHIN_S`; nan where no such stop is judged (no ridge ahead, no motion)."""
    contact_s = np.asarray(contact_s, dtype=float)
    start_s = contact_s + AFTER_CONTACT_S
    signs = run_signs(truth, start_s)
    out = np.full(len(contact_s), np.nan)
    for i, (t, sign) in enumerate(zip(start_s, signs, strict=True)):
        if sign == 0:
            continue
        observable = sr.stop_observable_s(truth, float(t), int(sign))
        if observable is not None:
            out[i] = observable + sr.CLEAR_WITHIN_S
    return out


def last_known(t_upd_s: np.ndarray, contact_s: np.ndarray, known_s: np.ndarray) -> np.ndarray:
    """Per update: the index of the latest contact (by its own time) known by then
    (`known_s`: when the decoder learns of it - the contact itself for a perfect detector,
    later with a latency); -1 where none is."""
    contact_s = np.asarray(contact_s, dtype=float)
    if not len(contact_s):
        return np.full(len(t_upd_s), -1)
    known = np.asarray(known_s, dtype=float)[None, :] <= np.asarray(t_upd_s)[:, None]
    latest = np.where(known, contact_s[None, :], -np.inf)
    return np.where(known.any(axis=1), np.argmax(latest, axis=1), -1)


def silent_down(
    t_upd_s: np.ndarray,
    contact_s: np.ndarray,
    known_s: np.ndarray,
    due_s: np.ndarray,
    wait_s: float = 0.0,
) -> np.ndarray:
    """Per update: the silence decoder's flag down - the report of a stop right after the
    last known contact is due (`due_s`, plus `wait_s`) no later than the next update, so
    a decoder whose first clean update must come by then drops it here at the latest.
    The last update takes the median update period as its next."""
    t = np.asarray(t_upd_s, dtype=float)
    if not len(t) or not len(contact_s):
        return np.zeros(len(t), bool)
    period = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    t_next = np.append(t[1:], t[-1] + period)
    j = last_known(t, contact_s, known_s)
    due = np.where(j >= 0, np.asarray(due_s, dtype=float)[np.maximum(j, 0)], np.nan)
    with np.errstate(invalid="ignore"):
        return (j >= 0) & np.isfinite(due) & (t_next > due + wait_s)


def silence_estimates(t_upd_s: np.ndarray, flag: np.ndarray) -> list[SlipEstimate]:
    """Updates carrying only a slip flag (no speed): what `score` judges a flag by."""
    return [
        SlipEstimate(float(t), bool(f), None, None, None, 0.0)
        for t, f in zip(t_upd_s, flag, strict=True)
    ]


def dropped_where(t_upd_s: np.ndarray, down: np.ndarray, truth: SkinRecording) -> tuple[int, int]:
    """(`score`'s slip-dropped count with the flag down exactly at `down`, its scored
    updates): the denominator is the benchmark's own."""
    s = sr.score(silence_estimates(t_upd_s, ~np.asarray(down, bool)), truth)
    return s.dropped_from2, s.moving_from2


def stops_cleared(t_upd_s: np.ndarray, down: np.ndarray, truth: SkinRecording) -> tuple[int, int]:
    """(judged stops cleared within `CLEAR_WITHIN_S` of observable, judged stops) for a
    decoder whose flag is down exactly at `down` and which never gives a speed."""
    s = sr.score(silence_estimates(t_upd_s, ~np.asarray(down, bool)), truth)
    judged = [x for x in s.stops if x.judged]
    return sum(1 for x in judged if x.delay_s <= sr.CLEAR_WITHIN_S + 1e-9), len(judged)


def motion_level_move_n(
    truth: SkinRecording,
    t_upd_s: np.ndarray,
    object_length_mm: float,
    window_s: float = LEVEL_WINDOW_S,
    load_kg: float = LOAD_KG,
) -> np.ndarray:
    """Per update: |noise-free FSR level now - the level the object had `window_s` before|,
    both at today's grip (`skin.FsrForce` run on the truth's edge, speed and slip state,
    then on the same `window_s` earlier): the move the object's own motion made - its
    coverage of the skin, and a slip starting or stopping. Ridge pulses, hysteresis and
    saturation left out (the pulses are the contacts; the rest only hide a move)."""
    t = truth.t_s
    speed = np.asarray(truth.speed_mm_s, dtype=float)
    moving = speed[speed != 0]
    direction = "reverse" if len(moving) and moving[0] < 0 else "forward"
    past = np.clip(np.searchsorted(t, t - window_s), 0, len(t) - 1)
    times_us = harness.sample_times_us(truth.fs_hz, len(t) / truth.fs_hz)
    levels = []
    for k in (np.arange(len(t)), past):
        ctx = harness.context(seed=0, rate_hz=truth.fs_hz, layout_mm=tuple(truth.layout_mm))
        fsr = harness.make(
            skin.FsrForce, ctx, object_length_mm=object_length_mm, direction=direction
        )
        out = harness.run(
            [fsr],
            times_us,
            {
                sig.HAND_GRIP_N: truth.grip_n,
                sig.LOAD_FORCE_N: np.full(len(t), load_kg * G_M_S2),
                sig.OBJECT_POSITION_MM: truth.position_mm[k],
                sig.OBJECT_SPEED_MM_S: speed[k],
                sig.OBJECT_SLIPPING: truth.slipping[k],
            },
            chunk=4096,
        )
        levels.append(out[sig.SKIN_FORCE_N])
    return np.abs(np.interp(t_upd_s, t, levels[0] - levels[1]))


def white_noise_n(force_n: Sequence[float] | np.ndarray) -> float:
    """The recording's white noise per sample, from its second differences (robust: the
    median absolute one; pulses and steps are rare, drift is slow): std(d2) = sqrt(6) s."""
    d2 = np.diff(np.asarray(force_n, dtype=float), 2)
    if not len(d2):
        return 0.0
    return float(np.median(np.abs(d2)) / 0.6745 / np.sqrt(6.0))

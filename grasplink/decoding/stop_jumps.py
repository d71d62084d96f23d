"""A contact told a pulse that jumped like a stop's step: a ridge only at a speed this fast.

Physics (thesis ch. 4.3): when a slipping object sticks the FSR's level moves from the
sliding level (1 - k mu) W + k P to the resting W within the braking - a jump over
6-10 ms whatever the speed was. A ridge contact's pulse rises while the edge pushes the
ridge over, about a millimetre of travel: its jump lasts ~1 mm / v. A stop often lands
on the falling tail of the last ridge's pulse (the ridge goes on relaxing when the object
stops); the tail then falls on under the jump and the watcher tells it a pulse, and the
tracker took it for the ridge then due: at that time, in the spacings' ratios, with a
pulse's evidence for a slip (`benchmarks/stop_causes.py`, full plan, 1 seed: 11 of 16
stops cleared late had their own contact told a pulse).

So a contact told a pulse whose jump is as fast as a stop's (`fast_jump_s`) is branched
like a step (`TrackerDecoder._branch`: "stopped there" and "a grip change, slipping on"
children besides the ridge ones), and each slipping track is weighed by its own speed v
(`weigh`): a ridge of a track at v rises over v x jump of travel - under
`TrackerDecoder.FAST_JUMP_TRAVEL_MM` (0.8 mm) that track's ridge child is unlikely (a
stop's jump, not its ridge), over it its stop child is (a fast ridge at that speed: the
pulse fell back).
Measured (`benchmarks/contact_jumps.py`, full plan, 1 seed, 9 kinds, at the truth's
speed; the jump to 90 % of the smoothed peak over the level before, its trend carried
to the onset, `step_shape.measure`, on `despiked` samples): the stops' own contacts jump
in 6.2-10 ms (10-90 %) at every speed, 0.26-0.50 mm of travel at 30-60 mm/s (those told
a pulse 0.34-0.50 mm); the ridge contacts told a pulse travel 0.77-1.26 mm over their
jump at 30-60 mm/s, 0.90 mm and more above (10 %). Above ~80 mm/s a stop's jump spans
a ridge's travel: no shape tells them apart there, and `weigh` leaves such tracks'
ridge children alone. A ridge at 30-60 mm/s jumps in 16 ms or more (10 %): over
`FAST_RISE_S`, never weighed.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from grasplink.decoding.detector import step_shape
from grasplink.decoding.kernels.layout import F_SCORE, F_STOP, F_V, I_LAST, I_N, I_RUN

# the window a pulse's jump is read in: its onset to this long after (its verdict no later)
WINDOW_S = 0.06
# the samples read before the onset (`step_shape.measure`'s noise and level: 0.15 s)
LEAD_S = 0.2
# a stop's jump is over within `step_shape.FAST_RISE_S` (or its samples at a slow rate)
# and stands at least this many white-noise units over the level before (its trend
# carried): smaller jumps' timing is the noise's
JUMP_SNR_MIN = 4.0


def despiked(x: np.ndarray) -> np.ndarray:
    """x with every sample replaced by the median of it and its two neighbours (the ends
    kept): a one-sample spike goes, a jump that stays (a stop's) keeps its sample."""
    out = x.copy()
    if len(x) >= 3:
        out[1:-1] = np.median(np.stack([x[:-2], x[1:-1], x[2:]]), axis=0)
    return out


class Jump(NamedTuple):
    """How long a fast jump can have lasted, at most and at least (s): a track's ridge
    child is weighed on the longest (only a jump surely faster than its ridge's rise is
    no ridge of it), its stop child on the shortest (only a jump surely slower than a
    stop's is no stop)."""

    longest_s: float
    shortest_s: float


def fast_jump_s(recent: step_shape.Recent, onset: int, told: int, resolved: int = 0) -> Jump | None:
    """How long the jump of the contact with this onset, told a pulse at sample `told`
    (global indices, `step_shape.Recent`), can have lasted, when it jumped as fast as a
    stop's step and stood clear of the noise; None otherwise (or when its samples are not
    held). Both bounds are its time to 90 % of the peak plus the sample it is resolved to
    (at 100 Hz a 60 mm/s ridge rises within two samples: the sample its rise ended on
    only bounds it) - unless `resolved` and the samples are read unsmoothed
    (`resolved_s`). Read on the samples `despiked`: a one-sample spike on a slow ridge's
    rise (thesis-like noise, 10 mm/s) jumped "in 4 ms" through the 10 ms mean."""
    fs_hz = recent.fs_hz
    end = min(told, onset + round(WINDOW_S * fs_hz))
    start = onset - round(LEAD_S * fs_hz)
    x = recent.held(start, end + 2)
    if x is None:
        return None
    clean = despiked(x)
    shape = step_shape.measure(clean, onset - start, end - start, fs_hz)
    if shape is None or not math.isfinite(shape.jump_s):
        return None
    fast_s = max(step_shape.FAST_RISE_S, step_shape.FAST_RISE_SAMPLES / fs_hz)
    tall = shape.jump_n >= JUMP_SNR_MIN * shape.noise_n
    if not (shape.jump_s <= fast_s and tall):
        return None
    whole = shape.jump_s + 1.0 / fs_hz
    if not resolved or round(step_shape.SMOOTH_S * fs_hz) > 1:
        return Jump(whole, whole)
    longest, shortest = resolved_s(clean[onset - start : end - start + 1], shape, fs_hz)
    if resolved == 1:
        return Jump(longest, longest)
    if resolved == 2:
        return Jump(longest, shortest)
    if resolved == 3:
        return Jump(whole, longest)
    if resolved == 4:
        return Jump(whole, shortest)
    raise ValueError(f"stop jumps: resolved {resolved!r} is none of 0-4")


def resolved_s(after: np.ndarray, shape: step_shape.StepShape, fs_hz: float) -> tuple[float, float]:
    """How long a jump read on unsmoothed samples can have lasted from 10 to 90 % of its
    height, at most and at least (s): its last sample at or under 10 % before the first
    at 90 % (`after`: the samples from the onset on, the first at 90 % `shape.jump_s` in)
    are k samples apart, so its crossings lie k - 2 to k samples apart. A stop's level
    changes within one sample at 100 Hz (6-10 ms of braking) where a ridge at 47 mm/s
    takes two (its ~1 mm of travel); `jump_s` + a sample bounded both by 20 ms or more,
    over `FAST_JUMP_TRAVEL_MM` at 53 mm/s, so a stop told a pulse was weighed as a fast
    ridge (its stop child charged). When the onset's own sample rose past 10 % already,
    the jump may have begun a sample before it: a sample more, as at faster rates."""
    top = round(shape.jump_s * fs_hz)
    base0 = float(after.max()) - shape.jump_n  # (`measure`: the peak less the jump)
    low = np.flatnonzero(after[:top] <= base0 + 0.1 * shape.jump_n)
    k = top - (int(low[-1]) if len(low) else -1)
    return k / fs_hz, max(0, k - 2) / fs_hz


def weigh(
    floats: np.ndarray,
    ints: np.ndarray,
    contact_id: int,
    t_s: float,
    jump_s: float,
    travel_min_mm: float,
    log_ridge: float,
    log_stop: float,
    stop_jump_s: float | None = None,
) -> None:
    """Weigh the children of a fast-jumping contact (in place, the bank's matrices): a
    slipping track with a measured speed taking it for a ridge at a speed whose ridge
    would travel under `travel_min_mm` over the jump (at most `jump_s`) gets `log_ridge`;
    a track stopped at it whose speed before made such a jump (at least `stop_jump_s`;
    None: `jump_s`) a ridge's travel gets `log_stop`."""
    stop_s = jump_s if stop_jump_s is None else stop_jump_s
    if not (jump_s > 0 and travel_min_mm > 0 and stop_s >= 0):
        raise ValueError(
            f"stop jumps: jump {jump_s!r} s (stop's {stop_s!r} s), travel {travel_min_mm!r} mm"
        )
    travel_mm = np.abs(floats[:, F_V]) * jump_s
    slipping = np.isnan(floats[:, F_STOP])
    # (a restart's speed is not known yet: run 1)
    ridge = (ints[:, I_LAST] == contact_id) & (ints[:, I_N] >= 2) & (ints[:, I_RUN] >= 2)
    ridge &= slipping
    floats[ridge & (travel_mm < travel_min_mm), F_SCORE] += log_ridge
    stop = floats[:, F_STOP] == t_s
    stop_mm = np.abs(floats[:, F_V]) * stop_s
    floats[stop & (stop_mm >= travel_min_mm), F_SCORE] += log_stop

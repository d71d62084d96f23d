"""A step on an earlier ridge pulse's rise: the level judged with that pulse's course out.

Physics (thesis ch. 5.3.1): the object meeting ridge i starts the segment
c_i(t) = kappa alpha (t - t_i) e^(-beta (t - t_i)), kappa = e beta, which rises to alpha at
t_i + 1/beta and decays; it is in force until the next ridge contact replaces it (during
its rise the new one starts from the old one's value). The segment is a function of the
time since the collision, not of the travel: the thesis draws alpha and beta from fixed
intervals and nothing in its model moves with the object after the contact. So a slip
that stops during a pulse makes no next contact, and the last pulse runs its course -
rises to its peak and decays - while the end of slipping adds the friction term's step
(ch. 4.3: M = (1 - k mu) W + k P while slipping, W at rest). The simulator
(`simulators.effects.skin.RidgeContacts`) does the same: the segment in force goes on in
time after the object stops (its rise time is set from the speed at the contact, which
the thesis does not say: not used here - the rise is fitted).

A stop within a pulse's width after a ridge contact (issue 22: 10 of 18 late stops on
the full plan) lands its step on that pulse's rise; the level then falls back with the
pulse's decay, and step-then-flat reads as rise-then-fall: a pulse. With the earlier
pulse's course out - height and rise fitted over the level from its onset to this one's,
carried on past it - the stop's level stays up like any step, while a ridge contact's
(whose new pulse replaces the old one's course and decays with it) still falls back.

Pure functions of a smoothed level (a moving mean of `2 half + 1` samples by centre
index, as `watch.PulseWatcher` keeps it); `watch.PulseWatcher` calls them behind
`WatchSettings.pulse_under_step`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

# rise times (onset to peak, 1/beta) a fit tries, s: the simulator's clip range, a grid
# even in log - the thesis draws beta from a fixed interval and gives no figure for it
RISE_MIN_S = 0.005
RISE_MAX_S = 0.2
RISE_STEPS = 24
MIN_FIT_SAMPLES = 3  # level samples between the two onsets the fit needs at the least
# an earlier onset at most this long before: the full plan's stops told pulses on one came
# 35-70 ms after it (benchmarks/stop_pulse_under.py); a ridge train at ~41 mm/s on 4 mm
# spacings (98 ms) read a step at 95 ms, the earlier pulse's fall held up by the FSR's
# hysteresis and its fitted course falling under it (reversal kind, uniform4)
MAX_GAP_S = 0.075


class Course(NamedTuple):
    """The earlier pulse's fitted course: `height` (N over the level before it) and `rise`
    (samples, onset to peak) and the fit's rms misfit (N)."""

    height: float
    rise: float
    rms: float


def shape(offsets: np.ndarray, rise: float) -> np.ndarray:
    """The unit pulse u e^(1 - u), u = offset / rise (0 before its onset): peak 1 at rise."""
    u = np.maximum(np.asarray(offsets, dtype=float), 0.0) / rise
    return u * np.exp(1.0 - u)


def smoothed(offsets: np.ndarray, rise: float, half: int) -> np.ndarray:
    """`shape` as the level sees it: the mean over the 2 half + 1 samples centred on each
    offset (the level is a moving mean)."""
    offsets = np.asarray(offsets, dtype=float)
    if half <= 0:
        return shape(offsets, rise)
    taps = np.arange(-half, half + 1, dtype=float)
    return shape(offsets[:, None] + taps[None, :], rise).mean(axis=1)


def rises(fs_hz: float) -> np.ndarray:
    """The rise times a fit tries, in samples."""
    return np.geomspace(RISE_MIN_S * fs_hz, RISE_MAX_S * fs_hz, RISE_STEPS)


def fit(level: np.ndarray, offsets: np.ndarray, half: int, fs_hz: float) -> Course | None:
    """The earlier pulse's course from `level` (its change over its base, N) at `offsets`
    (samples since its onset, level centres): for each rise time the height by least
    squares (>= 0), the rise with the smallest misfit. None with too few samples, or with
    no rise to fit (a height of 0)."""
    level = np.asarray(level, dtype=float)
    if len(level) < MIN_FIT_SAMPLES or len(level) != len(offsets):
        return None
    best: Course | None = None
    for rise in rises(fs_hz):
        g = smoothed(offsets, rise, half)
        gg = float(np.dot(g, g))
        if gg <= 0.0:
            continue
        height = max(0.0, float(np.dot(g, level)) / gg)
        rms = math.sqrt(float(np.mean((level - height * g) ** 2)))
        if best is None or rms < best.rms:
            best = Course(height, float(rise), rms)
    if best is None or best.height <= 0.0:
        return None
    return best


def residual(
    level: np.ndarray, first: int, before: int, earlier: int, base: float, half: int,
    fs_hz: float,
) -> np.ndarray | None:  # fmt: skip
    """The level after an onset with the earlier pulse's course out, as a watch's `plain`
    (level - base): `level` holds centres `first`, `first + 1`, ...; the onset's own base
    at centre `before` (its last centre the new rise does not touch), the earlier pulse's
    onset at sample `earlier` and its base level `base`. The course is fitted over the
    centres from `earlier - half` to `before` and carried on; the result runs from
    `before` on (the watch's `plain` from its onset on is `[before + 1 + half + ...]`).
    None when the earlier onset leaves too few samples, or no rise to fit."""
    i0 = earlier - half - first
    i1 = before - first
    if i0 < 0 or i1 >= len(level) or i1 - i0 + 1 < MIN_FIT_SAMPLES:
        return None
    centres = np.arange(first, first + len(level))
    course = fit(level[i0 : i1 + 1] - base, centres[i0 : i1 + 1] - earlier, half, fs_hz)
    if course is None:
        return None
    after = centres[i1:] - earlier
    model = course.height * smoothed(after, course.rise, half)
    out = level[i1:] - model
    return out - out[0]

"""The shape of a contact told a step: a slip's stop, or a ridge pulse held by hysteresis?

Physics (thesis ch. 4.3, 3.4): while slipping the FSR reads M = (1 - k mu) W + k P plus
the ridge pulses; at rest it reads W. When the object sticks the static level moves once
(over the braking, tens of ms) and then stays flat: no pulses, only noise and slow
drift. A ridge pulse rises fast (the edge pushing the ridge over) and relaxes; under the
FSR's hysteresis (a play operator) its fall is held when the level under it rises, so it
too rises and stays - a step by the watcher's verdict. Both reach the tracker as "a step
at the time a ridge was due". This module measures what the signal itself tells of the
two, from the samples up to the verdict only (so the evidence is the same however the
input is chunked): the step's height, the overshoot of its peak over the level it holds
(a pulse rises past its held level, a stop's level change does not), how fast it rose,
and the level's slope and roughness before and after, each in units of the white noise
measured just before the onset.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

PRE_S = 0.06  # the level before the onset: its base and slope
NOISE_S = 0.15  # ... and its white noise, over this long (at least NOISE_SAMPLES)
NOISE_SAMPLES = 16
POST_S = 0.03  # the level held at the verdict: the last this long before it
SMOOTH_S = 0.01  # the peak is read on a moving mean this long (noise would raise a max)
NOISE_FLOOR_N = 1e-3  # the quietest white noise assumed (an ideal FSR), N per sample
RISE_NOISE = 1.5  # the rise ends within this many noise units of the level held (`measure`)


class StepShape(NamedTuple):
    """What a step's samples show (heights in N, slopes in N/s, *_snr in noise units)."""

    height_n: float  # level held at the verdict less the base before the onset
    overshoot_n: float  # the smoothed peak since the onset above the level held
    rise_s: float  # from the onset to the first smoothed sample at 90 % of the height
    pre_slope_n_s: float  # the level's slope over PRE_S before the onset
    post_slope_n_s: float  # ... over POST_S before the verdict
    post_rough_snr: float  # the residual of that fit (rms) in noise units
    noise_n: float  # white noise before the onset (first differences, robust)
    # the smoothed peak above the level before, its trend carried to the onset (on a
    # pulse's falling tail the median before lies above it), and how soon 90 % of it came
    jump_n: float = 0.0
    jump_s: float = float("nan")
    # the largest one-sample rise around the onset, and how far the level went on rising
    # after it (the mean of the JUMP_THEN_SAMPLES after it less the sample it rose to):
    # the rise's speed, read below a sample
    step_n: float = 0.0
    then_n: float = 0.0


def _fit(t: np.ndarray, x: np.ndarray) -> tuple[float, float]:
    """(slope, rms residual) of a least-squares line through (t, x)."""
    if len(x) < 3:
        return 0.0, 0.0
    tc = t - t.mean()
    den = float(tc @ tc)
    slope = float(tc @ (x - x.mean())) / den if den > 0 else 0.0
    resid = x - x.mean() - slope * tc
    return slope, float(np.sqrt(np.mean(resid * resid)))


def measure(x: np.ndarray, onset: int, verdict: int, fs_hz: float) -> StepShape | None:
    """The step's shape from samples x (x[0] is the first held; onset and verdict index
    into x): None when the samples before the onset or up to the verdict are not all held
    or not finite (nothing is guessed)."""
    if fs_hz <= 0:
        raise ValueError(f"step shape: sample rate {fs_hz!r} Hz is not positive")
    pre = max(3, round(PRE_S * fs_hz))
    quiet = max(pre, NOISE_SAMPLES, round(NOISE_S * fs_hz))
    post = max(2, round(POST_S * fs_hz))
    if onset - quiet < 0 or verdict >= len(x) or verdict - onset < post + 1:
        return None
    before = x[onset - pre : onset]
    after = x[onset : verdict + 1]
    if not (np.all(np.isfinite(x[onset - quiet : onset])) and np.all(np.isfinite(after))):
        return None
    # white noise from first differences (robust: a pulse or a step among them moves a few)
    diffs = np.abs(np.diff(x[onset - quiet : onset]))
    noise = max(float(np.median(diffs)) * 1.4826 / math.sqrt(2.0), NOISE_FLOOR_N)
    t_pre = np.arange(-pre, 0) / fs_hz
    pre_slope, _ = _fit(t_pre, before)
    base = float(np.median(before))
    held_x = after[-post:]
    held = float(np.median(held_x))
    t_post = np.arange(post) / fs_hz
    post_slope, rough = _fit(t_post, held_x)
    width = max(1, round(SMOOTH_S * fs_hz))
    smooth = np.convolve(after, np.full(width, 1.0 / width), mode="valid")
    height = held - base
    peak = float(smooth.max()) if len(smooth) else held
    # within 10 % of the height or RISE_NOISE units of the (smoothed) noise of it
    near = max(0.1 * height, RISE_NOISE * noise / math.sqrt(width))
    reached = np.flatnonzero(smooth - base >= height - near) if height > 0 else np.zeros(0)
    rise = (float(reached[0]) + (width - 1) / 2.0) / fs_hz if len(reached) else float("nan")
    # the base carried to the onset along the level's trend before it (the fit's line)
    base0 = float(np.mean(before)) + pre_slope * (pre / 2.0 + 0.5) / fs_hz
    jump = peak - base0
    jumped = np.flatnonzero(smooth - base0 >= 0.9 * jump) if jump > 0 else np.zeros(0)
    jump_s = (float(jumped[0]) + (width - 1) / 2.0) / fs_hz if len(jumped) else float("nan")
    step, then = _one_sample_step(x, onset, verdict)
    return StepShape(
        height_n=height,
        overshoot_n=peak - held,
        rise_s=rise,
        pre_slope_n_s=pre_slope,
        post_slope_n_s=post_slope,
        post_rough_snr=rough / noise,
        noise_n=noise,
        jump_n=jump,
        jump_s=jump_s,
        step_n=step,
        then_n=then,
    )


JUMP_SAMPLES = 3  # the one-sample rises looked at, the first from the sample before the onset
JUMP_THEN_SAMPLES = 2  # ... and the level's further rise read over this many after it


def _one_sample_step(x: np.ndarray, onset: int, verdict: int) -> tuple[float, float]:
    """(the largest rise from one sample to the next over the JUMP_SAMPLES from the one
    before the onset, the mean of the JUMP_THEN_SAMPLES after it less the sample it rose
    to), N; only samples up to the verdict are read."""
    first = max(onset - 1, 0)
    rises = np.diff(x[first : min(first + JUMP_SAMPLES, verdict) + 1])
    if not len(rises):
        return 0.0, 0.0
    top = first + 1 + int(np.argmax(rises))
    after = x[top + 1 : min(top + JUMP_THEN_SAMPLES, verdict) + 1]
    return float(rises.max()), float(after.mean() - x[top]) if len(after) else 0.0


# the verdicts of `classify`; AMBIGUOUS: a fast rise past the level held, or off a falling
# tail to a level under it - a ridge pulse held up, or a stop landing on a
# ridge's pulse (the edge pushed the ridge over, then stuck): the stop kinds' steps not
# told sure, full plan, 1 seed (stop_causes.py --shapes): of 106 stops' 7 rose fast to a
# peak, 5 slowly; of 294 ridges' and others' 22 and 234
RIDGE_LIKE, UNTOLD, STOP_LIKE, AMBIGUOUS = -1, 0, 1, 2
# a stop's level change is over within the braking (the object sticks): told fast when it
# reached 90 % of its height this soon after the onset (or within this many samples of a
# slow input); a ridge pulse rises over the ~1.25 mm the edge needs to push a ridge over,
# held pulses on a rising level later still (benchmarks/stop_causes.py --shapes)
FAST_RISE_S = 0.011
FAST_RISE_SAMPLES = 2.5
# Below FAST_RISE_SAMPLES / FAST_RISE_S (227 Hz) the rise is read in whole samples, and a
# ridge's push-over (12-60 ms at 20-100 mm/s) can fit within the samples called fast. A
# stop's level change ends within the one sample interval it falls in: the level stays
# where that sample took it. A rise that goes on past its largest one-sample step by this
# share of it, and this many noise units (white noise alone passes 5 % of the time: the
# mean of two samples less a third has 1.22 noise units of spread), is no stop's.
# Rates-drops seeds 0-5 at 100 / 200 Hz (the stop-like steps of `stop_causes.py
# --shapes`): of 21 / 22 ridge steps read STOP_LIKE 9 / 17 go on rising; of 282 / 296
# stops 2 / 0 do.
THEN_SHARE = 0.2
THEN_SNR = 2.0
# ... and a pulse rises past the level it is held at (the hysteresis holds only part of
# its fall): a peak this share of the height above the held level, and this many noise
# units, is a pulse's
PULSE_OVERSHOOT = 0.25
PULSE_OVERSHOOT_SNR = 3.0


def classify(shape: StepShape | None, fs_hz: float, read_then: bool = True) -> int:
    """STOP_LIKE (a fast, monotone level change), RIDGE_LIKE (a slow rise, or no rise at
    all: a ridge pulse held up), AMBIGUOUS (a fast rise to a peak well above the level
    held, or off a falling tail to a level under it: a ridge pulse held up, or a stop on
    one), or UNTOLD (no shape). `read_then` False: the rise in whole samples only."""
    if shape is None:
        return UNTOLD
    fast_s = max(FAST_RISE_S, FAST_RISE_SAMPLES / fs_hz)
    if not shape.height_n > 0 or not math.isfinite(shape.rise_s):
        # the level held is no higher than before: no stop's step - unless it jumped at
        # once from a falling tail (a stop on a ridge's pulse: the tail goes on falling
        # under the level it holds) to a peak well above the noise
        jumped = shape.jump_s <= fast_s and shape.jump_n > PULSE_OVERSHOOT_SNR * shape.noise_n
        return AMBIGUOUS if jumped and shape.pre_slope_n_s < 0 else RIDGE_LIKE
    fast = shape.rise_s <= fast_s and not (read_then and _rise_goes_on(shape, fs_hz))
    peaked = (
        shape.overshoot_n > PULSE_OVERSHOOT * shape.height_n
        and shape.overshoot_n > PULSE_OVERSHOOT_SNR * shape.noise_n
    )
    if not fast:
        return RIDGE_LIKE
    return AMBIGUOUS if peaked else STOP_LIKE


def _rise_goes_on(shape: StepShape, fs_hz: float) -> bool:
    """Whether, at a rate that reads the rise in whole samples, the level rose on past
    its largest one-sample step (THEN_SHARE, THEN_SNR): a ridge's push-over, no stop."""
    if FAST_RISE_S * fs_hz >= FAST_RISE_SAMPLES or not shape.step_n > 0:
        return False
    return shape.then_n > THEN_SHARE * shape.step_n and shape.then_n > THEN_SNR * shape.noise_n


# a verdict told late (a revision, a probe's contact) is read on the rise it told of: the
# samples up to this long after the onset at most
HELD_S = 0.2
RECENT_S = 1.0  # `Recent` holds at least this long (twice that at most)


class Recent:
    """The last RECENT_S of samples by global index (the detector's numbering: every
    sample fed, in order), what a step's shape is read from however late its verdict
    comes. Appends copy the new samples only; the buffer is cut from the front when
    full."""

    __slots__ = ("_x", "fs_hz", "size", "span", "start")

    def __init__(self, fs_hz: float):
        if not fs_hz > 0:
            raise ValueError(f"step shape: sample rate {fs_hz!r} Hz is not positive")
        self.fs_hz = float(fs_hz)
        self.span = max(64, round(RECENT_S * fs_hz))
        self._x = np.empty(2 * self.span)
        self.start = 0  # global index of _x[0]
        self.size = 0

    def append(self, x: np.ndarray) -> None:
        if self.size + len(x) > len(self._x):
            keep = min(self.size, self.span)
            self._x[:keep] = self._x[self.size - keep : self.size]
            self.start += self.size - keep
            self.size = keep
            if keep + len(x) > len(self._x):
                grown = np.empty(2 * (keep + len(x)))
                grown[:keep] = self._x[:keep]
                self._x = grown
        self._x[self.size : self.size + len(x)] = x
        self.size += len(x)

    def _view(self, start: int, end: int) -> np.ndarray | None:
        """The samples start..end-1 (global indices), not copied: None when not all held."""
        if start < self.start or end > self.start + self.size or end < start:
            return None
        return self._x[start - self.start : end - self.start]

    def mean(self, start: int, stop: int) -> float | None:
        """The mean of the samples at global indices start..stop-1; None unless all held."""
        x = self._view(start, stop)
        return float(np.mean(x)) if x is not None and len(x) else None

    def verdict(self, onset: int, told: int, read_then: bool = True) -> int:
        """`classify` of the step whose onset and verdict are global sample indices."""
        held = min(told, onset + round(HELD_S * self.fs_hz))
        return classify(self.shape(onset, held), self.fs_hz, read_then)

    def held(self, start: int, end: int) -> np.ndarray | None:
        """A copy of the samples start..end-1 (global indices): None when not all held."""
        x = self._view(start, end)
        return None if x is None else x.copy()

    def shape(self, onset: int, told: int) -> StepShape | None:
        """`measure` of the samples from before `onset` to `told` (global sample indices):
        None when they are no longer (or not yet) held."""
        if onset - self.start < 0:
            return None
        return measure(self._x[: self.size], onset - self.start, told - self.start, self.fs_hz)

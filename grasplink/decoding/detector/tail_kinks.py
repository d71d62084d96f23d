"""Tail kinks: a ridge contact whose pulse starts on the previous pulse's falling tail.

Physics (thesis ch. 5.3.1, `decoding.ridge_pulses`): after a short spacing the new pulse
starts from the previous pulse's value, so the force does not rise at the onset - the
tail merely stops falling for a rise time (the new pulse rising by about what the old one
falls), then falls again with the new pulse's decay. The kink bank sees the slope jump
(often 10-20 noise units at 20-80 ms: the kink is 0.05-0.1 of a lone pulse's onset slope,
`onset_kinks`), but its rise check (`HingeSettings.rise_fraction`: the force rising after
a contact) drops it: alpha0.3's 4 and 7 mm ridges after the tall first pulse, uniform4's
4 mm ridges after a 3 mm one (issue 22: constant speed missing from the 3rd contact).

The rise check is there for kinks with a flat level after them that are no contact: the
end of a grip release or ramp, the slow bend at the end of a pulse's decay. This module
tells a tail kink from those by the tail's own decay model: a candidate the rise check
dropped is a contact when

* it lies on the falling tail of a pulse: the level peaked within `look_s` (or, where
  that finds none, `slow_look_s`) before it, at least `tall` white-noise units above the
  level at the kink, after rising to that peak by at least as much (a pulse, not the
  start of a ramp down);
* the tail from the peak to the kink is a ridge pulse's decay (u e^(1 - u); where on it
  the highest sample sits and the rise from a grid, base and height least squares) that
  fits it within `fit_rms` noise units RMS (a tail, not a corner of two ramps);
* over the kink's scale after it, the level stands above that decay's extrapolation by
  `residual_z` standard errors of the mean (the decay's own extrapolation error
  included) - and above every other decay that fits the tail about as well
  (`spread_chi2`: a short tail leaves the rise open, and its extrapolation with it): the
  new pulse lifting the tail. The slow bend at a decay's end IS the decay
  (extrapolated, no residual); a grip ramp's end has no pulse before it.

False alarms: under white noise the residual mean is N(0, 1) in its own standard errors,
so at `residual_z` 4 a candidate that is noise passes about 3e-5 of the time - and only
after a kink over the bank's threshold on a tall pulse's tail, never on a held object's
flat level (no tall pulse before it: measured on the held sets,
`benchmarks/detector_contacts.py --held`).

Pure functions of the samples before and up to the kink's scale after it (all held when
the kink bank tests a candidate: its z is known over +-w), so chunking changes nothing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from grasplink.decoding import arrival


@dataclass(frozen=True)
class TailKinkSettings:
    """When a kink the rise check dropped is a contact on a pulse's tail (module doc).

    `residual_z` 0 turns the test off (the rise check alone, as before issue 22's tail
    kinks). Shipped on at `ON_RESIDUAL_Z` (4) since the tests' cases that regressed were
    traced: test_tracker_braking's to the tail kink's late time (`tail_onsets`),
    test_step_stop_wait's to the tracker's detection model of 3 mm ridges
    (`TrackerDecoder.DETECT_P`, re-measured with the tail kinks; docs/decoding.md, "Tail
    kinks")."""

    residual_z: float = 4.0  # the lift over the decay, standard errors of its mean
    floor: float = -0.5  # slope after / hinge at least this (a tail that falls on less)
    look_s: float = 0.35  # the pulse under the kink peaked within this before it ...
    slow_look_s: float = 0.6  # ... or, where none did, within this (a slow slip's kink)
    tall: float = 8.0  # ... this many white-noise units above the level at the kink
    fit_rms: float = 1.6  # the decay fits the tail within this (white-noise units, RMS)
    spread_chi2: float = 6.0  # decays fitting within this (noise variances) of the best
    min_fit: int = 6  # samples of tail to fit, at least
    # a tail kink on the first load's pulse keeps the kink bank's time (`arrival_tail`):
    # the sensor's unloaded level (N); 0: every tail kink moved back (shipped on, s25)
    arrival_empty_n: float = arrival.EMPTY_N
    # a tail kink with the level flat after it is a pulse hysteresis hides (`held_corners`):
    # kept at the kink bank's time and merged within corner_merge_widths; 0: off
    corner_flat_z: float = 0.0
    corner_merge_widths: float = 1.0


ON_RESIDUAL_Z = 4.0  # the shipped setting (`benchmarks/tail_kinks.py`, tune_tracker_kinds)

# the decay models tried (`_models`): where the tail's first sample (the highest, in
# noise) sits on the pulse (u, 1 at its peak) and the pulse's rise (in units of the
# tail's length, peak to kink)
PEAK_U = tuple(np.linspace(0.6, 1.6, 11))
RISE_SHARES = tuple(np.geomspace(0.05, 2.5, 24))


def decay_shape(u: np.ndarray) -> np.ndarray:
    """A ridge pulse's shape past its onset (thesis ch. 5.3.1: u e^(1 - u), 1 at the peak
    u = 1; u in rise times since the onset)."""
    return u * np.exp(1.0 - u)


@lru_cache(maxsize=64)
def _models(n_fit: int, n_after: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every decay model (`PEAK_U` x `RISE_SHARES`) over a tail of n_fit samples and
    n_after after it: the shapes (model x sample), their means over the tail and their
    sums of squares about that mean - what a least-squares base and height need."""
    u0, share = np.meshgrid(np.array(PEAK_U), np.array(RISE_SHARES), indexing="ij")
    k = np.arange(n_fit + n_after, dtype=np.float64)
    u = u0.reshape(-1, 1) + k / (share.reshape(-1, 1) * n_fit)
    shapes = decay_shape(u)
    tail = shapes[:, :n_fit]
    mean = tail.mean(axis=1)
    spread = ((tail - mean[:, None]) ** 2).sum(axis=1)
    return shapes, mean, spread


def tail_kink(
    x: np.ndarray, k: int, width: int, white_n: float, fs_hz: float, settings: TailKinkSettings
) -> bool:
    """Is the kink at x[k] (found at a scale of `width` samples, dropped by the rise
    check) a ridge contact on a pulse's falling tail (module doc)? `white_n`: the white
    noise (N per sample); x must hold k - slow_look_s .. k + width. The peak is looked
    for within `look_s` first; only where that finds no tail, within `slow_look_s`: at
    8 mm/s a 4 mm ridge's kink comes 0.34 s after the peak it sits under, but a longer
    window alone finds an older, taller peak before some kinks (its tail no one decay)."""
    if settings.residual_z <= 0.0 or white_n <= 0.0:
        return False
    if _tail_kink(x, k, width, white_n, fs_hz, settings, settings.look_s):
        return True
    slow = settings.slow_look_s
    return slow > settings.look_s and _tail_kink(x, k, width, white_n, fs_hz, settings, slow)


def _tail_kink(
    x: np.ndarray,
    k: int,
    width: int,
    white_n: float,
    fs_hz: float,
    settings: TailKinkSettings,
    look_s: float,
) -> bool:
    """`tail_kink` with the peak looked for within look_s before the kink."""
    look = max(2, round(look_s * fs_hz))
    lo = k - look
    if lo < 0 or k + width >= len(x):
        return False
    window = x[lo : k + 1]
    p = int(np.argmax(window))
    top = float(window[p])
    drop = top - float(x[k])
    if drop < settings.tall * white_n or p < 2:
        return False  # not under a tall peak, or the peak is the window's edge: a ramp
    if top - float(window[:p].min()) < drop:
        return False  # no rise to the peak as tall as the fall since: no pulse
    tail = x[lo + p : k + 1]
    n_fit = len(tail)
    if n_fit < settings.min_fit:
        return False
    after = float(np.mean(x[k + 1 : k + width + 1]))
    shapes, mean, spread = _models(n_fit, width)
    centred = tail - float(tail.mean())
    cross = shapes[:, :n_fit] @ centred  # per model: sum (shape - its mean)(tail - mean)
    height = cross / spread
    sse = float(centred @ centred) - cross * height
    sse[height <= 0.0] = np.inf  # not a pulse's decay
    best = float(sse.min())
    if not math.isfinite(best) or math.sqrt(max(best, 0.0) / n_fit) > settings.fit_rms * white_n:
        return False  # the tail is no pulse's decay
    # every model that fits about as well (within `spread_chi2` noise variances of the best
    # one's squared residual: the tail cannot tell them apart) must fall short of the level
    # after the kink, by residual_z standard errors of its extrapolated mean
    near = sse <= best + settings.spread_chi2 * white_n * white_n
    lift = shapes[near, n_fit:].mean(axis=1) - mean[near]
    predicted = float(tail.mean()) + height[near] * lift
    var = 1.0 / width + 1.0 / n_fit + lift * lift / spread[near]  # per unit noise
    bound = predicted + settings.residual_z * white_n * np.sqrt(var)
    return after >= float(bound.max())

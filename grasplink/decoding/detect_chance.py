"""The chance a ridge is detected, measured from the signal rather than fixed.

The tracker's penalty for a ridge its track expected and no contact told is
log(1 - DETECT_P(spacing)), a table measured once on clean signals (99 % past 5 mm):
a skip costs 4.6 nats. At 10 dB SNR the detector tells about half the crossings (issue
22: 46 % at 22 mm/s), so a true track that skipped a ridge or two paid as if it had been
nearly sure to see them, and lost to aliases pairing the same contacts as neighbours
or to "stopped" (docs/decoding.md, the snr10 section).

Here the chance follows from what the detector measures: the told pulses' rise z on the
probe's window (`rise_evidence.RiseEvidence.median_h`, white-noise units) and the
threshold a rise must cross to be told (`rise_evidence.TOLD_Z`, the pulse probe's). The
pulse size is the one `rise_evidence` assumes - log-uniform from `h_low` to `H_HIGH`
times the told median - and z ~ N(h, 1), so P(detect) is the mean over that prior of
Phi(h - threshold): about 0.4 for a told median of 5 (10 dB), 1 for 20 or more (clean).
A skipped ridge then pays at least log(1 - P) (`floor`): small at 10 dB, the table's
own on a clean signal (the table caps P, so short spacings keep their lower chance).
"""

from __future__ import annotations

import functools
import math

import numpy as np
from scipy.special import ndtr

from grasplink.decoding import rise_evidence


@functools.lru_cache(maxsize=512)
def chance(median_h: float, h_low: float, threshold_z: float) -> float:
    """P(a ridge pulse is told): the mean of Phi(h - threshold_z) over the size prior
    (`rise_evidence`'s grid for `median_h`, the told pulses' median z). ValueError for a
    median that is not a positive number or a threshold that is not finite."""
    if not math.isfinite(threshold_z):
        raise ValueError(f"detect chance: threshold {threshold_z!r} is not finite")
    sizes = rise_evidence.sizes(float(median_h), float(h_low))
    return float(np.mean(ndtr(sizes - threshold_z)))


def floor(
    log_miss: np.ndarray,
    median_h: float | np.ndarray,
    *,
    h_low: float,
    threshold_z: float,
    weight: float,
) -> np.ndarray:
    """Each skipped ridge's least score: its table's log(1 - DETECT_P) (`log_miss`)
    raised `weight` of the way (0..1, in log) to log(1 - P) with P the measured `chance`
    for its window's told median (one per ridge), never lowered (the table caps P)."""
    log_miss = np.asarray(log_miss, dtype=float)
    if not 0.0 <= weight <= 1.0:
        raise ValueError(f"detect chance: weight {weight!r} is not in [0, 1]")
    medians = np.broadcast_to(np.asarray(median_h, dtype=float), log_miss.shape)
    if weight == 0.0 or not log_miss.size:
        return log_miss
    p = np.array([chance(float(m), h_low, threshold_z) for m in medians.ravel().tolist()])
    with np.errstate(divide="ignore", invalid="ignore"):
        measured = np.log1p(-np.minimum(p, 1.0)).reshape(log_miss.shape)
        raised = log_miss + weight * (np.maximum(measured, log_miss) - log_miss)
    # the coast end (-inf: past it the slip has stopped) stays as it is
    return np.where(np.isfinite(log_miss), raised, log_miss)

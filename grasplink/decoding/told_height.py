"""A told contact's height, weighed against the spacing before the ridge a track gives it.

Physics (the skin model, `evaluation.height_evidence`): a ridge's pulse peaks at
a x d x f(s), f(s) = 1 - exp(-s / `SPACING_MM`), s the free spacing the edge crossed
before that ridge in its direction of travel, d a draw per contact and a a scale the run
shares (the grip, the skin: unknown to the decoder). A 4 mm spacing gives f = 0.33, a
40 mm one 0.98, and in travel order the spacing before a ridge differs by direction: where
contact *times* leave aliases (issue 22, 10 dB SNR: a hypothesis set cannot tell them
apart for 45 % of the slipping updates even with the oracle's contacts), the heights
tell some of them apart (the oracle's heights: 35 %).

The decoder's height of a contact is the pulse probe's rise statistic z at its onset on
the window of the track's rise time (`told_rise` reads the same z; in white-noise units),
over the median z of the contacts told lately on that window (`RiseEvidence.median_h`:
the unknown scale a, shared by the run). On snr10's told crossings (full plan, 2 seeds:
`benchmarks/snr10_told_heights.py`) log z grows with log f by `SLOPE` (0.36, not 1: the
detector tells the tall pulses after short spacings and misses the rest, and a pulse
rises from the previous one's tail), with a residual spread of `SIGMA` (0.50) nats.

A child taking the contact for ridge k of its direction gains log N(x; mu_k, SIGMA) less
log of the mean of that density over every ridge either way (the contact is some ridge's:
no child gains on average against the ones taking it for clutter), x = log(z / median),
mu_k = SLOPE (log f_k - c), c the detection-weighted mean of log f (the told pulses'
centre), clipped to +-`CLIP` nats so one odd pulse cannot end a track. z under `Z_FLOOR`
is read as `Z_FLOOR`; where z is not held by the contact's decision (NaN) nothing is
added (a contact told at once, the clean signal's usual case).
"""

from __future__ import annotations

import numpy as np

from grasplink.decoding.kernels.layout import F_SCORE, I_DIRN, I_RIDGE
from grasplink.decoding.rise_evidence import RiseEvidence

SPACING_MM = 10.0  # the spacing factor's length (the skin model's)
SLOPE = 0.36  # log z per log f on snr10's told crossings (benchmarks/snr10_told_heights.py)
SIGMA = 0.50  # ... and the spread about that line (nats)
CLIP = 1.0  # nats a child gains or loses at most
Z_FLOOR = 0.5  # z under this (a told contact reads no rise here) is read as this


def log_factor(before_mm: np.ndarray) -> np.ndarray:
    """log f per (direction, ridge) from the spacing before each ridge (travel order)."""
    return np.log1p(-np.exp(-np.asarray(before_mm, float) / SPACING_MM))


def centre(log_f: np.ndarray, detect_p: np.ndarray) -> float:
    """The told pulses' mean log f: every ridge either way weighed by its detection odds."""
    w = np.asarray(detect_p, float)
    return float(np.sum(w * log_f) / np.sum(w))


def gain(
    z: np.ndarray,
    median_z: np.ndarray,
    mu: np.ndarray,
    mu_all: np.ndarray,
    sigma: float = SIGMA,
    clip: float = CLIP,
) -> np.ndarray:
    """Per child: log N(x; mu, sigma) - log mean_j N(x; mu_all_j, sigma), x = log(max(z,
    Z_FLOOR) / median_z), clipped to +-clip; 0 where z is NaN."""
    if not (sigma > 0.0 and clip >= 0.0):
        raise ValueError(f"told height: sigma {sigma!r} must be > 0, clip {clip!r} >= 0")
    z = np.asarray(z, float)
    known = np.isfinite(z)
    x = np.log(np.maximum(np.where(known, z, 1.0), Z_FLOOR) / np.asarray(median_z, float))
    own = -0.5 * ((x - mu) / sigma) ** 2
    every = -0.5 * ((x[:, None] - np.asarray(mu_all, float).ravel()[None, :]) / sigma) ** 2
    top = np.max(every, axis=1)
    norm = top + np.log(np.mean(np.exp(every - top[:, None]), axis=1))
    return np.where(known, np.clip(own - norm, -clip, clip), 0.0)


def weigh(
    floats: np.ndarray,
    ints: np.ndarray,
    read: tuple[np.ndarray, np.ndarray, np.ndarray],
    evidence: RiseEvidence,
    mu_table: np.ndarray,
    weight: float = 1.0,
    sigma: float = SIGMA,
) -> np.ndarray:
    """Add `weight` x `gain` to the score of each child in `read` (rows taking the contact
    for their ridge, the probe window and the z each read: `told_rise.rise_z`);
    `mu_table`: mu per (direction index, ridge), travel order. Returns the gains."""
    rows, width, z = read
    if not len(rows):
        return np.zeros(0)
    medians = {w: evidence.median_h(w) for w in np.unique(width).tolist()}
    median_z = np.array([medians[w] for w in width.tolist()], float)
    way = (1 - ints[rows, I_DIRN]) // 2
    mu = mu_table[way, ints[rows, I_RIDGE]]
    out = gain(z, median_z, mu, mu_table.ravel(), sigma)
    floats[rows, F_SCORE] += weight * out
    return out

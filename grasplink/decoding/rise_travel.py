"""How likely a contact's scale is for a ridge at a track's speed, against clutter (issue 22).

A ridge pulse rises while the edge pushes the ridge over: about a millimetre of the
edge's travel whatever the speed. The kink bank finds a contact at the scale matching its
rise (`detector.hinges`), so for a true contact scale x speed (its *travel*) clusters,
while a false one (the level starting to rise as the object covers the sensor, a grip
change, noise) is found at a scale that has nothing to do with the speed. A track's speed
thus predicts the scale of its next ridge contact - the headline loop's false contact at
1.496 s spans 80 ms at 65 mm/s, 5 mm of travel, where ridges span 0.2-1.2 mm.

The model, its numbers measured (`benchmarks/contact_scale_model.py`, full plan):

* a true contact's ln scale is Normal(`MU_LN_S` + `SLOPE` x ln speed, `SIGMA_LN`): with
  `SLOPE` -1 its travel would be the same at every speed; measured, it is about -0.5 - the
  bank tells a contact at the finest scale whose z crosses the threshold first, and a
  strong pulse crosses on a scale shorter than its rise, a slow one's kink on one
  shorter than its whole rise; a track's own speed is uncertain (its Kalman variance,
  acceleration included), which widens the ln scale it predicts by `SLOPE` x the speed's
  relative sd, in quadrature;
* the bank reads a rise as one of its scales at the rate (distinct in samples: at 100 Hz
  the 5 ms scale is the 10 ms one): each scale is the bin of ln scale between the
  geometric means of its neighbours, the finest taking every shorter rise (a fast ridge
  at a low rate reads long) and the coarsest every longer one;
* a share (`ANY_SCALE`) of true contacts is found at any scale alike (pulses merged,
  a ridge found on another's tail): no scale is impossible for a ridge;
* a false contact's scale is a measured share per scale (`FALSE_SHARE`), whatever the
  speed, the shares of scales merged at the rate summed.

`log_ratio` is the log of the ratio: what a track taking the contact for its ridge gains
(or loses) against the contact being clutter.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
from scipy.special import ndtr

from grasplink.decoding.detector.hinges import DEFAULT_SCALES_S, HingeSettings, hinge_widths

__all__ = [
    "ANY_SCALE",
    "FALSE_SHARE",
    "MU_LN_S",
    "SIGMA_LN",
    "SLOPE",
    "bank_scales",
    "log_ratio",
    "true_probability",
]

# benchmarks/contact_scale_model.py --seeds 2 (full plan, 2 seeds)
MU_LN_S = -2.509  # 23.5 ms at 10 mm/s, 13.0 at 30, 6.8 at 100
SLOPE = -0.539
SIGMA_LN = 0.666
FALSE_SHARE = (0.4979, 0.1268, 0.0905, 0.1318, 0.1531)  # per DEFAULT_SCALES_S, moving
ANY_SCALE = 0.0253
PROBABILITY_FLOOR = 1e-9  # (a share measured as 0)


@cache
def bank_scales(fs_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The bank's scales at fs_hz (s), their bins' ln edges (-inf ... +inf) and the false
    contacts' share of each (`FALSE_SHARE` of the scales each one merges)."""
    if not fs_hz > 0:
        raise ValueError(f"fs_hz must be positive, got {fs_hz}")
    widths = hinge_widths(fs_hz, HingeSettings())
    scales = np.array(widths, dtype=float) / fs_hz
    ln = np.log(scales)
    edges = np.concatenate([[-np.inf], 0.5 * (ln[1:] + ln[:-1]), [np.inf]])
    share = np.zeros(len(scales))
    for s, p in zip(DEFAULT_SCALES_S, FALSE_SHARE, strict=True):
        share[int(np.argmin(np.abs(ln - math.log(s))))] += p
    for a in (scales, edges, share):
        a.flags.writeable = False
    return scales, edges, share


def _index(scale_s: float, scales: np.ndarray) -> int:
    if not scale_s > 0:
        raise ValueError(f"a contact's scale_s must be positive, got {scale_s}")
    return int(np.argmin(np.abs(np.log(scales / scale_s))))


def true_probability(
    scale_s: np.ndarray | float,
    speed_mm_s: np.ndarray,
    speed_var_mm2_s2: np.ndarray | float,
    fs_hz: np.ndarray | float,
    mu_ln_s: float = MU_LN_S,
    slope: float = SLOPE,
    sigma_ln: float = SIGMA_LN,
    any_scale: float = ANY_SCALE,
) -> np.ndarray:
    """P(the bank reads a true contact at scale_s | the edge's speed), element-wise."""
    scale, speed, var, fs = np.broadcast_arrays(
        np.asarray(scale_s, float), np.asarray(speed_mm_s, float),
        np.asarray(speed_var_mm2_s2, float), np.asarray(fs_hz, float),
    )  # fmt: skip
    out = np.empty(scale.shape)
    speed = np.maximum(np.abs(speed), 1e-6)
    sigma = np.sqrt(sigma_ln**2 + slope**2 * np.maximum(var, 0.0) / speed**2)
    centre = mu_ln_s + slope * np.log(speed)  # the ln scale a ridge at this speed is found at
    for rate in np.unique(fs):
        scales, edges, _ = bank_scales(float(rate))
        at = fs == rate
        k = np.array([_index(float(s), scales) for s in scale[at]], dtype=np.int64)
        hi = ndtr((edges[k + 1] - centre[at]) / sigma[at])
        lo = ndtr((edges[k] - centre[at]) / sigma[at])
        out[at] = (1.0 - any_scale) * (hi - lo) + any_scale / len(scales)
    return np.maximum(out, PROBABILITY_FLOOR)


def log_ratio(
    scale_s: float, speed_mm_s: np.ndarray, speed_var_mm2_s2: np.ndarray, fs_hz: float
) -> np.ndarray:
    """ln P(scale | a ridge at each speed) - ln P(scale | clutter), per speed."""
    scales, _, share = bank_scales(float(fs_hz))
    false = max(float(share[_index(scale_s, scales)]), PROBABILITY_FLOOR)
    true = true_probability(scale_s, speed_mm_s, speed_var_mm2_s2, fs_hz)
    return np.log(true) - math.log(false)

"""Held corners: a ridge contact whose pulse the FSR's hysteresis hides, told by where the
previous pulse's decay stops.

Physics (the loop's FSR chain: a play operator 0.2 N wide, `simulators.effects`): while a
pulse decays the sensor follows it down; when the next ridge's pulse starts under it, the
input turns up and the play operator holds the output flat until the input has risen
through the band - so the new pulse shows no rise, often none at all (s30,
`benchmarks/missed_ridges.py`: "hysteresis-held"). But the decay stops at once where the
input turns: a slope jump from falling to *flat*, at about the new pulse's onset. The kink
bank sees it on its coarse scales and drops it, for nothing rises after it (the rise check,
`HingeSettings.rise_fraction`); the tail test (`tail_kinks`) may take it back, but then moves
it back by a share of its scale (`tail_onsets`: a new pulse on a tail bends the hinge late)
and the merge rule takes it, 80-160 ms after the previous contact, for that contact again.

A held corner is a tail kink (`tail_kinks.tail_kink` passed) after which the level lies flat
over the kink's scale: its least-squares slope within `flat_z` standard errors of zero (the
slope of a new pulse's rise, or of a decay going on, is not). It keeps the kink bank's time
(the corner is where the input turned) and is merged only within `merge_widths` of its
scale of an earlier contact (a distinct local maximum of its own channel lies a width off).

Off at `flat_z` 0 (`TailKinkSettings.corner_flat_z`), as shipped. Measured at 3 (s31, full
plan, 3 seeds, one run each; docs/decoding.md, "Held corners"): the loop's slip dropped
26.3 -> 25.9 %, constant missing 4.8 -> 4.0 %, but stick-slip wrong direction 3.5 -> 6.2 %.
"""

from __future__ import annotations

import math

import numpy as np


def slope_se_per_noise(width: int) -> float:
    """The standard error of a least-squares slope over width + 1 samples (N/sample), per
    unit of white noise (N per sample)."""
    k = np.arange(width + 1, dtype=np.float64) - width / 2.0
    return 1.0 / math.sqrt(float(k @ k))


def held_corner(slope_after: float, width: int, white_n: float, flat_z: float) -> bool:
    """Is a tail kink whose level's slope over its scale after it is `slope_after`
    (N/sample, `width` samples) a held corner (module doc)?"""
    if flat_z <= 0.0 or white_n <= 0.0:
        return False
    return abs(slope_after) <= flat_z * white_n * slope_se_per_noise(width)

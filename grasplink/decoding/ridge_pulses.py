"""How visible each ridge's contact is: the kink its pulse makes on the one before.

Physics (thesis ch. 5.3.1): the leading edge reaching ridge i starts a pulse that peaks
at alpha_i = 1 - exp(-D / `PULSE_SCALE_MM`) (times the contact's own strength), D the
spacing crossed before it, after a rise of `RISE_MM` of travel, as alpha u e^(1 - u) with
u the travel since the onset over RISE_MM. The pulse does not start from the level but
from the previous pulse's tail, so what the contact detector sees at the onset - a jump
of the slope, a *kink* - is the new pulse's rise less the previous pulse's fall:

    kink_i = alpha_i - alpha_(i-1) e^(-u) (e u + 1 - u),   u = D / RISE_MM

(in units of a lone full-height pulse's slope at its onset, which is speed-free: both
slopes scale with the speed). A short spacing after a tall pulse hides the ridge: 4 mm
after the first ridge met (alpha 0.86) leaves a kink of 0.10, 4 mm after a 3 mm one 0.26,
and 3 mm after a 48 mm gap none at all (the new pulse peaks below the old one's tail).
The spacing before alone (the tracker's former detection model) took the first for the
second: on alpha0.3 = (4, 3, 48, 29) forward, the 4 mm ridge after the first is found
about half the time, not 90 %, and the tracks that skipped it lost the posterior
(issue 22: constant speed missing from the 3rd contact).

Pure functions of the layout (no signal): the tracker builds its detection model from
them once (`TrackerDecoder`, `DETECT_KINKS`), the benchmarks group true contacts by them.
"""

from __future__ import annotations

import math

import numpy as np

PULSE_SCALE_MM = 10.0  # a pulse's height grows with the spacing before as 1 - exp(-D / this)
RISE_MM = 1.25  # a pulse peaks after this travel (half the ridge's 2.5 mm side)


def pulse_heights(spacings_before_mm: np.ndarray) -> np.ndarray:
    """Each contact's relative pulse height from the spacing crossed before it (mm)."""
    before = np.asarray(spacings_before_mm, dtype=float)
    return -np.expm1(-before / PULSE_SCALE_MM)


def onset_kinks(spacings_before_mm: np.ndarray) -> np.ndarray:
    """Per ridge in travel order: the kink at its contact's onset (module doc), given the
    spacing crossed before each ridge (the first's: the lead-in, any long distance - no
    pulse came before it). Below 0 the new pulse rises less than the old one falls: no
    kink. For spacings under RISE_MM the previous pulse was still rising; its tail is
    taken as if it had peaked (an approximation: such skins resolve no ridge anyway)."""
    before = np.asarray(spacings_before_mm, dtype=float)
    if before.ndim != 1 or not len(before):
        raise ValueError(f"spacings before each ridge: a non-empty 1-D array, got {before!r}")
    if not np.all(before > 0.0):
        raise ValueError(f"spacings before each ridge must be positive mm, got {before!r}")
    alpha = pulse_heights(before)
    u = before / RISE_MM
    previous = np.concatenate([[0.0], alpha[:-1]])  # the first ridge met: nothing before
    tail = previous * np.exp(-u) * (math.e * u + 1.0 - u)
    return alpha - tail

"""Where a slipping track expects its next ridge contacts: the detector's gate (issue 22).

The detector's gated pulse probe (`detector.pulse_gate`) reads a wider window at a lower
threshold, but only where it is told a contact is due (`ContactDetector.expect`). The
tracker tells it while it flags a slip, from a track with a speed: the time each of its
next ridges is due (its position and speed at its last contact, the ridge's position
ahead) give or take `k_sigma` of the timing's uncertainty (the Kalman position and speed
variances carried to that ridge) and a floor of `floor_s`. Past the last ridge no contact
can come, so no window is opened there: the rest after a slip (where a flag coasts) is
read as it is read today. Pure functions of numbers: sans-IO and deterministic.
"""

from __future__ import annotations

import math

import numpy as np


def due_windows(
    numbers: tuple, pos_mm: np.ndarray, count: int, ahead: int, floor_s: float, k_sigma: float
) -> list[tuple[float, float]]:
    """(first, last) times (s) in which a track's next `ahead` ridges are due.

    `numbers`: the track as `tracker._One.numbers` holds it (travel s at its contact
    time t, speed v, ..., P entries, direction, ridge of its last contact); `pos_mm`: the
    ridge positions along its direction (travel from the first ridge met), `count`
    ridges. No window for a track without a forward speed, or past the last ridge."""
    s, v = float(numbers[0]), float(numbers[1])
    t = float(numbers[5])
    p00, p01, p11 = float(numbers[7]), float(numbers[8]), float(numbers[9])
    ridge = int(numbers[14])
    if not (v > 0.0 and math.isfinite(v) and math.isfinite(t)):
        return []
    out = []
    for k in range(ridge + 1, min(count, ridge + 1 + ahead)):
        dt = (float(pos_mm[k]) - s) / v
        if dt <= 0.0:
            continue
        # the travel's variance at the due time, over the speed: the time's uncertainty
        var_mm2 = max(0.0, p00 + 2.0 * dt * p01 + dt * dt * p11)
        half = floor_s + k_sigma * math.sqrt(var_mm2) / v
        out.append((t + dt - half, t + dt + half))
    return out

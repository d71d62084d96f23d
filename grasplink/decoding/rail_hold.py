"""Holding the slip flag while the sensor sits on its rail (issue 22, "slip dropped").

Physics: a saturated FSR reads its full scale whatever lies on it, so no ridge contact can
show while it sits on the rail - but the object does not stop because the sensor
saturated. The tracker already discounts the rail from its silence (`TrackerDecoder._blind`),
yet the squeeze that drives the sensor into the rail is itself a slow rise, which the
contact detector tells as a step, and a step read as the slip's stop then held the
posterior with the flag down to the rail's end and past it (`benchmarks/dropped_causes.py`,
full plan, 2 seeds: the saturation kind's flag down 29 % of its sliding updates, 55 % of
them a stop at such a step, most of the rest silence or braking over the rail).

The rule: when the flag was up within `before_s` of the stretch of rail the sensor sits on
now (the squeeze's ramp and the detector's delay come first), the flag is held - no speed,
no direction: nothing on the rail tells either - until `after_s` past the rail's end. A
held object's flag never went up, so a held object is never flagged by it; a slip that
stops while the sensor saturates stays flagged until the rail ends (the stop is not
observable before then either: no contact, no step shows on the rail). `before_s` 0.6 s:
at 22 mm/s the squeeze's step was read as the stop up to 0.6 s before the sensor reached
its rail (0.3 s held only part: the saturation kind's slip dropped 29.3 -> 20.0 %, 0.6 s
-> 12.7 %, 1.0 s the same; `benchmarks/tune_tracker_kinds.py --full --seeds 2`).
"""

from __future__ import annotations

from collections.abc import Sequence


def stretch_start(blind: Sequence[tuple[float, float]], gap_s: float) -> float:
    """Start time of the stretch of rail the last blind block (`NoiseFloor.blind`: first
    and last sample time of each saturated block) belongs to: blocks whose gap to the next
    is at most `gap_s` are one stretch."""
    if not blind:
        raise ValueError("rail_hold: no rail block to start a stretch from")
    start = blind[-1][0]
    for k in range(len(blind) - 2, -1, -1):
        if start - blind[k][1] > gap_s:
            break
        start = blind[k][0]
    return start


def holds(
    blind: Sequence[tuple[float, float]],
    g: float,
    flag_t: float,
    lag_s: float,
    gap_s: float,
    before_s: float,
    after_s: float,
) -> bool:
    """Whether the flag is held at update time g: the sensor on its rail now (its last
    saturated block ended at most `lag_s` before g - the rail is told per noise block - or
    `after_s` more past it) and the flag up last at `flag_t`, no more than `before_s`
    before that stretch of rail began (`stretch_start` with `gap_s`)."""
    if lag_s < 0 or gap_s < 0 or before_s < 0 or after_s < 0:
        raise ValueError(
            f"rail_hold: lag, gap, before and after must be >= 0 s, got "
            f"{lag_s!r}, {gap_s!r}, {before_s!r}, {after_s!r}"
        )
    if not blind or blind[-1][1] < g - lag_s - after_s:
        return False
    return flag_t >= stretch_start(blind, gap_s) - before_s

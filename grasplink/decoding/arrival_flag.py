"""A slip shown from its arrival: the flag raised on a first contact onto an unloaded sensor.

Physics (`arrival`): the one FSR sees load only through the skin the object covers, so a
contact told while the sensor read unloaded is the object's edge sliding onto the skin at
one of its ends - it is moving. A held object never reads unloaded before a contact (the
grip presses it onto the skin first). The tracker's posterior flags a slip only once a
track has two contacts (`TrackerDecoder.EVIDENT_CONTACTS`, a pulse among them): on the
closed loop (object 8 mm off the skin) the slip belt waited for the second ridge, 19 mm
on (40 mm/s seed 1: arrival 1.200 s, flag 1.71 s).

The rule: after such a contact, while the posterior flags nothing, the slip is flagged
(no speed, no direction: one contact tells neither, and either end may be the one it
came in at) for as long as the next ridge of an entering slip may still be unseen -
P(no ridge contact told yet | a slip entering at either end, the tracker's speed prior and
detection model) at least `HOLD_P` (`TrackerDecoder.ARRIVAL_FLAG_P`). Silence ends it: an
object that slid onto the skin and stopped before its next ridge is no longer flagged
once that ridge is overdue for all but the slowest slips (1.9 s after a 20 mm/s arrival
on alpha0.1). Sooner, a stall ends it (`STALL_N`): an edge sliding on covers more skin,
so the level rises; once it lies flat for 0.2 s the object has stopped (that case: 0.4 s
after the stop, before its next ridge was due). It also ends for good once the
posterior has flagged the slip (the normal path has taken over: a later "no slip" there
is the posterior's stop or doubt, not the arrival's) and when the arrival contact is told
noise's pulse (noise, not an edge crossing a ridge) - a step no longer ends it
(`TrackerDecoder.ARRIVAL_STEP_KEEP`, s27): an edge sliding onto the skin leaves the object
lying there, so the level rises and stays, and the reversal kind's 25 mm object was told a
step in 7 of 9 arrivals, its flag down to the 2nd ridge; a grip pressing a placed object
is told by the stall and the silence - and while
the sensor reads unloaded again (`arrival.unloaded` over the last `arrival.LEVEL_S`:
nothing lies on the skin - a noise kink on the empty sensor, the loop's 30 mm/s alpha0.5
seed 162201 at 0.58 s, 0.4 s before the slip began).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from grasplink.decoding.kernels import posterior as posterior_kernels
from grasplink.decoding.kernels.common import ring_slot

#: the flag is held while P(the entering slip's next ridge not yet told) is at least this
HOLD_P = 0.2
#: a stall: the level's means over `STALL_WINDOWS` windows of `STALL_S` since the arrival
#: lie within this (N) of each other - an edge sliding on covers more skin, so the level
#: rises (stick-slip 118 mm/s alpha0.1: 0.2 N per 40 ms), and at rest it is flat (within
#: 0.01 N); the arrival pulse's fall is no stall. 0: off (silence alone ends the flag)
STALL_N = 0.02
STALL_S = 0.04
STALL_WINDOWS = 5


def waiting_p(
    elapsed_s: float, rows: Sequence[int], waiting: tuple, K: np.ndarray, latency_s: float
) -> float:
    """P(no ridge contact told yet) `elapsed_s` after a slip's first contact, averaged
    over the tracks' rows `rows` (direction x ridge: each way it may have entered), from
    the tracker's waiting tables (`TrackerDecoder._waiting_tables`: speed prior, spacing
    and detection model) less the detector's latency `latency_s`."""
    if not rows:
        raise ValueError("arrival_flag: no rows to wait on (a skin has two ends)")
    total = 0.0
    for row in rows:
        total += math.exp(posterior_kernels.log_waiting(elapsed_s - latency_s, row, waiting, K))
    return total / len(rows)


class ArrivalFlag:
    """Which arrival the flag is held for, and whether the posterior has taken over.

    `note(arrival_id, slipping)` at each report: the arrival contact in the tracker's
    history (its id, or -1 for none) and whether the posterior flags a slip. The flag may
    show only for an arrival the posterior has not yet flagged since it came, nor its
    silence ended (`expire`: the waiting probability only falls as the silence lasts, so
    it is not computed again for every update at rest)."""

    __slots__ = ("_done", "_id")

    def __init__(self) -> None:
        self._id = -1
        self._done = False

    def note(self, arrival_id: int, slipping: bool) -> bool:
        """Whether the arrival flag may still show for `arrival_id`."""
        if arrival_id != self._id:
            self._id, self._done = arrival_id, False
        if slipping and arrival_id >= 0:
            self._done = True
        return arrival_id >= 0 and not self._done

    def expire(self) -> None:
        """The current arrival's silence has ended its flag."""
        self._done = True


def verdict(contact_id: int, ring: np.ndarray, ring_id: np.ndarray) -> int:
    """A contact's pulse verdict in the tracker's ring (0: not told, or no longer held)."""
    slot = ring_slot(contact_id, len(ring))
    return int(ring[slot]) if ring_id[slot] == contact_id else 0


def stalled(
    mean: Callable[[int, int], float | None], end: int, since: int, fs_hz: float, flat_n: float
) -> bool:
    """Whether the level lay flat (`STALL_N`: its window means within `flat_n`) over the
    last `STALL_WINDOWS` windows of `STALL_S` before sample `end`, all after sample `since`
    (the arrival's onset); `mean(start, stop)` the mean of samples start..stop-1 (None: not
    held)."""
    samples = max(1, round(STALL_S * fs_hz))
    start = end - STALL_WINDOWS * samples
    if not flat_n > 0 or start < since:
        return False
    levels: list[float] = []
    for k in range(STALL_WINDOWS):
        level = mean(start + k * samples, start + (k + 1) * samples)
        if level is None:
            return False
        levels.append(level)
    return max(levels) - min(levels) < flat_n

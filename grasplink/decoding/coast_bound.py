"""The coast past the last ridge: how long a speed may be shown where none is observed.

Past a layout's last ridge (in a track's direction of travel) no contact can come, so
nothing observes the slip there: no ridge tells it went on, no silence tells it
stopped (the tracker's silence tables count no miss at the coast end, so a track that
reached the last ridge was shown slipping at its last speed until a step told the stop
- at 10 dB SNR a stop's step is seldom told - or the track went stale). Physics bounds
it instead: a slip that crossed the last ridge at v is, one typical interval later
(`intervals` x the spacing it crossed last, at v), either off the skin or stopped, and
which of the two no sensor here tells. From then the track is taken as stopped: no speed
is shown for it, and the slip it carried is no longer flagged.

Measured (benchmarks/rest_speed_causes.py, full plan, 2 seeds, snr10 with the rise
evidence on): 1127 of the 1944 at-rest updates showing a speed came from tracks whose
last contact was the last ridge, 864 of them more than one such interval after it;
bounded at one interval, 1052 at-rest updates with a speed are left.

The bound is applied to the silence schedule (`kernels.posterior.schedule`'s due,
adj, stopped, limit): for each slipping track with a speed, the column where its
schedule reaches the coast end (after its last contact at the last ridge, or after the
last ridge passed unseen) is due once its travel at its speed lies that far past the
last ridge, and stopped from then. Vectorised over the tracks.
"""

from __future__ import annotations

import numpy as np

V_FLOOR_MM_S = 2.0  # a speed below this is the tracker's slowest slip (`V_MIN_MM_S`)


def last_gaps(pos_mm: np.ndarray, count: int) -> np.ndarray:
    """Per direction (travel order rows of `pos_mm`, ridges then the coast end), the
    spacing crossed into the last ridge: the interval a track there measured last. A
    single-ridge layout has none: ValueError (no interval to bound a coast by)."""
    pos_mm = np.asarray(pos_mm, dtype=float)
    if count < 2 or pos_mm.ndim != 2 or pos_mm.shape[1] < count:
        raise ValueError(
            f"coast bound: needs 2 or more ridges in travel order, got {count} ridges "
            f"and positions of shape {pos_mm.shape}"
        )
    gaps = pos_mm[:, count - 1] - pos_mm[:, count - 2]
    if not np.all(np.isfinite(gaps) & (gaps > 0)):
        raise ValueError(f"coast bound: the spacings into the last ridge {gaps} are not > 0")
    return gaps


def bound(
    sched: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    tracks: dict[str, np.ndarray],
    pos_mm: np.ndarray,
    gaps_mm: np.ndarray,
    count: int,
    intervals: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The schedule with each slipping track stopped `intervals` intervals past the last
    ridge (see the module doc): in the column where its schedule reaches the coast end
    (the last ridge told by its contact, or passed unseen - a miss, or a rise read there:
    `rise_evidence.silence`), due when its travel at its speed has gone that far past
    the last ridge, and stopped from then. `tracks`: the tracks' s (travel at the last
    contact, mm), t (its time, s), v (speed, mm/s), stop (NaN: slipping), run (contacts
    since a (re)start), dirn (+1 / -1) and ridge (of the last contact, travel order);
    `pos_mm`: the ridges' positions by direction (travel order); `gaps_mm`: `last_gaps`.
    Writes into `sched`'s due and stopped (fresh arrays: a cached schedule is bounded
    once, when built)."""
    if not intervals > 0:
        raise ValueError(f"coast bound: {intervals!r} intervals is not a positive number")
    due, adj, stopped, limit = sched
    ahead = (count - 1) - tracks["ridge"]  # the column before the coast end's
    slipping = np.isnan(tracks["stop"]) & (tracks["run"] >= 2)
    rows = np.flatnonzero(slipping & (ahead >= 0) & (ahead + 1 < due.shape[1]))
    if not len(rows):
        return sched
    col = ahead[rows] + 1
    known = np.isfinite(due[rows, col])
    rows, col = rows[known], col[known]
    if not len(rows):
        return sched
    way = (1 - tracks["dirn"][rows]) // 2
    speed = np.maximum(np.abs(tracks["v"][rows]), V_FLOOR_MM_S)
    beyond = pos_mm[way, count - 1] + intervals * gaps_mm[way] - tracks["s"][rows]
    when = tracks["t"][rows] + np.maximum(beyond, 0.0) / speed
    due[rows, col] = np.maximum(when, due[rows, col - 1])
    stopped[rows, col] = True
    return due, adj, stopped, limit

"""A speed shown only while the ridge its own track predicts next is not overdue.

Why (issue 22, *speed after a stop's report was due*): the posterior keeps a slipping
track whose next ridge is due and silent for as long as "that ridge was missed" stays
likelier than its rivals ("stopped", "no slip"). A missed ridge is common (a 4 mm ridge
is told 92 % of the time), so that is right for the slip flag: its keep is the
posterior's. But the speed the report gives is a measurement: the motion the track's
contacts made, predicting when its next ridge comes. Once that ridge is overdue, by
the timing's own uncertainty at that speed, the speed has nothing behind it: either the
ridge was missed (the next contact will say so, and the speed comes back with it) or the
object stopped (and the speed would be the speed at rest the stop target counts).

So the report withholds the speed of a track past its next ridge's due time, computed
as the tracker's silence schedule computes it (`kernels.posterior.schedule`: the
interval at the track's speed and acceleration, its timing sigma three times, `LATE_REL`
of the interval and the detector's latency for that contact, the probes' where its last
contact came from one), with the timing sigma capped at `span_rel` of the interval
rather than the schedule's `SPAN_MAX_REL`: a braking twin with an unsure acceleration
otherwise waits up to 2.65 intervals (rates-drops 130520: due 1.47 s against a stop
ending 1.35 s). The flag and the range of speeds stay as the posterior has them, so
neither the slip dropped nor the stops' flag moves with it; the cost is the speed
missing while a missed ridge's next contact is awaited.

The ridge whose silence decides is never past the one the posterior itself stops the
track at (`report_log_p`: its LOG_STOP, P 0.2 - a 4 mm ridge, missed with P 0.08): the
posterior schedules none past that one, so a wait for it was a wait for the posterior's
own, later, due time (issue 22, session 29: stick-slip 86111, rates-drops 130111).

Pure functions of the tracker's arrays: the tracker (`TrackerDecoder._overdue`) calls
them once per bank and reads its chosen track's row.
"""

from __future__ import annotations

import math

import numpy as np

from grasplink.decoding.kernels import posterior as posterior_kernels


def report_constants(K: np.ndarray, span_rel: float, late_rel: float) -> np.ndarray:
    """The posterior kernels' constants `K` with the timing sigma capped at `span_rel` of
    the interval and `late_rel` of it allowed late: the report's own due times."""
    if not span_rel > 0 or not late_rel >= 0:
        raise ValueError(
            f"overdue speed: span_rel {span_rel} must be > 0, late_rel {late_rel} >= 0"
        )
    out = K.copy()
    out[posterior_kernels.SPAN_MAX_REL] = span_rel
    out[posterior_kernels.LATE_REL] = late_rel
    return out


def report_columns(log_miss: np.ndarray, ahead: int, log_p: float) -> np.ndarray:
    """Per (direction, ridge) row (di * (R + 1) + ridge, as the silence tables), the ridge
    ahead (0: the next, up to `ahead` - 1; `ahead`: none) whose silence withholds the speed:
    the first by which every ridge so far would have been missed with P <= exp(`log_p`).
    A ridge told 92 % of the time is missed often enough that its silence alone says
    little (a 4 mm spacing: `TrackerDecoder.DETECT_P`); the one after it then decides.
    `log_miss`: (2, R + 1) log P(a ridge missed), travel order, the coast end -inf."""
    if not log_p <= 0:
        raise ValueError(f"overdue speed: log P(missed) {log_p} must be <= 0")
    R = log_miss.shape[1] - 1
    di = np.repeat(np.arange(2), R + 1)
    ridge = np.tile(np.arange(R + 1), 2)
    kk = np.minimum(ridge[:, None] + 1 + np.arange(ahead), R)
    missed = np.cumsum(log_miss[di[:, None], kk], axis=1)
    hit = missed <= log_p
    return np.where(hit.any(axis=1), hit.argmax(axis=1), ahead)


def report_log_p(miss_p: float, log_stop: float | None) -> float:
    """log P(every ridge so far missed) at which the report's ridge ahead decides
    (`report_columns`' `log_p`): `miss_p`'s, but never below `log_stop`, the posterior's
    own (None: `miss_p` alone). The posterior reports a stop at the first ridge whose
    silence leaves P(all missed) under exp(`log_stop`) and never schedules the ridges past
    it (their time due is inf), so a report waiting for a later one would wait for the
    posterior's own due time - later than the report's, its sigma and late allowance
    wider - and show the speed until then (issue 22: a 4 mm ridge, told 92 %, stops the
    track at P 0.08, under log_stop's 0.2, while `miss_p` 0.05 waited for the next)."""
    log_p = math.log(miss_p) if miss_p > 0 else -math.inf
    return log_p if log_stop is None else max(log_p, log_stop)


def next_due_s(
    tracks: tuple, silence: tuple, skin: tuple, floor: np.ndarray, columns: np.ndarray
) -> np.ndarray:
    """Per track, when the ridge whose silence withholds its speed (`report_columns`'s
    `columns`, by row) is overdue (inf: none due - stopped, no speed yet, or nothing
    ahead), by the schedule kernel on `skin` (its `K` from `report_constants`).
    `tracks`, `silence`, `skin`: plain tuples of a `Tracks`, `Silence` and `Skin`;
    `floor`: each track's least latency (`TrackerDecoder._latency_floor`)."""
    due = posterior_kernels.schedule(tracks, silence, skin, floor)[0]
    named = posterior_kernels.Tracks(*tracks)
    R = posterior_kernels.Skin(*skin).pos.shape[1] - 1
    rows = (1 - named.dirn) // 2 * (R + 1) + np.minimum(named.ridge, R)
    col = columns[rows] + 1
    out = np.full(len(due), np.inf)
    ok = col < due.shape[1]
    out[ok] = due[np.flatnonzero(ok), col[ok]]
    return out


def overdue(due_s: float, g_s: float, blind_s: float = 0.0) -> bool:
    """Is a ridge due at `due_s` overdue at `g_s`, its track's contact having spent
    `blind_s` of that time on the sensor's rail (where no contact can show)?"""
    return g_s - blind_s > due_s


def latched(last: int, withheld: int, withheld_s: float, g_s: float, latch_s: float) -> bool:
    """Is a track whose last contact is `last` withheld at `g_s` by the latch: a speed from
    that contact (`withheld`) first went overdue at `withheld_s`, at most `latch_s` ago?"""
    return last == withheld and g_s - withheld_s <= latch_s

"""The coast past the last ridge (`decoding.coast_bound`): a speed shown there is no
longer observed, so it is shown for one interval at most.

Past a layout's last ridge no contact can come: without the bound a track there kept
its last speed until a step told the stop, which at 10 dB SNR seldom comes.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasplink.decoding import coast_bound
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

POS = np.array([[0.0, 5.0, 17.0, 84.0, 151.0], [0.0, 67.0, 79.0, 84.0, 151.0]])  # alpha0.5


def _sched(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    due = np.full((n, 4), np.inf)
    due[:, 0] = -np.inf
    due[:, 1] = 9.0  # the coast end or the next ridge, as the tables put it
    return due, np.zeros((n, 4)), np.zeros((n, 4), bool), np.zeros((n, 4), np.int64)


def _tracks(**fields) -> dict[str, np.ndarray]:
    base = {"s": 84.0, "t": 1.0, "v": 50.0, "stop": math.nan, "run": 3, "dirn": 1, "ridge": 3}
    n = max(np.size(v) for v in fields.values()) if fields else 1
    return {k: np.broadcast_to(fields.get(k, v), n).copy() for k, v in base.items()}


def test_a_track_at_the_last_ridge_stops_one_interval_after_its_contact():
    gaps = coast_bound.last_gaps(POS, 4)
    assert gaps.tolist() == [67.0, 5.0]  # the spacing into the last ridge, either way
    due, _, stopped, _ = coast_bound.bound(_sched(2), _tracks(dirn=[1, -1]), POS, gaps, 4, 1.0)
    assert due[0, 1] == pytest.approx(1.0 + 67.0 / 50.0)
    assert due[1, 1] == pytest.approx(1.0 + 5.0 / 50.0)
    assert stopped[:, 1].all() and not stopped[:, 2:].any()


def test_a_track_passing_the_last_ridge_unseen_stops_past_it_too():
    # its last contact two ridges back (column 2 is its coast end), 10 mm short of it
    tracks = _tracks(ridge=[1, 2, 2, 2], s=[5.0, 17.0, 17.0, 17.0], stop=[math.nan] * 3 + [1.0])
    tracks["run"][2] = 1  # no speed yet: nothing to bound
    sched = _sched(4)
    sched[0][:, 2] = 9.5
    due, _, stopped, _ = coast_bound.bound(sched, tracks, POS, np.array([67.0, 5.0]), 4, 1.0)
    assert due[1, 2] == pytest.approx(max(9.0, 1.0 + (84.0 + 67.0 - 17.0) / 50.0))
    assert stopped[1, 2] and not stopped[1, 1]
    assert not stopped[0].any()  # its coast end lies past the columns scheduled
    assert not stopped[2:].any()  # no speed yet / stopped already


def test_a_coast_already_done_stays_done():
    sched = _sched(1)
    sched[0][0, 1] = np.inf  # silence stopped it before the coast end
    due, _, stopped, _ = coast_bound.bound(sched, _tracks(), POS, np.array([67.0, 5.0]), 4, 1.0)
    assert due[0, 1] == np.inf and not stopped[0, 1]


def test_bad_input_is_refused_by_name():
    with pytest.raises(ValueError, match="2 or more ridges"):
        coast_bound.last_gaps(POS[:, :1], 1)
    with pytest.raises(ValueError, match="not > 0"):
        coast_bound.last_gaps(np.array([[0.0, 0.0, 1.0]]), 2)
    with pytest.raises(ValueError, match="intervals"):
        coast_bound.bound(_sched(1), _tracks(), POS, np.array([67.0, 5.0]), 4, 0.0)


def test_ten_db_slip_past_the_last_ridge_shows_no_speed_at_rest():
    # snr10, alpha0.1 reversed at 57 mm/s: the last contact at 1.889 s, the edge stops
    # 6 mm past the last ridge at 2.025 s; the spacing into it is 19 mm (0.33 s)
    case = next(
        c
        for c in sr.cases(sr.FULL)
        if c.kind == "snr10" and c.layout == "alpha0.1" and c.reverse and c.seed == 110001
        and c.variant == "57 mm/s"
    )  # fmt: skip
    rec = case.make()

    def speeds(tuning: dict) -> tuple[np.ndarray, np.ndarray]:
        decoder = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz, tuning=tuning)
        est, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
        return np.array([e.t_s for e in est]), np.array([e.speed_mm_s or 0.0 for e in est])

    rest = 2.025 + sr.REST_SETTLED_S
    t, unbounded = speeds({"RISE_EVIDENCE": 1.0, "COAST_INTERVALS": 0.0})
    assert (unbounded[t > rest] > 0).any()  # shown on through the rest
    t, bounded = speeds({"RISE_EVIDENCE": 1.0, "COAST_INTERVALS": 1.0})
    assert not (bounded[t > rest] > 0).any()
    assert (bounded[(t > 1.9) & (t < 2.1)] > 0).all()  # within the interval: shown

"""The compiled pruning keeps exactly the tracks the numpy pruning kept (`reference.tracker`,
the numpy `_prune` of 0858d90, run in this process on the same pools).

Exactly, on any CPU: the pruning compares scores it is given (order, a floor at one
subtraction from the best, `score[0] - negligible - 20` in the same order both sides),
integer keys (int64 multiply-adds, wrapping alike) and counts; no rounding can differ.
"""

from __future__ import annotations

from functools import cache
from types import SimpleNamespace

import numpy as np
import pytest

from grasplink.decoding import tracker as tr
from grasplink.decoding.kernels import layout
from grasplink.decoding.kernels.prune import prune_choice
from grasplink.evaluation import nonstationary
from tests.decoding.reference import tracker as reference

NEGLIGIBLE, MAX_HYPOTHESES, PER_START = (
    tr.TrackerDecoder.NEGLIGIBLE,
    24,
    tr.TrackerDecoder.PER_START,
)


def choose(score, stop, ints, recent, held, max_hypotheses=MAX_HYPOTHESES):
    """The compiled choice, checked against the numpy code's on the same pool."""
    recent, held = np.asarray(recent, np.int64), np.asarray(held, np.int64)
    chosen = prune_choice(score, stop, ints, recent, held, NEGLIGIBLE, max_hypotheses, PER_START)
    constants = SimpleNamespace(
        NEGLIGIBLE=NEGLIGIBLE, max_hypotheses=max_hypotheses, PER_START=PER_START
    )
    pool = tr._Bank(np.zeros((len(score), tr._F_WIDTH)), np.asarray(ints))
    pool._f[:, layout.F_SCORE], pool._f[:, layout.F_STOP] = score, stop
    expected = reference.prune_choice(constants, pool, recent, held)  # type: ignore[arg-type]
    np.testing.assert_array_equal(chosen, expected)
    return chosen


@cache
def pools() -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Every pool the tracker pruned decoding slips (steady, speeding up, stopping,
    reversing) three samples at a time, as the gateway does: (score, stop, int columns,
    recent and held contact ids)."""
    out = []
    for sig in nonstationary.signals(True)[:10]:
        rec = sig.make()
        dec = tr.TrackerDecoder(rec.truth.layout_mm, rec.fs_hz)
        prune = dec._prune

        def recording(B, recent, held, prune=prune):
            if len(B):
                out.append((B.score.copy(), B.stop.copy(), B._i.copy(), recent.copy(), held.copy()))
            return prune(B, recent, held)

        dec._prune = recording  # type: ignore[method-assign]
        t, x = np.asarray(rec.t_s), np.asarray(rec.force_n)
        for i in range(0, len(t), 3):
            dec.process(t[i : i + 3], x[i : i + 3])
    return out


def bank(rows: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(score, stop, ints) of tracks given by a few fields (the rest zero)."""
    ints = np.zeros((len(rows), tr._I_WIDTH), np.int64)
    for r, row in enumerate(rows):
        ints[r, layout.I_COLS["ids"]] = row.get("ids", (r, r + 1000, r + 2000, 0, 0, 0))[::-1]
        ints[r, layout.I_N] = row.get("n", 3)
        ints[r, layout.I_RUN] = row.get("run", 3)
        ints[r, layout.I_FIRST] = row.get("first", 0)
        ints[r, layout.I_RIDGE] = row.get("ridge", 0)
    score = np.array([row["score"] for row in rows], float)
    stop = np.array([row.get("stop", np.nan) for row in rows], float)
    return score, stop, ints


def test_compiled_pruning_keeps_the_tracks_the_numpy_pruning_kept():
    found = pools()
    assert len(found) >= 100
    dropped = quota = 0
    for k, (score, stop, ints, recent, held) in enumerate(found):
        chosen = choose(score, stop, ints, recent, held)
        dropped += len(chosen) < len(score)
        quota += len(chosen) > MAX_HYPOTHESES
        assert len(chosen), f"pool {k}"
    assert dropped >= 50 and quota >= 5  # pools that were cut, and kept beyond the best 24


def test_pruning_breaks_score_ties_by_pool_order():
    score, stop, ints = bank([{"score": 1.0, "first": r} for r in range(6)])
    assert choose(score, stop, ints, [], [], max_hypotheses=4).tolist() == [0, 1, 2, 3]


def test_pruning_keeps_the_best_of_tracks_with_the_same_key():
    same = (7, 8, 9, 0, 0, 0)
    score, stop, ints = bank([{"score": 1.0, "ids": same}, {"score": 2.0, "ids": same}])
    assert choose(score, stop, ints, [], []).tolist() == [1]
    stop[0] = 5.0  # stopped and slipping are different states: both kept
    assert choose(score, stop, ints, [], []).tolist() == [1, 0]


def test_pruning_drops_tracks_far_below_the_best_and_old_one_contact_starts():
    score, stop, ints = bank(
        [
            {"score": 0.0},
            {"score": -(NEGLIGIBLE + 20.0) - 1e-9},  # just beyond the floor
            {"score": -1.0, "n": 1, "run": 1, "ids": (42, -1, -1, -1, -1, -1)},
            {"score": -2.0, "n": 1, "run": 1, "ids": (43, -1, -1, -1, -1, -1)},
        ]
    )
    assert choose(score, stop, ints, recent=[43], held=[]).tolist() == [0, 3]


def test_pruning_keeps_per_start_quota_beyond_the_best_max_hypotheses():
    rows = [{"score": -r, "first": 1} for r in range(6)] + [{"score": -10 - r, "first": 2}
                                                            for r in range(6)]  # fmt: skip
    score, stop, ints = bank(rows)
    kept = choose(score, stop, ints, [], held=[2], max_hypotheses=2).tolist()
    assert kept == [0, 1, 6, 7, 8, 9]  # the best two, and the best PER_START of start 2
    assert PER_START == 4


@pytest.mark.parametrize("size", [1, 2])
def test_pruning_a_tiny_pool(size):
    score, stop, ints = bank([{"score": -float(r)} for r in range(size)])
    assert choose(score, stop, ints, [], []).tolist() == list(range(size))


def test_pruning_tells_apart_tracks_whose_keys_wrap_int64():
    big = 2**40  # id * 1000003^3 wraps around 2^64
    score, stop, ints = bank(
        [
            {"score": 0.0, "ids": (big, 1, 2, 0, 0, 0)},
            {"score": -1.0, "ids": (big + 1, 1, 2, 0, 0, 0)},
        ]
    )
    assert choose(score, stop, ints, [], []).tolist() == [0, 1]

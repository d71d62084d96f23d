"""The compiled pruning keeps exactly the tracks the numpy pruning kept (golden pools)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from grasplink.gateway.decoding import tracker as tr
from grasplink.gateway.decoding.kernels.prune import prune_choice

GOLDEN = Path(__file__).parent / "data" / "prune_golden.npz"
NEGLIGIBLE, MAX_HYPOTHESES, PER_START = (
    tr.TrackerDecoder.NEGLIGIBLE,
    24,
    tr.TrackerDecoder.PER_START,
)


def choose(score, stop, ints, recent, held, max_hypotheses=MAX_HYPOTHESES):
    recent, held = np.asarray(recent, np.int64), np.asarray(held, np.int64)
    return prune_choice(score, stop, ints, recent, held, NEGLIGIBLE, max_hypotheses, PER_START)


def bank(rows: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(score, stop, ints) of tracks given by a few fields (the rest zero)."""
    ints = np.zeros((len(rows), tr._I_WIDTH), np.int64)
    for r, row in enumerate(rows):
        ints[r, tr._IDS] = row.get("ids", (r, r + 1000, r + 2000, 0, 0, 0))[::-1]
        ints[r, tr._N] = row.get("n", 3)
        ints[r, tr._RUN] = row.get("run", 3)
        ints[r, tr._FIRST] = row.get("first", 0)
        ints[r, tr._RIDGE] = row.get("ridge", 0)
    score = np.array([row["score"] for row in rows], float)
    stop = np.array([row.get("stop", np.nan) for row in rows], float)
    return score, stop, ints


def test_compiled_pruning_keeps_the_tracks_the_numpy_pruning_kept():
    golden = np.load(GOLDEN)
    pools = len(golden.files) // 6
    assert pools >= 10
    for k in range(pools):
        chosen = choose(
            golden[f"score{k}"], golden[f"stop{k}"], golden[f"ints{k}"],
            golden[f"recent{k}"], golden[f"held{k}"],
        )  # fmt: skip
        np.testing.assert_array_equal(chosen, golden[f"chosen{k}"], err_msg=f"pool {k}")


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

"""The tracker's hypothesis bank (`_Bank`): all fields packed in two matrices, read as
views. Taking tracks must carry every field of each track along."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding.tracker import IDS, _Bank

N = 5


def bank(offset: float = 0.0, n: int = N) -> _Bank:
    """A bank whose every field differs between tracks (and from `offset`'s other bank)."""
    rows = np.arange(n)
    return _Bank.of(
        P=(offset + rows[:, None, None] * 100.0 + np.arange(16).reshape(4, 4)).astype(float),
        X=offset + rows[:, None] * 10.0 + np.arange(4.0),
        dirn=np.where(rows % 2 == 0, 1, -1),
        first=int(offset) + rows + 1000,
        ids=int(offset) + rows[:, None] * 10 + np.arange(IDS),
        m=offset + rows + 0.5,
        model=rows % 2,
        n=int(offset) + rows + 1,
        ridge=int(offset) + rows + 3,
        run=int(offset) + rows + 2,
        score=offset - rows * 1.5,
        sig=offset + rows * 0.001,
        stop=np.where(rows % 2 == 0, np.nan, offset + rows * 0.1),
        t=offset + rows * 0.25,
        before=offset + rows * 2.5,
    )


def fields(B: _Bank, i: int) -> dict[str, np.ndarray]:
    return {key: np.array(getattr(B, key)[i]) for key in _Bank.FIELDS}


def same(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    return all(np.array_equal(a[k], b[k], equal_nan=True) for k in _Bank.FIELDS)


def test_taking_tracks_keeps_every_field_of_each_track():
    B = bank()
    idx = np.array([3, 0, 3, 4])
    out = B.take(idx)
    assert len(out) == len(idx)
    for j, i in enumerate(idx):
        assert same(fields(out, j), fields(B, int(i)))


def test_field_views_stay_consistent_with_the_packed_matrices():
    B = bank()
    assert B.P.shape == (N, 4, 4) and B.X.shape == (N, 4) and B.ids.shape == (N, IDS)
    assert B.score.shape == (N,) and B.n.dtype == np.int64 and B.score.dtype == np.float64
    assert np.may_share_memory(B.P, B.X) and np.may_share_memory(B.ids, B.ridge)  # views
    some = B.take(np.arange(1, 4))
    assert len(some) == 3 and same(fields(some, 0), fields(B, 1))
    assert np.array_equal(some.P, B.P[1:4]) and np.array_equal(some.ids, B.ids[1:4])


def test_the_empty_bank_is_one_read_only_instance_with_every_field():
    E = _Bank.empty()
    assert E is _Bank.empty() and len(E) == 0
    assert E.P.shape == (0, 4, 4) and E.X.shape == (0, 4) and E.ids.shape == (0, IDS)
    for key in _Bank.FIELDS:
        assert len(getattr(E, key)) == 0
        with pytest.raises(ValueError):
            getattr(E, key)[...] = 0
    assert len(E.take(np.zeros(0, np.int64))) == 0


def test_a_bank_has_no_other_fields():
    with pytest.raises(AttributeError):
        _ = bank().speed  # type: ignore[attr-defined]

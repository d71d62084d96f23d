"""The tracker's branching as one compiled kernel (`kernels.branch`, called by
`TrackerDecoder._branch`): the children pools it builds are those the numpy code built
(recorded in data/branch_golden.npz by data/make_branch_golden.py, before the numpy code
was replaced), in the same order, within 1e-9 relative - numpy's SIMD exp/log and BLAS's
FMAs round differently from the kernel's, by ulps."""

from __future__ import annotations

from functools import cache
from pathlib import Path

import numpy as np
import pytest

from grasplink.gateway.decoding.contacts import STEP_IDS, ContactEvent
from grasplink.gateway.decoding.kernels import branch as kernel
from grasplink.gateway.decoding.tracker import _F_WIDTH, _I_WIDTH, TrackerDecoder, _Bank
from grasplink.profiles.layouts import LAYOUTS_MM

GOLDEN = Path(__file__).parent / "data" / "branch_golden.npz"


@cache
def golden() -> dict[str, np.ndarray]:
    with np.load(GOLDEN) as data:
        return dict(data)


@cache
def decoder(layout: str, fs: int) -> TrackerDecoder:
    """One decoder per layout and rate (building one takes a while); each case sets the
    state `_branch` reads."""
    return TrackerDecoder(LAYOUTS_MM[layout], fs)


def branch_case(k: int) -> tuple[_Bank, float, _Bank, float]:
    """Case k of the golden file branched now: (pool, null score, golden pool, golden
    null score)."""
    g = golden()
    dec = decoder(str(g["layouts"][g["layout"][k]]), int(g["fs"][k]))
    a, b = g["in_at"][k], g["in_at"][k + 1]
    dec._tracks, dec._null = _Bank(g["in_f"][a:b].copy(), g["in_i"][a:b].copy()), g["null"][k, 0]
    ev_id = int(g["ev_id"][k])
    t_s, sigma_s, z = (float(x) for x in g["ev"][k])
    dec._steps = {ev_id: (None, False, True)[g["trend_on"][k] + 1]} if g["step"][k] else {}
    pool = dec._branch(ContactEvent(ev_id, t_s, 0, 0, z, 0.0, 0.0, sigma_s))
    a, b = g["out_at"][k], g["out_at"][k + 1]
    return pool, dec._null, _Bank(g["out_f"][a:b], g["out_i"][a:b]), float(g["null"][k, 1])


def assert_same_pool(pool: _Bank, expected: _Bank) -> None:
    assert pool._f.shape == expected._f.shape
    np.testing.assert_array_equal(pool._i, expected._i)
    np.testing.assert_allclose(pool._f, expected._f, rtol=1e-9, atol=0.0, equal_nan=True)


def test_compiled_branch_matches_the_numpy_children_pools():
    g = golden()
    kinds = {"step": 0, "probe": 0}
    for k in range(len(g["layout"])):
        pool, null, expected, expected_null = branch_case(k)
        assert_same_pool(pool, expected)
        assert null == expected_null
        kinds["step"] += bool(g["step"][k])
        kinds["probe"] += bool(g["ev_id"][k] >= STEP_IDS)
    assert kinds["step"] >= 20 and kinds["probe"] >= 10  # the rarer branch kinds are in


def test_compiled_branch_keeps_the_numpy_codes_edge_cases():
    """The last six golden cases: no tracks (a contact: births only; a probe: nothing),
    one track, NaN speed / inf dip variance / -inf score, a contact at a track's own time
    with exact timing, and the odd bank at a step probe."""
    g = golden()
    first = len(g["layout"]) - 6
    sizes = []
    for k in range(first, first + 6):
        pool, null, expected, expected_null = branch_case(k)
        assert_same_pool(pool, expected)
        assert null == expected_null
        sizes.append(len(pool))
    assert sizes[0] == 2 * decoder(str(g["layouts"][g["layout"][first]]), 400).count
    assert sizes[1] == 0
    pool, *_ = branch_case(first + 3)
    assert np.isnan(pool._f).any() and np.isinf(pool._f).any()  # the odd numbers go through


def test_compiled_branch_of_no_tracks_at_a_probe_is_the_shared_empty_bank():
    """A probe on no tracks has no children: `_branch` gives the one empty bank, as
    before (the replay memo compares banks by identity)."""
    g = golden()
    pool, *_ = branch_case(len(g["layout"]) - 5)
    assert pool is _Bank.empty()


def test_a_banks_fields_are_the_kernels_columns():
    """The tracker's field views read the columns the kernels write (one layout, defined
    in kernels.branch): each field of a track round-trips through its column."""
    floats = np.arange(2 * _F_WIDTH, dtype=float).reshape(2, _F_WIDTH)
    ints = np.arange(2 * _I_WIDTH).reshape(2, _I_WIDTH)
    bank = _Bank(floats, ints)
    assert bank.score[1] == floats[1, kernel.F_SCORE] and bank.t[0] == floats[0, kernel.F_T]
    assert bank.X[1, 1] == floats[1, kernel.F_V] and bank.P[0, 3, 3] == floats[0, kernel.P33]
    assert bank.run[1] == ints[1, kernel.I_RUN] and bank.ids[0, -1] == ints[0, kernel.I_LAST]
    assert bank.model[0] == ints[0, kernel.I_MODEL]


def test_compiled_branch_constants_are_packed_by_name():
    dec = decoder("alpha0.1", 400)
    values = dec._branch_constant_values()
    packed = kernel.pack_constants(values)
    assert packed[kernel.LOG_RESTART] == dec.LOG_RESTART
    assert packed[kernel.STALE_S] == dec._stale_s
    with pytest.raises(ValueError, match="stale_s"):
        kernel.pack_constants({k: v for k, v in values.items() if k != "stale_s"})

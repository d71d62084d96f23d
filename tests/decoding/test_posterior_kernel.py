"""The compiled posterior says what the numpy posterior said, call by call (golden runs)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from grasplink.evaluation import nonstationary
from grasplink.gateway.decoding import tracker
from grasplink.gateway.decoding.kernels.posterior import constants, pairwise_sum
from tests.decoding.data.make_posterior_golden import record
from tests.decoding.test_numerical_edges import railed_slip

GOLDEN = np.load(Path(__file__).parent / "data" / "posterior_golden.npz")


def golden_runs() -> list[str]:
    return [name for name in GOLDEN.files if name != "columns"]


@pytest.mark.parametrize("name", golden_runs())
def test_compiled_posterior_matches_the_numpy_posterior(name):
    if name.startswith("railed"):
        rec = railed_slip(60.0, name == "railed1")
        got = record(rec.t_s, rec.force_n, rec.layout_mm, rec.fs_hz)
    else:
        rec = nonstationary.signals(True)[int(name.removeprefix("signal"))].make()
        t, x = np.asarray(rec.t_s), np.asarray(rec.force_n)
        got = record(t, x, rec.truth.layout_mm, rec.fs_hz)
    want = GOLDEN[name]
    assert got.shape == want.shape
    # exp and log round differently from numpy's SIMD loops: equal to ~1e-15, not in bits
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12, equal_nan=True)


def test_the_golden_runs_cover_slips_silence_on_the_rail_and_no_slip():
    runs = [GOLDEN[name] for name in golden_runs()]
    blind = sum(int(r[:, -1].sum()) for r in runs)
    chosen = sum(int(np.isfinite(r[:, 7]).sum()) for r in runs)
    none = sum(int(np.isnan(r[:, 7]).sum()) for r in runs)
    stopped = sum(int((r[:, 5] == 1.0).sum()) for r in runs)
    assert blind >= 20 and chosen >= 100 and none >= 30 and stopped >= 10


@pytest.mark.parametrize("size", [0, 1, 7, 8, 9, 16, 127, 128, 129, 300, 1000])
def test_pairwise_sum_adds_in_numpys_order(size):
    x = np.exp(np.random.default_rng(size).normal(size=size) * 6)
    assert pairwise_sum(x) == np.add.reduce(x)  # bit for bit


def test_posterior_constants_are_all_named():
    with pytest.raises(ValueError, match=r"missing .*refresh_s"):
        constants(negligible=25.0)


def test_warm_up_leaves_the_decoder_it_is_asked_of_as_it_was():
    rec = nonstationary.signals(True)[0].make()
    t, x = np.asarray(rec.t_s), np.asarray(rec.force_n)
    warmed = tracker.TrackerDecoder(rec.truth.layout_mm, rec.fs_hz)
    tracker._WARM = False  # as in a fresh process
    warmed.warm_up()
    assert tracker._WARM
    fresh = tracker.TrackerDecoder(rec.truth.layout_mm, rec.fs_hz)
    assert warmed.feed(t, x) == fresh.feed(t, x)

"""The rise-scale likelihood (`decoding.rise_travel`): a ridge contact's scale against the
track's speed, beside clutter's."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding import rise_travel as rt

SPEEDS = np.array([3.0, 10.0, 30.0, 65.0, 150.0])


@pytest.mark.parametrize("fs_hz", [100.0, 200.0, 400.0, 1000.0])
def test_a_ridge_is_found_at_one_of_the_banks_scales_at_every_rate(fs_hz):
    """Per speed the scales' probabilities sum to one, with the speed known or not; at
    100 Hz the 5 ms scale is the 10 ms one (one sample), so the bank has four."""
    scales = rt.bank_scales(fs_hz)[0]
    assert len(scales) == (4 if fs_hz == 100.0 else 5)
    for var in (0.0, 400.0):
        total = sum(rt.true_probability(s, SPEEDS, var, fs_hz) for s in scales)
        np.testing.assert_allclose(total, 1.0, rtol=1e-12)


def test_a_long_rise_at_a_fast_track_is_clutter_and_a_short_one_a_ridge():
    """The headline loop's false contact (80 ms scale, read at 65 mm/s: 5 mm of travel)
    against a ridge's 10 ms at the same speed."""
    long_rise = rt.log_ratio(0.08, np.array([65.0]), np.array([0.0]), 400.0)[0]
    ridge = rt.log_ratio(0.01, np.array([65.0]), np.array([0.0]), 400.0)[0]
    assert long_rise < -2.0 < 0.5 < ridge
    # the same 80 ms at a slow track (5 mm/s: 0.4 mm of travel) is a ridge's
    assert rt.log_ratio(0.08, np.array([5.0]), np.array([0.0]), 400.0)[0] > 0.0


def test_an_uncertain_speed_predicts_the_scale_less_sharply():
    """A track whose speed is known to +-30 mm/s (one sigma) at 65 mm/s says less about
    an 80 ms contact than one known exactly."""
    exact = rt.log_ratio(0.08, np.array([65.0]), np.array([0.0]), 400.0)[0]
    loose = rt.log_ratio(0.08, np.array([65.0]), np.array([900.0]), 400.0)[0]
    assert exact < loose < 0.0


def test_a_rise_shorter_than_the_finest_scale_reads_as_it():
    """At 100 Hz a fast ridge (150 mm/s) is read at 10 ms, the finest scale there: as
    likely as a 5 or 10 ms contact together at 400 Hz (but for the share found at any
    scale, spread over four scales at 100 Hz, five at 400)."""
    fast = np.array([150.0])
    at_100 = rt.true_probability(0.01, fast, 0.0, 100.0, any_scale=0.0)[0]
    at_400 = sum(rt.true_probability(s, fast, 0.0, 400.0, any_scale=0.0)[0] for s in (0.005, 0.01))
    assert at_100 == pytest.approx(at_400, rel=1e-12)


@pytest.mark.parametrize(
    ("scale_s", "fs_hz", "words"),
    [(0.0, 400.0, "scale_s"), (0.01, 0.0, "fs_hz"), (-1.0, 400.0, "scale_s")],
)
def test_bad_numbers_are_refused_by_name(scale_s, fs_hz, words):
    with pytest.raises(ValueError, match=words):
        rt.log_ratio(scale_s, np.array([30.0]), np.array([0.0]), fs_hz)

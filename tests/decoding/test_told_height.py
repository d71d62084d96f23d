"""`told_height`: a told pulse's height weighed against the spacing before the ridge a child
gives it - a tall pulse favours a ridge after a wide spacing, a low one a ridge after a
short spacing, and no one pulse moves a child by more than the clip."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasplink.decoding import rise_evidence as rev
from grasplink.decoding import told_height, told_rise
from grasplink.decoding.detector.events import ContactEvent
from grasplink.decoding.detector.step_shape import Recent
from grasplink.decoding.kernels.layout import (
    F_SCORE,
    F_STOP,
    F_V,
    F_WIDTH,
    I_DIRN,
    I_LAST,
    I_RIDGE,
    I_RUN,
    I_WIDTH,
)
from grasplink.decoding.ridge_pulses import RISE_MM

FS_HZ = 400.0
WHITE_N = 0.1  # 10 dB: pulses a few noise units high
ONSET = 300
SPEED_MM_S = 40.0
# travel order, both ways: a 4 mm spacing before ridge 1 going +1, a 40 mm one before it
# going -1 (the first ridge met after the skin's length)
BEFORE_MM = np.array([[60.0, 4.0, 40.0], [60.0, 40.0, 4.0]])


def _mu() -> np.ndarray:
    log_f = told_height.log_factor(BEFORE_MM)
    return told_height.SLOPE * (log_f - told_height.centre(log_f, np.ones(BEFORE_MM.shape)))


def test_a_tall_pulse_favours_the_ridge_after_the_wide_spacing():
    mu = _mu()
    median = np.ones(2)
    tall = told_height.gain(np.array([2.0, 2.0]), median, np.array([mu[0, 1], mu[1, 1]]), mu)
    low = told_height.gain(np.array([0.4, 0.4]), median, np.array([mu[0, 1], mu[1, 1]]), mu)
    assert tall[1] > 0 > tall[0]  # (ridge 1 after 40 mm going -1 wins)
    assert low[0] > low[1]


@pytest.mark.parametrize("z", [1e-3, 1e3, -5.0])
def test_one_odd_pulse_moves_a_child_no_more_than_the_clip(z):
    mu = _mu()
    g = told_height.gain(np.array([z]), np.ones(1), mu[:1, 1], mu, clip=1.0)
    assert abs(float(g[0])) <= 1.0


def test_a_height_not_read_adds_nothing():
    mu = _mu()
    assert told_height.gain(np.array([math.nan]), np.ones(1), mu[:1, 1], mu)[0] == 0.0


def test_a_nonsense_spread_is_refused():
    mu = _mu()
    with pytest.raises(ValueError):
        told_height.gain(np.ones(1), np.ones(1), mu[:1, 1], mu, sigma=0.0)


def _evidence(x: np.ndarray) -> rev.RiseEvidence:
    recent = Recent(FS_HZ)
    recent.append(x)
    return rev.RiseEvidence(FS_HZ, recent, lambda block: (WHITE_N, 8), 50, 1e-3)


def test_the_child_whose_ridge_fits_the_pulse_height_gains_against_its_alias():
    """A 1 N pulse where the told median is 0.35 N: the child going -1 (40 mm before its
    ridge) gains on the child going +1 (4 mm before the same ridge)."""
    rng = np.random.default_rng(5)
    n = 600
    tau_s = np.clip((np.arange(n) - ONSET) / FS_HZ, 0.0, None)
    u = tau_s * SPEED_MM_S / RISE_MM
    x = 0.6 + 1.0 * u * np.exp(1.0 - u) + WHITE_N * rng.standard_normal(n)
    evidence = _evidence(x)
    width = int(evidence.width_for(np.array([SPEED_MM_S]))[0])
    evidence._told = {1: np.where(evidence.widths == width, 3.5, math.nan)}
    floats, ints = np.zeros((2, F_WIDTH)), np.zeros((2, I_WIDTH), np.int64)
    floats[:, F_STOP] = math.nan
    floats[:, F_V] = SPEED_MM_S
    ints[:, I_LAST], ints[:, I_RUN], ints[:, I_RIDGE] = 7, 2, 1
    ints[:, I_DIRN] = [1, -1]
    ev = ContactEvent(7, ONSET / FS_HZ, ONSET, ONSET + 80, 5.0, 2.0, 0.08, 0.01)
    read = told_rise.rise_z(floats, ints, ev, evidence)
    assert np.all(np.isfinite(read[2]))
    told_height.weigh(floats, ints, read, evidence, _mu())
    assert floats[1, F_SCORE] > floats[0, F_SCORE]

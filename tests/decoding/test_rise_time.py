"""`rise_time`: a told pulse's rise read on the probe's windows favours the speed whose rise
time (RISE_MM / speed) made it, and reads nothing it does not hold."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding import rise_evidence as rev
from grasplink.decoding import rise_time
from grasplink.decoding.detector.step_shape import Recent
from grasplink.decoding.kernels.layout import F_SCORE, F_V, F_WIDTH
from grasplink.decoding.ridge_pulses import RISE_MM

FS_HZ = 400.0
WHITE_N = 0.1
ONSET = 300


def _evidence(speed_mm_s: float, seed: int, n: int = 700) -> rev.RiseEvidence:
    rng = np.random.default_rng(seed)
    tau_s = np.clip((np.arange(n) - ONSET) / FS_HZ, 0.0, None)
    u = tau_s * speed_mm_s / RISE_MM
    x = 0.6 + 1.0 * u * np.exp(1.0 - u) + WHITE_N * rng.standard_normal(n)
    recent = Recent(FS_HZ)
    recent.append(x)
    return rev.RiseEvidence(FS_HZ, recent, lambda block: (WHITE_N, 8), 50, 1e-3)


def test_a_unit_pulse_reads_highest_on_the_window_nearest_its_rise():
    widths = np.array([4, 8, 16])
    g = rise_time.response(widths, np.array([4.0, 16.0]))
    assert np.argmax(g[0]) < np.argmax(g[1])


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("true_mm_s, alias_mm_s", [(80.0, 20.0), (20.0, 80.0), (60.0, 150.0)])
def test_the_child_at_the_pulse_own_speed_gains_on_its_alias(seed, true_mm_s, alias_mm_s):
    reader = rise_time.RiseTime(_evidence(true_mm_s, seed), weight=1.0)
    floats = np.zeros((2, F_WIDTH))
    floats[:, F_V] = [true_mm_s, -alias_mm_s]
    reader.weigh(floats, np.arange(2), (ONSET / FS_HZ, ONSET, ONSET + 200))
    assert floats[0, F_SCORE] > floats[1, F_SCORE]


def test_nothing_is_read_before_two_windows_are_held():
    reader = rise_time.RiseTime(_evidence(40.0, 1))
    floats = np.zeros((1, F_WIDTH))
    floats[:, F_V] = 40.0
    assert reader.weigh(floats, np.arange(1), (ONSET / FS_HZ, ONSET, ONSET + 5))[0] == 0.0
    assert floats[0, F_SCORE] == 0.0


def test_a_rail_over_the_windows_reads_nothing():
    reader = rise_time.RiseTime(_evidence(40.0, 1))
    floats = np.zeros((1, F_WIDTH))
    floats[:, F_V] = 40.0
    rail = [(ONSET / FS_HZ - 1.0, ONSET / FS_HZ + 1.0)]
    assert reader.weigh(floats, np.arange(1), (ONSET / FS_HZ, ONSET, ONSET + 200), rail)[0] == 0


def test_no_gain_exceeds_the_clip():
    reader = rise_time.RiseTime(_evidence(40.0, 2), weight=50.0, clip=1.5)
    curve = reader.curve(np.array([30.0, -30.0, 30.0]))
    assert curve is not None and np.max(np.abs(curve)) <= 1.5


def test_a_negative_weight_is_refused():
    with pytest.raises(ValueError):
        rise_time.RiseTime(_evidence(40.0, 1), weight=-1.0)

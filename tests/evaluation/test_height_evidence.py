"""Pulse heights as evidence of the ridge (`evaluation/height_evidence.py`) and the alias
bound weighing them (`alias_bound.chain` with `evidence`): on hand-built cases, equal
heights change nothing, a 4 mm against a 40 mm spacing before the ridge decides between
two aliases the times cannot tell apart, the unknown scale is marginalised, and the
oracle's least-squares height ignores a linear background."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.evaluation import alias_bound as ab
from grasplink.evaluation import height_evidence as he

CONSTANT = ab.AliasSettings(rel=0.1, dv_dx_per_s=0.0)
SPEED_MM_S = 40.0


def _chain(
    spacings_mm: tuple[float, ...],
    p_det: np.ndarray,
    times_s: np.ndarray,
    heights_n: np.ndarray | None = None,
    model: he.HeightModel | None = None,
    sigma_n: float = 0.05,
) -> ab.Chain:
    pos = np.concatenate([[0.0], np.cumsum(spacings_mm)])
    if heights_n is None:
        return ab.chain(pos, times_s, p_det, CONSTANT)
    m = model or he.HeightModel()
    ev = he.evidence(heights_n, np.full(len(heights_n), sigma_n), pos, m)
    return ab.chain(pos, times_s, p_det, CONSTANT, evidence=ev, prior=m.prior)


def test_the_shape_factor_follows_the_spacing_before_the_ridge():
    f = he.shape_factor(np.array([4.0, 40.0]))
    assert f == pytest.approx([1 - np.exp(-0.4), 1 - np.exp(-4.0)])
    # in travel order: the lead-in before the first ridge, then the layout's spacings
    model = he.HeightModel()
    assert model.factor(np.array([0.0, 4.0, 44.0])) == pytest.approx(
        he.shape_factor(np.array([20.0, 4.0, 40.0]))
    )


def test_the_density_is_the_uniform_draw_blurred_by_the_error():
    h = np.linspace(-1.0, 3.0, 4001)
    p = he.density(h, np.full(len(h), 0.01), np.full(len(h), 1.0), he.DRAW)
    assert np.trapezoid(p, h) == pytest.approx(1.0, abs=1e-3)
    inside = (h > 0.9) & (h < 1.1)
    assert p[inside] == pytest.approx(1 / 0.4, rel=1e-3)  # flat where the draw reaches
    assert p[h > 1.5].max() < 1e-6
    # an unknown height weighs every ridge alike
    assert he.density(np.array([np.nan]), np.array([np.inf]), np.array([0.3]), he.DRAW)[0] == 1


def test_equal_heights_on_a_uniform_skin_change_nothing():
    spacings = (4.0,) * 10
    model = he.HeightModel(lead_in_mm=4.0)  # every ridge, the first too, after 4 mm
    pos = np.concatenate([[0.0], np.cumsum(spacings)])
    times = 0.5 + pos[[3, 4]] / SPEED_MM_S
    p_det = np.full(11, 0.7)
    plain = _chain(spacings, p_det, times)
    weighed = _chain(spacings, p_det, times, np.array([0.33, 0.33]), model)
    assert np.array_equal(plain.fits, weighed.fits)
    ratio = weighed.weight[plain.weight > 0] / plain.weight[plain.weight > 0]
    assert ratio == pytest.approx(np.full(len(ratio), ratio[0]))  # the posterior alike


# Two aliases 44 mm apart: ridges 0 and 2 (one ridge skipped, 4 mm before ridge 2) or
# ridges 1 and 3 (one missed before and one between, 40 mm before ridge 3).
ALIASES_MM = (40.0, 4.0, 40.0, 40.0)
P_DET = np.array([0.7, 0.7, 0.7, 0.7, 0.0])
TIMES_S = np.array([0.5, 0.5 + 44.0 / SPEED_MM_S])


def test_times_alone_favour_the_alias_with_fewer_misses():
    c = _chain(ALIASES_MM, P_DET, TIMES_S)
    assert c.fits[0, 2] and c.fits[1, 3]
    assert c.speed_mm_s[0, 2] == pytest.approx(c.speed_mm_s[1, 3])
    assert c.weight[0, 2] == pytest.approx(0.7 * 0.3 * 0.7)
    assert c.weight[1, 3] == pytest.approx(0.3 * 0.7 * 0.3 * 0.7)


def test_a_low_second_pulse_names_the_ridge_after_4_mm():
    f = he.HeightModel().factor(np.array([0.0, 40.0, 44.0, 84.0, 124.0]))
    c = _chain(ALIASES_MM, P_DET, TIMES_S, f[[0, 2]])  # the heights of ridges 0 and 2
    assert c.weight[0, 2] > 100 * c.weight[1, 3]


def test_two_equal_full_pulses_name_the_ridges_after_40_mm():
    f = he.HeightModel().factor(np.array([0.0, 40.0, 44.0, 84.0, 124.0]))
    c = _chain(ALIASES_MM, P_DET, TIMES_S, f[[1, 3]])  # the heights of ridges 1 and 3
    assert c.weight[1, 3] > 100 * c.weight[0, 2]


def test_the_unknown_scale_is_marginalised_and_a_known_one_is_not():
    f = he.HeightModel().factor(np.array([0.0, 40.0, 44.0, 84.0, 124.0]))
    doubled = 2.0 * f[[1, 3]]  # the same two full pulses at twice the scale
    c = _chain(ALIASES_MM, P_DET, TIMES_S, doubled)
    assert c.weight[1, 3] > 100 * c.weight[0, 2]
    known = he.HeightModel(np.array([he.SIM_SCALE_N]))
    c = _chain(ALIASES_MM, P_DET, TIMES_S, doubled, known)
    assert c.weight[1, 3] < 1e-6  # 1.96 N is beyond a 1 N scale's 1.2 N


def test_the_least_squares_height_ignores_a_linear_background():
    fs, rise, onset, alpha = 400.0, 0.05, 1.0025, 0.6
    offsets = np.arange(-40, 40)
    at = int(np.ceil(onset * fs))
    t = np.arange(800) / fs
    line = 0.3 + 0.8 * t  # a drift: the pulses taken out, no noise
    h, sigma = he.measure(line, at, offsets, alpha, rise, fs, 0.1, onset)
    assert h == pytest.approx(alpha)
    assert 0 < sigma < 0.1
    rng = np.random.default_rng(5)
    noisy = [
        he.measure(line + rng.normal(0, 0.1, len(t)), at, offsets, alpha, rise, fs, 0.1, onset)
        for _ in range(400)
    ]
    estimates = np.array([e[0] for e in noisy])
    assert np.std(estimates) == pytest.approx(sigma, rel=0.15)  # sigma is its noise
    assert he.measure(line, 10, offsets, alpha, rise, fs, 0.1, onset)[1] == np.inf


def test_the_least_squares_rise_finds_a_clean_pulse_and_tells_the_speed():
    fs, onset, alpha = 400.0, 1.0025, 0.8
    rise = 2.5 / (2 * SPEED_MM_S)  # the simulator's rise at 40 mm/s: 31 ms
    offsets = np.arange(-40, 40)
    at = int(np.ceil(onset * fs))
    line = 0.3 + 0.8 * np.arange(800) / fs
    grid = he.log_grid(0.002, 0.25, 400)
    got = he.measure_rise(line, at, offsets, alpha, rise, fs, onset, grid)
    assert got == pytest.approx(rise, rel=0.015)  # the grid's step
    bound = he.rise_sigma(at, offsets, alpha, rise, fs, 0.1, onset)
    assert 0 < bound < he.rise_sigma(at, offsets, alpha, rise, fs, 0.2, onset)
    # the measured rise weighs 40 mm/s above 80 mm/s, and a speed range holding neither
    sigma = np.array(0.002)
    at_40 = he.rise_density(np.array(rise), sigma, np.array(38.0), np.array(42.0))
    at_80 = he.rise_density(np.array(rise), sigma, np.array(76.0), np.array(84.0))
    assert at_40 > 100 * at_80


def test_the_rise_decides_between_aliases_of_different_speeds():
    spacings = (4.0,) * 10  # ridges 3-4 at 40 mm/s or 3-5 at 80 mm/s: the same times
    pos = np.concatenate([[0.0], np.cumsum(spacings)])
    times = 0.5 + pos[[3, 4]] / SPEED_MM_S
    p_det = np.full(11, 0.7)
    rise = np.array([[2.5 / (2 * SPEED_MM_S)] * 2, [0.002, 0.002]])  # both pulses read 40
    plain = ab.chain(pos, times, p_det, CONSTANT)
    weighed = ab.chain(pos, times, p_det, CONSTANT, rise=rise)
    assert plain.weight[3, 5] > 0.1 * plain.weight[3, 4]
    assert weighed.weight[3, 4] > 100 * weighed.weight[3, 5]
    assert weighed.weight[3, 4] > 0

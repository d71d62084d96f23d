"""Every decoder in the registry against hostile input (issue 11).

Time gaps of any length reset the decoder and cost what the samples cost;
steps far below a sample period, out-of-range forces and times are counted
and dropped; layouts and sample rates outside what the skin node can hold
are refused with a ConfigError naming the bound.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from grasplink.decoding import base
from grasplink.decoding.base import (
    GAP_PERIODS,
    MIN_STEP_PERIODS,
    SkinGeometry,
    check_sample_rate,
    skin_limits,
)
from grasplink.errors import ConfigError
from grasplink.evaluation.decoders import make_decoder
from grasplink.profiles import load_profile
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.profiles.objects import (
    SKIN_FSR_CALIBRATION,
    SKIN_RIDGE_SPACING_UM,
    SKIN_SAMPLE_RATE_HZ,
)
from grasplink.simulators import synth
from tests.decoding.test_baselines import ALL_AVAILABLE, HOME, assert_clean

NAMES = ALL_AVAILABLE
PERIOD_S = base.DEFAULT_UPDATE_S


@pytest.fixture(scope="module")
def slip():
    """3 s: a 40 mm/s slip over alpha0.1 (every decoder's home but fft's)."""
    return {
        name: synth.slip_recording(LAYOUTS_MM[HOME.get(name, "alpha0.1")], 40.0, seed=31)
        for name in NAMES
    }


def feed(decoder, t, x, chunk: int | None = 256):
    if chunk is None:
        return decoder.feed(t, x)
    out = []
    for start in range(0, len(t), chunk):
        out += decoder.feed(t[start : start + chunk], x[start : start + chunk])
    return out


def decoder_for(name, rec):
    return make_decoder(name, rec.layout_mm, rec.fs_hz)


# -- gaps --------------------------------------------------------------------------------------
@pytest.mark.parametrize("gap_s", [1e4, 1e6, 1e9])
@pytest.mark.parametrize("name", NAMES)
def test_gap_resets_the_decoder_and_yields_no_updates_inside(name, gap_s, slip):
    rec = slip[name]
    half = len(rec.t_s) // 2
    t = rec.t_s.copy()
    t[half:] += gap_s
    decoder = decoder_for(name, rec)
    started = time.perf_counter()
    estimates = feed(decoder, t, rec.force_n)
    elapsed = time.perf_counter() - started
    assert decoder.stats.gaps == 1
    assert decoder.stats.longest_gap_s == pytest.approx(gap_s, rel=1e-6)
    before, after = t[half - 1], t[half]
    assert not [e for e in estimates if before < e.t_s < after]
    # updates cover the samples' span only: about one per period on each side
    span_s = (t[half - 1] - t[0]) + (t[-1] - t[half])
    assert len(estimates) <= span_s / PERIOD_S + 3
    assert elapsed < 60  # a 1e9 s span on the old grid: 1e11 updates, a MemoryError
    assert_clean(estimates)
    # after the gap the decoder knows nothing of before: a fresh one says the same
    fresh = feed(decoder_for(name, rec), t[half:], rec.force_n[half:], chunk=100)
    assert [e for e in estimates if e.t_s >= after] == fresh


@pytest.mark.parametrize("name", NAMES)
def test_gap_inside_one_chunk_equals_gap_between_chunks(name, slip):
    rec = slip[name]
    half = len(rec.t_s) // 2
    t = rec.t_s.copy()
    t[half:] += 1e4
    whole = feed(decoder_for(name, rec), t, rec.force_n, chunk=None)
    split = decoder_for(name, rec)
    pieces = split.feed(t[:half], rec.force_n[:half]) + split.feed(t[half:], rec.force_n[half:])
    assert whole == pieces


@pytest.mark.parametrize("name", NAMES)
def test_lost_packets_are_bridged_and_a_longer_hole_is_a_gap(name, slip):
    """Two lost 3-sample CAN packets leave a step of 7 sample periods: not a gap."""
    rec = slip[name]
    hole = int(GAP_PERIODS) - 2  # samples missing: a step of GAP_PERIODS - 1 periods
    keep = np.ones(len(rec.t_s), dtype=bool)
    for start in range(100, len(keep) - 50, 97):
        keep[start : start + hole] = False
    decoder = decoder_for(name, rec)
    estimates = feed(decoder, rec.t_s[keep], rec.force_n[keep])
    assert decoder.stats.gaps == 0
    expected = math.floor(rec.t_s[-1] / PERIOD_S + 1e-9) - math.ceil(rec.t_s[0] / PERIOD_S) + 1
    assert len(estimates) == expected  # the grid runs on through the holes
    assert_clean(estimates)
    keep[len(keep) // 2 : len(keep) // 2 + hole + 2] = False  # a step of GAP_PERIODS + 1
    decoder = decoder_for(name, rec)
    feed(decoder, rec.t_s[keep], rec.force_n[keep])
    assert decoder.stats.gaps == 1


# -- timing errors -----------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_steps_far_below_a_sample_period_are_counted_and_dropped(name, slip):
    rec = slip[name]
    every = np.arange(5, len(rec.t_s) - 1, 4)
    t = np.insert(rec.t_s, every + 1, rec.t_s[every] + 1e-12)
    x = np.insert(rec.force_n, every + 1, 90.0)  # garbage: must never be decoded
    decoder = decoder_for(name, rec)
    dirty = feed(decoder, t, x)
    assert decoder.stats.rejected_time == len(every)
    assert decoder.stats.accepted == len(rec.t_s)
    assert dirty == feed(decoder_for(name, rec), rec.t_s, rec.force_n)


@pytest.mark.parametrize("name", NAMES)
def test_a_stream_of_picosecond_steps_costs_nothing(name, slip):
    rec = slip[name]
    n = 200_000
    t = 1.0 + np.arange(n) * 1e-12
    x = np.resize(rec.force_n, n)
    decoder = decoder_for(name, rec)
    started = time.perf_counter()
    estimates = feed(decoder, t, x, chunk=50_000)
    assert time.perf_counter() - started < 30
    assert decoder.stats.accepted == 1 and decoder.stats.rejected_time == n - 1
    assert len(estimates) <= 1


@pytest.mark.parametrize("name", NAMES)
def test_jitter_well_within_a_period_is_not_a_timing_error(name, slip):
    rec = slip[name]
    rng = np.random.default_rng(7)
    jitter = rng.uniform(-0.3, 0.3, len(rec.t_s)) / rec.fs_hz
    decoder = decoder_for(name, rec)
    feed(decoder, rec.t_s + jitter, rec.force_n)
    assert decoder.stats.rejected == 0 and decoder.stats.gaps == 0
    assert MIN_STEP_PERIODS < 1 - 2 * 0.3  # the smallest jittered step stays clear of it


# -- out-of-range values -------------------------------------------------------------------------
@pytest.mark.parametrize("name", NAMES)
def test_out_of_range_forces_are_rejected_like_nan(name, slip):
    rec = slip[name]
    bad = np.arange(40, len(rec.t_s) - 40, 53)
    x = rec.force_n.copy()
    x[bad[0::3]] = 1e308
    x[bad[1::3]] = -1e308
    x[bad[2::3]] = skin_limits().max_force_n * 1.01
    decoder = decoder_for(name, rec)
    dirty = feed(decoder, rec.t_s, x)
    assert decoder.stats.rejected_range == len(bad)
    keep = np.ones(len(x), dtype=bool)
    keep[bad] = False
    assert dirty == feed(decoder_for(name, rec), rec.t_s[keep], rec.force_n[keep])
    assert_clean(dirty)
    assert all(e.force_n is not None and math.isfinite(e.force_n) for e in dirty)


@pytest.mark.parametrize("name", NAMES)
def test_times_float64_cannot_resolve_are_rejected(name, slip):
    rec = slip[name]
    decoder = decoder_for(name, rec)
    assert decoder.feed(np.array([1e300, -1e300, 1e17]), np.ones(3)) == []
    assert decoder.stats.rejected_range == 3
    assert decoder.max_time_s * np.finfo(float).eps <= 1e-3 / rec.fs_hz * 1.0001


# -- layout and rate bounds ----------------------------------------------------------------------
def test_bounds_are_the_skin_node_object_limits():
    od = load_profile("skin", 0x10)
    limits = skin_limits()
    spacing = od[SKIN_RIDGE_SPACING_UM][1]
    assert limits.spacing_mm == (spacing.min / 1000, spacing.max / 1000)
    assert limits.max_spacings == od[SKIN_RIDGE_SPACING_UM][0].max
    assert limits.rate_hz == (od[SKIN_SAMPLE_RATE_HZ].min, od[SKIN_SAMPLE_RATE_HZ].max)
    assert limits.max_force_n == od[SKIN_FSR_CALIBRATION][2].max / 1000


@pytest.mark.parametrize(
    "layout, words",
    [
        ((1e300, 1.0), ["#1", "1e+300", "0.5-200 mm", "0x2140"]),
        ((5.0, 0.2), ["#2", "0.2 mm"]),
        ((5.0, 250.0), ["#2", "250 mm"]),
        ((2.0,) * 41, ["41 spacings", "at most 40"]),
        ((math.nan, 1.0), ["finite"]),
        ((-3.0, 1.0), ["> 0"]),
        ((), ["at least one"]),
    ],
)
@pytest.mark.parametrize("name", NAMES)
def test_absurd_layouts_are_config_errors(name, layout, words):
    with pytest.raises(ConfigError) as caught:
        make_decoder(name, layout, 400.0)
    for word in words:
        assert word in str(caught.value)


@pytest.mark.parametrize("fs", [1e300, 0.0, -5.0, math.nan, math.inf, 79.0, 1001.0])
@pytest.mark.parametrize("name", NAMES)
def test_absurd_sample_rates_are_config_errors(name, fs):
    with pytest.raises(ConfigError, match="Hz"):
        make_decoder(name, LAYOUTS_MM["alpha0.1"], fs)


def test_sample_rate_bounds_name_the_reason():
    with pytest.raises(ConfigError, match=r"outside 80-1000 Hz.*0x2120"):
        check_sample_rate(1e300)
    assert check_sample_rate(80) == 80.0 and check_sample_rate(1000) == 1000.0


@pytest.mark.parametrize("period", [1e-300, 0.0, math.nan, 1e300])
def test_absurd_update_periods_are_config_errors(period):
    with pytest.raises(ConfigError, match="update period"):
        make_decoder("ratio", LAYOUTS_MM["alpha0.1"], 400.0, update_period_s=period)


def test_layout_geometry_accepts_every_named_layout():
    for name, spacings in LAYOUTS_MM.items():
        assert SkinGeometry(spacings).ridge_count == len(spacings) + 1, name

"""External stimulator codes: electrotactile (thesis ch. 2.3.3) and vibrotactile (ch. 4.5.2)."""

from __future__ import annotations

import math

import pytest

from grasplink.errors import ConfigError
from grasplink.gateway.encodings import (
    ELECTROTACTILE_SET_HZ,
    THESIS_SPEEDS_MM_S,
    ElectrotactileOccurrence,
    ElectrotactileSpeed,
    StimulusEncoder,
    Vibrotactile,
)


def test_slip_occurrence_is_68_hz_while_slipping_and_off_otherwise():
    encoding = ElectrotactileOccurrence()
    assert encoding.encode(True).frequency_hz == 68.0
    assert encoding.encode(True, 0.0).on
    assert not encoding.encode(False, 5.0).on


@pytest.mark.parametrize(
    ("speed_mm_s", "hz"), list(zip(THESIS_SPEEDS_MM_S, ELECTROTACTILE_SET_HZ, strict=True))
)
def test_the_thesis_speeds_give_the_thesis_frequencies(speed_mm_s, hz):
    stimulus = ElectrotactileSpeed().encode(True, speed_mm_s)
    assert stimulus.frequency_hz == pytest.approx(hz, abs=0.05)
    assert stimulus.speed_known


def test_between_the_thesis_speeds_the_formula_is_linear():
    assert ElectrotactileSpeed().encode(True, 5.0).frequency_hz == pytest.approx(
        22.85 * 5.0 - 37.14
    )


@pytest.mark.parametrize(
    ("speed_mm_s", "hz"), [(0.0, 4.0), (1.0, 4.0), (-0.5, 4.0), (6.5, 100.0), (40.0, 100.0)]
)
def test_speeds_outside_the_thesis_range_are_clamped_to_the_electrode_range(speed_mm_s, hz):
    stimulus = ElectrotactileSpeed().encode(True, speed_mm_s)
    assert (stimulus.frequency_hz, stimulus.saturated) == (hz, True)


def test_a_reverse_slip_is_encoded_by_its_speed_magnitude():
    encoding = ElectrotactileSpeed()
    assert encoding.encode(True, -4.6) == encoding.encode(True, 4.6)


def test_no_slip_switches_the_speed_stimulus_off_whatever_the_speed():
    assert not ElectrotactileSpeed().encode(False, 4.6).on


@pytest.mark.parametrize("speed", [None, math.nan, math.inf])
def test_an_unknown_speed_is_shown_at_the_occurrence_frequency(speed):
    stimulus = ElectrotactileSpeed().encode(True, speed)
    assert (stimulus.frequency_hz, stimulus.speed_known) == (68.0, False)


def test_snapping_to_the_thesis_set_gives_the_nearest_frequency_of_h():
    encoding = ElectrotactileSpeed(levels_hz=ELECTROTACTILE_SET_HZ)
    assert encoding.encode(True, 5.0).frequency_hz == 68.0  # 77.1 Hz -> 68
    assert encoding.encode(True, 5.5).frequency_hz == 100.0  # 88.5 Hz -> 100


def test_another_speed_range_can_be_spread_over_the_electrode_range():
    encoding = ElectrotactileSpeed.for_speed_range(10.0, 45.0)
    assert encoding.encode(True, 10.0).frequency_hz == pytest.approx(4.0)
    assert encoding.encode(True, 27.5).frequency_hz == pytest.approx(52.0)
    assert encoding.encode(True, 45.0).frequency_hz == pytest.approx(100.0)


@pytest.mark.parametrize(
    "build",
    [
        lambda: ElectrotactileSpeed(slope_hz_per_mm_s=0.0),
        lambda: ElectrotactileSpeed(min_hz=100.0, max_hz=4.0),
        lambda: ElectrotactileSpeed(intercept_hz=math.nan),
        lambda: ElectrotactileSpeed(unknown_speed_hz=150.0),
        lambda: ElectrotactileSpeed(levels_hz=(4.0, 200.0)),
        lambda: ElectrotactileSpeed.for_speed_range(6.0, 1.8),
        lambda: ElectrotactileOccurrence(frequency_hz=0.0),
    ],
)
def test_a_bad_electrotactile_encoding_is_a_config_error(build):
    with pytest.raises(ConfigError, match="electrotactile"):
        build()


def test_slip_frequency_is_speed_over_ridge_spacing():
    assert Vibrotactile().slip_frequency_hz(8.0) == pytest.approx(2.0)  # 4 mm ridges
    assert Vibrotactile(ridge_spacing_mm=2.5).slip_frequency_hz(-10.0) == pytest.approx(4.0)


@pytest.mark.parametrize(
    ("slip_hz", "pulse_hz"), [(1.0, 1.0), (2.0, 1 + 149 / 19), (10.5, 75.5), (20.0, 150.0)]
)
def test_slip_frequency_maps_linearly_onto_1_to_150_hz_pulse_trains(slip_hz, pulse_hz):
    encoding = Vibrotactile()
    train = encoding.encode(True, slip_hz * encoding.ridge_spacing_mm)
    assert train.frequency_hz == pytest.approx(pulse_hz)
    assert not train.saturated


def test_pulse_width_is_constant_whatever_the_frequency():
    encoding = Vibrotactile()
    widths = {encoding.encode(True, v).pulse_width_us for v in (4.0, 16.0, 40.0, 80.0)}
    assert widths == {2000}
    train = encoding.encode(True, 80.0)
    assert train.period_us == round(1e6 / 150.0) and train.period_us > train.pulse_width_us


@pytest.mark.parametrize(("speed_mm_s", "hz"), [(0.0, 1.0), (2.0, 1.0), (100.0, 150.0)])
def test_slip_frequencies_outside_1_to_20_hz_are_clamped_and_flagged(speed_mm_s, hz):
    train = Vibrotactile().encode(True, speed_mm_s)
    assert (train.frequency_hz, train.saturated) == (hz, True)


def test_no_slip_means_no_pulses_and_an_unknown_speed_pulses_at_mid_range():
    assert Vibrotactile().encode(False, 40.0).period_us is None
    train = Vibrotactile().encode(True, None)
    assert (train.frequency_hz, train.speed_known) == (75.5, False)


@pytest.mark.parametrize(
    "options",
    [
        {"ridge_spacing_mm": 0.0},
        {"slip_low_hz": 20.0, "slip_high_hz": 1.0},
        {"pulse_low_hz": 0.0},
        {"pulse_width_us": 7000},  # longer than the 6.7 ms period at 150 Hz
        {"pulse_width_us": 2.5},
        {"unknown_speed_hz": 200.0},
    ],
)
def test_a_bad_vibrotactile_encoding_is_a_config_error(options):
    with pytest.raises(ConfigError, match="vibrotactile"):
        Vibrotactile(**options)


def test_the_encoder_applies_all_three_codes_to_the_same_input():
    stimuli = StimulusEncoder().encode(True, 4.6)
    assert stimuli.electrotactile_occurrence.frequency_hz == 68.0
    assert stimuli.electrotactile_speed.frequency_hz == pytest.approx(68.0, abs=0.05)
    assert stimuli.vibrotactile.frequency_hz == pytest.approx(1 + (4.6 / 4.0 - 1) * 149 / 19)

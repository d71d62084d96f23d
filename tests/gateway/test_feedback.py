"""The feedback controller: modes, slip overriding force, hysteresis, bad inputs, mode changes."""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Iterable

import pytest

from grasplink.decoding.base import SlipEstimate
from grasplink.errors import ConfigError
from grasplink.gateway.feedback import (
    BeltCommand,
    FeedbackConfig,
    FeedbackController,
    FeedbackMode,
    Reason,
)
from grasplink.gateway.levels import Belt, force_table, slip_table
from grasplink.gateway.percept import Percept

MS = 1000
PERIOD_US = 10 * MS  # decoder update period
OCCURRENCE = -4500


def percept(
    t_ms: float,
    force_n: float | None = 15.0,
    slipping: bool = False,
    speed_mm_s: float | None = None,
    confidence: float = 0.9,
    *,
    direction: int | None = None,
    low_mm_s: float | None = None,
    high_mm_s: float | None = None,
) -> Percept:
    way = None if direction is None else 0.9
    return Percept(
        round(t_ms * MS),
        force_n,
        slipping,
        speed_mm_s,
        confidence,
        low_mm_s,
        high_mm_s,
        direction,
        way,
    )


def feed(controller: FeedbackController, percepts: Iterable[Percept]) -> list[BeltCommand]:
    return [controller.update(p).belt for p in percepts]


def steady(t0_ms: float, t1_ms: float, **fields) -> list[Percept]:
    """Percepts every 10 ms from t0 (inclusive) to t1 (exclusive)."""
    return [percept(t, **fields) for t in range(int(t0_ms), int(t1_ms), 10)]


def changes(commands: list[BeltCommand]) -> list[BeltCommand]:
    """The commands whose velocity differs from the one before."""
    out = commands[:1]
    for previous, command in itertools.pairwise(commands):
        if command.velocity_mrad_s != previous.velocity_mrad_s:
            out.append(command)
    return out


# --- modes ---------------------------------------------------------------------------


def test_off_mode_keeps_the_belt_still_whatever_the_input():
    c = FeedbackController(mode="off")
    inputs = steady(0, 300, force_n=35.0) + steady(300, 600, slipping=True, speed_mm_s=80.0)
    for command in feed(c, inputs):
        assert (command.velocity_mrad_s, command.belt, command.reason) == (
            0,
            Belt.NONE,
            Reason.MODE_OFF,
        )


def test_slip_occurrence_turns_the_slip_belt_at_one_speed_only_while_slipping():
    c = FeedbackController(mode=FeedbackMode.SLIP_OCCURRENCE)
    before = feed(c, steady(0, 100, force_n=20.0))
    slow = feed(c, steady(100, 300, slipping=True, speed_mm_s=10.0))
    fast = feed(c, steady(300, 500, slipping=True, speed_mm_s=80.0))
    after = feed(c, steady(500, 1000))
    assert {b.velocity_mrad_s for b in before} == {0}
    assert {(b.velocity_mrad_s, b.level, b.reason) for b in slow + fast} == {
        (OCCURRENCE, None, Reason.SLIP)
    }
    assert after[0].velocity_mrad_s == OCCURRENCE  # slip ends only after slip_off_us
    assert after[-1].velocity_mrad_s == 0 and after[-1].reason == Reason.NO_SLIP


@pytest.mark.parametrize(
    ("speed_mm_s", "level", "velocity"),
    [(5.0, 1, -2000), (20.0, 2, -3700), (35.0, 3, -5300), (60.0, 4, -7000)],
)
def test_slip_speed_mode_shows_the_level_of_the_slip_speed(speed_mm_s, level, velocity):
    c = FeedbackController(mode="slip_speed")
    command = c.update(percept(0, slipping=True, speed_mm_s=speed_mm_s)).belt
    assert (command.velocity_mrad_s, command.belt, command.level) == (velocity, Belt.SLIP, level)
    assert command.reason == Reason.SLIP_SPEED


def test_slip_speed_mode_keeps_the_belt_still_without_slip():
    c = FeedbackController(mode="slip_speed")
    command = c.update(percept(0, force_n=30.0)).belt
    assert (command.velocity_mrad_s, command.reason) == (0, Reason.NO_SLIP)


@pytest.mark.parametrize(
    ("force_n", "level", "velocity", "reason"),
    [
        (0.2, None, 0, Reason.NO_GRIP),
        (5.0, 1, 3500, Reason.GRIP_FORCE),
        (15.0, 2, 5000, Reason.GRIP_FORCE),
        (25.0, 3, 6500, Reason.GRIP_FORCE),
        (35.0, 4, 8000, Reason.GRIP_FORCE),
    ],
)
def test_grip_force_mode_shows_the_level_of_the_grip_force(force_n, level, velocity, reason):
    c = FeedbackController(mode="grip_force")
    command = c.update(percept(0, force_n=force_n, slipping=True, speed_mm_s=60.0)).belt
    assert (command.velocity_mrad_s, command.level, command.reason) == (velocity, level, reason)
    assert command.belt == (Belt.FORCE if velocity else Belt.NONE)


def test_slip_overrides_force_and_force_returns_after_the_hold():
    c = FeedbackController(mode="force_and_slip")
    assert feed(c, steady(0, 1000))[-1].velocity_mrad_s == 5000  # 15 N: level 2
    during = feed(c, steady(1000, 2000, slipping=True, speed_mm_s=20.0))
    assert {b.velocity_mrad_s for b in during} == {-3700}  # slip overrides at once
    # last slip report at 1990 ms: slip over at 1990 + 250 ms, force back 1 s later
    assert c.next_deadline_us() == 2240 * MS
    assert c.advance(2239 * MS).belt.velocity_mrad_s == -3700
    ended = c.advance(2240 * MS).belt
    assert (ended.velocity_mrad_s, ended.reason) == (0, Reason.SLIP_ENDED)
    assert c.next_deadline_us() == 3240 * MS
    returning = feed(c, steady(2250, 3300))
    assert {b.velocity_mrad_s for b in returning if b.t_us < 3240 * MS} == {0}
    assert {b.velocity_mrad_s for b in returning if b.t_us >= 3240 * MS} == {5000}
    assert returning[-1].reason == Reason.GRIP_FORCE


def test_a_slip_during_the_force_return_hold_takes_the_slip_belt_back_at_once():
    c = FeedbackController(mode="force_and_slip")
    feed(c, steady(0, 500, slipping=True, speed_mm_s=40.0))
    assert c.advance(800 * MS).belt.reason == Reason.SLIP_ENDED
    again = c.update(percept(900, slipping=True, speed_mm_s=40.0)).belt
    assert (again.velocity_mrad_s, again.level) == (-5300, 3)


def test_slip_only_modes_stop_the_belt_when_the_slip_ends_without_a_hold():
    c = FeedbackController(mode="slip_speed")
    feed(c, steady(0, 500, slipping=True, speed_mm_s=40.0))
    command = c.advance(740 * MS).belt  # last report 490 ms + 250 ms
    assert (command.velocity_mrad_s, command.reason) == (0, Reason.NO_SLIP)


# --- no chatter ----------------------------------------------------------------------


def test_a_slip_flag_dithering_every_update_does_not_chatter():
    c = FeedbackController(mode="force_and_slip")
    inputs = [percept(t, slipping=(t // 10) % 2 == 0, speed_mm_s=20.0) for t in range(0, 3000, 10)]
    commands = feed(c, inputs)
    assert [b.velocity_mrad_s for b in changes(commands)] == [-3700]


@pytest.mark.parametrize("first_n", [9.6, 10.4])
def test_a_force_dithering_across_a_level_boundary_never_changes_the_level(first_n):
    c = FeedbackController(mode="grip_force")
    # 10 N is the level 1/2 boundary; +-0.4 N stays inside the 1 N band
    inputs = [
        percept(t, force_n=first_n if (t // 10) % 2 == 0 else 20.0 - first_n)
        for t in range(0, 3000, 10)
    ]
    commands = feed(c, inputs)
    assert len(changes(commands)) == 1


def test_a_slip_speed_dithering_across_a_level_boundary_never_changes_the_level():
    c = FeedbackController(mode="slip_speed")
    # 30 mm/s is the level 2/3 boundary; +-3.5 mm/s stays inside the 8 mm/s band
    inputs = [
        percept(t, slipping=True, speed_mm_s=26.5 if (t // 10) % 2 == 0 else 33.5)
        for t in range(0, 3000, 10)
    ]
    commands = feed(c, inputs)
    assert [(b.velocity_mrad_s, b.level) for b in changes(commands)] == [(-3700, 2)]


def test_an_oscillation_wider_than_the_band_changes_the_level_at_most_once_per_dwell():
    c = FeedbackController(mode="grip_force")
    inputs = [percept(t, force_n=5.0 if (t // 50) % 2 == 0 else 15.0) for t in range(0, 4000, 10)]
    shown = changes(feed(c, inputs))
    assert len(shown) > 2  # it does follow the input, slowly
    gaps = [b.t_us - a.t_us for a, b in itertools.pairwise(shown)]
    assert min(gaps) >= c.config.level_dwell_us


def test_a_level_held_back_by_the_dwell_is_shown_at_the_dwell_deadline():
    c = FeedbackController(mode="grip_force")
    c.update(percept(0, force_n=5.0))
    held = c.update(percept(100, force_n=15.0)).belt
    assert (held.velocity_mrad_s, held.level, held.reason) == (3500, 1, Reason.GRIP_FORCE)
    assert c.next_deadline_us() == 500 * MS
    assert c.advance(500 * MS).belt.velocity_mrad_s == 5000


def test_a_slip_starts_without_waiting_for_the_force_level_dwell():
    c = FeedbackController(mode="force_and_slip")
    c.update(percept(0, force_n=5.0))
    c.update(percept(10, force_n=15.0))  # force level change held back by the dwell
    command = c.update(percept(20, slipping=True, speed_mm_s=50.0)).belt
    assert command.velocity_mrad_s == -7000


def test_a_single_spurious_slip_report_is_ignored_with_a_slip_on_delay():
    c = FeedbackController(FeedbackConfig(slip_on_us=20 * MS), mode="slip_occurrence")
    commands = feed(c, [percept(0), percept(10, slipping=True), percept(20), percept(30)])
    assert {b.velocity_mrad_s for b in commands} == {0}
    commands = feed(c, steady(40, 80, slipping=True))
    assert [b.velocity_mrad_s for b in commands] == [0, 0, OCCURRENCE, OCCURRENCE]


# --- inputs at the edges -------------------------------------------------------------


def test_zero_slip_speed_while_slipping_shows_the_lowest_slip_level():
    c = FeedbackController(mode="slip_speed")
    command = c.update(percept(0, slipping=True, speed_mm_s=0.0)).belt
    assert (command.velocity_mrad_s, command.level) == (-2000, 1)


@pytest.mark.parametrize("mode", ["slip_speed", "force_and_slip"])
def test_an_unknown_slip_speed_still_shows_slip_occurrence(mode):
    c = FeedbackController(mode=mode)
    command = c.update(percept(0, slipping=True, speed_mm_s=None)).belt
    assert (command.velocity_mrad_s, command.level) == (OCCURRENCE, None)
    assert command.reason == Reason.SLIP_SPEED_UNKNOWN


def test_the_first_known_speed_replaces_slip_occurrence_without_waiting_for_the_dwell():
    c = FeedbackController(mode="slip_speed")
    c.update(percept(0, slipping=True, speed_mm_s=None))
    command = c.update(percept(10, slipping=True, speed_mm_s=50.0)).belt
    assert (command.velocity_mrad_s, command.level) == (-7000, 4)


def test_a_speed_trusted_less_than_the_minimum_confidence_is_unknown():
    c = FeedbackController(mode="slip_speed")
    command = c.update(percept(0, slipping=True, speed_mm_s=50.0, confidence=0.1)).belt
    assert command.reason == Reason.SLIP_SPEED_UNKNOWN


def test_a_speed_lost_mid_slip_keeps_the_last_level():
    c = FeedbackController(mode="slip_speed")
    feed(c, steady(0, 100, slipping=True, speed_mm_s=35.0))
    commands = feed(c, steady(100, 400, slipping=True, speed_mm_s=None))
    assert {(b.velocity_mrad_s, b.level) for b in commands} == {(-5300, 3)}


@pytest.mark.parametrize("direction", [-1, 1, None])
def test_a_slip_is_shown_by_its_speed_whatever_its_direction(direction):
    c = FeedbackController(mode="slip_speed")
    output = c.update(percept(0, slipping=True, speed_mm_s=40.0, direction=direction))
    assert (output.belt.velocity_mrad_s, output.belt.level) == (-5300, 3)
    assert output.stimuli.electrotactile_speed.frequency_hz == 100.0


@pytest.mark.parametrize("mode", list(FeedbackMode))
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_nan_and_infinite_inputs_never_produce_a_nan_command(mode, bad):
    c = FeedbackController(mode=mode)
    inputs = [
        percept(0, force_n=bad, slipping=False),
        percept(10, force_n=bad, slipping=True, speed_mm_s=bad),
        percept(20, force_n=15.0, slipping=True, speed_mm_s=30.0, confidence=bad),
        percept(30, force_n=bad, slipping=True, speed_mm_s=bad, confidence=bad),
    ]
    for p in inputs:
        output = c.update(p)
        assert isinstance(output.belt.velocity_mrad_s, int)
        for stimulus in vars_of(output.stimuli):
            assert math.isfinite(stimulus.frequency_hz)
    assert isinstance(c.advance(5000 * MS).belt.velocity_mrad_s, int)


def vars_of(stimuli):
    return (stimuli.electrotactile_occurrence, stimuli.electrotactile_speed, stimuli.vibrotactile)


def test_an_unknown_force_keeps_the_last_level_until_it_goes_stale():
    c = FeedbackController(mode="grip_force")
    c.update(percept(0, force_n=15.0))
    assert c.update(percept(10, force_n=math.nan)).belt.velocity_mrad_s == 5000
    assert c.update(percept(20, force_n=None)).belt.velocity_mrad_s == 5000
    assert c.next_deadline_us() == 500 * MS  # 500 ms after the last known force
    stale = c.advance(500 * MS).belt
    assert (stale.velocity_mrad_s, stale.reason) == (0, Reason.FORCE_UNKNOWN)


def test_no_percept_for_the_stale_time_stops_the_force_display():
    c = FeedbackController(mode="force_and_slip")
    c.update(percept(0, force_n=25.0))
    assert c.advance(499 * MS).belt.velocity_mrad_s == 6500
    assert c.advance(500 * MS).belt.reason == Reason.FORCE_UNKNOWN
    assert c.update(percept(600, force_n=25.0)).belt.velocity_mrad_s == 6500  # back at once


@pytest.mark.parametrize(("mode", "velocity"), [("grip_force", 8000), ("slip_speed", -7000)])
def test_inputs_beyond_the_top_level_saturate_at_it(mode, velocity):
    c = FeedbackController(mode=mode)
    command = c.update(percept(0, force_n=1e6, slipping=True, speed_mm_s=1e6)).belt
    assert (command.velocity_mrad_s, command.level, command.clamped) == (velocity, 4, False)


def test_a_lowered_belt_max_velocity_clamps_the_command_and_raises_the_alarm():
    c = FeedbackController(mode="force_and_slip", max_velocity_mrad_s=6000)
    force = c.update(percept(0, force_n=35.0)).belt
    assert (force.velocity_mrad_s, force.level, force.clamped) == (6000, 4, True)
    slip = c.update(percept(10, slipping=True, speed_mm_s=80.0)).belt
    assert (slip.velocity_mrad_s, slip.clamped) == (-6000, True)
    back = c.set_max_velocity(8000, 20 * MS).belt
    assert (back.velocity_mrad_s, back.clamped) == (-7000, False)


def test_a_negative_grip_force_shows_no_grip():
    c = FeedbackController(mode="grip_force")
    command = c.update(percept(0, force_n=-0.3)).belt
    assert (command.velocity_mrad_s, command.reason) == (0, Reason.NO_GRIP)


# --- run-time changes ----------------------------------------------------------------


def test_a_mode_change_takes_effect_at_once():
    c = FeedbackController(mode="grip_force")
    feed(c, steady(0, 200, slipping=True, speed_mm_s=35.0))
    assert c.set_mode("slip_speed", 200 * MS).belt.velocity_mrad_s == -5300
    assert c.set_mode("slip_occurrence", 210 * MS).belt.velocity_mrad_s == OCCURRENCE
    assert c.set_mode("off", 220 * MS).belt.velocity_mrad_s == 0
    assert c.set_mode("grip_force", 230 * MS).belt.velocity_mrad_s == 5000


def test_a_mode_change_during_the_force_return_hold_shows_force_at_once():
    c = FeedbackController(mode="force_and_slip")
    feed(c, steady(0, 300, slipping=True, speed_mm_s=35.0))
    c.update(percept(300))
    assert c.advance(600 * MS).belt.reason == Reason.SLIP_ENDED
    assert c.set_mode("grip_force", 610 * MS).belt.velocity_mrad_s == 5000


def test_a_mode_change_does_not_wait_for_the_level_dwell():
    c = FeedbackController(mode="grip_force")
    c.update(percept(0, force_n=5.0))
    c.update(percept(10, force_n=25.0))  # held back by the dwell
    c.set_mode("off", 20 * MS)
    assert c.set_mode("grip_force", 30 * MS).belt.velocity_mrad_s == 6500


@pytest.mark.parametrize("bad", ["vibrate", 5, -1, True, 2.0])
def test_an_unknown_mode_is_a_config_error_naming_the_modes(bad):
    c = FeedbackController()
    with pytest.raises(ConfigError, match=r"unknown feedback mode .*2 slip_speed"):
        c.set_mode(bad, 0)
    assert c.mode == FeedbackMode.FORCE_AND_SLIP


def test_a_mode_can_be_given_by_its_register_code():
    assert [m.code for m in FeedbackMode] == [0, 1, 2, 3, 4]
    assert FeedbackMode.parse(2) == FeedbackMode.SLIP_SPEED
    assert FeedbackController(mode=0).mode == FeedbackMode.OFF


def test_time_running_backwards_is_refused():
    c = FeedbackController()
    c.update(percept(100))
    with pytest.raises(ValueError, match="backwards"):
        c.update(percept(50))


# --- configuration and stimuli -------------------------------------------------------


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"occurrence_velocity_mrad_s": -3700}, r"occurrence_velocity_mrad_s -3700"),
        ({"occurrence_velocity_mrad_s": 3700.0}, r"occurrence_velocity_mrad_s must be whole"),
        ({"slip_off_us": 0}, r"slip_off_us must be whole microseconds > 0"),
        ({"level_dwell_us": -1}, r"level_dwell_us"),
        ({"min_speed_confidence": 1.5}, r"min_speed_confidence"),
        ({"force_table": slip_table()}, r"force_table must be a force-belt LevelTable"),
        ({"slip_table": force_table()}, r"slip_table must be a slip-belt LevelTable"),
    ],
)
def test_a_bad_feedback_config_is_a_config_error(options, message):
    with pytest.raises(ConfigError, match=message):
        FeedbackConfig(**options)


def test_a_custom_table_changes_what_the_belt_shows():
    table = force_table([(2.0, 3000), (6.0, 6000)], hysteresis_n=1.0)
    c = FeedbackController(FeedbackConfig(force_table=table), mode="grip_force")
    assert c.update(percept(0, force_n=8.0)).belt.velocity_mrad_s == 6000


def test_stimuli_are_computed_from_the_same_slip_state_as_the_belt():
    c = FeedbackController(mode="force_and_slip")
    quiet = c.update(percept(0))
    assert not quiet.slipping and not quiet.stimuli.vibrotactile.on
    output = c.update(percept(10, slipping=True, speed_mm_s=8.0))
    assert output.slipping
    assert output.stimuli.electrotactile_occurrence.frequency_hz == 68.0
    assert output.stimuli.electrotactile_speed.frequency_hz == 100.0  # 8 mm/s > 6.0 mm/s
    assert output.stimuli.vibrotactile.frequency_hz == pytest.approx(1 + 149 / 19)  # f = 2 Hz
    # a dithering flag keeps the stimuli on, like the belt
    assert c.update(percept(20, slipping=False)).stimuli.electrotactile_occurrence.on


def test_a_decoder_estimate_becomes_a_percept_in_gateway_microseconds():
    estimate = SlipEstimate.from_velocity(1.25, True, -31.5, 12.0, 4.5, 0.8)
    p = Percept.from_estimate(estimate, t0_us=2_000_000)
    assert p == Percept(3_250_000, 4.5, True, 31.5, 0.8, None, None, -1, 0.8)
    assert p.velocity_mm_s == -31.5


def test_cleaning_a_percept_makes_unusable_numbers_unknown():
    p = Percept(0, math.nan, True, math.inf, math.nan).clean()
    assert (p.grip_force_n, p.slip_speed_mm_s, p.confidence) == (None, None, 0.0)
    assert Percept(0, 1.0, False, None, 7.0).clean().confidence == 1.0


def test_a_cleaned_percept_is_cleaned_once():
    """The gateway cleans a decoder update once; the controllers' clean() gives it back
    as it is. A percept made from a clean one (replace) is cleaned again."""
    dirty = Percept(0, math.nan, True, 12.0, 1.5, None, None, 1, math.inf)
    clean = dirty.clean()
    assert clean.clean() is clean and dirty.clean() is not dirty
    assert clean == Percept(0, None, True, 12.0, 1.0)
    again = dataclasses.replace(clean, confidence=math.nan)
    assert again.clean() is not again and again.clean().confidence == 0.0


def test_the_default_occurrence_speed_is_none_of_the_slip_speed_levels():
    config = FeedbackConfig()
    assert config.occurrence_velocity_mrad_s not in config.slip_table.velocities_mrad_s

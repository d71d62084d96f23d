"""The hybrid reflex and the grip arbiter: threshold, proportional raise, crush limit, release."""

from __future__ import annotations

import itertools
import math

import pytest

from grasplink.errors import ConfigError
from grasplink.gateway.percept import Percept
from grasplink.gateway.reflex import (
    DEFAULT_CRUSH_LIMIT_N,
    GripArbiter,
    GripCommand,
    GripSource,
    ReflexConfig,
    ReflexState,
    human_limit_mm_s,
)
from grasplink.profiles import load_profile
from grasplink.profiles import objects as obj

MS = 1000
S = 1_000_000


def slip(t_ms: float, speed_mm_s: float | None, *, slipping: bool = True, confidence=0.9):
    return Percept(round(t_ms * MS), 5.0, slipping, speed_mm_s, confidence)


def still(t_ms: float) -> Percept:
    return Percept(round(t_ms * MS), 5.0, False, None, 0.9)


def holding(voluntary_n: float = 5.0, config: ReflexConfig | None = None) -> GripArbiter:
    arbiter = GripArbiter(config)
    arbiter.set_voluntary(0, voluntary_n)
    return arbiter


def test_the_default_threshold_is_the_human_limit_on_an_80_mm_skin():
    assert human_limit_mm_s(80.0) == pytest.approx(45.7, abs=0.1)  # 80 mm / 1.75 s
    assert human_limit_mm_s(80.0, 1.51) == pytest.approx(53.0, abs=0.1)
    assert ReflexConfig().threshold_mm_s == 45.0


def test_the_default_crush_limit_is_the_hand_profiles():
    default_mn = load_profile("hand", 0x40)[obj.HAND_CRUSH_LIMIT_MN].default
    assert default_mn == DEFAULT_CRUSH_LIMIT_N * 1000


def test_below_the_threshold_the_wearer_decides():
    arbiter = holding(5.0)
    for t in range(10, 2000, 10):
        command = arbiter.update(slip(t, 44.0))
        assert (command.grip_n, command.reflex, command.source) == (
            5.0,
            ReflexState.IDLE,
            GripSource.VOLUNTARY,
        )
    assert arbiter.set_voluntary(2000 * MS, 8.0).grip_n == 8.0


def test_above_the_threshold_the_reflex_raises_the_grip_and_says_so():
    arbiter = holding(5.0)
    command = arbiter.update(slip(10, 60.0))
    assert command.reflex == ReflexState.ACTIVE and command.reflex_active
    assert command.source == GripSource.REFLEX
    assert command.grip_n == pytest.approx(5.0 + 0.1 * 60.0)
    assert command.target_grip_mn == 11000


def test_the_raise_is_proportional_to_slip_speed():
    raises = {}
    for speed in (50.0, 75.0, 100.0):
        command = holding(5.0).update(slip(10, speed))
        raises[speed] = command.grip_n - 5.0
    assert raises[75.0] / raises[50.0] == pytest.approx(1.5)
    assert raises[100.0] / raises[50.0] == pytest.approx(2.0)
    config = ReflexConfig(gain_n_per_mm_s=0.2)
    assert holding(5.0, config).update(slip(10, 50.0)).grip_n == pytest.approx(15.0)


@pytest.mark.parametrize("direction", [-1, 1, None])
def test_a_slip_triggers_the_reflex_by_its_speed_whatever_its_direction(direction):
    way = None if direction is None else 0.9
    fast = Percept(10 * MS, 5.0, True, 60.0, 0.9, None, None, direction, way)
    command = holding(5.0).update(fast)
    assert command.grip_n == pytest.approx(11.0)


def test_a_faster_slip_raises_more_but_a_slowing_one_never_lowers_the_grip():
    arbiter = holding(5.0)
    assert arbiter.update(slip(10, 50.0)).grip_n == pytest.approx(10.0)
    assert arbiter.update(slip(20, 80.0)).grip_n == pytest.approx(13.0)
    assert arbiter.update(slip(30, 46.0)).grip_n == pytest.approx(13.0)


def test_the_reflex_never_goes_beyond_the_crush_limit():
    arbiter = holding(35.0)
    command = arbiter.update(slip(10, 100.0))  # 35 + 10 N wanted
    assert (command.grip_n, command.clamped, command.source) == (40.0, True, GripSource.REFLEX)
    assert holding(5.0, ReflexConfig(crush_limit_n=8.0)).update(slip(10, 60.0)).grip_n == 8.0


def test_a_voluntary_grip_above_the_crush_limit_is_clamped():
    command = holding(55.0).advance(10 * MS)
    assert (command.grip_n, command.clamped, command.voluntary_grip_n) == (40.0, True, 55.0)


def test_a_lowered_crush_limit_applies_at_once_and_a_bad_one_is_refused():
    arbiter = holding(30.0)
    assert arbiter.set_crush_limit(20.0, 10 * MS).grip_n == 20.0
    for bad in (0.0, -1.0, 150.0, math.nan):
        with pytest.raises(ConfigError, match="crush limit"):
            arbiter.set_crush_limit(bad, 20 * MS)
    assert arbiter.crush_limit_n == 20.0


def test_the_threshold_has_hysteresis():
    arbiter = holding(5.0)
    assert arbiter.update(slip(10, 46.0)).reflex == ReflexState.ACTIVE
    for t, speed in zip(range(20, 1000, 10), itertools.cycle((41.0, 47.0)), strict=False):
        assert arbiter.update(slip(t, speed)).reflex == ReflexState.ACTIVE  # band 40..45
    assert arbiter.update(slip(1000, 39.0)).reflex == ReflexState.HOLD


def test_a_speed_dithering_across_the_threshold_does_not_ratchet_the_grip_up():
    arbiter = holding(5.0)
    grips = []
    for k, t in enumerate(range(10, 20_000, 10)):
        speed = 46.0 if k % 50 < 25 else 38.0  # in and out of the reflex every 250 ms
        grips.append(arbiter.update(slip(t, speed)).grip_n)
    assert max(grips) == pytest.approx(5.0 + 0.1 * 46.0)


def test_the_raised_grip_is_held_after_the_slip_stops_then_released_at_a_bounded_rate():
    config = ReflexConfig(hold_us=2 * S, release_rate_n_s=2.0, release_floor_share=0.0)
    arbiter = holding(1.0, config)
    arbiter.update(slip(10, 100.0))  # 11 N
    stopped = arbiter.update(still(20))
    assert (stopped.reflex, stopped.grip_n) == (ReflexState.HOLD, pytest.approx(11.0))
    assert arbiter.next_deadline_us() == 20 * MS + 2 * S
    assert arbiter.advance(2019 * MS).grip_n == pytest.approx(11.0)
    commands = [arbiter.advance(t) for t in range(2020 * MS, 8000 * MS, 10 * MS)]
    assert commands[0].reflex == ReflexState.RELEASE
    drops = [a.grip_n - b.grip_n for a, b in itertools.pairwise(commands)]
    assert max(drops) <= 2.0 * 0.010 + 1e-9  # never faster than the release rate
    assert commands[300].grip_n == pytest.approx(11.0 - 2.0 * 3.0)  # 3 s into the release
    assert commands[-1].grip_n == 1.0 and commands[-1].reflex == ReflexState.IDLE


def test_with_no_floor_the_release_hands_back_to_the_voluntary_grip():
    arbiter = holding(5.0, ReflexConfig(release_floor_share=0.0))
    arbiter.update(slip(10, 60.0))
    arbiter.update(still(20))
    end = arbiter.advance(2020 * MS)
    assert end.reflex == ReflexState.RELEASE
    assert arbiter.next_deadline_us() == 2020 * MS + 3 * S  # 6 N at 2 N/s
    handed = arbiter.advance(5020 * MS)
    assert (handed.grip_n, handed.reflex, handed.source) == (
        5.0,
        ReflexState.IDLE,
        GripSource.VOLUNTARY,
    )
    assert handed.reflex_grip_n is None and not handed.reflex_active
    assert arbiter.set_voluntary(5030 * MS, 2.0).grip_n == 2.0  # the wearer decides again


def test_the_wearer_gripping_harder_takes_over_during_the_hold():
    arbiter = holding(5.0)
    arbiter.update(slip(10, 60.0))
    arbiter.update(still(20))
    command = arbiter.set_voluntary(500 * MS, 12.0)
    assert (command.grip_n, command.reflex, command.source) == (
        12.0,
        ReflexState.IDLE,
        GripSource.VOLUNTARY,
    )


def test_the_wearer_cannot_lower_the_grip_below_an_active_reflex():
    arbiter = holding(5.0)
    arbiter.update(slip(10, 60.0))
    assert arbiter.update(slip(20, 60.0), voluntary_grip_n=0.0).grip_n == pytest.approx(11.0)


def test_the_release_pauses_while_the_object_slips():
    arbiter = holding(5.0, ReflexConfig(hold_us=0))
    arbiter.update(slip(10, 60.0))
    arbiter.update(slip(20, 30.0))  # below the band: hold, then release at once
    grips = [arbiter.update(slip(t, 30.0)).grip_n for t in range(30, 1030, 10)]
    assert grips[-1] == pytest.approx(11.0)  # a slow slip: the reflex does not let go
    released = [arbiter.update(still(t)).grip_n for t in range(1030, 2030, 10)]
    assert released[-1] == pytest.approx(11.0 - 2.0 * 0.99)


def test_a_fast_slip_during_the_release_raises_again_from_the_episode_base():
    arbiter = holding(5.0, ReflexConfig(hold_us=0))
    arbiter.update(slip(10, 60.0))  # 11 N
    arbiter.update(still(20))
    assert arbiter.advance(520 * MS).grip_n == pytest.approx(10.0)
    again = arbiter.update(slip(530, 46.0))  # base 5 N + 4.6 N < the 9.98 N still held
    assert (again.reflex, again.grip_n) == (ReflexState.ACTIVE, pytest.approx(9.98))
    assert arbiter.update(slip(540, 80.0)).grip_n == pytest.approx(13.0)  # 5 + 8, not 10 + 8


def released_after_a_stop(arbiter: GripArbiter, until_ms: int) -> float:
    """A 60 mm/s slip (11 N from 5 N) stopped at 20 ms, released until `until_ms`."""
    arbiter.update(slip(10, 60.0))
    arbiter.update(still(20))
    return arbiter.advance(until_ms * MS).grip_n


def test_a_slip_that_the_release_starts_again_returns_to_the_grip_that_held():
    arbiter = holding(5.0)
    assert released_after_a_stop(arbiter, 3020) == pytest.approx(9.0)  # 1 s into the release
    again = arbiter.update(slip(3030, 12.0))  # slow: below the threshold, but the reflex's doing
    assert (again.reflex, again.grip_n) == (ReflexState.HOLD, pytest.approx(11.0))
    assert arbiter.next_deadline_us() is None  # held: no release planned
    assert arbiter.update(still(3100)).grip_n == pytest.approx(11.0)
    assert arbiter.advance(60_000 * MS).grip_n == pytest.approx(11.0)  # a minute later still


def test_the_release_stops_above_the_grip_the_slip_began_at():
    arbiter = holding(5.0)  # 60 mm/s: 11 N; the default floor keeps half the 6 N raise
    assert released_after_a_stop(arbiter, 2020 + 1000) == pytest.approx(9.0)
    assert arbiter.next_deadline_us() == 3020 * MS + 500 * MS  # 1 N to go at 2 N/s
    floor = arbiter.advance(3520 * MS)
    assert (floor.reflex, floor.grip_n) == (ReflexState.HOLD, pytest.approx(8.0))
    assert arbiter.next_deadline_us() is None
    assert arbiter.advance(600_000 * MS).grip_n == pytest.approx(8.0)  # kept: 5 N slipped
    handed = arbiter.set_voluntary(600_010 * MS, 8.5)
    assert (handed.reflex, handed.grip_n) == (ReflexState.IDLE, 8.5)


def test_a_re_slip_at_the_floor_returns_to_the_grip_that_held():
    arbiter = holding(5.0)
    released_after_a_stop(arbiter, 4000)
    assert arbiter.update(still(4010)).grip_n == pytest.approx(8.0)
    assert arbiter.update(slip(4500, 10.0)).grip_n == pytest.approx(11.0)


def test_switching_the_reflex_off_releases_through_the_floor_to_the_wearer():
    arbiter = holding(5.0)
    released_after_a_stop(arbiter, 4000)
    arbiter.set_reflex_enabled(False, 4000 * MS)
    assert arbiter.advance(6000 * MS).reflex == ReflexState.IDLE


def test_the_learned_grip_is_handed_back_when_the_wearer_grips_as_hard():
    arbiter = holding(5.0)
    released_after_a_stop(arbiter, 3020)
    arbiter.update(slip(3030, 12.0))
    assert arbiter.set_voluntary(4000 * MS, 10.0).grip_n == pytest.approx(11.0)
    handed = arbiter.set_voluntary(5000 * MS, 11.5)
    assert (handed.grip_n, handed.reflex) == (11.5, ReflexState.IDLE)


def test_the_wearer_opening_the_hand_ends_a_reflex_hold():
    arbiter = holding(5.0)
    released_after_a_stop(arbiter, 3020)
    arbiter.update(slip(3030, 12.0))
    opened = arbiter.set_voluntary(4000 * MS, 0.0)
    assert (opened.grip_n, opened.reflex) == (0.0, ReflexState.IDLE)


def test_no_voluntary_grip_from_the_start_is_not_an_opening_hand():
    arbiter = GripArbiter()  # no EMG path: the voluntary grip is 0 N throughout
    arbiter.update(slip(10, 60.0))  # base 0 N: 6 N
    held = arbiter.update(still(20))
    assert (held.reflex, held.grip_n) == (ReflexState.HOLD, pytest.approx(6.0))


def test_a_slip_never_seen_to_stop_is_not_a_re_slip():
    arbiter = holding(5.0, ReflexConfig(hold_us=0, release_floor_share=0.0))
    arbiter.update(slip(10, 60.0))
    arbiter.update(slip(20, 30.0))  # slowed below the band, still slipping: hold, release
    # no percept for a while: stale after 500 ms, the release goes on from there
    command = arbiter.update(slip(1600, 30.0))
    assert command.reflex == ReflexState.RELEASE
    assert command.grip_n < 11.0 - 2.0  # released on through the gap, not gripped again


def test_a_disabled_reflex_does_not_grip_again_on_a_re_slip():
    arbiter = holding(5.0)
    released_after_a_stop(arbiter, 3020)
    arbiter.set_reflex_enabled(False, 3020 * MS)
    command = arbiter.update(slip(3030, 12.0))
    assert command.reflex == ReflexState.RELEASE and command.grip_n < 9.0 + 1e-9


@pytest.mark.parametrize(
    ("options", "key"),
    [
        ({"open_below_n": -1.0}, "open_below_n"),
        ({"release_floor_share": 1.5}, "release_floor_share"),
        ({"release_floor_share": math.nan}, "release_floor_share"),
    ],
)
def test_open_threshold_and_release_floor_are_validated(options, key):
    with pytest.raises(ConfigError, match=key):
        ReflexConfig(**options)


@pytest.mark.parametrize("speed", [None, math.nan, math.inf])
def test_an_unknown_slip_speed_does_not_trigger_the_reflex(speed):
    command = holding(5.0).update(slip(10, speed))
    assert (command.reflex, command.grip_n) == (ReflexState.IDLE, 5.0)


def test_a_speed_trusted_less_than_the_minimum_confidence_does_not_trigger_the_reflex():
    assert holding(5.0).update(slip(10, 80.0, confidence=0.1)).reflex == ReflexState.IDLE
    assert holding(5.0).update(slip(10, 80.0, confidence=math.nan)).reflex == ReflexState.IDLE


def test_an_unknown_speed_during_a_fast_slip_keeps_the_reflex_active():
    arbiter = holding(5.0)
    arbiter.update(slip(10, 60.0))
    assert arbiter.update(slip(20, None)).reflex == ReflexState.ACTIVE


def test_percepts_that_stop_coming_end_the_fast_slip_and_the_grip_is_released_slowly():
    arbiter = holding(5.0)
    arbiter.update(slip(10, 60.0))
    assert arbiter.next_deadline_us() == 510 * MS  # stale after 500 ms
    assert arbiter.advance(510 * MS).reflex == ReflexState.HOLD
    assert arbiter.advance(2510 * MS).reflex == ReflexState.RELEASE
    assert arbiter.advance(3510 * MS).grip_n == pytest.approx(9.0)


@pytest.mark.parametrize("bad", [None, math.nan, math.inf])
def test_a_missing_or_bad_voluntary_grip_keeps_the_last_one(bad):
    arbiter = holding(7.0)
    assert arbiter.set_voluntary(10 * MS, bad).grip_n == 7.0


def test_a_negative_voluntary_grip_is_no_grip():
    assert holding(-3.0).advance(10 * MS).grip_n == 0.0


def test_switching_the_reflex_off_while_it_acts_releases_instead_of_dropping():
    arbiter = holding(5.0)
    arbiter.update(slip(10, 60.0))
    off = arbiter.set_reflex_enabled(False, 20 * MS)
    assert (off.reflex, off.grip_n) == (ReflexState.RELEASE, pytest.approx(11.0))
    assert arbiter.advance(1020 * MS).grip_n == pytest.approx(9.0)
    assert arbiter.update(slip(1030, 90.0)).grip_n == pytest.approx(9.0 - 2.0 * 0.01)
    assert arbiter.advance(5000 * MS).reflex == ReflexState.IDLE
    arbiter.set_reflex_enabled(True, 5010 * MS)
    assert arbiter.update(slip(5020, 90.0)).reflex == ReflexState.ACTIVE


def test_a_disabled_reflex_never_acts():
    command = holding(5.0, ReflexConfig(enabled=False)).update(slip(10, 90.0))
    assert (command.reflex, command.grip_n) == (ReflexState.IDLE, 5.0)


def test_the_grip_command_is_a_plain_record():
    command = holding(5.0).advance(0)
    assert command == GripCommand(0, 5.0, 5.0, None, ReflexState.IDLE, GripSource.VOLUNTARY)


def test_time_running_backwards_is_refused():
    arbiter = holding(5.0)
    arbiter.advance(100 * MS)
    with pytest.raises(ValueError, match="backwards"):
        arbiter.update(slip(50, 60.0))


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"threshold_mm_s": 0.0}, "threshold_mm_s"),
        ({"threshold_mm_s": math.inf}, "threshold_mm_s"),
        ({"hysteresis_mm_s": 45.0}, "hysteresis_mm_s"),
        ({"hysteresis_mm_s": -1.0}, "hysteresis_mm_s"),
        ({"gain_n_per_mm_s": 0.0}, "gain_n_per_mm_s"),
        ({"gain_n_per_mm_s": math.nan}, "gain_n_per_mm_s"),
        ({"crush_limit_n": 120.0}, "crush limit"),
        ({"release_rate_n_s": 0.0}, "release_rate_n_s"),
        ({"hold_us": -1}, "hold_us"),
        ({"hold_us": 1.5}, "hold_us"),
        ({"stale_us": 0}, "stale_us"),
        ({"min_confidence": 2.0}, "min_confidence"),
        ({"enabled": "yes"}, "enabled"),
    ],
)
def test_a_bad_reflex_config_is_a_config_error(options, message):
    with pytest.raises(ConfigError, match=message):
        ReflexConfig(**options)


def test_human_limit_refuses_nonsense():
    with pytest.raises(ConfigError, match="skin length"):
        human_limit_mm_s(0.0)
    with pytest.raises(ConfigError, match="reaction time"):
        human_limit_mm_s(80.0, math.nan)

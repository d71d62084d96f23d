"""No speed from a track whose last contact was told a step the level lay flat after
(`flat_step_speed`, `TrackerDecoder.FLAT_STEP_SPEED`): a stop's friction step ends the
speed shown, not the flag - at level 2 (shipped) only where the track told fewer than two
pulses, so a ridge train's own flat step keeps its speed."""

from __future__ import annotations

import pytest

from grasplink.decoding import flat_step_speed
from grasplink.decoding.tracker import TrackerDecoder
from tests.decoding.test_overdue_speed import decoded, speeds_after_due
from tests.decoding.test_quantised_input import adc, rail_start, signs_and_errors

# stick-slip, alpha0.3 at 118 mm/s (seed 81200): the 3 and 4 mm ridges' pulses merged, a
# 35 mm/s alias on a contact no ridge made (0.468 s) and the stop's step (0.559 s, told a
# step with the level flat after it at 0.662 s); its next ridge 48 mm on, due at 2.3 s,
# the stop observable at 0.827 s: 7 updates with a speed after the report was due
FLAT_CASE = ("stick-slip", 81_200, 7)
ON = {"FLAT_STEP_SPEED": 1.0}  # every flat step (not shipped: ridge contacts read so too)
OFF = {"FLAT_STEP_SPEED": 0.0}


def test_only_a_step_the_level_lay_flat_after_withholds():
    steps = {3: False, 4: None, 5: True}
    assert flat_step_speed.withheld(3, steps)
    assert not flat_step_speed.withheld(4, steps)  # no trend to tell
    assert not flat_step_speed.withheld(5, steps)  # the level still rising: moving
    assert not flat_step_speed.withheld(6, steps)  # not told a step


def test_the_alias_ending_at_a_flat_step_gives_no_speed_after_due():
    kind, seed, _ = FLAT_CASE
    estimates, stops = decoded(kind, seed, ON)
    assert not speeds_after_due(estimates, stops)


def test_off_the_alias_gives_its_speed_after_due_and_the_flag_is_the_same():
    """The control: off, the speed after due of 8a8786d; at either level or off, every
    flag the same."""
    kind, seed, updates = FLAT_CASE
    on, _ = decoded(kind, seed, ON)
    shipped, _ = decoded(kind, seed, {})
    off, stops = decoded(kind, seed, OFF)
    assert len(speeds_after_due(off, stops)) == updates
    assert [e.slip for e in on] == [e.slip for e in off] == [e.slip for e in shipped]


def test_at_level_two_the_alias_told_one_pulse_gives_no_speed_after_due():
    """As shipped: the alias's contacts told one pulse (0.360 s; 0.468 s not yet told, the
    step at 0.559 s), so its flat step still ends the speed."""
    kind, seed, _ = FLAT_CASE
    estimates, stops = decoded(kind, seed, {})
    assert not speeds_after_due(estimates, stops)


def test_a_lone_pulse_is_fewer_than_two():
    assert flat_step_speed.lone_pulse(0) and flat_step_speed.lone_pulse(1)
    assert not flat_step_speed.lone_pulse(2)


def rail_speeds(tuning: dict) -> int:
    """Speeds given while slipping on the 40 mm/s rail start over ADC counts (seed 1)."""
    rec, x = rail_start(40.0, False, 1)
    decoder = TrackerDecoder(rec.layout_mm, 400.0, tuning=tuning)
    signal = adc(x)
    out = []
    for start in range(0, len(rec.t_s), 3):
        out += decoder.feed(rec.t_s[start : start + 3], signal[start : start + 3])
    return signs_and_errors(rec, out)[0]


@pytest.mark.parametrize("level,speeds", [(0.0, 189), (1.0, 106), (2.0, 189)])
def test_a_ridge_trains_flat_step_keeps_its_speed_at_level_two(level, speeds):
    """The rail start's ridges told five pulses before the step at 2.415 s: at level 2 its
    last gap (51 -> 84 mm, the object sliding) keeps its speed, as off; level 1 loses 83.
    (170 speeds before the ridge-shaped step's prior, `LOG_SHAPE_RIDGE_STOP`, s34.)"""
    assert rail_speeds({"FLAT_STEP_SPEED": level}) == speeds

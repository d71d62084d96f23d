"""No speed from a track whose last contact was told a step the level lay flat after
(`flat_step_speed`, `TrackerDecoder.FLAT_STEP_SPEED`): a stop's friction step ends the
speed shown, not the flag."""

from __future__ import annotations

from grasplink.decoding import flat_step_speed
from tests.decoding.test_overdue_speed import decoded, speeds_after_due

# stick-slip, alpha0.3 at 118 mm/s (seed 81200): the 3 and 4 mm ridges' pulses merged, a
# 35 mm/s alias on a contact no ridge made (0.468 s) and the stop's step (0.559 s, told a
# step with the level flat after it at 0.662 s); its next ridge 48 mm on, due at 2.3 s,
# the stop observable at 0.827 s: 7 updates with a speed after the report was due
FLAT_CASE = ("stick-slip", 81_200, 7)
ON = {"FLAT_STEP_SPEED": 1.0}  # (off by default: ridge contacts read so too)


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
    """The control: off, the speed after due of 8a8786d; on or off, every flag the same."""
    kind, seed, updates = FLAT_CASE
    on, _ = decoded(kind, seed, ON)
    off, stops = decoded(kind, seed, {})
    assert len(speeds_after_due(off, stops)) == updates
    assert [e.slip for e in on] == [e.slip for e in off]

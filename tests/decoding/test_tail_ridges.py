"""A ridge whose small pulse starts on the previous pulse's fall keeps its track
(`TOLD_RISE_TAIL_Z`, `TOLD_RISE_TAIL_FALL_Z`).

Constant 50151: 10 mm/s over alpha0.1 in reverse, ridge contacts 0.91, 4.21, 4.51,
4.91, 5.71, 6.21, 7.41, 9.31 s. The ridge at 4.51 s lies 3 mm after the one at 4.21 s:
its pulse is small (its height grows with the spacing before it) and starts while the
first one's falls, and the level falls on through its rise. The told-rise check (a
contact taken for a ridge must show a pulse's rise on the track's rise time,
`told_rise`) read no rise there and charged the true track 4 nats, enough for the
pruning to drop it; aliases in the wrong direction took the slip for the 5 s after.
Where the level fell just before the onset and on through the rise's window the rise
is not read. Where a fall ends the level flattens after the bend and it is read: the
scene loop_least_force's kink at 2.55 s, where the tail rule alone let an alias show
speed at rest (`test_efference.py`)."""

from __future__ import annotations

from grasplink.decoding.tracker import TrackerDecoder
from tests.decoding.plan_cases import score_case

OFF = {"TOLD_RISE_TAIL_Z": 0.0}


def test_a_ridge_on_a_falling_tail_does_not_cost_the_true_track():
    on = score_case("constant", 50151, {}, "10 mm/s")
    assert on.moving_from3 > 400
    assert on.missing_from3 <= 60
    assert on.dropped_from2 <= 10
    off = score_case("constant", 50151, OFF, "10 mm/s")
    assert off.missing_from3 >= 300
    assert off.dropped_from2 >= 100


def test_the_tail_rule_is_on_by_default_only_where_the_level_falls_on():
    assert TrackerDecoder.TOLD_RISE_TAIL_Z > 0
    assert TrackerDecoder.TOLD_RISE_TAIL_FALL_Z > 0

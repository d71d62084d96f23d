"""A ridge whose pulse starts on the previous pulse's fall keeps its track
(`TOLD_RISE_TAIL_Z`).

Constant 50151: 10 mm/s over alpha0.1 in reverse, ridge contacts 0.91, 4.21, 4.51,
4.91, 5.71, 6.21, 7.41, 9.31 s. The ridge at 4.51 s lies 3 mm after the one at 4.21 s:
its pulse starts while the first one's falls, and the level falls on through its rise.
The told-rise check (a contact taken for a ridge must show a pulse's rise on the
track's rise time, `told_rise`) read no rise there and charged the true track 4 nats,
enough for the pruning to drop it; aliases in the wrong direction took the slip for the
5 s after. With `TOLD_RISE_TAIL_Z` set, where the level fell just before the onset the
rise is not read. It is off: in the scene loop_least_force it also lets through a kink
where a ridge pulse's fall ends with no ridge there (`test_efference.py`'s speed at
rest), which the samples around it do not tell from 50151's."""

from __future__ import annotations

from grasplink.decoding.tracker import TrackerDecoder
from tests.decoding.plan_cases import score_case

ON, OFF = {"TOLD_RISE_TAIL_Z": 3.0}, {"TOLD_RISE_TAIL_Z": 0.0}


def test_a_ridge_on_a_falling_tail_does_not_cost_the_true_track():
    on = score_case("constant", 50151, ON, "10 mm/s")
    assert on.moving_from3 > 400
    assert on.missing_from3 <= 60
    assert on.dropped_from2 <= 10
    off = score_case("constant", 50151, OFF, "10 mm/s")
    assert off.missing_from3 >= 300
    assert off.dropped_from2 >= 100


def test_the_tail_rule_is_off_by_default_for_the_rest_it_costs():
    assert TrackerDecoder.TOLD_RISE_TAIL_Z == 0.0

"""A restart's first speed needs one of its two contacts told a pulse (or a third
contact) while the flag is down (`restart_confirm`, `TrackerDecoder.RESTART_CONFIRM_TWO`;
shipped with `RESTART_AGREE_REL`, test_restart_agree, off here): two kinks at rest are no
restart."""

from __future__ import annotations

import numpy as np

from grasplink.decoding import restart_confirm
from grasplink.decoding.tracker import NOISE, PULSE, STEP, UNCLEAR, UNKNOWN
from tests.decoding.test_overdue_speed import decoded, speeds_after_due

# stop 96200 (uniform4, 80 mm/s): the object at rest from 0.84 s to the recording's end
# (1.89 s); two kinks (1.603 s, z 5.0, never told; 1.847 s, z 5.4, not yet told) restarted
# the stopped track at 16.4 mm/s and the report flagged that speed at 1.87 and 1.88 s,
# after the stop's report was due (0.985 s)
AT_REST = ("stop", 96_200)
ON = {"RESTART_CONFIRM_TWO": 1.0, "RESTART_AGREE_REL": 0.0}
OFF = {"RESTART_CONFIRM_TWO": 0.0}


def test_two_kinks_at_rest_give_no_speed_after_the_stops_report_was_due():
    estimates, stops = decoded(*AT_REST, ON)
    assert not speeds_after_due(estimates, stops)


def test_two_kinks_at_rest_raise_no_flag_after_the_stop():
    """The flag is as wrong as the speed there: with the rule, down from 1.6 s on."""
    estimates, _ = decoded(*AT_REST, ON)
    assert not any(e.slip for e in estimates if e.t_s >= 1.6)


def test_without_the_rule_they_restart_the_track_with_a_speed():
    """The control (the tests above can fail): the rule off gives the two updates."""
    estimates, stops = decoded(*AT_REST, OFF)
    assert len(speeds_after_due(estimates, stops)) == 2
    assert any(e.slip for e in estimates if e.t_s >= 1.6)


def test_the_table_holds_both_contacts_as_the_first_one_is_held():
    """Row 1 (a restart's first two contacts) holds what row 0 (its first) holds; a pulse
    never holds; off, row 1 holds nothing."""
    V = 5
    on = restart_confirm.hold_table(V, STEP, NOISE, UNCLEAR, UNKNOWN, 3.0, True)
    off = restart_confirm.hold_table(V, STEP, NOISE, UNCLEAR, UNKNOWN, 3.0, False)
    assert on[0, [UNKNOWN, STEP, UNCLEAR, NOISE]].all() and not on[0, PULSE]
    assert np.array_equal(on[1], on[0])
    assert np.array_equal(off[0], on[0]) and not off[1].any()
    two = restart_confirm.hold_table(V, STEP, NOISE, UNCLEAR, UNKNOWN, 2.0, True)
    assert not two[1, UNKNOWN] and two[1, UNCLEAR]

"""A restart's first speed that agrees with the speed the track had before it stopped is
not held (`restart_confirm`, `TrackerDecoder.RESTART_AGREE_REL` with RESTART_CONFIRM_TWO):
a slip going on after a stick resumes about its speed, two kinks at rest give any."""

from __future__ import annotations

from dataclasses import replace

from grasplink.decoding.kernels import posterior as posterior_kernels
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
from tests.decoding.test_overdue_speed import speeds_after_due

# stick-slip 86200 (uniform4, 118 mm/s, forward): the slip's own restarts after its two
# sticks, each restart contact and the one after it not told a pulse in time; stop 96200
# (uniform4, 80 mm/s): two kinks at rest restart the stopped track at 16.4 mm/s where it
# slid at 79 (test_restart_confirm_two)
STICK = ("stick-slip", 86_200)
AT_REST = ("stop", 96_200)
TWO_ONLY = {"RESTART_CONFIRM_TWO": 1.0, "RESTART_AGREE_REL": 0.0}
NEITHER = {"RESTART_CONFIRM_TWO": 0.0}


def scored(kind: str, seed: int, tuning: dict) -> tuple[list, sr.CaseScore]:
    """The tracker's estimates of a full-plan case with `tuning` (over the shipped
    settings), and their score."""
    case = next(c for c in sr.cases(replace(sr.FULL, seeds=3)) if (c.kind, c.seed) == (kind, seed))
    rec = case.make()
    decoder = sr.build_decoder("tracker", rec.truth.layout_mm, rec.fs_hz, {"tuning": tuning})
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    return estimates, sr.score(estimates, rec.truth)


def test_a_first_speed_agrees_within_the_share_of_the_speed_before():
    assert posterior_kernels.agrees(40.0, 50.0, 0.6)
    assert posterior_kernels.agrees(79.0, 50.0, 0.6)
    assert not posterior_kernels.agrees(16.4, 79.0, 0.6)  # 96200's: 79 % off


def test_no_speed_before_or_the_rule_off_never_agrees():
    assert not posterior_kernels.agrees(50.0, 0.0, 0.6)  # never restarted
    assert not posterior_kernels.agrees(50.0, 50.0, 0.0)


def test_the_shipped_rule_holds_both_contacts_and_exempts_within_the_share():
    assert TrackerDecoder.RESTART_CONFIRM_TWO and TrackerDecoder.RESTART_AGREE_REL > 0


def test_a_slips_own_restart_after_a_stick_is_not_held_when_its_speed_agrees():
    """Holding every restart's first speed drops the flag while the slip goes on; with the
    agreement the drops are those of neither hold."""
    _, shipped = scored(*STICK, {})
    _, two_only = scored(*STICK, TWO_ONLY)
    _, neither = scored(*STICK, NEITHER)
    assert shipped.dropped_from2 < two_only.dropped_from2
    assert shipped.dropped_from2 == neither.dropped_from2


def test_two_kinks_at_rest_disagree_and_give_no_speed_after_the_stops_report_was_due():
    estimates, score = scored(*AT_REST, {})
    assert not speeds_after_due(estimates, score.stops)
    assert not any(e.slip for e in estimates if e.t_s >= 1.6)
    control, control_score = scored(*AT_REST, NEITHER)
    assert len(speeds_after_due(control, control_score.stops)) == 2

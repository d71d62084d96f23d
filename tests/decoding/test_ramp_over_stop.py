"""The ramp hold over the posterior's stop (`TrackerDecoder.RAMP_OVER_STOP`, s32).

The loop kind's objects slide onto the skin from 8 mm before it, and the level climbs as
they cover more of it: a ramp tells the object still slides where the contacts have
gone quiet and the posterior has settled on a stop. Held over a stop only once the
ramp's five windows all lie after the stop was first reported (the stop's own step and
the ramp before it out of them), only up (a pulse's tail decays after a stop), and only
at least `RAMP_OVER_STOP_SLOPE_N_S` steep: a sensor at rest drifts (the scenes' 0.05 N
at 0.5 Hz wanders about 0.2 N/s; stop 92100's level rose 0.3 N/s 1.8 s after its stop).
"""

from __future__ import annotations

from grasplink.evaluation import slip_reporting as sr
from tests.decoding.plan_cases import plan_case, score_case

OFF = {"RAMP_OVER_STOP": 0.0}


def _loop_score(tuning: dict) -> sr.CaseScore:
    """Loop 165100 (20 mm/s onto fibonacci, forward), decoded with its grip commands."""
    case = plan_case("loop", 165100)
    return sr.case_job(case, "tracker", {"x": {"tuning": tuning}}, False)["scores"]["x"]


def _judged_delays(score: sr.CaseScore) -> list[float]:
    return [s.delay_s for s in score.stops if s.judged]


def test_the_flag_is_held_over_a_stop_report_while_the_object_slides_onto_the_skin():
    held, off = _loop_score({}), _loop_score(OFF)
    assert off.dropped_from2 > 120 and held.dropped_from2 < off.dropped_from2 - 60
    # its stop clears as before: the level stops ramping where the object stops
    assert _judged_delays(held) == _judged_delays(off)
    assert all(d <= sr.CLEAR_WITHIN_S for d in _judged_delays(held))
    assert held.rest_flagged == off.rest_flagged == 0


def _stop_delays(tuning: dict) -> list[float]:
    return _judged_delays(score_case("stop", 92100, tuning, "35 mm/s"))


def test_a_level_drifting_up_at_rest_holds_no_flag():
    (delay,) = _stop_delays({})
    assert delay <= sr.CLEAR_WITHIN_S
    # as gentle a ramp as the hold asks while the posterior sees motion: held 0.77 s late
    (late,) = _stop_delays({"RAMP_OVER_STOP_SLOPE_N_S": 0.2})
    assert late > 0.5

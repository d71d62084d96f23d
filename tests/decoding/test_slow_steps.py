"""A step whose level rose slowly is no stop (`TrackerDecoder.LOG_SHAPE_RIDGE_STOP`).

When an object sticks its static level moves once, within the braking, and stays; a level
that rose over tens of ms is a ridge pulse held up by the FSR's hysteresis or the grip
rising under a sliding object (`detector.step_shape`). Read as "stopped here" it dropped
the slip flag while the object slid on, until the next ridge restarted the slip: in the
saturation kind's case below the grip ramps into the rail between two ridges 48 mm apart
(2.2 s at 22 mm/s), and the flag was down for 157 of the 250 updates it should have been
up (c22be85).
"""

from __future__ import annotations

from grasplink.evaluation import slip_reporting as sr


def test_a_grip_ramp_into_the_rail_while_sliding_keeps_the_slip_flag_up():
    case = sr.Case("saturation", "22 mm/s", (22,), "alpha0.3", True, 121101)
    score = sr.case_job(case, "tracker", {"0": {}}, baseline=False)["scores"]["0"]
    assert score.moving_from2 >= 200, score.moving_from2
    assert score.dropped_from2 <= 0.05 * score.moving_from2, (
        score.dropped_from2,
        score.moving_from2,
    )

"""A step whose level rose slowly is no stop (`TrackerDecoder.LOG_SHAPE_RIDGE_STOP`, off by
default: docs/decoding.md, its cost).

When an object sticks its static level moves once, within the braking, and stays; a level
that rose over tens of ms is a ridge pulse held up by the FSR's hysteresis or the grip
rising under a sliding object (`detector.step_shape`). Read as "stopped here" it dropped
the slip flag while the object slid on, until the next ridge restarted the slip: in the
saturation kind's case below the grip ramps into the rail between two ridges 48 mm apart
(2.2 s at 22 mm/s), and the flag was down for 157 of the 250 updates it should have been
up (c22be85, and with the ridge side off). Since s27 the flag is held while the sensor
sits on its rail (`decoding.rail_hold`): 64 of the 250 dropped with the ridge side off,
what is left before the rail and after it; the rule under test is read without it.
"""

from __future__ import annotations

import math

from grasplink.evaluation import slip_reporting as sr

RIDGE_SIDE = {"LOG_SHAPE_RIDGE_STOP": math.log(0.1), "SHAPE_AMBIGUOUS_RIDGE": 0.0}


def test_a_grip_ramp_into_the_rail_while_sliding_keeps_the_slip_flag_up():
    case = sr.Case("saturation", "22 mm/s", (22,), "alpha0.3", True, 121101)
    bare = {"LOG_SHAPE_RIDGE_STOP": 0.0, "RAIL_HOLD": 0.0, "STEP_HOLD": 0.0}
    configs = {
        "off": {"tuning": bare},
        "on": {"tuning": {**RIDGE_SIDE, "RAIL_HOLD": 0.0, "STEP_HOLD": 0.0}},
        "shipped": {"tuning": {}},  # the ridge side off, the rail hold on
    }
    scores = sr.case_job(case, "tracker", configs, baseline=False)["scores"]
    off, on, shipped = scores["off"], scores["on"], scores["shipped"]
    assert on.moving_from2 >= 200, on.moving_from2
    assert off.dropped_from2 > 0.5 * off.moving_from2  # the case: a ramp read as a stop
    assert on.dropped_from2 <= 0.05 * on.moving_from2, (on.dropped_from2, on.moving_from2)
    assert shipped.dropped_from2 < 0.5 * off.dropped_from2, shipped.dropped_from2

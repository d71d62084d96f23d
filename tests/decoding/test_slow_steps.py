"""A step whose level rose slowly is no stop (`TrackerDecoder.LOG_SHAPE_RIDGE_STOP`, off by
default: docs/decoding.md, its cost).

When an object sticks its static level moves once, within the braking, and stays; a level
that rose over tens of ms is a ridge pulse held up by the FSR's hysteresis or the grip
rising under a sliding object (`detector.step_shape`). Read as "stopped here" it dropped
the slip flag while the object slid on, until the next ridge restarted the slip: in the
saturation kind's case below the grip ramps into the rail between two ridges 48 mm apart
(2.2 s at 22 mm/s), and the flag was down for 157 of the 250 updates it should have been
up (c22be85, and with the ridge side off).
"""

from __future__ import annotations

import math

from grasplink.evaluation import slip_reporting as sr

RIDGE_SIDE = {"LOG_SHAPE_RIDGE_STOP": math.log(0.1), "SHAPE_AMBIGUOUS_RIDGE": 0.0}


def test_a_grip_ramp_into_the_rail_while_sliding_keeps_the_slip_flag_up():
    case = sr.Case("saturation", "22 mm/s", (22,), "alpha0.3", True, 121101)
    configs = {"off": {"tuning": {"LOG_SHAPE_RIDGE_STOP": 0.0}}, "on": {"tuning": RIDGE_SIDE}}
    scores = sr.case_job(case, "tracker", configs, baseline=False)["scores"]
    off, on = scores["off"], scores["on"]
    assert on.moving_from2 >= 200, on.moving_from2
    assert off.dropped_from2 > 0.5 * off.moving_from2  # the case: a ramp read as a stop
    assert on.dropped_from2 <= 0.05 * on.moving_from2, (on.dropped_from2, on.moving_from2)

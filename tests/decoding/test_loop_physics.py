"""The default decoder on the closed-loop scenes' physics (slip_reporting's `loop` kind).

The loop benchmark's wearer lost the slip belt mid-slip (docs/benchmarks/loop.md,
session 13's notes): on the loop's signals - the object sliding onto the skin from 8 mm
before it, speed dips at every ridge, hysteresis, drift, the grip rising as it stops - the
decoder dropped the slip flag while the object slid. The belt shows slip occurrence or
speed only while the flag is up, so a wearer sees a slip that blinks off.
"""

from __future__ import annotations

import pytest

from grasplink.evaluation import slip_reporting as sr

LOOP_DEFECT = (
    "on the loop's physics (alpha0.1, 20 and 30 mm/s, seeds 7001-7004) the slip flag is down "
    "in 48.6 % of the observable slipping updates from the 2nd contact and the speed missing "
    "in 59.6 % from the 3rd (at a47a6c4; 41.2 / 51.2 % with 14b2ad2's ramp check, reverted): "
    "of the ridge contacts found 41 % are told steps (the FSR's 0.2 N hysteresis holds the "
    "pulse's fall; 8 % on the constant set) and 21 % only by the slow probes, 24 % are "
    "missed; a step's 'stopped here' outweighs the ridge (STEP_STOP_WAIT's curve: "
    "docs/benchmarks/slip_reporting.md), a missed 2nd ridge leaves one-contact tracks"
)


def loop_scores() -> dict:
    scores = []
    for speed in (20, 30):
        for seed in range(1, 5):
            case = sr.Case(
                "loop", f"{speed} mm/s", (speed,), "alpha0.1", seed % 2 == 0, 7000 + seed
            )
            scores.append(sr.case_job(case, "tracker", {"0": {}}, baseline=False)["scores"]["0"])
    return sr.summarise(scores)


@pytest.mark.xfail(strict=True, reason=LOOP_DEFECT)
def test_the_slip_flag_stays_up_while_the_object_slides_in_the_loop_physics():
    figures = loop_scores()
    assert figures["dropped_from2_pct"] <= 2.0, figures["dropped_from2_pct"]
    assert figures["missing_from3_pct"] <= 10.0, figures["missing_from3_pct"]
    assert figures["speed_at_rest_pct"] == 0.0 and figures["flagged_at_rest_pct"] == 0.0

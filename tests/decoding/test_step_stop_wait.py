"""`TrackerDecoder.STEP_STOP_WAIT`: a stop at a step is told once the next ridge due after
the step would have been decided, not at once.

On the loop's physics (slip_reporting's `loop` kind: the FSR's hysteresis holds a ridge
pulse's fall) 41 % of the ridge contacts found are told steps, and each such step branches
the slipping tracks into "stopped there": told at once (the shipped 0), the flag drops at
the step verdict while the object slides on. With the wait, the step's stop hypothesis
counts as slipping on - with the speed it had - until the next ridge due after the step
(the one after the next when the step sits on the next one: it may be that ridge's
contact) would have been decided; its silence there then tells the stop.
"""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding.tracker import TrackerDecoder
from grasplink.errors import ConfigError
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

# alpha0.1 at 30 mm/s backwards (test_loop_physics' set): a ridge contact at 2.921 s is
# told a step at 3.03 s; the next ridge is crossed at 3.095 s. (Seed 7002's step, pinned
# before, went with the loop kind's reverse physics fixed in 3adc6b8: the object no longer
# lies on the skin before it moves.)
CASE = sr.Case("loop", "30 mm/s", (30,), "alpha0.1", True, 7004)
STEP_TOLD_S, NEXT_RIDGE_S = 3.03, 3.095


def flags(wait: float, **tuning: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rec = CASE.make()
    tuning = {"STEP_STOP_WAIT": wait, **tuning}
    dec = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz, tuning=tuning)
    est, _ = ns.feed(dec, rec.t_s, rec.force_n, sr.CHUNK)
    t = np.array([e.t_s for e in est])
    slip = np.array([e.slip for e in est])
    speed = np.array([np.nan if e.speed_mm_s is None else e.speed_mm_s for e in est])
    return t, slip, speed


@pytest.fixture(scope="module")
def waited() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return flags(1.0)


def test_the_case_has_a_ridge_told_a_step_and_at_once_the_flag_drops_there():
    # (with `told_rise` and the ridge-shaped step's prior off, as the case was pinned:
    # with either the flag holds here even at 0)
    t, slip, _ = flags(0.0, TOLD_RISE_LOG=0.0, LOG_SHAPE_RIDGE_STOP=0.0)
    after = (t >= STEP_TOLD_S) & (t < STEP_TOLD_S + 0.1)
    before = (t >= STEP_TOLD_S - 0.3) & (t < STEP_TOLD_S - 0.1)
    assert slip[before].all()  # slipping before the step
    assert not slip[after].any()


def test_waiting_keeps_the_slip_and_its_speed_past_the_step_verdict(waited):
    t, slip, speed = waited
    after = (t >= STEP_TOLD_S) & (t < STEP_TOLD_S + 0.1)
    assert slip[after].all()
    # the speed measured at the step's ridge: the dips there (4-15 mm/s) lower it
    assert np.all(np.abs(speed[after] - 30.0) <= 0.2 * 30.0), speed[after]


def test_waiting_still_tells_the_stop_at_rest(waited):
    rec = CASE.make()
    t, slip, speed = waited
    at_rest = t >= float(rec.truth.t_s[-1]) - 0.3
    assert not slip[at_rest].any() and not np.nan_to_num(speed[at_rest]).any()


def test_the_wait_is_a_checked_tuning():
    with pytest.raises(ConfigError, match="STEP_STOP_WAIT = 'soon' is not a number"):
        TrackerDecoder([5.0, 5.0], 400.0, tuning={"STEP_STOP_WAIT": "soon"})

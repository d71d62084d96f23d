"""The slip flag held over a step shaped like a ridge's (`decoding.step_hold`).

The case: the full plan's reversal kind at 22 -> -58 mm/s on alpha0.5 (5, 12, 67 mm),
seed 102110: the 25 mm object slides on at 22 mm/s (ridge contacts 0.58, 0.81, 1.36 s),
crosses the 67 mm spacing (3 s at that speed), turns at 3.65 s and comes back (contacts
4.10, 4.31, 4.39 s) to rest at 4.53 s. Without the hold a step after the 1.36 s ridge,
shaped like a ridge's, is taken for the stop and the flag drops from 1.89 s to 4.21 s
while the object slides (176 of its 293 scored updates)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasplink.decoding import step_hold
from grasplink.decoding.detector import step_shape
from grasplink.decoding.kernels import posterior as posterior_kernels
from grasplink.evaluation import slip_reporting as sr
from tests.decoding.plan_cases import decode_case


def _reversal(tuning: dict):
    """(update times, flags, speeds, truth, estimates) of the reversal case."""
    rec, _, estimates = decode_case("reversal", 102110, tuning, "22->-58 mm/s")
    t = np.array([e.t_s for e in estimates])
    flags = np.array([e.slip for e in estimates])
    return t, flags, [e.speed_mm_s for e in estimates], rec.truth, estimates


def test_the_flag_is_held_while_the_object_slides_past_a_ridge_shaped_step():
    t, flags, speeds, truth, estimates = _reversal({"STEP_HOLD": 1.0})
    gap = (t >= 1.9) & (t <= 3.6)  # after the step, before the turn
    assert (np.interp(t[gap], truth.t_s, truth.speed_mm_s) > 20.0).all()
    assert flags[gap].all()
    assert all(speeds[k] is None for k in np.flatnonzero(gap))  # a step tells no speed
    assert sr.score(estimates, truth).dropped_from2 == 0


def test_without_it_the_flag_drops_there():
    t, flags, _, truth, estimates = _reversal({"STEP_HOLD": 0.0})
    gap = (t >= 1.9) & (t <= 3.6)
    assert not flags[gap].any()
    assert sr.score(estimates, truth).dropped_from2 > 100


def test_the_hold_ends_at_rest():
    t, flags, _, truth, _ = _reversal({"STEP_HOLD": 1.0})
    moving = np.flatnonzero(np.abs(truth.speed_mm_s) >= 1.0)
    late = t > truth.t_s[moving[-1]] + 0.15
    assert late.any() and not flags[late].any()


def test_only_a_ridge_shaped_step_after_the_flag_was_up_is_held():
    ridge, stop = step_shape.RIDGE_LIKE, step_shape.STOP_LIKE
    assert step_hold.holds(ridge, up_s=1.5, step_s=1.4, now_s=2.0, seen_s=4.0, max_s=3.0)
    assert not step_hold.holds(stop, 1.5, 1.4, 2.0, 4.0, 3.0)  # a stop's step: told at once
    assert not step_hold.holds(step_shape.UNTOLD, 1.5, 1.4, 2.0, 4.0, 3.0)
    assert not step_hold.holds(ridge, 1.3, 1.4, 2.0, 4.0, 3.0)  # the flag never up past it
    assert not step_hold.holds(ridge, 1.5, 1.4, 4.0, 4.0, 3.0)  # next ridge decided: silence
    assert not step_hold.holds(ridge, 1.5, 1.4, 2.0, 4.0, 0.5)  # held no longer than max_s
    assert not step_hold.holds(ridge, 1.5, math.nan, 2.0, 4.0, 3.0)  # no step's stop


def test_the_wait_is_set_in_a_copy_of_the_constants():
    K = np.zeros(len(posterior_kernels.NAMES))
    out = step_hold.hold_constants(K, 1.0)
    assert out[posterior_kernels.STEP_STOP_WAIT] == 1.0 and K[posterior_kernels.STEP_STOP_WAIT] == 0
    with pytest.raises(ValueError, match="wait must be > 0"):
        step_hold.hold_constants(K, 0.0)

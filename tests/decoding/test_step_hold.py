"""The slip flag held over a step shaped like a ridge's (`decoding.step_hold`).

The case: the full plan's reversal kind at 22 -> -58 mm/s on alpha0.5 (5, 12, 67 mm),
seed 102110: the 25 mm object slides on at 22 mm/s (ridge contacts 0.58, 0.81, 1.36 s),
crosses the 67 mm spacing (3 s at that speed), turns at 3.65 s and comes back (contacts
4.10, 4.31, 4.39 s) to rest at 4.53 s. Without the hold a step after the 1.36 s ridge,
shaped like a ridge's, is taken for the stop and the flag drops from 1.89 s to 4.21 s
while the object slides (176 of its 293 scored updates). With the hold the flag stays up
to the turn. A step probe's contact after the step (1.68 s: the object's trailing edge
leaving the first ridge, told RIDGE_LIKE) ended it at 2.52 s until s32: the stop still
chosen 0.3 s after a contact that came after its step (`STEP_HOLD_AFTER_S`, the price of
the loop case below); a contact told ridge-like no longer counts there
(`STEP_HOLD_AFTER_UNRIDGED`).

The hold's two limits, each on the stop it cleared late: loop 161210 (30 mm/s on 4, 3,
48, 29 mm: a contact after its stop's step that no moving track took up held the stop
2.6 s, to its end) and stop 95100 (35 mm/s: stopped just short of the next ridge, the
wait ran to the ridge after and cleared it 0.61 s late).

These cases were pinned before the ridge-shaped step's prior (`LOG_SHAPE_RIDGE_STOP`,
s34), which takes most such steps for ridges in the first place: the reversal's step is
then no stop at all, and the hold has nothing to hold. They run without it (`BARE`), so
that they check the hold; `test_shape_ridge_stop` checks the prior on them."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasplink.decoding import step_hold
from grasplink.decoding.detector import step_shape
from grasplink.decoding.kernels import posterior as posterior_kernels
from grasplink.evaluation import slip_reporting as sr
from tests.decoding.plan_cases import decode_case, score_case

BARE = {"LOG_SHAPE_RIDGE_STOP": 0.0}  # the step taken for a stop, as the cases were pinned


def _reversal(tuning: dict):
    """(update times, flags, speeds, truth, estimates) of the reversal case."""
    rec, _, estimates = decode_case("reversal", 102110, {**BARE, **tuning}, "22->-58 mm/s")
    t = np.array([e.t_s for e in estimates])
    flags = np.array([e.slip for e in estimates])
    return t, flags, [e.speed_mm_s for e in estimates], rec.truth, estimates


def test_the_flag_is_held_while_the_object_slides_past_a_ridge_shaped_step():
    t, flags, speeds, truth, estimates = _reversal({})
    gap = (t >= 1.9) & (t <= 2.5)  # after the step, before the contact after it is 0.3 s old
    assert (np.interp(t[gap], truth.t_s, truth.speed_mm_s) > 20.0).all()
    assert flags[gap].all()
    assert all(speeds[k] is None for k in np.flatnonzero(gap))  # a step tells no speed
    assert sr.score(estimates, truth).dropped_from2 < 120


def test_held_to_the_turn_without_the_limit_on_contacts_after_the_step():
    t, flags, _, truth, estimates = _reversal({"STEP_HOLD_AFTER_S": 0.0})
    gap = (t >= 1.9) & (t <= 3.6)  # after the step, before the turn
    assert flags[gap].all()
    assert sr.score(estimates, truth).dropped_from2 == 0


def test_a_contact_after_the_step_told_ridge_like_does_not_end_the_hold():
    t, flags, _, truth, estimates = _reversal({})
    gap = (t >= 1.9) & (t <= 3.6)  # after the step, before the turn
    assert flags[gap].all()
    assert sr.score(estimates, truth).dropped_from2 == 0
    # counted, the trailing edge's contact at 1.68 s ends the hold at 2.52 s
    t, flags, _, truth, estimates = _reversal({"STEP_HOLD_AFTER_UNRIDGED": 0.0})
    assert flags[(t >= 1.9) & (t <= 2.5)].all() and not flags[(t >= 2.6) & (t <= 3.6)].any()


def test_without_it_the_flag_drops_there():
    t, flags, _, truth, estimates = _reversal({"STEP_HOLD": 0.0})
    gap = (t >= 1.9) & (t <= 3.6)
    assert not flags[gap].any()
    assert sr.score(estimates, truth).dropped_from2 > 100


def test_the_hold_ends_at_rest():
    t, flags, _, truth, _ = _reversal({})
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


def _stop_delay_s(kind: str, seed: int, variant: str, tuning: dict) -> float:
    """The case's one judged stop: seconds from observable to cleared for good."""
    (stop,) = [s for s in score_case(kind, seed, {**BARE, **tuning}, variant).stops if s.judged]
    return stop.delay_s


def test_a_contact_after_the_step_left_to_the_stop_ends_the_hold():
    assert _stop_delay_s("loop", 161210, "30 mm/s", {}) <= sr.CLEAR_WITHIN_S
    # without the limit the flag stays up to the stop's end
    assert _stop_delay_s("loop", 161210, "30 mm/s", {"STEP_HOLD_AFTER_S": 0.0}) == math.inf


def test_the_wait_runs_to_the_next_ridge_only():
    assert _stop_delay_s("stop", 95100, "35 mm/s", {}) <= sr.CLEAR_WITHIN_S
    # waiting for the ridge after the next, as the posterior's STEP_STOP_WAIT does
    assert _stop_delay_s("stop", 95100, "35 mm/s", {"STEP_HOLD_SKIP": 1.0}) > 0.5


def test_a_contact_after_the_step_ends_the_hold_only_once_older_than_the_limit():
    assert not step_hold.unlinked([], now_s=5.0, within_s=0.3)  # silence: the wait's to tell
    assert not step_hold.unlinked([2.0], now_s=2.3, within_s=0.3)  # a track may take it up yet
    assert step_hold.unlinked([2.0], now_s=2.31, within_s=0.3)
    assert step_hold.unlinked([2.2, 2.0], now_s=2.31, within_s=0.3)  # the first one counts

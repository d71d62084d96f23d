"""The compiled posterior (`kernels.posterior`) says what the numpy posterior said
(`reference.tracker`, the numpy `_posterior` of 0858d90), call by call: at every posterior
of a real decode, the numpy code runs in this process on the decoder's state of that moment.

What must hold (`reference.compare`): the chosen track, whether it is stopped, the ridge it
has not reached and whether an estimate is reported exactly, as the numpy code chose them,
unless one of the numpy code's decisions on the way sits within the reach of rounding (a
perturbed numpy run decided otherwise: then the kernel may decide as either did, and such
calls are counted); the valid-until time, P(slip), the agreement and the direction odds
within the allowance derived from the exp, log and erf they pass through."""

from __future__ import annotations

from collections.abc import Callable
from functools import cache

import numpy as np
import pytest

from grasplink.decoding import tracker
from grasplink.decoding.kernels.posterior import constants, pairwise_sum
from grasplink.evaluation import nonstationary, slip_reporting
from tests.decoding.reference import tracker as reference
from tests.decoding.reference.compare import (
    MAGNIFY,
    allowance,
    assert_within,
    perturbed_runs,
)
from tests.decoding.test_numerical_edges import railed_slip

RUNS = [f"signal{k}" for k in range(10)] + ["railed0", "railed1", "loopwait"]
# a loop-physics slip whose ridges are told steps, decoded with STEP_STOP_WAIT on: the
# stops at steps told only once the next ridge is due (kernels.posterior.stop_seen)
LOOP_WAIT = {"STEP_STOP_WAIT": 1.0}


def told(out: tuple) -> tuple[tuple, np.ndarray]:
    """A posterior's decisions (None, or the chosen track's numbers, stopped, the ridge it
    has not reached) and its numbers (valid until, P(slip), agreement, odds)."""
    until, chosen, p_slip, agree, odds = out[:5]  # the magnitude (issue 22) after them
    if chosen is None:
        choice: tuple = (None,)
    else:
        one, stopped, limit = chosen
        choice = (one.s, one.v, one.t, one.dirn, one.ridge, one.n, stopped, limit)
    return choice, np.array([until, p_slip, agree, odds])


def same_marks(a: list, b: list) -> bool:
    return len(a) == len(b) and all(
        x.shape == y.shape and np.array_equal(x, y) for x, y in zip(a, b, strict=True)
    )


def signal(name: str) -> tuple[np.ndarray, np.ndarray, list[float], float]:
    if name == "loopwait":
        rec = slip_reporting.Case("loop", "30 mm/s", (30,), "alpha0.1", True, 7002).make()
        return np.asarray(rec.t_s), np.asarray(rec.force_n), rec.truth.layout_mm, rec.fs_hz
    if name.startswith("railed"):
        rec = railed_slip(60.0, name == "railed1")
        return rec.t_s, rec.force_n, rec.layout_mm, rec.fs_hz
    made = nonstationary.signals(True)[int(name.removeprefix("signal"))].make()
    return np.asarray(made.t_s), np.asarray(made.force_n), made.truth.layout_mm, made.fs_hz


@cache
def compared(name: str) -> dict[str, int]:
    """Decode run `name` three samples at a time (as the gateway does), checking every
    posterior against the numpy code's; what the calls covered."""
    t, x, layout_mm, fs_hz = signal(name)
    dec = tracker.TrackerDecoder(layout_mm, fs_hz, tuning=LOOP_WAIT if name == "loopwait" else None)
    compiled: Callable = dec._posterior
    seen = {"calls": 0, "near": 0, "blind": 0, "chosen": 0, "none": 0, "stopped": 0}

    def checked(g: float):
        want, marks = reference.posterior(dec, g)
        runs = perturbed_runs(lambda: reference.posterior(dec, g), seen["calls"])
        magnified = perturbed_runs(lambda: reference.posterior(dec, g), seen["calls"], MAGNIFY)
        got = compiled(g)
        (choice, numbers), (want_choice, want_numbers) = told(got), told(want)
        near = not all(same_marks(run_marks, marks) for _, run_marks in runs)
        where = f"{name}, posterior {seen['calls']} at {g}"
        if choice != want_choice:  # only where the arithmetic could have chosen so too
            others = [told(run) for run, _ in runs if told(run)[0] == choice]
            assert near and others, f"{where}: chose {choice}, the numpy code {want_choice}"
            want_numbers = others[0][1]
        alike = [told(run)[1] for run, run_marks in runs if same_marks(run_marks, marks)]
        big = [told(run)[1] for run, run_marks in magnified if same_marks(run_marks, marks)]
        if near:  # the numbers of either decision are in reach
            alike = [told(run)[1] for run, _ in runs] + [told(want)[1]]
        assert_within(numbers, want_numbers, allowance(want_numbers, alike, big), where)
        seen["calls"] += 1
        seen["near"] += near
        seen["blind"] += dec._blind(dec._tracks.t, g) is not None
        seen["chosen"] += choice != (None,)
        seen["none"] += choice == (None,)
        seen["stopped"] += choice[-2:-1] == (True,)
        return got

    dec._posterior = checked  # type: ignore[method-assign]
    for i in range(0, len(t), 3):
        dec.process(t[i : i + 3], x[i : i + 3])
    return seen


@pytest.mark.parametrize("name", RUNS)
def test_compiled_posterior_matches_the_numpy_posterior(name):
    seen = compared(name)
    assert seen["calls"] >= 20
    assert seen["near"] <= max(1, seen["calls"] // 50), seen  # thresholds rarely in reach


def test_the_compared_runs_cover_slips_silence_on_the_rail_and_no_slip():
    seen = {key: sum(compared(name)[key] for name in RUNS) for key in compared(RUNS[0])}
    assert seen["blind"] >= 20 and seen["chosen"] >= 100, seen
    assert seen["none"] >= 30 and seen["stopped"] >= 10, seen


@pytest.mark.parametrize("size", [0, 1, 7, 8, 9, 16, 127, 128, 129, 300, 1000])
def test_pairwise_sum_adds_in_numpys_order(size):
    x = np.exp(np.random.default_rng(size).normal(size=size) * 6)
    assert pairwise_sum(x) == np.add.reduce(x)  # bit for bit


def test_posterior_constants_are_all_named():
    with pytest.raises(ValueError, match=r"missing .*refresh_s"):
        constants(negligible=25.0)


def test_warm_up_leaves_the_decoder_it_is_asked_of_as_it_was():
    rec = nonstationary.signals(True)[0].make()
    t, x = np.asarray(rec.t_s), np.asarray(rec.force_n)
    warmed = tracker.TrackerDecoder(rec.truth.layout_mm, rec.fs_hz)
    tracker._WARM = False  # as in a fresh process
    warmed.warm_up()
    assert tracker._WARM
    fresh = tracker.TrackerDecoder(rec.truth.layout_mm, rec.fs_hz)
    assert warmed.feed(t, x) == fresh.feed(t, x)

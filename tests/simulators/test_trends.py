"""Guessed commands: a ramp's repeating steps continued to the bit, anything else held."""

from __future__ import annotations

import math

import pytest

from grasplink.simulators.trends import HISTORY, continue_steps


def _mn(counts: list[int]) -> list[float]:
    """Commands as a hand binding gives them: mN counts / 1000."""
    return [c / 1000 for c in counts]


def test_a_grip_ramp_stepping_on_skin_packets_is_continued_to_the_bit():
    """loop_headline's grip falls -15, -15, -30 mN per 10 ms chunk (a ramp step on each
    7.5 ms packet): the guesses are the floats the node's counts / 1000 give, not the
    float sums (9.786 - 0.015 is 9.771000000000001)."""
    counts = [11_421]
    for k in range(40):
        counts.append(counts[-1] - (30 if k % 3 == 2 else 15))
    history, future = counts[:HISTORY], counts[HISTORY : HISTORY + 20]
    assert continue_steps(_mn(history), 20) == _mn(future)


def test_two_equal_steps_of_a_longer_pattern_are_not_taken_for_a_period_of_one():
    """..., -30, -15, -15: a period of one would guess -15 next, and the ramp gives -30."""
    history = _mn([11_421, 11_406, 11_391, 11_361, 11_346, 11_331])
    assert continue_steps(history, 1) == [history[-1]]  # too short to tell: held
    longer = _mn([11_466, 11_451, 11_421, 11_406, 11_391, 11_361, 11_346, 11_331, 11_301, 11_286])
    assert continue_steps(longer, 2) == _mn([11_271, 11_241])


def test_a_linear_ramp_is_continued_once_three_equal_steps_came():
    assert continue_steps([0.0, 0.0, -400.0, -800.0], 3) == [-800.0] * 3
    assert continue_steps([0.0, -400.0, -800.0, -1200.0], 3) == [-1600.0, -2000.0, -2400.0]


@pytest.mark.parametrize(
    "history",
    [
        [5.0] * 8,  # held
        [5.0, 5.0, 5.0, 5.0, 5.5],  # a step nothing foretold
        [1.0, 2.0, 4.0, 8.0, 16.0, 32.0],  # no repeating steps
        [1.0, 2.0, 3.0, math.nan, 5.0, 6.0, 7.0],  # a NaN in the window
        [1.0, 2.0, 3.0, 4.0, math.inf],
    ],
)
def test_anything_else_is_held(history):
    guesses = continue_steps(history, 4)
    assert len(guesses) == 4
    assert all(g == history[-1] or (math.isnan(g) and math.isnan(history[-1])) for g in guesses)


def test_no_history_is_an_error_naming_it():
    with pytest.raises(ValueError, match="no history"):
        continue_steps([], 3)
    assert continue_steps([1.0], 0) == []

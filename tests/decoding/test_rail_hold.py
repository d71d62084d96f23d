"""The slip flag held while the sensor sits on its rail (`decoding.rail_hold`).

The case: the full plan's saturation kind at 22 mm/s on alpha0.7 (seed 123100): a squeeze
drives the FSR (5 N full scale) into its rail from 2.88 s to 3.87 s while the object slides
on; the squeeze's own rise, told a step at 2.28 s, was read as the stop, and the flag
dropped at 2.57 s until the slip's ridges came again after the rail."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding import rail_hold
from tests.decoding.plan_cases import decode_case


def _saturated(tuning: dict):
    """(update times, flags, the rail's stretches) of the saturation case."""
    rec, dec, estimates = decode_case("saturation", 123100, tuning, "22 mm/s")
    t = np.array([e.t_s for e in estimates])
    flags = np.array([e.slip for e in estimates])
    speeds = [e.speed_mm_s for e in estimates]
    return t, flags, speeds, list(dec.detector.blind), rec.truth


def test_the_flag_is_held_over_the_rail_and_carries_no_speed():
    t, flags, speeds, blind, truth = _saturated({})
    start, end = blind[0][0], blind[-1][1]
    assert 2.7 < start < 3.0 and 3.7 < end < 4.0  # the squeeze's rail
    assert np.interp(end, truth.t_s, truth.speed_mm_s) > 20.0  # it slides through it
    # the rail is told per noise block (0.125 s) after the detector's (0.01 s)
    on = (t >= start + 0.14) & (t <= end)
    assert flags[on].all()
    assert all(speeds[k] is None for k in np.flatnonzero(on))


def test_without_it_the_flag_drops_on_the_rail():
    # (and without the ridge-shaped step's prior, `LOG_SHAPE_RIDGE_STOP`: with it the
    # squeeze's slow rise is seldom the stop, and the flag stays up through most of the rail)
    t, flags, _, blind, _ = _saturated({"RAIL_HOLD": 0.0, "LOG_SHAPE_RIDGE_STOP": 0.0})
    on = (t >= blind[0][0] + 0.14) & (t <= blind[-1][1])
    assert not flags[on].any()  # main's behaviour: the squeeze's step held as the stop


def test_a_held_object_is_never_flagged_by_the_rail():
    # never up: no stretch of rail raises the flag
    blind = [(1.0, 1.1), (1.1025, 1.2)]
    assert not rail_hold.holds(blind, 1.25, -np.inf, 0.15, 0.01, 0.6, 0.0)


def test_the_stretch_and_the_hold():
    blind = [(0.5, 0.6), (1.0, 1.1), (1.1025, 1.2), (1.2025, 1.3)]
    assert rail_hold.stretch_start(blind, 0.01) == 1.0  # the gap before 1.0 breaks it
    assert rail_hold.holds(blind, 1.4, 0.5, 0.15, 0.01, 0.6, 0.0)  # up 0.5 s before
    assert not rail_hold.holds(blind, 1.4, 0.3, 0.15, 0.01, 0.6, 0.0)  # up 0.7 s before
    assert not rail_hold.holds(blind, 1.5, 1.2, 0.15, 0.01, 0.6, 0.0)  # off the rail
    assert rail_hold.holds(blind, 1.5, 1.2, 0.15, 0.01, 0.6, 0.1)  # ... held after it


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="no rail block"):
        rail_hold.stretch_start([], 0.01)
    with pytest.raises(ValueError, match="must be >= 0"):
        rail_hold.holds([(1.0, 1.1)], 1.2, 1.0, -0.1, 0.01, 0.6, 0.0)

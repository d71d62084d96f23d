"""object.damped: a load pulls the object through a damper; the speed measures the grip it lacks."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.core.params import SceneError
from grasplink.simulators.core import REGISTRY
from grasplink.simulators.effects.damped import DampedObject
from grasplink.simulators.harness import context, make, run, sample_times_us

CHUNKS = (1, 2, 7, 333, 1000)


def _run(grip_n, times, chunk=None, load_n=10.0, **params):
    params = {"damping_n_s_per_mm": 0.2, "mu_static": 0.5, **params}
    effect = make(DampedObject, context(seed=1, rate_hz=1000), **params)
    load = np.broadcast_to(np.asarray(load_n, dtype=float), times.shape)
    return run([effect], times, {"hand.grip_n": grip_n, "load.force_n": load}, chunk=chunk)


def test_it_is_registered_under_its_kind():
    assert REGISTRY["object.damped"] is DampedObject


@pytest.mark.parametrize("grip_n", [10.0, 10.5, 40.0])
def test_a_grip_whose_friction_reaches_the_load_holds_it_at_rest(grip_n):
    times = sample_times_us(1000, 1.0)
    out = _run(np.full(len(times), grip_n), times, start_mm=3.0)  # 2 · 0.5 · 10 N = 10 N
    assert np.all(out["object.speed_mm_s"] == 0.0)
    assert np.all(out["object.position_mm"] == 3.0)


@pytest.mark.parametrize("grip_n", [0.0, 2.0, 6.0, 9.9])
def test_the_slip_speed_is_the_missing_friction_over_the_damping(grip_n):
    times = sample_times_us(1000, 1.0)
    out = _run(np.full(len(times), grip_n), times)
    expected_mm_s = (10.0 - 2 * 0.5 * grip_n) / 0.2
    assert np.allclose(out["object.speed_mm_s"], expected_mm_s)
    elapsed_s = (times[-1] - times[0]) / 1e6
    assert out["object.position_mm"][-1] == pytest.approx(expected_mm_s * elapsed_s, rel=1e-9)
    assert np.all(out["object.slipping"] == 1.0)


def test_a_reverse_slip_moves_towards_the_first_ridge():
    times = sample_times_us(1000, 0.5)
    out = _run(np.zeros(len(times)), times, load_n=-10.0, start_mm=80.0)
    assert np.all(out["object.speed_mm_s"] == -50.0)
    elapsed_s = (times[-1] - times[0]) / 1e6
    assert out["object.position_mm"][-1] == pytest.approx(80.0 - 50.0 * elapsed_s)


def test_the_pull_cannot_exceed_its_top_speed():
    times = sample_times_us(1000, 0.2)
    out = _run(np.zeros(len(times)), times, max_speed_mm_s=30.0)
    assert np.all(out["object.speed_mm_s"] == 30.0)


def test_a_slip_needs_more_grip_to_stop_than_to_prevent():
    """µ_k < µ_s: a grip between load/(2µ_s) and load/(2µ_k) holds a resting object but
    does not stop a sliding one; raising it past load/(2µ_k) stops it."""
    times = sample_times_us(1000, 3.0)
    t_s = times / 1e6
    grip = np.where(t_s < 1.0, 0.0, np.where(t_s < 2.0, 11.0, 13.0))  # limits 10 N and 12.5 N
    out = _run(grip, times, mu_kinetic=0.4)
    speed = out["object.speed_mm_s"]
    assert np.all(speed[t_s < 1.0] == 50.0)
    middle = (t_s >= 1.0) & (t_s < 2.0)
    assert np.allclose(speed[middle], (10.0 - 0.8 * 11.0) / 0.2)  # still sliding, slower
    assert np.all(speed[t_s >= 2.0] == 0.0)
    held = _run(np.full(len(times), 11.0), times, mu_kinetic=0.4)
    assert np.all(held["object.speed_mm_s"] == 0.0)  # 11 N holds it from rest


def test_friction_that_drops_lets_a_held_object_slip():
    times = sample_times_us(1000, 2.0)
    t_s = times / 1e6
    out = _run(
        np.full(len(times), 12.0), times, friction_scale=[[0, 1.0], [1.0, 1.0], [1.001, 0.5]]
    )
    speed = out["object.speed_mm_s"]
    assert np.all(speed[t_s <= 1.0] == 0.0)
    assert np.allclose(speed[t_s >= 1.001], (10.0 - 0.5 * 12.0) / 0.2)


def test_nothing_moves_before_the_load_is_applied():
    times = sample_times_us(1000, 1.0)
    t_s = times / 1e6
    out = _run(np.zeros(len(times)), times, load_n=np.where(t_s < 0.5, 0.0, 10.0))
    assert np.all(out["object.speed_mm_s"][t_s < 0.5] == 0.0)
    assert np.all(out["object.speed_mm_s"][t_s >= 0.5] == 50.0)


def test_chunked_stepping_is_bit_identical_to_one_shot():
    times = sample_times_us(1000, 4.0)
    t_s = times / 1e6
    grip = 9.0 + 4.0 * np.sin(5.0 * t_s)  # crosses both limits many times
    load = np.where(t_s < 0.3, 0.0, 10.0 * np.cos(0.7 * t_s))
    params = {"mu_kinetic": 0.4, "friction_scale": [[0, 1.0], [2.0, 0.8]], "load_n": load}
    whole = _run(grip, times, **params)
    for chunk in CHUNKS:
        chunked = _run(grip, times, chunk=chunk, **params)
        for name, values in whole.items():
            assert np.array_equal(chunked[name], values), (name, chunk)
            assert np.all(np.isfinite(values)), name


def test_a_nan_grip_is_no_grip_rather_than_a_nan_position():
    times = sample_times_us(1000, 0.2)
    grip = np.full(len(times), np.nan)
    out = _run(grip, times)
    assert np.all(np.isfinite(out["object.position_mm"]))
    assert np.all(out["object.speed_mm_s"] == 50.0)


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"mu_kinetic": 0.6}, r"mu_kinetic.*<= mu_static"),
        ({"damping_n_s_per_mm": 0.0}, r"damping_n_s_per_mm"),
        ({"friction_scale": [[0, -0.5]]}, r"friction_scale"),
    ],
)
def test_bad_parameters_name_the_key(params, message):
    with pytest.raises(SceneError, match=message):
        make(
            DampedObject,
            context(seed=1, rate_hz=1000),
            **{"damping_n_s_per_mm": 0.2, "mu_static": 0.5, **params},
        )

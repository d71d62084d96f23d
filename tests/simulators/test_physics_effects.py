"""Physics-domain effects: object kinematics, hand/belt actuators, scripted forces and wearer."""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest

from grasplink.core.params import SceneError
from grasplink.simulators.core import REGISTRY, Io
from grasplink.simulators.effects.actuators import (
    BeltMotor,
    HandActuator,
    ScriptedGrip,
    ScriptedLoad,
)
from grasplink.simulators.effects.kinematics import (
    CoulombObject,
    RidgeDips,
    ScriptedObject,
    SlipTask,
)
from grasplink.simulators.effects.wearer import WearerScript
from grasplink.simulators.harness import context, make, run, sample_times_us

LAYOUT_MM = (10.0, 20.0, 30.0)  # ridges at 0, 10, 30, 60 mm
RIDGES_MM = (0.0, 10.0, 30.0, 60.0)
CHUNKS = (1, 2, 7, 333, 1000)


def ctx(layout=LAYOUT_MM, seed=1, rate_hz=1000):
    return context(seed=seed, rate_hz=rate_hz, layout_mm=layout)


def ones(times, value=1.0):
    return np.full(len(times), float(value))


# ---------------------------------------------------------------- chunking


def _cases():
    """(name, rate_hz, duration_s, effects factory, inputs factory)."""

    def t_s(times):
        return times / 1e6

    return [
        (
            "scripted-linear",
            1000,
            3.0,
            lambda: [
                make(ScriptedObject, ctx(), speed_mm_s=[[0, 0], [1, 30], [2.5, -10]], start_mm=-3)
            ],
            lambda t: {},
        ),
        (
            "scripted-step",
            700,
            3.0,
            lambda: [
                make(
                    ScriptedObject,
                    ctx(),
                    speed_mm_s=[[0.2, 5], [1, 30]],
                    interpolation="step",
                    direction="reverse",
                )
            ],
            lambda t: {},
        ),
        (
            "coulomb-stick-slip",
            1000,
            3.0,
            lambda: [make(CoulombObject, ctx(), mass_kg=0.1, mu_static=0.5, mu_kinetic=0.4)],
            lambda t: {
                "hand.grip_n": 1.0 + 0.3 * np.sin(7 * t_s(t)),
                "load.force_n": 1.1 * np.sin(3 * t_s(t)),
            },
        ),
        (
            "coulomb-odd-rate",
            700,
            3.0,
            lambda: [make(CoulombObject, ctx(), mass_kg=0.2)],
            lambda t: {"hand.grip_n": ones(t), "load.force_n": 2.0 * np.cos(2 * t_s(t))},
        ),
        (
            "ridge-dips-back-and-forth",
            1000,
            4.0,
            lambda: [
                make(ScriptedObject, ctx(), speed_mm_s=[[0, 40], [1.5, 40], [2, -40]], start_mm=-5),
                make(RidgeDips, ctx()),
            ],
            lambda t: {},
        ),
        (
            "ridge-dips-oscillating-long",
            1000,
            12.0,
            lambda: [
                make(
                    ScriptedObject,
                    ctx(),
                    start_mm=3,
                    speed_mm_s=[[0.5 * i, 30.0 * (-1) ** i] for i in range(25)],
                ),
                make(RidgeDips, ctx(), recovery_s=0.002, depth_mm_s=[10, 40]),
            ],
            lambda t: {},
        ),
        (
            "slip-task",
            1000,
            4.0,
            lambda: [
                make(WearerScript, ctx(), levels=[[0, 0], [0.5, 1], [2.3, 2]]),
                make(SlipTask, ctx(), update_period_s=0.75),
            ],
            lambda t: {},
        ),
        (
            "slip-task-fast-phases",
            700,
            1.0,
            lambda: [
                make(WearerScript, ctx(), levels=[[0, 1]]),
                make(SlipTask, ctx(), update_period_s=0.0005),
            ],
            lambda t: {},
        ),
        (
            "hand-actuator",
            700,
            2.0,
            lambda: [make(HandActuator, ctx(), crush_limit_n=40, max_force_n=60)],
            lambda t: {"hand.target_n": np.where(t_s(t) < 1, 80.0, 10.0)},
        ),
        (
            "grip-and-load-scripted",
            1000,
            2.0,
            lambda: [
                make(ScriptedGrip, ctx(), grip_n=[[0, 0], [1, 5]]),
                make(ScriptedLoad, ctx(), force_n=[[0, 1], [1.5, -2]], interpolation="step"),
            ],
            lambda t: {},
        ),
        ("load-weight", 1000, 0.5, lambda: [make(ScriptedLoad, ctx(), mass_kg=0.3)], lambda t: {}),
        (
            "belt-motor",
            700,
            2.0,
            lambda: [make(BeltMotor, ctx())],
            lambda t: {"belt.command_mrad_s": np.where(t_s(t) < 1, 5000.0, -3700.0)},
        ),
        (
            "wearer-script",
            1000,
            2.0,
            lambda: [make(WearerScript, ctx(), levels=[[0.1, 2], [0.5, 5], [1.2, 0]])],
            lambda t: {},
        ),
    ]


@pytest.mark.parametrize(
    ("rate_hz", "duration_s", "effects", "inputs"),
    [c[1:] for c in _cases()],
    ids=[c[0] for c in _cases()],
)
def test_chunked_stepping_is_bit_identical_to_one_shot(rate_hz, duration_s, effects, inputs):
    times = sample_times_us(rate_hz, duration_s)
    whole = run(effects(), times, inputs(times))
    for chunk in CHUNKS:
        chunked = run(effects(), times, inputs(times), chunk=chunk)
        assert chunked.keys() == whole.keys()
        for name, values in whole.items():
            assert np.array_equal(chunked[name], values), (name, chunk)
            assert np.all(np.isfinite(values)), name


def test_every_physics_effect_is_registered_under_its_kind():
    for cls in (
        ScriptedObject,
        CoulombObject,
        RidgeDips,
        SlipTask,
        HandActuator,
        ScriptedGrip,
        ScriptedLoad,
        BeltMotor,
        WearerScript,
    ):
        assert REGISTRY[cls.kind] is cls
        assert cls.domain == "physics"
        assert cls.summary


# ---------------------------------------------------------------- object.scripted


def test_scripted_position_is_the_exact_integral_of_a_linear_profile():
    times = sample_times_us(1000, 8.0)
    effect = make(
        ScriptedObject, ctx(), speed_mm_s=[[0, 0], [2, 10], [5, 10], [6, 0]], start_mm=1.5
    )
    out = run([effect], times)
    t = times / 1e6
    expected_speed = np.interp(t, [0, 2, 5, 6], [0, 10, 10, 0])
    expected_position = 1.5 + np.select(
        [t <= 2, t <= 5, t <= 6],
        [2.5 * t**2, 10 + 10 * (t - 2), 40 + 10 * (t - 5) - 5 * (t - 5) ** 2],
        45.0,
    )
    np.testing.assert_allclose(out["object.speed_mm_s"], expected_speed, rtol=0, atol=1e-12)
    np.testing.assert_allclose(out["object.position_mm"], expected_position, rtol=0, atol=1e-12)
    assert np.array_equal(out["object.slipping"], (expected_speed != 0).astype(float))


def test_scripted_step_profile_holds_values_and_the_first_value_before_the_first_point():
    times = sample_times_us(1000, 4.0)
    out = run(
        [make(ScriptedObject, ctx(), speed_mm_s=[[1, 3], [2, 8]], interpolation="step")], times
    )
    t = times / 1e6
    np.testing.assert_array_equal(out["object.speed_mm_s"], np.where(t < 2, 3.0, 8.0))
    np.testing.assert_allclose(
        out["object.position_mm"], np.where(t < 2, 3 * t, 6 + 8 * (t - 2)), rtol=0, atol=1e-12
    )


def test_scripted_reverse_direction_negates_speed_and_position():
    times = sample_times_us(1000, 2.0)
    forward = run(
        [make(ScriptedObject, ctx(), speed_mm_s=[[0, 4], [1, 6]], direction="forward")], times
    )
    reverse = run(
        [
            make(
                ScriptedObject, ctx(), speed_mm_s=[[0, 4], [1, 6]], direction="reverse", start_mm=84
            )
        ],
        times,
    )
    np.testing.assert_array_equal(reverse["object.speed_mm_s"], -forward["object.speed_mm_s"])
    np.testing.assert_allclose(
        reverse["object.position_mm"], 84 - forward["object.position_mm"], rtol=0, atol=1e-12
    )


def test_scripted_signed_speeds_are_allowed_without_direction_but_not_with_it():
    make(ScriptedObject, ctx(), speed_mm_s=[[0, -4]])
    with pytest.raises(SceneError, match=r"effect\.speed_mm_s\[1\]\[1\].*magnitude"):
        make(ScriptedObject, ctx(), speed_mm_s=[[0, 4], [1, -2]], direction="reverse")


def _last_values(effect, rate_hz, duration_s, chunk_samples):
    """Step an effect without inputs in chunks, keeping only each output's last value."""
    count = round(duration_s * rate_hz)
    last: dict[str, float] = {}

    def write(name, values):
        last[name] = float(values[-1])

    def read(name, times):
        raise KeyError(name)

    for start in range(0, count, chunk_samples):
        index = np.arange(start, min(start + chunk_samples, count), dtype=np.int64)
        effect.step(Io(index * 1_000_000 // rate_hz, read, write))
    return last


def test_scripted_position_does_not_drift_over_ten_hours_at_1khz():
    effect = make(ScriptedObject, ctx(), speed_mm_s=[[0, 0], [10, 12.5]], start_mm=-2)
    last = _last_values(effect, 1000, 10 * 3600.0, 1_000_000)
    final_s = Fraction(10 * 3600 * 1000 - 1, 1000)
    exact = -2 + Fraction(125, 10) * 10 / 2 + Fraction(125, 10) * (final_s - 10)
    assert last["object.speed_mm_s"] == 12.5
    assert abs(last["object.position_mm"] - float(exact)) <= 2 * math.ulp(float(exact))


# ---------------------------------------------------------------- object.coulomb


def _coulomb(times, grip, load, **params):
    params = {"mass_kg": 0.1, "mu_static": 0.5, **params}
    effect = make(CoulombObject, ctx(), **params)
    return run([effect], times, {"hand.grip_n": grip, "load.force_n": load})


@pytest.mark.parametrize("fraction", [0.0, 0.5, 0.999, 1.0])
def test_coulomb_object_holds_while_load_is_within_two_surfaces_of_static_friction(fraction):
    times = sample_times_us(1000, 2.0)
    capacity = 2 * 0.5 * 3.0
    for sign in (1, -1):
        out = _coulomb(times, ones(times, 3.0), ones(times, sign * fraction * capacity), start_mm=7)
        assert np.all(out["object.speed_mm_s"] == 0)
        assert np.all(out["object.position_mm"] == 7)
        assert np.all(out["object.slipping"] == 0)


def test_coulomb_object_at_exactly_the_static_limit_stays_put():
    times = sample_times_us(1000, 10.0)
    out = _coulomb(times, ones(times, 10.0), ones(times, 10.0))  # 2 · 0.5 · 10 N = 10 N
    assert np.all(out["object.speed_mm_s"] == 0)
    assert np.all(out["object.position_mm"] == 0)


def test_coulomb_slip_acceleration_is_load_minus_kinetic_friction_over_mass():
    times = sample_times_us(1000, 1.0)
    for sign in (1, -1):
        out = _coulomb(times, ones(times), ones(times, sign * 1.5), mu_kinetic=0.4)
        # (1.5 N − 2 · 0.4 · 1 N) / 0.1 kg = 7 m/s² = 7000 mm/s²
        a_mm_s2 = sign * 7000.0
        speed = out["object.speed_mm_s"]
        np.testing.assert_allclose(np.diff(speed) / 1e-3, a_mm_s2, rtol=1e-9)
        n = np.arange(len(times))
        # semi-implicit Euler: x_n = a·dt²·n(n+1)/2
        np.testing.assert_allclose(
            out["object.position_mm"], a_mm_s2 * 1e-6 * n * (n + 1) / 2, rtol=1e-9, atol=1e-12
        )
        assert np.all(out["object.slipping"][1:] == 1)


def test_coulomb_one_contact_surface_halves_the_friction():
    times = sample_times_us(1000, 0.5)
    held = _coulomb(times, ones(times), ones(times, 0.7))
    slips = _coulomb(times, ones(times), ones(times, 0.7), contact_surfaces=1)
    assert np.all(held["object.speed_mm_s"] == 0)
    assert slips["object.speed_mm_s"][-1] > 0


def test_coulomb_object_sticks_at_zero_speed_without_chattering():
    times = sample_times_us(1000, 3.0)
    load = np.where(times < 500_000, 1.3, 0.5)  # breaks away, then below kinetic friction
    out = _coulomb(times, ones(times), load, mu_kinetic=0.45)
    speed = out["object.speed_mm_s"]
    stopped = int(np.flatnonzero((speed == 0) & (times > 500_000))[0])
    assert np.all(speed[1:stopped] > 0)
    assert np.all(speed[stopped:] == 0)
    assert np.count_nonzero(np.diff(out["object.slipping"])) == 2  # starts once, stops once
    assert np.all(out["object.position_mm"][stopped:] == out["object.position_mm"][stopped])


def test_coulomb_load_exactly_at_kinetic_friction_keeps_a_constant_speed():
    times = sample_times_us(1000, 2.0)
    load = np.where(times < 100_000, 2.0, 1.0)  # 2 · 0.5 · 1 N = 1 N kinetic friction
    out = _coulomb(times, ones(times), load, mu_static=0.6, mu_kinetic=0.5)
    speed = out["object.speed_mm_s"]
    later = speed[times >= 100_000]
    assert later[0] > 0
    assert np.all(later == later[0])


# ---------------------------------------------------------------- object.ridge_dips


def _dipped(speed_profile, duration_s=3.0, seed=1, layout=LAYOUT_MM, **params):
    times = sample_times_us(1000, duration_s)
    source = make(ScriptedObject, ctx(layout, seed), **speed_profile)
    dips = make(RidgeDips, ctx(layout, seed), **params)
    original = run([make(ScriptedObject, ctx(layout, seed), **speed_profile)], times)
    return original, run([source, dips], times)


def _drops(original, out):
    """Speed-magnitude reduction at each sample."""
    return np.abs(original["object.speed_mm_s"]) - np.abs(out["object.speed_mm_s"])


def test_ridge_dips_slow_the_object_at_each_crossing_within_the_configured_depth():
    original, out = _dipped({"speed_mm_s": [[0, 40]], "start_mm": -5})
    drops = _drops(original, out)
    jumps = np.flatnonzero(np.diff(drops) > 1.0) + 1
    assert len(jumps) == len(RIDGES_MM)
    position = out["object.position_mm"]
    for sample, ridge in zip(jumps, RIDGES_MM, strict=True):
        assert position[sample - 1] < ridge <= position[sample]  # first sample past the ridge
        assert 4.0 <= drops[sample] <= 15.0 + 1e-9
    assert np.all(drops[: jumps[0]] == 0)
    assert np.all(out["object.speed_mm_s"] >= 0)
    assert np.all(out["object.speed_mm_s"] <= original["object.speed_mm_s"])
    np.testing.assert_array_equal(out["object.slipping"], 1.0)


def test_ridge_dips_recover_exponentially_with_the_recovery_time():
    original, out = _dipped({"speed_mm_s": [[0, 40]], "start_mm": -5}, recovery_s=0.02)
    drops = _drops(original, out)
    first = int(np.flatnonzero(drops > 0)[0])
    np.testing.assert_allclose(drops[first + 20], drops[first] * math.exp(-1), rtol=1e-9)


def test_ridge_dips_position_is_consistent_with_the_dipped_speed():
    original, out = _dipped({"speed_mm_s": [[0, 40]], "start_mm": -5}, duration_s=3.0)
    drops = _drops(original, out)
    starts = np.flatnonzero(np.diff(drops) > 1.0) + 1
    depths = drops[starts] - drops[starts - 1] * math.exp(-1e-3 / 0.05)  # minus earlier dips
    lost = original["object.position_mm"] - out["object.position_mm"]
    # all dips have decayed by the end: each removed exactly depth · recovery_s of travel
    assert lost[-1] == pytest.approx(float(np.sum(depths)) * 0.05, rel=1e-9)
    # and sample by sample the position follows the trapezoidal integral of the speed
    speed = out["object.speed_mm_s"]
    integral = np.concatenate(([0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * 1e-3)))
    travelled = out["object.position_mm"] - out["object.position_mm"][0]
    assert np.max(np.abs(travelled - integral)) < len(depths) * 15.0 * 1e-3


def test_ridge_dips_work_in_reverse():
    original, out = _dipped({"speed_mm_s": [[0, 40]], "direction": "reverse", "start_mm": 65})
    drops = _drops(original, out)
    jumps = np.flatnonzero(np.diff(drops) > 1.0) + 1
    assert len(jumps) == len(RIDGES_MM)
    position = out["object.position_mm"]
    for sample, ridge in zip(jumps, RIDGES_MM[::-1], strict=True):
        assert position[sample - 1] >= ridge > position[sample]
        assert 4.0 <= drops[sample] <= 15.0 + 1e-9
    assert np.all(out["object.speed_mm_s"] <= 0)
    assert np.all(np.diff(position) < 0)


def test_ridge_dips_count_each_crossing_once_when_the_object_turns_back():
    # 5 → 25 mm (crosses the ridge at 10) → back to 5 mm (crosses it again)
    original, out = _dipped(
        {"speed_mm_s": [[0, 20], [1, 20], [1.001, -20]], "interpolation": "step", "start_mm": 5},
        duration_s=2.0,
    )
    jumps = np.flatnonzero(np.diff(_drops(original, out)) > 1.0) + 1
    assert len(jumps) == 2
    same_sign = np.sign(out["object.speed_mm_s"]) == np.sign(original["object.speed_mm_s"])
    assert np.all(same_sign | (out["object.speed_mm_s"] == 0))


def test_ridge_dips_never_reverse_a_slow_object():
    _, out = _dipped({"speed_mm_s": [[0, 2]], "start_mm": -1}, duration_s=6.0)
    speed = out["object.speed_mm_s"]
    assert np.all(speed >= 0)
    assert np.min(speed) == 0  # a dip deeper than the speed stops the object for a moment
    assert np.all(np.diff(out["object.position_mm"]) >= 0)


def test_ridge_dips_leave_a_still_object_alone():
    _, out = _dipped({"speed_mm_s": [[0, 0]], "start_mm": 10})
    np.testing.assert_array_equal(out["object.speed_mm_s"], 0.0)
    np.testing.assert_array_equal(out["object.position_mm"], 10.0)
    np.testing.assert_array_equal(out["object.slipping"], 0.0)


def test_ridge_dip_depths_come_from_the_scene_seed():
    profile = {"speed_mm_s": [[0, 40]], "start_mm": -5}
    _, first = _dipped(profile, seed=1)
    _, again = _dipped(profile, seed=1)
    _, other = _dipped(profile, seed=2)
    assert np.array_equal(first["object.speed_mm_s"], again["object.speed_mm_s"])
    assert not np.array_equal(first["object.speed_mm_s"], other["object.speed_mm_s"])


def test_ridge_dips_need_a_skin_layout():
    with pytest.raises(SceneError, match="layout"):
        make(RidgeDips, ctx(layout=None))


# ---------------------------------------------------------------- object.slip_task


def _task(levels, duration_s=4.0, **params):
    times = sample_times_us(1000, duration_s)
    out = run([make(WearerScript, ctx(), levels=levels), make(SlipTask, ctx(), **params)], times)
    return times, out


def test_slip_task_spec_example_six_mm_s_at_level_e3_becomes_1_8_mm_s():
    times, out = _task([[0, 0], [0.5, 3]], duration_s=1.5)
    speed = out["object.speed_mm_s"]
    assert np.all(speed[times < 1_000_000] == 6.0)
    assert np.all(speed[times >= 1_000_000] == 1.8)
    assert np.all(out["hand.crushed"] == 0)
    after = times >= 1_000_000
    np.testing.assert_allclose(
        out["object.position_mm"][after], 6.0 + 1.8 * (times[after] / 1e6 - 1.0), rtol=0, atol=1e-12
    )


def test_slip_task_level_e0_leaves_the_speed_unchanged():
    times, out = _task([[0, 0]])
    np.testing.assert_array_equal(out["object.speed_mm_s"], 6.0)
    np.testing.assert_allclose(out["object.position_mm"], 6.0 * times / 1e6, rtol=0, atol=1e-12)


def test_slip_task_level_e5_crushes_the_object():
    times, out = _task([[0, 5]], duration_s=2.0)
    before = times < 1_000_000
    assert np.all(out["object.speed_mm_s"][before] == 6.0)
    assert np.all(out["object.speed_mm_s"][~before] == 0.0)
    assert np.all(out["hand.crushed"][before] == 0)
    assert np.all(out["hand.crushed"][~before] == 1)
    assert np.all(out["object.slipping"][~before] == 0)


@pytest.mark.parametrize(
    ("initial", "level", "after", "crushed"),
    [
        (6.0, 4, 0.0, 0),
        (6.0, 1, 4.6, 0),
        (6.0, 2, 3.2, 0),
        (3.2, 2, 0.0, 0),
        (3.2, 1, 1.8, 0),
        (3.2, 3, 0.0, 1),
        (1.8, 1, 0.0, 0),
        (1.8, 2, 0.0, 1),
    ],
)
def test_slip_task_level_ej_at_speed_vi_goes_to_v_i_minus_j_stops_at_i_crushes_above(
    initial, level, after, crushed
):
    _, out = _task([[0, level]], duration_s=1.5, initial_speed_mm_s=initial)
    assert out["object.speed_mm_s"][-1] == after
    assert out["hand.crushed"][-1] == crushed


def test_slip_task_updates_once_per_phase_and_ignores_levels_after_the_session_ends():
    times, out = _task([[0, 1], [2.5, 2], [3.5, 5]], duration_s=5.0)
    speed = out["object.speed_mm_s"]
    t = times / 1e6
    # e1: 6.0 → 4.6 (t=1) → 3.2 (t=2); e2 at t=3: 3.2 → stopped; e5 at t=4 comes too late
    for start, stop, value in [(0, 1, 6.0), (1, 2, 4.6), (2, 3, 3.2), (3, 5, 0.0)]:
        assert np.all(speed[(t >= start) & (t < stop)] == value)
    assert np.all(out["hand.crushed"] == 0)
    assert out["object.position_mm"][-1] == pytest.approx(6.0 + 4.6 + 3.2)


def test_slip_task_reverse_direction_moves_towards_the_first_ridge():
    _, out = _task([[0, 0]], duration_s=1.0, direction="reverse", start_mm=80)
    np.testing.assert_array_equal(out["object.speed_mm_s"], -6.0)
    assert out["object.position_mm"][-1] == pytest.approx(80 - 6.0 * 0.999)


# ---------------------------------------------------------------- actuators


def test_hand_actuator_reaches_63_percent_of_a_step_at_one_time_constant():
    times = sample_times_us(1000, 1.0)
    out = run(
        [make(HandActuator, ctx(), time_constant_s=0.1)],
        times,
        {"hand.target_n": ones(times, 50.0)},
    )
    grip = out["hand.grip_n"]
    assert grip[0] == 0.0
    assert grip[100] == pytest.approx(50.0 * (1 - math.exp(-1)), rel=1e-12)
    np.testing.assert_allclose(grip, 50.0 * (1 - np.exp(-times / 1e6 / 0.1)), rtol=1e-12)
    assert np.all(out["hand.crushed"] == 0)


def test_hand_actuator_is_limited_to_its_maximum_force_and_never_pulls():
    times = sample_times_us(1000, 2.0)
    target = np.where(times < 1_000_000, 500.0, -20.0)
    grip = run([make(HandActuator, ctx(), max_force_n=80)], times, {"hand.target_n": target})[
        "hand.grip_n"
    ]
    assert grip[999] == pytest.approx(80.0, rel=1e-4)
    assert np.max(grip) <= 80.0
    assert np.min(grip) >= 0.0


def test_hand_actuator_latches_crushed_once_the_grip_exceeds_the_crush_limit():
    times = sample_times_us(1000, 2.0)
    target = np.where(times < 500_000, 60.0, 0.0)
    out = run([make(HandActuator, ctx(), crush_limit_n=30)], times, {"hand.target_n": target})
    first = int(np.flatnonzero(out["hand.grip_n"] > 30)[0])
    assert np.all(out["hand.crushed"][:first] == 0)
    assert np.all(out["hand.crushed"][first:] == 1)
    assert out["hand.grip_n"][-1] < 1.0  # released, still crushed


def test_scripted_grip_and_weight_load():
    times = sample_times_us(1000, 2.0)
    out = run(
        [
            make(ScriptedGrip, ctx(), grip_n=[[0, 0], [1, 5]]),
            make(ScriptedLoad, ctx(), mass_kg=0.25),
        ],
        times,
    )
    np.testing.assert_allclose(out["hand.grip_n"], np.minimum(5 * times / 1e6, 5), atol=1e-12)
    np.testing.assert_array_equal(out["load.force_n"], 0.25 * 9.81)


@pytest.mark.parametrize(("rad_s", "mm_s"), [(2.0, 55), (3.7, 100), (5.3, 145), (7.0, 190)])
def test_belt_motor_slip_levels_match_thesis_belt_speeds(rad_s, mm_s):
    times = sample_times_us(1000, 1.0)
    out = run([make(BeltMotor, ctx())], times, {"belt.command_mrad_s": ones(times, -1000 * rad_s)})
    assert out["belt.surface_mm_s"][-1] == pytest.approx(mm_s, rel=0.02)
    assert np.all(out["belt.tap_hz"] == 0)


@pytest.mark.parametrize("rad_s", [3.5, 5.0, 6.5, 8.0])
def test_belt_motor_force_levels_tap_at_nubs_times_revolutions(rad_s):
    times = sample_times_us(1000, 1.0)
    out = run([make(BeltMotor, ctx())], times, {"belt.command_mrad_s": ones(times, 1000 * rad_s)})
    assert out["belt.velocity_mrad_s"][-1] == pytest.approx(1000 * rad_s, rel=1e-6)
    assert out["belt.tap_hz"][-1] == pytest.approx(6 * rad_s / (2 * math.pi), rel=1e-6)
    assert np.all(out["belt.surface_mm_s"] == 0)


def test_belt_motor_reversal_passes_through_zero_and_drives_one_belt_at_a_time():
    times = sample_times_us(1000, 1.0)
    command = np.where(times < 500_000, 5000.0, -5000.0)
    out = run(
        [make(BeltMotor, ctx(), time_constant_s=0.05)], times, {"belt.command_mrad_s": command}
    )
    velocity = out["belt.velocity_mrad_s"]
    assert np.max(np.abs(np.diff(velocity))) < 10000 * (1 - math.exp(-0.02)) + 1e-9
    assert np.all((out["belt.tap_hz"] == 0) | (out["belt.surface_mm_s"] == 0))
    assert np.all(out["belt.tap_hz"][velocity > 0] > 0)
    assert np.all(out["belt.surface_mm_s"][velocity < 0] > 0)


# ---------------------------------------------------------------- wearer.script


def test_wearer_script_holds_each_level_until_the_next_point():
    times = sample_times_us(1000, 2.0)
    out = run([make(WearerScript, ctx(), levels=[[0.5, 2], [1.0, 5], [1.5, 0]])], times)
    t = times / 1e6
    expected = np.select([t < 1.0, t < 1.5], [2.0, 5.0], 0.0)
    np.testing.assert_array_equal(out["wearer.level"], expected)


# ---------------------------------------------------------------- parameter errors


@pytest.mark.parametrize(
    ("cls", "params", "key"),
    [
        (CoulombObject, {"mass_kg": -1}, "mass_kg"),
        (CoulombObject, {"mass_kg": 0}, "mass_kg"),
        (CoulombObject, {}, "mass_kg"),
        (CoulombObject, {"mass_kg": 1, "mu_static": 0.3, "mu_kinetic": 0.5}, "mu_kinetic"),
        (CoulombObject, {"mass_kg": 1, "contact_surfaces": 0}, "contact_surfaces"),
        (CoulombObject, {"mas_kg": 1, "mass_kg": 1}, "mas_kg"),
        (ScriptedObject, {"speed_mm_s": []}, "speed_mm_s"),
        (ScriptedObject, {"speed_mm_s": [[0, 1], [0, 2]]}, "speed_mm_s"),
        (ScriptedObject, {"speed_mm_s": [[1, 1], [0.5, 2]]}, "speed_mm_s"),
        (ScriptedObject, {"speed_mm_s": [[0, 1]], "interpolation": "cubic"}, "interpolation"),
        (ScriptedObject, {"speed_mm_s": [[0, 1]], "direction": "up"}, "direction"),
        (ScriptedObject, {"speed_mm_s": [[0, 1]], "start": 3}, "start"),
        (RidgeDips, {"depth_mm_s": [15, 4]}, "depth_mm_s"),
        (RidgeDips, {"depth_mm_s": [4, 8, 15]}, "depth_mm_s"),
        (RidgeDips, {"depth_mm_s": [-1, 4]}, r"depth_mm_s\[0\]"),
        (RidgeDips, {"recovery_s": 0}, "recovery_s"),
        (SlipTask, {"initial_speed_mm_s": 5.0}, "initial_speed_mm_s"),
        (SlipTask, {"level_speeds_mm_s": [1, 3, 2, 4]}, "level_speeds_mm_s"),
        (SlipTask, {"level_speeds_mm_s": [1, 2, 3]}, "level_speeds_mm_s"),
        (SlipTask, {"update_period_s": -1}, "update_period_s"),
        (HandActuator, {"time_constant_s": 0}, "time_constant_s"),
        (HandActuator, {"crush_limit_n": -5}, "crush_limit_n"),
        (ScriptedGrip, {"grip_n": [[0, -1]]}, r"grip_n\[0\]\[1\]"),
        (ScriptedLoad, {}, "force_n"),
        (ScriptedLoad, {"force_n": [[0, 1]], "mass_kg": 1}, "force_n"),
        (ScriptedLoad, {"mass_kg": -2}, "mass_kg"),
        (BeltMotor, {"nubs": 0}, "nubs"),
        (BeltMotor, {"effective_radius_mm": 0}, "effective_radius_mm"),
        (WearerScript, {"levels": [[0, 2.5]]}, r"levels\[0\]\[1\]"),
        (WearerScript, {"levels": [[0, 1], [1, 6]]}, r"levels\[1\]\[1\]"),
        (WearerScript, {"levels": [[0, 1], [0.5, 2], [0.5, 3]]}, "levels"),
    ],
)
def test_bad_parameters_raise_scene_errors_naming_the_key(cls, params, key):
    with pytest.raises(SceneError, match=rf"test: effect\.{key}"):
        make(cls, ctx(), **params)


@pytest.mark.parametrize("chunk", [1, 7, 100])
def test_ridge_dips_short_path_gives_the_crossing_loops_bits(monkeypatch, chunk):
    """A chunk with no dip in force and no ridge in reach skips the crossing loop: the same
    bits as the loop gives (moving between ridges, resting with the offset the dips left,
    moving back across them), and the short path is taken most of the time."""
    profile = {
        "speed_mm_s": [[0, 40], [0.4, 40], [0.5, 0], [3.0, 0], [3.1, -30]],
        "interpolation": "step",
        "start_mm": -5,
    }
    times = sample_times_us(1000, 4.5)
    source = make(ScriptedObject, ctx(), **profile)
    dips = make(RidgeDips, ctx())
    short = dips._crosses_nothing
    taken = []

    def counted(p0):
        taken.append(short(p0))
        return taken[-1]

    monkeypatch.setattr(dips, "_crosses_nothing", counted)
    out = run([source, dips], times, chunk=chunk)
    loop_only = make(RidgeDips, ctx())
    monkeypatch.setattr(loop_only, "_crosses_nothing", lambda p0: False)
    expected = run([make(ScriptedObject, ctx(), **profile), loop_only], times, chunk=chunk)
    for name, values in expected.items():
        assert np.array_equal(out[name], values), name
    assert dips.offset_mm == loop_only.offset_mm != 0.0  # the dips moved the edge back
    assert sum(taken) > 0.6 * len(taken)

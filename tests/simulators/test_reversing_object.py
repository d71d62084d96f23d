"""object.scripted with object_length_mm: a slip that reverses hands the contacts to the other edge.

Without the length one edge is integrated through a reversal and skin.fsr's
coverage jumps (docs/scenes.md, known limitations); with it the reported
leading edge switches, the coverage stays continuous, and object.ridge_dips
and skin.ridge_contacts see no ridge crossed by the switch.
"""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.core.params import SceneError
from grasplink.simulators.effects.actuators import ScriptedGrip, ScriptedLoad
from grasplink.simulators.effects.kinematics import RidgeDips, ScriptedObject
from grasplink.simulators.effects.skin import FsrForce, RidgeContacts
from grasplink.simulators.harness import context, make, run, sample_times_us

LAYOUT_MM = (10.0, 20.0, 30.0, 24.0)  # ridges at 0, 10, 30, 60, 84 mm
LENGTH_MM = 25.0
# forward at 40 mm/s from -5 mm, through zero at 1.5 s (edge at 55 mm), back at 40 mm/s
REVERSING = [[0.0, 0.0], [0.2, 40.0], [1.45, 40.0], [1.5, 0.0], [1.55, -40.0]]
CHUNKS = (1, 3, 7, 256, 1000)


def ctx(seed: int = 1, rate_hz: int = 1000):
    return context(seed=seed, rate_hz=rate_hz, layout_mm=LAYOUT_MM)


def chain(seed: int = 1, dips: bool = True, **scripted) -> list:
    c = ctx(seed)
    params = {"speed_mm_s": REVERSING, "start_mm": -5.0, "object_length_mm": LENGTH_MM}
    params.update(scripted)
    effects = [make(ScriptedObject, c, **params)]
    if dips:  # short recovery: each dip has ended before the next crossing
        effects.append(make(RidgeDips, c, recovery_s=0.005))
    return [
        *effects,
        make(ScriptedGrip, c, grip_n=[[0.0, 5.0]]),
        make(ScriptedLoad, c, mass_kg=0.2),
        make(FsrForce, c, object_length_mm=LENGTH_MM),
        make(RidgeContacts, c),
    ]


def test_reversing_chain_is_bit_identical_in_any_chunking():
    times = sample_times_us(1000, 3.5)
    whole = run(chain(), times)
    for chunk in CHUNKS:
        chunked = run(chain(), times, chunk=chunk)
        for name, values in whole.items():
            assert np.array_equal(chunked[name], values), (name, chunk)


def test_the_reported_edge_switches_to_the_rear_edge_at_the_reversal():
    times = sample_times_us(1000, 3.0)
    out = run(chain(dips=False), times)
    x, v = out["object.position_mm"], out["object.speed_mm_s"]
    turn = int(np.argmax(v < 0))
    front = -5.0 + 0.5 * 40.0 * 0.2 + 40.0 * (1.45 - 0.2) + 0.5 * 40.0 * 0.05  # 50 mm at v = 0
    assert x[turn - 1] == pytest.approx(front, abs=0.05)
    assert x[turn] == pytest.approx(front - LENGTH_MM, abs=0.05)
    assert np.all(np.delete(np.abs(np.diff(x)), turn - 1) < 0.05)  # one jump, no other


def test_coverage_of_the_skin_stays_continuous_through_the_reversal():
    times = sample_times_us(1000, 3.0)
    with_length = run(chain(dips=False), times)
    # the force without contacts: grip times coverage, continuous where the slip state is
    c = ctx()
    plain = [
        make(ScriptedObject, c, speed_mm_s=REVERSING, start_mm=-5.0, object_length_mm=LENGTH_MM),
        make(ScriptedGrip, c, grip_n=[[0.0, 5.0]]),
        make(ScriptedLoad, c, mass_kg=0.2),
        make(FsrForce, c, object_length_mm=LENGTH_MM),
    ]
    force = run(plain, times)["skin.force_n"]
    v = with_length["object.speed_mm_s"]
    moving = (v[1:] != 0) & (v[:-1] != 0)
    assert np.max(np.abs(np.diff(force))[moving]) < 0.01


def test_contacts_after_the_reversal_come_from_the_rear_edge_and_no_switch_makes_one():
    times = sample_times_us(1000, 3.5)
    effects = chain(dips=False)
    run(effects, times)
    contacts = effects[-1].contacts
    forward = [(c.ridge, c.direction) for c in contacts if c.time_s < 1.5]
    backward = [(c.ridge, c.direction) for c in contacts if c.time_s > 1.5]
    # the front edge reaches 0, 10, 30 mm and turns at 46 mm; the rear edge, now leading
    # from 21 mm, leaves 10 and 0 behind; the switch from 46 to 21 mm passes 30 untouched
    assert forward == [(0, 1), (1, 1), (2, 1)]
    assert backward == [(1, -1), (0, -1)]


def test_ridge_dips_start_no_dip_at_the_switch_of_edges():
    times = sample_times_us(1000, 3.5)
    t_s = times / 1e6
    with_dips = run(chain(dips=True), times)["object.speed_mm_s"]
    without = run(chain(dips=False), times)["object.speed_mm_s"]
    # the last dip before the turn (ridge 30 at ~0.98 s) has ended by 1.45 s; the rear
    # edge, 25 mm from 1.5 s on, reaches ridge 10 at ~1.9 s
    quiet = (t_s > 1.45) & (t_s < 1.85)
    assert np.array_equal(with_dips[quiet], without[quiet])
    after = (t_s > 1.85) & (t_s < 2.0)
    assert np.any(with_dips[after] != without[after])


def test_a_length_with_direction_and_magnitudes_changes_nothing():
    times = sample_times_us(700, 2.0)
    params = {"speed_mm_s": [[0.2, 5.0], [1.0, 30.0]], "direction": "reverse", "start_mm": 90.0}
    plain = run([make(ScriptedObject, ctx(rate_hz=700), **params)], times)
    with_length = run(
        [make(ScriptedObject, ctx(rate_hz=700), object_length_mm=LENGTH_MM, **params)], times
    )
    for name, values in plain.items():
        assert np.array_equal(with_length[name], values), name


def test_start_is_the_edge_of_the_first_motion_in_reverse():
    times = sample_times_us(1000, 1.0)
    out = run(
        [
            make(
                ScriptedObject,
                ctx(),
                speed_mm_s=[[0.0, 0.0], [0.5, -20.0]],
                start_mm=70.0,
                object_length_mm=LENGTH_MM,
            )
        ],
        times,
    )
    assert out["object.position_mm"][0] == 70.0
    assert out["object.position_mm"][-1] == pytest.approx(70.0 - 5.0 - 10.0, abs=0.05)


@pytest.mark.parametrize("length", [0.0, -3.0])
def test_object_length_must_be_positive(length):
    with pytest.raises(SceneError, match="object_length_mm"):
        make(ScriptedObject, ctx(), speed_mm_s=[[0.0, 1.0]], object_length_mm=length)

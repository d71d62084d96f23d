"""The least-force task: its objects, its scene, its trials and its report."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from grasplink.cli import main as cli_main
from grasplink.controllers import build_controllers
from grasplink.errors import ConfigError
from grasplink.evaluation import least_force, loop, loop_task
from grasplink.simulators.effects.damped import DampedObject
from grasplink.simulators.harness import context, make, run, sample_times_us
from grasplink.simulators.scene import parse_scene

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("speed_mm_s", least_force.SPEEDS_MM_S)
def test_each_task_speed_is_as_many_levels_missing_as_its_display_level(speed_mm_s):
    task = least_force.TaskObject(speed_mm_s)
    display_level = 1 + int(speed_mm_s // least_force.LEVEL_SPAN_MM_S)
    assert task.levels_missing == display_level
    held_n = least_force.GRIP_LEVELS_N[task.stopping_level]
    below_n = least_force.GRIP_LEVELS_N[task.stopping_level - 1]
    assert below_n < task.holding_grip_n <= held_n  # the level below does not stop it
    above = min(task.stopping_level + 1, len(least_force.GRIP_LEVELS_N) - 1)
    if above != task.stopping_level:  # one level too many breaks it
        assert least_force.GRIP_LEVELS_N[above] > task.crush_limit_n > held_n


@pytest.mark.parametrize("speed_mm_s", least_force.SPEEDS_MM_S)
def test_the_damped_object_slips_at_the_task_speed_at_rest_and_stops_at_its_level(speed_mm_s):
    task = least_force.TaskObject(speed_mm_s)
    for grip_n, expected_mm_s in (
        (least_force.GRIP_LEVELS_N[least_force.REST_LEVEL], speed_mm_s),
        (least_force.GRIP_LEVELS_N[task.stopping_level], 0.0),
    ):
        assert np.allclose(damped_speed_mm_s(task, grip_n), expected_mm_s)


def damped_speed_mm_s(task, grip_n, friction=1.0):
    """The task object's speed over 0.5 s at a steady grip (and friction factor)."""
    times = sample_times_us(1000, 0.5)
    effect = make(
        DampedObject,
        context(seed=1, rate_hz=1000),
        damping_n_s_per_mm=least_force.DAMPING_N_S_PER_MM,
        friction_scale=[[0.0, friction]],
    )
    inputs = {
        "hand.grip_n": np.full(len(times), grip_n),
        "load.force_n": np.full(len(times), task.load_n),
    }
    return run([effect], times, inputs)["object.speed_mm_s"]


def test_the_shipped_scene_is_the_task_template_at_20_mm_s():
    data = tomllib.loads((ROOT / "scenes" / "loop_least_force.toml").read_text())
    trial = loop.Trial("slip_speed", False, 20.0, 7, task="least_force")
    template = loop.scene_data(trial)
    assert data["effects"] == template["effects"]
    assert data["controller"]["feedback"] == template["controller"]["feedback"]
    assert data["controller"]["reflex"]["enabled"] is False


def test_a_task_trial_scene_parses_and_a_bad_task_or_speed_is_refused():
    data = loop.scene_data(loop.Trial("slip_occurrence", False, 4.0, 1, task="least_force"))
    scene = parse_scene(data, "<task>")
    assert [e.kind for e in scene.effects][:3] == [
        "hand.actuator",
        "load.scripted",
        "object.damped",
    ]
    with pytest.raises(ConfigError, match=r"task: expected one of pulled, least_force"):
        loop.scene_data(loop.Trial("slip_speed", False, 20.0, 1, task="thrown"))
    with pytest.raises(ValueError, match="slip speed must be > 0"):
        least_force.adapt(data, float("nan"), 1.0, -8.0)


def test_a_task_trial_never_slips_faster_than_the_task_speed():
    """The wearer only adds grip, so the object never moves faster than at the resting
    grip: a drop takes at least the crossing time at the task speed, a stop covers at most
    the task speed times its time."""
    speed_mm_s = 28.0
    trial = loop.Trial("slip_speed", False, speed_mm_s, 2, settle_s=1.0, task="least_force")
    out = loop.run_trial(trial, build_controllers)
    assert out.onset_s == pytest.approx(loop.START_S, abs=0.002)
    crossing_s = (loop.SKIN_END_MM - loop.START_MM) / speed_mm_s
    if out.dropped:
        assert out.end_s - out.onset_s >= crossing_s - 0.01
    if out.first_stop_s is not None:
        travelled_mm = out.first_stop_mm - loop.START_MM
        assert travelled_mm <= speed_mm_s * (out.first_stop_s - out.onset_s) + 0.1
    assert out.grip_mean_n >= least_force.GRIP_LEVELS_N[least_force.REST_LEVEL] - 0.01


def rows_for(speed_mm_s, mode, outcomes):
    """Result rows as run_trials gives them: (stopped, crushed, dropped) per trial."""
    return [
        {
            "mode": mode,
            "speed_mm_s": speed_mm_s,
            "seed": seed,
            "stopped": s,
            "crushed": c,
            "dropped": d,
            "slip_distance_mm": 30.0 if s else None,
            "time_to_stop_s": 2.0 if s else None,
            "grip_mean_n": 9.0,
            "i_emg": 0.3,
            "belt_latency_s": 1.0,
        }
        for seed, (s, c, d) in enumerate(outcomes, start=1)
    ]


def test_success_is_at_rest_unbroken_and_the_verdict_needs_two_standard_errors():
    rows = []
    for v in least_force.SPEEDS_MM_S:
        rows += rows_for(v, "slip_speed", [(True, False, False)] * 9 + [(True, True, False)])
        rows += rows_for(
            v, "slip_occurrence", [(False, False, True)] * 8 + [(True, False, False)] * 2
        )
    figures = loop_task.aggregate(rows)
    assert figures["speeds"]["slip_speed"]["20"]["success_pct"] == 90.0
    assert figures["speeds"]["slip_speed"]["20"]["crushed_pct"] == 10.0
    assert figures["compare"]["high"]["verdict"] == "beats"
    assert figures["compare"]["high"]["diff_pct"] == pytest.approx(70.0)
    close = rows_for(20.0, "slip_speed", [(True, False, False)] * 5 + [(False, False, True)] * 5)
    close += rows_for(
        20.0, "slip_occurrence", [(True, False, False)] * 4 + [(False, False, True)] * 6
    )
    assert loop_task.aggregate(close)["compare"]["20"]["verdict"] == "ties"


def test_the_report_renders_the_verdict_and_every_speed(tmp_path):
    rows = []
    for v in least_force.SPEEDS_MM_S:
        rows += rows_for(v, "slip_speed", [(True, False, False)])
        rows += rows_for(v, "slip_occurrence", [(False, True, False)])
    results = {
        "grid": {
            "modes": list(loop_task.TASK_MODES),
            "speeds_mm_s": list(least_force.SPEEDS_MM_S),
            "seeds": [1],
            "trials": len(rows),
        },
        "objects": loop_task.objects(),
        "figures": loop_task.aggregate(rows),
    }
    text = loop_task.render(results)
    assert "slip speed ties slip occurrence" in text  # one trial each: no power
    for v in least_force.SPEEDS_MM_S:
        assert f"| {v:g} |" in text
    loop_task.plot_report(results, tmp_path / "task.png")
    assert (tmp_path / "task.png").stat().st_size > 10_000


def test_a_report_rendered_from_its_json_lists_the_speeds_in_order():
    """JSON keys come back sorted as text ("12" before "4"); the tables stay in speed order."""
    rows = []
    for v in least_force.SPEEDS_MM_S:
        rows += rows_for(v, "slip_speed", [(True, False, False)])
        rows += rows_for(v, "slip_occurrence", [(False, False, True)])
    results = {
        "grid": {"modes": list(loop_task.TASK_MODES), "speeds_mm_s": [4.0, 12.0, 20.0, 28.0]},
        "objects": loop_task.objects(),
        "figures": loop_task.aggregate(rows),
        "trials": rows,
    }
    results["grid"] |= {"seeds": [1], "trials": len(rows)}
    text = loop_task.render(json.loads(loop.dump_json(results)))
    at = [text.index(f"| slip speed | {v:g} |") for v in least_force.SPEEDS_MM_S]
    assert at == sorted(at)
    assert "4 mm/s 0 %" in text  # no seed ended the same way in both modes


@pytest.mark.parametrize(
    ("options", "said"),
    [(["--workers", "0"], "workers"), (["--dask", "tcp://127.0.0.1:9"], "127.0.0.1:9")],
)
def test_the_task_from_the_cli_refuses_bad_workers_before_running_anything(
    tmp_path, capsys, options, said
):
    out = tmp_path / "x"
    argv = ["bench", "loop", "--task", "least-force", "--out", str(out), *options]
    assert cli_main(argv) == 1
    assert said in capsys.readouterr().err
    assert not out.exists()


@pytest.mark.parametrize("speed_mm_s", least_force.WET_SPEEDS_MM_S)
def test_a_wet_object_slides_again_at_the_level_that_held_it_dry_and_holds_one_above(
    speed_mm_s,
):
    task = least_force.TaskObject(speed_mm_s, wet=True)
    assert task.final_level == task.stopping_level + 1
    final_n = least_force.GRIP_LEVELS_N[task.final_level]
    assert final_n < task.crush_limit_n  # the grip that holds it wet does not break it
    for grip_n, expected_mm_s in (
        (least_force.GRIP_LEVELS_N[task.stopping_level], least_force.RESLIP_MM_S),
        (final_n, 0.0),
    ):
        speed_mm_s = damped_speed_mm_s(task, grip_n, task.friction_after)
        assert np.allclose(speed_mm_s, expected_mm_s)


def test_a_wet_trial_gets_wet_after_the_dry_hold_and_runs_until_the_wearer_answered():
    trial = loop.Trial("slip_speed", False, 12.0, 1, settle_s=8.0, task="least_force_wet")
    task = least_force.TaskObject(12.0, wet=True)
    damped = next(e for e in loop.scene_data(trial)["effects"] if e["type"] == "object.damped")
    at_s = task.wetting_s(loop.START_S)
    assert at_s == loop.START_S + least_force.REPEAT_S * (task.levels_missing + 1)
    assert damped["friction_scale"] == [
        [0.0, 1.0],
        [at_s, 1.0],
        [at_s + least_force.WETTING_S, task.friction_after],
    ]
    hand = next(e for e in loop.scene_data(trial)["effects"] if e["type"] == "hand.actuator")
    assert hand["crush_limit_n"] == task.crush_limit_n
    assert trial.duration_s == at_s + least_force.AFTER_WETTING_S + 8.0
    with pytest.raises(ValueError, match="strongest level"):
        loop.scene_data(loop.Trial("slip_speed", False, 28.0, 1, task="least_force_wet"))


def test_wet_trials_are_judged_apart_from_the_dry_ones_and_rendered():
    rows = []
    for v in least_force.SPEEDS_MM_S:
        rows += rows_for(v, "slip_speed", [(True, False, False)] * 10)
        rows += rows_for(v, "slip_occurrence", [(True, False, False)] * 10)
    wet = []
    for v in least_force.WET_SPEEDS_MM_S:
        wet += rows_for(v, "slip_speed", [(True, False, False)] * 10)
        wet += rows_for(v, "slip_occurrence", [(False, False, True)] * 10)
    for row in wet:
        row["task"] = "least_force_wet"
    figures = loop_task.aggregate(rows + wet)
    assert figures["compare"]["all"]["verdict"] == "ties"  # dry: the same in both modes
    assert figures["wet"]["compare"]["all"]["verdict"] == "beats"
    assert figures["wet"]["speeds"]["slip_occurrence"]["12"]["dropped_pct"] == 100.0
    assert {t.task for t in loop_task.grid(quick=True)} == {"least_force", "least_force_wet"}
    results = {
        "grid": {
            "modes": list(loop_task.TASK_MODES),
            "speeds_mm_s": list(least_force.SPEEDS_MM_S),
            "wet_speeds_mm_s": list(least_force.WET_SPEEDS_MM_S),
            "seeds": list(range(1, 11)),
            "trials": len(rows) + len(wet),
        },
        "objects": loop_task.objects(),
        "wet_objects": loop_task.objects(wet=True),
        "figures": figures,
        "trials": rows + wet,
    }
    text = loop_task.render(json.loads(loop.dump_json(results)))
    assert "## Friction that changes: the object gets wet" in text
    assert "**Over every wet object: slip speed beats slip occurrence**" in text
    at = [text.index(f"| {v:g} | 100 · 0 · 0 · 0 | 0 · 0 · 100 · 0 |") for v in (4, 12, 20)]
    assert at == sorted(at)

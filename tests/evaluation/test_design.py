"""`grasplink skin design`: encoding, objectives, reproducibility on any workers, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from grasplink.cli import main as cli_main
from grasplink.errors import ConfigError
from grasplink.evaluation import design
from grasplink.evaluation import design_slips as ds
from grasplink.evaluation.workers import open_workers
from grasplink.profiles.layouts import LAYOUTS_MM, parse_layout
from grasplink.simulators.synth import slip_recording

# A tiny search: 2 generations of 4 layouts on 2 slips at 2 speeds. A 60 mm skin leaves
# table 5.1's 84 mm layouts out of the confirmation, which keeps it short.
TINY = design.DesignSettings(
    length_mm=60.0,
    alpha=0.5,
    speeds_mm_s=(20.0, 60.0),
    generations=2,
    population=4,
    slips=2,
    seed=5,
)


def outcome(result: design.DesignResult) -> tuple:
    """Everything a search found, without the CPU seconds it took."""

    def figures(f: dict) -> dict:
        return {k: v for k, v in f.items() if k != "cpu_s"}

    population = [(x, figures(f)) for x, f in result.population]
    finalists = {x: figures(f) for x, f in result.finalists.items()}
    return result.chosen, population, finalists, result.generations


@pytest.fixture(scope="module")
def in_process() -> design.DesignResult:
    with open_workers(1) as workers:
        return design.search(TINY, workers, log=lambda _: None)


# -- encoding and objectives ---------------------------------------------------------------


def test_every_chromosome_is_a_layout_of_3_mm_spacings_or_more_summing_to_the_skin():
    rng = np.random.default_rng(0)
    counts = set()
    for x in rng.random((300, 13)):
        layout = design.spacings_of(x, 84.0)
        counts.add(len(layout))
        assert sum(layout) == pytest.approx(84.0)
        assert min(layout) >= 3.0 and max(layout) <= 81.0
        assert all(s == int(s) for s in layout)  # whole mm, as the thesis's integers
    assert counts == set(range(2, 13))
    assert design.spacings_of([0.0, 0.0, 1.0], 84.0) == (3.0, 81.0)  # the extremes reach
    short = design.spacings_of([1.0] + [0.5] * 12, 10.5, max_spacings=3)
    assert short == (4.0, 3.0, 3.5)  # the whole mm left to the first, the half to the last


def test_resolution_and_fitness_reproduce_table_5_1():
    max_r = {"alpha0.1": 0.7, "alpha0.3": 0.4, "alpha0.5": 0.3, "alpha0.7": 0.3, "fibonacci": 0.6}
    for name, r in max_r.items():
        assert design.resolution(LAYOUTS_MM[name]) == pytest.approx(r)
    # the α = 0.9 row: Max(A) 0.9737, Max(R) 0.3, Min(F) 0.0937
    assert design.fitness(0.9, 0.9737, 0.3) == pytest.approx(0.0937, abs=5e-5)


def test_speed_grids_are_read_as_start_stop_step_or_a_list():
    assert design.parse_speeds("10:100:5") == tuple(float(v) for v in range(10, 101, 5))
    assert design.parse_speeds("20, 40,60") == (20.0, 40.0, 60.0)


def test_a_plan_has_every_kind_both_ways_and_is_the_same_for_the_same_seed():
    plan = ds.plan_slips(8, (10.0, 50.0), seed=3)
    assert {(s.kind, s.reverse) for s in plan} == {(k, r) for k in ds.KINDS for r in (0, 1)}
    assert plan == ds.plan_slips(8, (10.0, 50.0), seed=3) != ds.plan_slips(8, (10.0, 50.0), 4)
    assert {s.speed_mm_s for s in plan} == {10.0, 50.0}


def test_a_clean_constant_slip_is_hit_after_three_contacts_on_a_unique_layout():
    slip = ds.SlipPlan("constant", 60.0, False, 0.0)
    score = ds.score_slip(LAYOUTS_MM["alpha0.1"], slip, "tracker", seed=5)
    assert score.updates > 0 and score.hits > 0.5
    assert score.speed_error < 0.1


# -- reproducibility -------------------------------------------------------------------------


def test_a_fixed_number_of_generations_gives_the_same_layouts_on_two_local_processes(in_process):
    with open_workers(2) as workers:
        assert workers.count == 2
        assert outcome(design.search(TINY, workers, log=lambda _: None)) == outcome(in_process)
    assert in_process.generations == 2 and sum(in_process.chosen) == pytest.approx(60.0)


def test_a_fixed_number_of_generations_gives_the_same_layouts_on_a_dask_cluster(in_process):
    from distributed import LocalCluster

    with (
        LocalCluster(
            processes=True,
            n_workers=2,
            threads_per_worker=1,
            host="127.0.0.1",
            dashboard_address=None,
        ) as cluster,
        open_workers(dask=cluster.scheduler_address) as workers,
    ):
        assert workers.count == 2
        result = design.search(TINY, workers, log=lambda _: None)
    assert outcome(result) == outcome(in_process)


# -- outputs ---------------------------------------------------------------------------------


def test_layout_toml_round_trips_through_parse_layout_and_grasplink_decode(
    in_process, tmp_path, capsys
):
    paths = design.write_outputs(in_process, tmp_path / "out")
    assert [p.name for p in paths] == ["front.csv", "layout.toml", "report.md", "search.json"]
    saved = json.loads(paths[3].read_text())
    assert saved["chosen_mm"] == list(in_process.chosen) and saved["generations"] == 2
    start, end = saved["load_avg"]  # what else the host ran while wall_s was measured
    assert start >= 0.0 and end >= 0.0
    toml = tmp_path / "out" / "layout.toml"
    assert parse_layout(str(toml)) == in_process.chosen
    front = (tmp_path / "out" / "front.csv").read_text().splitlines()
    assert front[0].startswith("spacings_mm,ridges,resolution,accuracy")
    assert len(front) == 1 + len(in_process.population)
    assert "Chosen layout" in (tmp_path / "out" / "report.md").read_text()
    rec = slip_recording(in_process.chosen, 40.0, seed=2)
    csv = tmp_path / "slip.csv"
    rows = "\n".join(f"{t:.6f},{f:.6f}" for t, f in zip(rec.t_s, rec.force_n, strict=True))
    csv.write_text("t_s,force_n\n" + rows + "\n")
    capsys.readouterr()
    assert cli_main(["decode", str(csv), "--skin", str(toml)]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert any(line["slip"] for line in lines)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("spacings_mm = [19, 12, 5]\nspacing = 3\n", "unknown key 'spacing'"),
        ("spacings_mm = []\n", "non-empty list"),
        ('spacings_mm = [19, "x"]\n', "#2 'x' is not a number"),
        ("spacings_mm = [19, 0.01]\n", "#2"),
        ("spacings_mm = [19, 12\n", "not valid TOML"),
    ],
)
def test_a_bad_layout_file_is_an_error_naming_the_file_and_the_problem(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message) as caught:
        parse_layout(str(path))
    assert str(path) in str(caught.value)
    with pytest.raises(ConfigError, match="not found"):
        parse_layout(str(tmp_path / "missing.toml"))


# -- bad input: one error before any work ----------------------------------------------------


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--length-mm", "5"], "at least three ridges"),
        (["--speeds", "100:10:5"], "speed grid is empty"),
        (["--speeds", ""], "speed grid is empty"),
        (["--decoder", "nope"], "unknown decoder"),
        (["--alpha", "1.5"], "weight in 0..1"),
        (["--workers", "0"], "at least 1 process"),
        (["--dask", "localhost:8786"], "tcp://HOST:PORT"),
        (["--generations", "0"], "at least 1"),
    ],
)
def test_bad_input_is_one_error_before_any_work(tmp_path, capsys, args, message):
    out = tmp_path / "design"
    assert cli_main(["skin", "design", *args, "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]
    assert not out.exists()


def test_a_scene_takes_a_layout_file_for_its_skin(in_process, tmp_path):
    from grasplink.simulators.scene import load_scene

    design.write_outputs(in_process, tmp_path / "out")
    scene = tmp_path / "slip.toml"
    layout = tmp_path / "out" / "layout.toml"
    scene.write_text(
        f'[scene]\nduration_s = 0.5\n\n[nodes.skin]\nlayout = "{layout}"\n'
        '\n[[effects]]\ntype = "object.scripted"\nspeed_mm_s = [[0.0, 60.0]]\nstart_mm = -5.0\n'
    )
    assert load_scene(scene).layout_mm == in_process.chosen

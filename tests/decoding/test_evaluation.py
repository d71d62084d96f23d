"""grasplink.evaluation: reference slips from the caller, scoring, the CAN path, where it writes.

The gateway's window matchers get their reference slips from the caller (the
gateway simulates nothing); the benchmark finds its output folder from the
current directory, never from where the package is installed; the CAN path
decodes what the skin node really sent.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from grasplink.cli import main
from grasplink.controllers import build_controllers
from grasplink.decoding import registry
from grasplink.decoding.base import Decoder, SlipEstimate
from grasplink.decoding.io import skin_tpdo
from grasplink.decoding.mmse import ReferenceSlip
from grasplink.errors import ConfigError
from grasplink.evaluation import decoding_bench as bench
from grasplink.evaluation import scoring
from grasplink.evaluation.decoders import make_decoder, reference_slips
from grasplink.evaluation.scenes import record_scene
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

ROOT = Path(__file__).resolve().parents[2]
SCENES = ROOT / "scenes"
SCENE = SCENES / "slip_alpha0.1_60mm_s_forward.toml"
WINDOW_MATCHERS = ("mmse", "dtw")


# -- reference slips come from the caller --------------------------------------------------
@pytest.mark.parametrize("name", WINDOW_MATCHERS)
def test_window_matcher_without_reference_slips_is_a_config_error(name):
    with pytest.raises(ConfigError, match=rf"decoder '{name}' needs reference slips"):
        registry.make_decoder(name, LAYOUTS_MM["alpha0.1"], 400)


@pytest.mark.parametrize("name", WINDOW_MATCHERS)
def test_reference_slips_may_come_as_any_iterable_of_reference_slips(name):
    layout = LAYOUTS_MM["alpha0.1"]
    slips = reference_slips(layout, 400)
    decoder = registry.make_decoder(name, layout, 400, references=(s for s in slips))
    assert [r.direction for r in decoder.searcher.references] == [1, -1]
    with pytest.raises(ConfigError, match="references must be ReferenceSlip, got tuple"):
        registry.make_decoder(name, layout, 400, references=[(20.0, [0.0, 1.0], [0.0, 1.0])])


def test_only_the_window_matchers_need_reference_slips():
    assert {n for n in registry.DECODERS if registry.needs_references(n)} == set(WINDOW_MATCHERS)


@pytest.mark.parametrize("name", WINDOW_MATCHERS)
def test_evaluation_supplies_reference_slips_the_matcher_decodes_with(name):
    rec = synth.slip_recording(LAYOUTS_MM["alpha0.1"], 40.0, seed=11)
    score = scoring.score(lambda: make_decoder(name, rec.layout_mm, rec.fs_hz), rec)
    assert score.scored > 0
    assert np.median(score.speed_rel_err) < 0.1
    assert score.wrong_sign == 0


def test_reference_slips_are_one_per_direction_at_the_reference_speed():
    forward, reverse = reference_slips(LAYOUTS_MM["fibonacci"], 400)
    assert (forward.speed_mm_s, reverse.speed_mm_s) == (20.0, -20.0)
    assert forward.direction == 1 and reverse.direction == -1
    length = sum(LAYOUTS_MM["fibonacci"])
    for slip in (forward, reverse):  # the whole skin is covered
        assert slip.position_mm.min() < 0 and slip.position_mm.max() > length


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"speed_mm_s": 0.0}, "speed must be non-zero"),
        ({"force_n": np.zeros(3)}, "of equal length"),
        ({"position_mm": np.full(4, 5.0)}, "does not move"),
        ({"force_n": np.array([0.0, np.nan, 1.0, 2.0])}, "finite"),
    ],
)
def test_a_malformed_reference_slip_is_refused(kwargs, message):
    good = {
        "speed_mm_s": 20.0,
        "position_mm": np.arange(4.0),
        "force_n": np.ones(4),
        "rest_force_n": 0.0,
    }
    with pytest.raises(ConfigError, match=message):
        ReferenceSlip(**(good | kwargs))


# -- scoring -------------------------------------------------------------------------------
class ConstantSpeed(Decoder):
    """Always reports slip at one speed: what the sign count must make of it."""

    name = "constant"

    def __init__(self, layout_mm, fs_hz, speed_mm_s: float):
        super().__init__(layout_mm, fs_hz)
        self.speed_mm_s = speed_mm_s

    def process(self, t, x):
        return [
            SlipEstimate.from_velocity(g, True, self.speed_mm_s, 0.0, 0.0, 1.0)
            for _, g in self.update_points(t)
        ]


class Undirected(ConstantSpeed):
    """Reports |speed| and no direction (a uniform skin, or before the direction is known)."""

    def process(self, t, x):
        return [
            SlipEstimate(g, True, abs(self.speed_mm_s), 0.0, 0.0, 1.0)
            for _, g in self.update_points(t)
        ]


@pytest.mark.parametrize(("speed", "wrong"), [(-40.0, True), (0.0, False), (40.0, False)])
def test_wrong_sign_counts_only_estimates_pointing_the_other_way(speed, wrong):
    rec = synth.slip_recording(LAYOUTS_MM["alpha0.1"], 40.0, seed=3)
    score = scoring.score(lambda: ConstantSpeed(rec.layout_mm, rec.fs_hz, speed), rec)
    estimated = len(score.speed_rel_err)
    assert estimated > 0
    assert score.wrong_sign == (estimated if wrong else 0)
    assert scoring.summarise([score])["wrong_sign_pct"] == (100.0 if wrong else 0.0)


@pytest.mark.parametrize("reverse", [False, True])
def test_a_speed_without_a_direction_is_scored_as_a_speed_and_never_a_wrong_sign(reverse):
    """Issue 22: speed and direction are separate outputs. |speed| without a direction
    counts for the speed error and against missing speed, as its magnitude; only a told
    direction can be the wrong one."""
    rec = synth.slip_recording(LAYOUTS_MM["alpha0.1"], 40.0, reverse=reverse, seed=3)
    score = scoring.score(lambda: Undirected(rec.layout_mm, rec.fs_hz, 40.0), rec)
    assert len(score.speed_rel_err) == score.scored > 0 and score.missing == 0
    assert np.median(score.speed_rel_err) < 0.05  # |40| against |-40|: right, not 200 %
    assert score.wrong_sign == 0
    told = scoring.score(lambda: ConstantSpeed(rec.layout_mm, rec.fs_hz, 40.0), rec)
    assert told.wrong_sign == (len(told.speed_rel_err) if reverse else 0)


class CoastBounded(ConstantSpeed):
    """The true |speed| until the edge lies `past_mm` past the last ridge ahead, then a stop."""

    def __init__(self, rec: synth.SkinRecording, past_mm: float):
        super().__init__(rec.layout_mm, rec.fs_hz, 40.0)
        self.rec, self.past_mm = rec, past_mm

    def process(self, t, x):
        out = []
        length = float(sum(self.rec.layout_mm))
        for _, g in self.update_points(t):
            edge = float(np.interp(g, self.rec.t_s, self.rec.position_mm))
            beyond = edge - length if self.rec.position_mm[-1] > 0 else -edge
            speed = self.speed_mm_s if beyond <= self.past_mm else 0.0
            out.append(SlipEstimate(g, speed > 0, speed, 0.0, 0.0, 1.0))
        return out


@pytest.mark.parametrize("reverse", [False, True])
def test_no_speed_is_owed_past_one_spacing_beyond_the_last_ridge(reverse):
    """Past the last ridge no contact can come: a speed is scored until the edge lies one
    spacing (the one into the last ridge) past it (`decoding.coast_bound`), not after."""
    layout = LAYOUTS_MM["alpha0.1"]
    rec = synth.slip_recording(layout, 40.0, reverse=reverse, seed=3)
    gap = layout[0] if reverse else layout[-1]
    bounded = scoring.score(lambda: CoastBounded(rec, gap), rec)
    assert bounded.scored > 0 and bounded.missing == 0
    assert float(np.max(bounded.speed_rel_err)) < 1e-9  # the stops lie outside the window
    early = scoring.score(lambda: CoastBounded(rec, 0.5 * gap), rec)
    assert float(np.max(early.speed_rel_err)) == 1.0  # stopped inside it: scored
    length = float(sum(layout))
    x = np.array([-layout[0] - 0.1, -layout[0] + 0.1, length + layout[-1] + 0.1, length])
    v = np.array([-40.0, -40.0, 40.0, 40.0])
    assert scoring.observed(rec.layout_mm, x, v).tolist() == [False, True, False, True]


# -- where the benchmark writes ------------------------------------------------------------
def write_pyproject(folder: Path, name: str) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "pyproject.toml").write_text(f'[project]\nname = "{name}"\n')
    return folder


def test_output_goes_to_the_checkout_found_upwards_from_the_current_folder(tmp_path):
    root = write_pyproject(tmp_path / "clone", "grasplink")
    nested = write_pyproject(root / "sub" / "other", "someone-else")
    (nested / "deeper").mkdir()
    assert bench.default_out_dir(nested / "deeper") == root / "docs" / "benchmarks"
    assert bench.default_scenes_dir(nested) == root / "scenes"


def test_outside_a_checkout_scenes_come_from_the_editable_install(tmp_path):
    root = bench.editable_checkout()
    if root is None:
        pytest.skip("grasplink is not installed in editable mode here")
    assert bench.find_checkout(root) == root
    assert bench.default_scenes_dir(tmp_path) == root / "scenes"


def test_outside_a_checkout_the_benchmark_asks_for_out(tmp_path):
    write_pyproject(tmp_path, "not-grasplink")
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "pyproject.toml").write_text("[project\n")
    with pytest.raises(ConfigError, match="give --out DIR"):
        bench.default_out_dir(tmp_path / "broken")


def test_bench_decode_outside_a_checkout_prints_one_line_and_exits_1(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["bench", "decode", "--quick"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("grasplink: error: ") and err.count("\n") == 1
    assert "--out" in err and "Traceback" not in err
    assert not any(tmp_path.iterdir())


def test_bench_decode_without_slip_scenes_names_the_folder(tmp_path, capsys):
    empty = tmp_path / "scenes"
    empty.mkdir()
    out = tmp_path / "out"
    rc = main(["bench", "decode", "--quick", "--out", str(out), "--scenes", str(empty)])
    assert rc == 1
    err = capsys.readouterr().err
    assert f"{empty}: no slip scenes" in err and err.count("\n") == 1
    assert not out.exists()


# -- the CAN path --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def recorded(tmp_path_factory):
    out = tmp_path_factory.mktemp("run")
    return out, record_scene(SCENE, build_controllers, out)


def test_can_path_signal_is_the_skin_nodes_adc_reading_of_skin_csv(recorded):
    _, signals = recorded
    can, csv = signals.can, signals.csv
    pdo = skin_tpdo()
    step_n = pdo.calibration.n_per_count
    at = np.searchsorted(csv.t_s, can.t_s - 1e-6)
    np.testing.assert_allclose(csv.t_s[at], can.t_s, atol=1e-6)  # the node's own timing
    np.testing.assert_allclose(can.force_n / step_n, np.round(can.force_n / step_n), atol=1e-6)
    sampled = csv.force_n[at]
    positive = sampled >= 0
    assert np.all(np.abs(can.force_n[positive] - sampled[positive]) <= step_n / 2 + 1e-9)
    assert np.all(can.force_n[~positive] == 0.0)  # the ADC does not read below zero
    assert signals.can_stats.packets * pdo.samples_per_pdo == len(can.t_s)


def test_can_path_truth_is_the_scenes(recorded):
    _, signals = recorded
    for rec in (signals.can, signals.csv):
        slipping = rec.slipping > 0.5
        np.testing.assert_allclose(rec.speed_mm_s[slipping], 60.0)
        assert not slipping[0] and slipping[-1]
        assert len(rec.contact_times_s) == len(LAYOUTS_MM["alpha0.1"]) + 1  # every ridge


@pytest.mark.parametrize("name", list(registry.DECODERS))
def test_grasplink_decode_reads_a_recorded_run_with_every_decoder(recorded, capsys, name):
    out, _ = recorded
    rc = main(["decode", str(out / "can.asc"), "--skin", "alpha0.1", "--decoder", name])
    captured = capsys.readouterr()
    assert rc == 0, captured.err
    lines = [json.loads(line) for line in captured.out.splitlines()]
    assert lines and any(d["slip"] for d in lines)


def test_can_path_decodes_every_scene_in_workers_and_skips_scenes_without_skin():
    paths = [SCENE, SCENES / "slip_task_ch2.toml"]
    logged: list[str] = []
    result = bench.can_path(paths, build_controllers, log=logged.append)
    assert result["scenes"] == [SCENE.stem]
    assert result["skipped"] == {"slip_task_ch2": "no skin node"}
    assert set(result["groups"]["all"]) == set(bench.default_settings())
    for name in bench.default_settings():
        for kind in bench.PATHS:
            figures = result["per_scene"][SCENE.stem][name][kind]
            assert set(figures) >= {"speed_p90_pct", "wrong_sign_pct", "missing_pct"}
    assert result["can_stats"]["packets"] > 0 and logged
    text = "\n".join(bench.render_can_path(result))
    assert "## CAN path" in text and "slip_task_ch2 (no skin node)" in text


def test_slip_scenes_are_every_shipped_slip_scene():
    found = {p.name for p in bench.slip_scenes(SCENES)}
    assert found == {p.name for p in SCENES.glob("slip_*.toml")} | {"headline_slip.toml"}

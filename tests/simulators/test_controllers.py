"""The controller seam and node bindings: scenes name their controller, the caller builds it."""

from __future__ import annotations

import io
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from grasplink import cli
from grasplink.controllers import CONTROLLERS, build_controllers, simulation
from grasplink.core.nmt import NmtState
from grasplink.errors import ConfigError
from grasplink.gateway.scripted import ScriptedMaster
from grasplink.profiles.kinds import KINDS
from grasplink.simulators.bindings import BINDINGS
from grasplink.simulators.engine import Simulation
from grasplink.simulators.recording import Recorder
from grasplink.simulators.scene import load_scene, parse_scene
from grasplink.terminal import ProgressBar

ROOT = Path(__file__).resolve().parents[2]

BELT_SCENE = """
[scene]
duration_s = 0.5
[nodes.belt]
[controller]
{controller}
"""


def scene_of(controller: str):
    import tomllib

    return parse_scene(tomllib.loads(BELT_SCENE.format(controller=controller)), "test.toml")


def test_every_device_kind_has_a_binding():
    assert tuple(BINDINGS) == KINDS


def test_default_controller_is_the_scripted_master_that_starts_the_nodes():
    scene = scene_of("")
    (master,) = build_controllers(scene)
    assert isinstance(master, ScriptedMaster)
    sim = simulation(scene)
    sim.run()
    assert sim.nodes["belt"].state == NmtState.OPERATIONAL


def test_no_controller_leaves_the_nodes_pre_operational():
    scene = scene_of('type = "none"')
    assert build_controllers(scene) == []
    summary = simulation(scene).run()
    assert summary["nodes"]["belt"]["state"] == "PRE_OPERATIONAL"
    assert summary["controller"] is None


def test_engine_runs_the_participants_its_caller_gives_it():
    scene = scene_of('type = "none"')
    master = ScriptedMaster(belt_id=0x20, belt_mrad_s=[(0.0, 3000.0)])
    sim = Simulation(scene, controllers=[master])
    sim.run()
    assert sim.nodes["belt"].state == NmtState.OPERATIONAL
    assert sim.nodes["belt"].app.velocity_mrad_s > 0


def test_unknown_controller_is_a_scene_error_naming_the_key():
    with pytest.raises(ConfigError, match=r"controller\.type: unknown controller 'gatway'"):
        build_controllers(scene_of('type = "gatway"'))


def test_misspelt_controller_option_is_an_error():
    with pytest.raises(ConfigError, match=r"controller.*belt_mrads"):
        build_controllers(scene_of("belt_mrads = [[0, 1000]]"))


@pytest.mark.parametrize(
    "option",
    ["belt_mrad_s = [[0.1, 1e300]]", "belt_mrad_s = [[0.1, -1e30]]", "hand_grip_n = [[0.1, 1e30]]"],
)
def test_command_profile_beyond_what_the_rpdo_carries_is_refused_before_running(tmp_path, option):
    text = BELT_SCENE.format(controller=option) + "[nodes.hand]\n"
    path = tmp_path / "huge.toml"
    path.write_text(text)
    out = tmp_path / "out"
    err = io.StringIO()
    sys_stderr, sys.stderr = sys.stderr, err
    try:
        code = cli.main(["run", str(path), "--out", str(out)])
    finally:
        sys.stderr = sys_stderr
    assert code == 1
    assert "controller." in err.getvalue() and "expected" in err.getvalue()
    assert not out.exists(), "nothing is written for a scene that cannot run"


def test_registry_names_a_module_and_class_for_every_controller():
    for target in CONTROLLERS.values():
        module, _, cls = target.partition(":")
        assert module.startswith("grasplink.") and cls


def test_run_asked_to_stop_leaves_a_complete_partial_recording(tmp_path):
    scene = load_scene(ROOT / "scenes" / "headline_slip.toml")
    chunks = []
    sim = simulation(scene, Recorder(tmp_path))
    summary = sim.run(should_stop=lambda: len(chunks) >= 20, progress=lambda t, d: chunks.append(t))
    assert summary["complete"] is False
    assert summary["simulated_s"] == pytest.approx(chunks[-1] / 1e6)
    written = json.loads((tmp_path / "summary.json").read_text())
    assert written["complete"] is False
    last_row = (tmp_path / "truth.csv").read_text().splitlines()[-1]
    assert float(last_row.split(",")[0]) == pytest.approx(chunks[-1] / 1e6)


def test_progress_bar_draws_only_on_a_terminal():
    quiet = io.StringIO()
    ProgressBar("x", quiet)(5, 10)
    assert quiet.getvalue() == ""
    shown = io.StringIO()
    bar = ProgressBar("scene", shown, force=True)
    bar(10_000_000, 10_000_000)
    bar.close()
    assert "100 %" in shown.getvalue() and shown.getvalue().endswith("\n")


@pytest.mark.slow
def test_sigterm_stops_a_run_with_a_marked_partial_recording(tmp_path):
    text = (ROOT / "scenes" / "slip_alpha0.1_20mm_s_forward.toml").read_text()
    long_scene = tmp_path / "long.toml"
    long_scene.write_text(text.replace("duration_s = ", "duration_s = 3600 #", 1))
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "grasplink.cli", "run", str(long_scene), "--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 30
    while not (out / "can.asc").exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(1.0)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143
    assert "partial recording" in stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is False and 0 < summary["simulated_s"] < 3600

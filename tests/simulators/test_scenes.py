"""Scenes end to end: determinism, isolation, thesis physics, hard cases, every shipped scene."""

from __future__ import annotations

import csv
import filecmp
import json
import struct
import tomllib
from pathlib import Path

import can
import numpy as np
import pytest

from grasplink.cli import main as cli_main
from grasplink.controllers import simulation
from grasplink.core.params import SceneError
from grasplink.devices.emg import EmgApp
from grasplink.gateway.master import CONSUMER_ALLOWANCE_MS
from grasplink.simulators.effects.emg import SurfaceEmg
from grasplink.simulators.recording import Recorder
from grasplink.simulators.scene import load_scene, parse_scene

ROOT = Path(__file__).resolve().parents[2]
SCENES = sorted((ROOT / "scenes").glob("*.toml"))


def scene_text(tmp_path: Path, text: str, name: str = "scene.toml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def record(path: Path, out: Path) -> dict:
    return simulation(load_scene(path), Recorder(out)).run()


def read_columns(path: Path) -> dict[str, np.ndarray]:
    with path.open() as handle:
        rows = list(csv.reader(handle))
    data = np.array(rows[1:], dtype=np.float64)
    return {name: data[:, i] for i, name in enumerate(rows[0])}


SLIP = """
[scene]
seed = {seed}
duration_s = 1.5

[nodes.skin]
layout = "alpha0.1"

[[effects]]
type = "grip.scripted"
grip_n = [[0.0, 5.0]]

[[effects]]
type = "load.scripted"
mass_kg = 0.2

[[effects]]
type = "object.scripted"
speed_mm_s = [[0.0, 60.0]]
start_mm = -5.0

[[effects]]
type = "skin.fsr"

[[effects]]
type = "skin.ridge_contacts"
{extra}
"""

NOISE = """
[[effects]]
type = "noise.white"
std = 0.05
"""


# -- determinism ---------------------------------------------------------------------------
def test_same_scene_and_seed_give_a_byte_identical_recording(tmp_path):
    path = scene_text(tmp_path, SLIP.format(seed=11, extra=NOISE))
    record(path, tmp_path / "a")
    record(path, tmp_path / "b")
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    assert names == ["can.asc", "skin.csv", "summary.json", "truth.csv"]
    _, mismatch, errors = filecmp.cmpfiles(tmp_path / "a", tmp_path / "b", names, shallow=False)
    assert mismatch == [] and errors == []


def test_one_parsed_scene_run_twice_gives_the_same_recording(tmp_path):
    """A scene's effects carry their run's state (grip, object, generators): the second
    run of the same parsed Scene must start from the scene, not from where the first ended."""
    data = tomllib.loads((ROOT / "scenes" / "loop_headline.toml").read_text())
    data["scene"]["duration_s"] = 1.5
    scene = parse_scene(data, "loop_headline.toml")
    for out in ("a", "b"):
        simulation(scene, Recorder(tmp_path / out)).run()
    names = sorted(p.name for p in (tmp_path / "a").iterdir())
    _, mismatch, errors = filecmp.cmpfiles(tmp_path / "a", tmp_path / "b", names, shallow=False)
    assert mismatch == [] and errors == []


def test_another_seed_changes_only_what_is_random(tmp_path):
    record(scene_text(tmp_path, SLIP.format(seed=1, extra=NOISE), "s1.toml"), tmp_path / "a")
    record(scene_text(tmp_path, SLIP.format(seed=2, extra=NOISE), "s2.toml"), tmp_path / "b")
    truth_a = (tmp_path / "a" / "truth.csv").read_text()
    assert truth_a == (tmp_path / "b" / "truth.csv").read_text()  # scripted physics
    assert (tmp_path / "a" / "skin.csv").read_text() != (tmp_path / "b" / "skin.csv").read_text()


def test_can_log_reads_back_with_python_can(tmp_path):
    record(scene_text(tmp_path, SLIP.format(seed=3, extra="")), tmp_path / "r")
    messages = list(can.LogReader(str(tmp_path / "r" / "can.asc")))
    skin_packets = [m for m in messages if m.arbitration_id == 0x190]
    assert len(skin_packets) > 100
    summary = json.loads((tmp_path / "r" / "summary.json").read_text())
    assert summary["frames"]["0x190"] == len(skin_packets)


# -- isolation: simulate only what the scene asks for ------------------------------------
def test_a_scene_without_noise_is_noiseless(tmp_path):
    """Without noise effects the signal is a pure function of the scene: seeds don't matter
    once the random ridge parameters are pinned."""
    extra = "alpha_n = [1.0, 1.0]\nrise_jitter = [1.0, 1.0]\n"
    body = SLIP.replace(
        'type = "skin.ridge_contacts"\n{extra}', 'type = "skin.ridge_contacts"\n' + extra
    )
    record(scene_text(tmp_path, body.format(seed=1), "a.toml"), tmp_path / "a")
    record(scene_text(tmp_path, body.format(seed=99), "b.toml"), tmp_path / "b")
    a = read_columns(tmp_path / "a" / "skin.csv")["skin.force_n"]
    b = read_columns(tmp_path / "b" / "skin.csv")["skin.force_n"]
    assert np.array_equal(a, b)
    # Before the first ridge contact the FSR reads the ch. 4.3 model exactly: (1 - k mu) W
    # + k P over the covered share of the sensor while slipping (no ripple from anywhere).
    skin = read_columns(tmp_path / "a" / "skin.csv")
    t = skin["t_s"]
    before = t < 5.0 / 60.0  # the leading edge reaches the first ridge (x=0) at 5 mm / 60 mm/s
    edge_mm = -5.0 + 60.0 * t[before]
    k = np.cos(np.pi / 3) / (np.sin(np.pi / 3) + 0.7813 * np.cos(np.pi / 3))
    share = np.clip(edge_mm, 0, None) / 90.0
    expected = (1 - k * 0.7813) * 5.0 * share + k * 0.2 * 9.81 * share
    assert np.allclose(a[before], expected, atol=1e-9)


def test_a_scene_without_emg_creates_no_emg_node_and_runs_no_emg_code(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(EmgApp, "advance", lambda *a: calls.append("node") or [])
    monkeypatch.setattr(SurfaceEmg, "step", lambda *a: calls.append("effect"))
    sim = simulation(load_scene(scene_text(tmp_path, SLIP.format(seed=1, extra=""))))
    sim.run()
    assert "emg" not in sim.nodes
    assert "emg" not in sim.domains and "emg" not in sim.samples
    assert calls == []


def test_a_minimal_scene_does_measurably_less_work_than_a_full_one():
    boot = simulation(load_scene(ROOT / "scenes" / "boot.toml"))
    boot.run()
    full = simulation(load_scene(ROOT / "scenes" / "headline_slip.toml"))
    full.run()
    assert boot.effect_steps == 0 and sum(boot.samples.values()) <= boot.samples.get("physics", 0)
    assert full.effect_steps > 0 and full.samples["skin"] > 0
    assert set(boot.cost_s) == set()  # nothing measured unless asked


def test_measuring_accounts_each_requested_effect_and_the_network():
    sim = simulation(load_scene(ROOT / "scenes" / "headline_slip.toml"), measure=True)
    sim.run()
    assert set(sim.cost_s) == {e.kind for e in sim.scene.effects} | {"network (nodes + bus)"}
    assert all(v >= 0 for v in sim.cost_s.values())


# -- physics against the thesis, through whole scenes --------------------------------------
def test_belt_levels_scene_shows_the_chapter_8_surface_speeds(tmp_path):
    record(ROOT / "scenes" / "belt_levels_ch8.toml", tmp_path / "belt")
    truth = read_columns(tmp_path / "belt" / "truth.csv")
    t, surface = truth["t_s"], truth["belt.surface_mm_s"]
    for level_start_s, expected_mm_s in ((4.8, 55), (5.8, 100), (6.8, 145), (7.8, 190)):
        settled = surface[(t > level_start_s + 0.7) & (t < level_start_s + 0.95)]
        assert np.median(settled) == pytest.approx(expected_mm_s, rel=0.02)


def test_belt_node_reports_the_simulated_motor(tmp_path):
    sim = simulation(load_scene(ROOT / "scenes" / "belt_levels_ch8.toml"), Recorder(tmp_path))
    sim.run()
    frames = [
        m
        for m in can.LogReader(str(tmp_path / "can.asc"))
        if m.arbitration_id == 0x2A0 and len(m.data) == 7
    ]
    surface = [struct.unpack_from("<IHB", m.data)[1] for m in frames if m.timestamp > 8.6]
    assert surface and abs(surface[-1] - 189) <= 2


def test_slip_task_scene_follows_the_chapter_2_speed_update(tmp_path):
    record(ROOT / "scenes" / "slip_task_ch2.toml", tmp_path / "task")
    truth = read_columns(tmp_path / "task" / "truth.csv")
    speed_at = {
        round(t, 3): v for t, v in zip(truth["t_s"], truth["object.speed_mm_s"], strict=True)
    }
    assert speed_at[0.5] == pytest.approx(6.0)
    assert speed_at[1.5] == pytest.approx(4.6)  # e1: one step of 1.4 mm/s
    assert speed_at[2.5] == pytest.approx(1.8)  # e2 at 4.6 -> v1
    assert speed_at[3.5] == pytest.approx(0.0)  # e1 at 1.8: the matching level stops it


def test_slip_from_friction_starts_when_load_exceeds_mu_times_grip(tmp_path):
    record(ROOT / "scenes" / "slip_friction.toml", tmp_path / "f")
    truth = read_columns(tmp_path / "f" / "truth.csv")
    t, speed, grip = truth["t_s"], truth["object.speed_mm_s"], truth["hand.grip_n"]
    load_n = 0.5 * 9.81
    limit = 2 * 0.7813 * grip
    assert np.all(speed[(t > 0.8) & (t < 1.5)] == 0)  # 4 N grip holds the 4.9 N load
    sliding = speed != 0
    assert sliding.any()
    first = np.argmax(sliding)
    assert limit[first] < load_n + 1e-9
    assert np.all(speed[t > 3.0] == 0)  # re-gripped at 6 N


def test_uniform_skin_contact_rate_is_v_over_d(tmp_path):
    body = SLIP.format(seed=5, extra="").replace('layout = "alpha0.1"', 'layout = "uniform4"')
    body = body.replace("duration_s = 1.5", "duration_s = 1.4")
    record(scene_text(tmp_path, body), tmp_path / "u")
    skin = read_columns(tmp_path / "u" / "skin.csv")
    t, force = skin["t_s"], skin["skin.force_n"]
    window = (t > 0.1) & (t < 1.3)  # leading edge on the ridged part
    x = force[window] - force[window].mean()
    spectrum = np.abs(np.fft.rfft(x * np.hanning(len(x)), n=8 * len(x)))
    freqs = np.fft.rfftfreq(8 * len(x), d=1 / 400)
    peak = freqs[np.argmax(spectrum * (freqs > 2))]
    assert peak == pytest.approx(60.0 / 4.0, rel=0.05)


# -- hard cases -------------------------------------------------------------------------------
def test_zero_speed_scene_has_no_contacts_and_no_nan(tmp_path):
    body = SLIP.format(seed=1, extra="").replace("[[0.0, 60.0]]", "[[0.0, 0.0]]")
    record(scene_text(tmp_path, body), tmp_path / "z")
    skin = read_columns(tmp_path / "z" / "skin.csv")["skin.force_n"]
    assert np.all(np.isfinite(skin)) and np.ptp(skin) == 0


def test_very_fast_slip_merges_pulses_without_breaking(tmp_path):
    body = SLIP.format(seed=1, extra="").replace("[[0.0, 60.0]]", "[[0.0, 2000.0]]")
    record(scene_text(tmp_path, body), tmp_path / "fast")
    skin = read_columns(tmp_path / "fast" / "skin.csv")["skin.force_n"]
    assert np.all(np.isfinite(skin)) and skin.max() < 50


def test_scene_ending_mid_pulse_records_up_to_its_end(tmp_path):
    body = SLIP.format(seed=1, extra="").replace("duration_s = 1.5", "duration_s = 0.0837")
    summary = record(scene_text(tmp_path, body), tmp_path / "cut")
    truth = read_columns(tmp_path / "cut" / "truth.csv")
    assert truth["t_s"][-1] == pytest.approx(0.0837, abs=1e-3)
    assert summary["duration_s"] == 0.0837


def test_hours_of_simulated_time_keep_the_clock_exact():
    scene = parse_scene(
        {
            "scene": {"duration_s": 2 * 3600.0, "chunk_ms": 1000.0, "layout": "alpha0.1"},
            "effects": [{"type": "object.scripted", "speed_mm_s": [[0.0, 0.5]]}],
        },
        "long.toml",
    )
    sim = simulation(scene)
    sim.run()
    physics = sim.domains["physics"]
    assert physics.times_us[-1] == 2 * 3600 * 1_000_000
    assert physics.values["object.position_mm"][-1] == pytest.approx(3600.0, abs=1e-9)


def test_saturated_sensor_clips_at_full_scale(tmp_path):
    body = SLIP.format(seed=1, extra='[[effects]]\ntype = "skin.saturation"\nfull_scale_n = 3.0\n')
    body = body.replace("[[0.0, 5.0]]", "[[0.0, 50.0]]")
    record(scene_text(tmp_path, body), tmp_path / "sat")
    skin = read_columns(tmp_path / "sat" / "skin.csv")["skin.force_n"]
    assert skin.max() == 3.0


# -- bad scenes: the error names file, key and what was expected ---------------------------
@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("[scene]\nduration_s = -1\n", "scene.duration_s: expected a number > 0"),
        ('[scene]\nduration_s = 1\nlayout = "4,0,5"\n', "layout"),
        ("[scene]\nduration_s = 1\n[nodes.elbow]\n", "nodes.elbow: unknown node kind"),
        ("[scene]\nduration_s = 1\ndurtion = 2\n", "scene.durtion: unknown key"),
        ('[scene]\nduration_s = 1\n[[effects]]\ntype = "skin.fsr"\n', "needs a skin layout"),
        (
            '[scene]\nduration_s = 1\nlayout = "alpha0.1"\n[[effects]]\ntype = "skin.fsr"\n',
            "needs hand.grip_n, which nothing in this scene provides; add",
        ),
        (
            '[scene]\nduration_s = 1\n[[effects]]\ntype = "warp.drive"\n',
            "unknown effect 'warp.drive'",
        ),
        ("[scene]\nduration_s = 1\n[nodes.skin]\nnode_id = 1\n", "already used by gateway"),
        ("[scene\nduration_s = 1\n", "not valid TOML"),
    ],
)
def test_bad_scene_errors_name_the_file_key_and_expectation(tmp_path, text, needle):
    path = scene_text(tmp_path, text, "bad.toml")
    with pytest.raises(SceneError) as info:
        load_scene(path)
    assert str(path) in str(info.value) and needle in str(info.value)


def test_zero_length_spacing_is_rejected(tmp_path):
    path = scene_text(tmp_path, '[scene]\nduration_s = 1\n[nodes.skin]\nlayout = "19,0,5"\n')
    with pytest.raises(SceneError, match="spacing"):
        load_scene(path)


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        (b"\x89PNG\r\n\x1a\n\x00\xff binary", "byte 0x89 on line 1 is not UTF-8"),
        (b'[scene]\nduration_s = 1\nname = "caf\xe9"\n', "byte 0xE9 on line 3 is not UTF-8"),
    ],
)
def test_binary_scene_file_is_one_line_scene_error(tmp_path, capsys, data, needle):
    path = tmp_path / "binary.toml"
    path.write_bytes(data)
    with pytest.raises(SceneError, match=needle):
        load_scene(path)
    assert cli_main(["run", str(path), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err == f"grasplink: error: {path}: not a TOML text file: {needle}\n"
    assert not (tmp_path / "out").exists()


# -- safe states under power loss ------------------------------------------------------------
POWER_LOSS = """
[scene]
seed = 1
duration_s = 4.0

[nodes.skin]
[nodes.belt]

[controller]
type = "scripted"
belt_mrad_s = [[0.2, 5000]]

[[effects]]
type = "belt.motor"

[[effects]]
type = "bus.faults"
power_loss = [{{ node = "{node}", at_s = 1.0, restore_s = {restore_s} }}]
"""


def can_frames(out: Path, can_id: int) -> list[tuple[float, bytes]]:
    return [
        (m.timestamp, bytes(m.data))
        for m in can.ASCReader(str(out / "can.asc"))
        if m.arbitration_id == can_id and not m.is_error_frame
    ]


def test_belt_watching_a_powered_off_skin_turns_again_only_after_the_skin_returns(tmp_path):
    sim = simulation(
        load_scene(scene_text(tmp_path, POWER_LOSS.format(node="skin", restore_s=2.5))),
        Recorder(tmp_path),
    )
    skin_id = sim.nodes["skin"].node_id
    sim.nodes["belt"].store.nvm[(0x1016, 2)] = (skin_id << 16) | 300  # consumer of the skin
    sim.run()
    truth = read_columns(tmp_path / "truth.csv")
    t_s, velocity = truth["t_s"], truth["belt.velocity_mrad_s"]
    assert velocity[(t_s > 0.9) & (t_s < 1.0)].min() > 4900
    # Quick stop once the skin's heartbeat is 300 ms overdue; no motion until it is back.
    turning_again_s = t_s[(t_s > 1.5) & (velocity > 50)][0]
    assert turning_again_s > 2.5
    assert turning_again_s < 2.5 + 0.25  # error reset -> NMT start -> enable sequence
    assert velocity[t_s > 3.5].min() > 4900
    states = [(t, data[0]) for t, data in can_frames(tmp_path, 0x700 + sim.nodes["belt"].node_id)]
    assert all(state == 0x7F for t, state in states if 1.35 < t < 2.5)


def test_belt_turns_again_after_a_skin_outage_shorter_than_its_quick_stop(tmp_path):
    # The skin is back at 1.35 s while the belt motor is still spinning down (quick stop
    # active): the master must take the drive out of quick stop, not send enables it ignores.
    sim = simulation(
        load_scene(scene_text(tmp_path, POWER_LOSS.format(node="skin", restore_s=1.35))),
        Recorder(tmp_path),
    )
    sim.nodes["belt"].store.nvm[(0x1016, 2)] = (sim.nodes["skin"].node_id << 16) | 300
    sim.run()
    truth = read_columns(tmp_path / "truth.csv")
    t_s, velocity = truth["t_s"], truth["belt.velocity_mrad_s"]
    assert velocity[(t_s > 1.3) & (t_s < 1.6)].min() < 50  # it did stop
    assert velocity[t_s > 2.5].min() > 4900


def test_powered_off_belt_gets_no_rpdos_until_it_boots_again(tmp_path):
    sim = simulation(
        load_scene(scene_text(tmp_path, POWER_LOSS.format(node="belt", restore_s=2.5))),
        Recorder(tmp_path),
    )
    belt_id = sim.nodes["belt"].node_id
    sim.run()
    beats = [t for t, _ in can_frames(tmp_path, 0x700 + belt_id)]
    # three 100 ms heartbeat periods and the scheduling allowance
    lost_s = max(t for t in beats if t <= 1.0) + 0.3 + CONSUMER_ALLOWANCE_MS / 1000
    rpdos = [t for t, _ in can_frames(tmp_path, 0x200 + belt_id)]
    assert not [t for t in rpdos if lost_s < t < 2.5]
    assert [t for t in rpdos if t > 2.5]


# -- every shipped scene runs and plots -------------------------------------------------------
@pytest.mark.parametrize("scene", SCENES, ids=[s.stem for s in SCENES])
def test_every_shipped_scene_runs_and_plots(tmp_path, scene, capsys):
    out = tmp_path / scene.stem
    assert cli_main(["run", str(scene), "--out", str(out)]) == 0
    assert cli_main(["plot", str(out)]) == 0
    pngs = list(out.glob("*.png"))
    assert pngs, f"no plot for {scene.name}"
    summary = json.loads((out / "summary.json").read_text())
    assert all(node["state"] == "OPERATIONAL" for node in summary["nodes"].values())


@pytest.mark.slow
def test_realtime_clock_paces_the_same_scene_to_the_wall_clock(tmp_path):
    """Same code, same result: only the pacing differs."""
    import time

    path = scene_text(
        tmp_path, SLIP.format(seed=4, extra="").replace("duration_s = 1.5", "duration_s = 0.6")
    )
    virtual = simulation(load_scene(path), Recorder(tmp_path / "v"))
    virtual.run()
    t0 = time.monotonic()
    paced = simulation(load_scene(path), Recorder(tmp_path / "r"))
    paced.run(realtime=True)
    assert time.monotonic() - t0 >= 0.6
    assert (tmp_path / "v" / "skin.csv").read_text() == (tmp_path / "r" / "skin.csv").read_text()

"""The closed-loop benchmark: outcome metrics, trials in virtual time, the report and its CLI."""

from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from grasplink.cli import main as cli_main
from grasplink.controllers import build_controllers
from grasplink.errors import ConfigError
from grasplink.evaluation import loop
from grasplink.gateway.emg import EmgCalibration
from grasplink.simulators import signals as sig
from grasplink.simulators.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
SCENES = ROOT / "scenes"
CAL = EmgCalibration(50.0, 500.0)
RATE_HZ = 1000


def physics(
    speed_mm_s: np.ndarray, *, start_mm: float = -8.0, crushed_at_s: float | None = None
) -> dict[str, np.ndarray]:
    """A hand-made trial's truth at 1 kHz from its speed profile (one value per sample)."""
    t = np.arange(len(speed_mm_s)) / RATE_HZ
    position = start_mm + np.cumsum(speed_mm_s) / RATE_HZ
    crushed = np.zeros(len(t)) if crushed_at_s is None else (t >= crushed_at_s).astype(float)
    return {
        "t_s": t,
        sig.OBJECT_POSITION_MM: position,
        sig.OBJECT_SLIPPING: (speed_mm_s != 0).astype(float),
        sig.HAND_GRIP_N: np.full(len(t), 5.0),
        sig.HAND_CRUSHED: crushed,
    }


def profile(*pieces: tuple[float, float]) -> np.ndarray:
    """Speed samples from (duration s, speed mm/s) pieces."""
    return np.concatenate([np.full(round(d * RATE_HZ), v) for d, v in pieces])


def judged(truth, *, belt=None, hand=None, voluntary=None, envelope=None) -> loop.Outcome:
    empty = (np.zeros(0), np.zeros(0))
    hand = hand or empty
    return loop.outcome(
        truth,
        belt=belt or empty,
        hand=hand,
        voluntary_n=np.full(len(hand[0]), 5.0) if voluntary is None else voluntary,
        envelope=envelope or empty,
        calibration=CAL,
    )


# -- outcome metrics on hand-made trials -------------------------------------------------------


def test_slip_that_comes_to_rest_and_stays_is_stopped_with_its_distance_and_time():
    truth = physics(profile((1.0, 0.0), (2.0, 20.0), (3.0, 0.0)))
    out = judged(truth)
    assert out.stopped and not out.dropped and not out.crushed
    assert out.onset_s == pytest.approx(1.0)
    assert out.time_to_stop_s == pytest.approx(2.0)
    assert out.slip_distance_mm == pytest.approx(40.0)
    assert out.first_stop_s == out.stop_s
    assert out.slip_episodes == 1


def test_leading_edge_past_the_skin_end_is_a_drop_not_a_stop():
    truth = physics(profile((1.0, 0.0), (5.0, 20.0)))  # -8 + 100 mm > 84 mm
    out = judged(truth)
    assert out.dropped and not out.stopped
    assert out.slip_distance_mm is None and out.time_to_stop_s is None and out.first_stop_s is None


def test_object_at_rest_after_leaving_the_skin_is_still_dropped():
    truth = physics(profile((1.0, 0.0), (5.0, 20.0), (2.0, 0.0)))
    out = judged(truth)
    assert out.dropped and not out.stopped


def test_stop_lost_again_counts_as_first_stop_and_re_slip_not_as_stopped():
    truth = physics(profile((1.0, 0.0), (1.0, 30.0), (2.0, 0.0), (3.0, 30.0)))
    out = judged(truth)
    assert not out.stopped and out.dropped
    assert out.first_stop_s == pytest.approx(2.0)
    assert out.slip_episodes == 2


def test_distance_and_time_run_to_the_final_rest_after_a_re_slip():
    truth = physics(profile((1.0, 0.0), (1.0, 10.0), (1.0, 0.0), (0.5, 10.0), (2.0, 0.0)))
    out = judged(truth)
    assert out.stopped and out.slip_episodes == 2
    assert out.first_stop_s == pytest.approx(2.0)
    assert out.time_to_stop_s == pytest.approx(2.5)
    assert out.slip_distance_mm == pytest.approx(15.0)


def test_crush_is_reported_beside_the_stop():
    truth = physics(profile((1.0, 0.0), (1.0, 20.0), (2.0, 0.0)), crushed_at_s=2.5)
    out = judged(truth)
    assert out.crushed and out.stopped


def test_speed_dip_touching_zero_for_a_moment_is_no_stop():
    speed = profile((1.0, 0.0), (3.0, 10.0), (2.0, 0.0))
    speed[1500:1510] = 0.0  # a ridge dip down to 0 mm/s for 10 ms
    out = judged(physics(speed))
    assert out.stopped and out.slip_episodes == 1
    assert out.time_to_stop_s == pytest.approx(3.0)


def test_object_that_never_slips_has_no_onset_and_is_not_stopped():
    out = judged(physics(profile((3.0, 0.0))))
    assert out.onset_s is None and not out.stopped and not out.dropped
    assert out.slip_episodes == 0


def test_stop_needs_a_rest_at_the_end_of_the_trial():
    truth = physics(profile((1.0, 0.0), (1.0, 20.0), (0.05, 0.0)))  # came to rest 50 ms ago
    assert not judged(truth).stopped


def test_first_belt_command_ignores_refreshes_of_what_was_shown_before_onset():
    truth = physics(profile((1.0, 0.0), (1.0, 20.0), (2.0, 0.0)))
    belt_t = np.array([0.5, 0.9, 1.1, 1.3, 1.4, 1.6])
    belt_v = np.array([3500.0, 3500.0, 3500.0, 3500.0, -4500.0, -5300.0])
    out = judged(truth, belt=(belt_t, belt_v))
    assert out.belt_latency_s == pytest.approx(0.4)
    assert out.belt_first_mrad_s == -4500.0
    assert out.slip_belt_latency_s == pytest.approx(0.4)


def test_first_belt_display_is_where_the_slewed_ramp_settles_not_its_first_step():
    # The gateway slews the belt 400 mrad/s per 10 ms command interval, refreshing
    # every 5 ms: the occurrence display (-4500) goes out as a ramp, held once reached.
    truth = physics(profile((1.0, 0.0), (1.0, 20.0), (2.0, 0.0)))
    ramp = np.repeat(np.maximum(-400.0 * np.arange(1, 13), -4500.0), 2)
    belt_v = np.concatenate(([0.0], ramp, np.full(20, -4500.0), np.full(5, -7000.0)))
    belt_t = 1.2 + 0.005 * np.arange(len(belt_v))
    out = judged(truth, belt=(belt_t, belt_v))
    assert out.belt_latency_s == pytest.approx(0.205)
    assert out.belt_first_mrad_s == -4500.0


def test_first_belt_display_still_ramping_at_the_end_is_its_last_command():
    truth = physics(profile((1.0, 0.0), (1.0, 20.0), (2.0, 0.0)))
    belt_t = np.array([0.5, 1.2, 1.21, 1.22])
    belt_v = np.array([0.0, -400.0, -800.0, -1200.0])
    assert judged(truth, belt=(belt_t, belt_v)).belt_first_mrad_s == -1200.0


def test_force_belt_change_is_the_first_belt_command_and_the_slip_belt_comes_later():
    truth = physics(profile((1.0, 0.0), (1.0, 20.0), (2.0, 0.0)))
    belt_t = np.array([0.5, 1.2, 1.5])
    belt_v = np.array([0.0, 3500.0, -2000.0])
    out = judged(truth, belt=(belt_t, belt_v))
    assert out.belt_latency_s == pytest.approx(0.2) and out.belt_first_mrad_s == 3500.0
    assert out.slip_belt_latency_s == pytest.approx(0.5)


def test_reflex_is_a_hand_command_above_the_wearers_grip_not_a_voluntary_rise():
    truth = physics(profile((1.0, 0.0), (1.0, 20.0), (2.0, 0.0)))
    hand_t = np.array([0.5, 1.2, 1.5, 1.7])
    hand_n = np.array([5.0, 8.0, 8.0, 12.5])
    voluntary = np.array([5.0, 8.0, 8.0, 8.0])  # the wearer rose to e2 at 1.2 s
    out = judged(truth, hand=(hand_t, hand_n), voluntary=voluntary)
    assert out.reflex_latency_s == pytest.approx(0.7)
    out = judged(truth, hand=(hand_t[:3], hand_n[:3]), voluntary=voluntary[:3])
    assert out.reflex_latency_s is None


def test_a_grip_command_ramping_down_after_the_wearer_relaxed_is_no_reflex():
    # The gateway slews the grip command at the hand's rate: when the wearer relaxes from
    # e3 (11 N) to e2 (8 N) the commands step down over 60 ms, above what the wearer asks.
    truth = physics(profile((1.0, 0.0), (1.0, 20.0), (2.0, 0.0)))
    hand_t = np.array([1.20, 1.30, 1.31, 1.32, 1.33, 1.34, 1.35, 1.36])
    hand_n = np.array([11.0, 11.0, 10.5, 10.0, 9.5, 9.0, 8.5, 8.0])
    voluntary = np.array([11.0, 8.0, 8.0, 8.0, 8.0, 8.0, 8.0, 8.0])
    out = judged(truth, hand=(hand_t, hand_n), voluntary=voluntary)
    assert out.reflex_latency_s is None


def test_i_emg_is_the_thesis_mean_normalised_intensity_from_the_onset_on():
    truth = physics(profile((1.0, 0.0), (1.0, 20.0), (2.0, 0.0)))
    env_t = np.array([0.5, 1.0, 2.0, 3.0])
    env_uv = np.array([500.0, 50.0, 275.0, 500.0])  # before onset: not counted
    out = judged(truth, envelope=(env_t, env_uv))
    assert out.i_emg == pytest.approx((0.0 + 0.5 + 1.0) / 3)
    assert loop.i_emg(np.array([10.0, 950.0]), CAL) == pytest.approx((0.0 + 2.0) / 2)
    assert loop.i_emg(np.zeros(0), CAL) is None


# -- trials in virtual time --------------------------------------------------------------------


def fast_trial(mode: str, reflex: bool, seed: int = 3) -> loop.Trial:
    """A 150 mm/s slip, watched for 1 s after it would have left the skin."""
    return loop.Trial(mode, reflex, 150.0, seed, settle_s=1.0)


@pytest.mark.parametrize("mode", list(loop.MODES))
def test_fast_slip_in_every_mode_drops_without_the_reflex_and_is_stopped_with_it(mode):
    without = loop.run_trial(fast_trial(mode, False), build_controllers)
    assert without.onset_s == pytest.approx(loop.START_S, abs=0.002)
    assert without.dropped and not without.stopped and without.reflex_latency_s is None
    # a drop ends the run within a chunk: the edge passes 84 mm 92 mm / 150 mm/s after the
    # onset, a little later for the speed dips at the ridges
    assert 0 < without.end_s - (loop.START_S + 92 / 150) < 0.05
    with_reflex = loop.run_trial(fast_trial(mode, True), build_controllers)
    assert with_reflex.stopped and not with_reflex.crushed
    assert 0 < with_reflex.reflex_latency_s < with_reflex.time_to_stop_s < 0.6
    assert 0 < with_reflex.slip_distance_mm < loop.SKIN_END_MM - loop.START_MM
    if mode == "off":
        assert with_reflex.belt_latency_s is None
    elif mode == "grip_force":
        assert with_reflex.slip_belt_latency_s is None
    else:  # the slip belt runs no later than the reflex, which needs the speed as well
        # (one contact more until s25: a slip onto the empty skin now enters at an end,
        # `decoding/arrival.py`, and its speed may come with the flag)
        assert 0 < with_reflex.slip_belt_latency_s <= with_reflex.reflex_latency_s


def test_trial_is_the_same_for_the_same_seed():
    trial = fast_trial("slip_speed", True, seed=11)
    assert loop.run_trial(trial, build_controllers) == loop.run_trial(trial, build_controllers)


def test_trial_scene_is_loop_headline_with_the_trials_settings():
    """The report's trials keep loop_headline.toml's nodes, controller and physics."""
    headline = tomllib.loads((SCENES / "loop_headline.toml").read_text())
    trial = loop.Trial("force_and_slip", True, 40.0, 7, threshold_mm_s=30.0)
    data = loop.scene_data(trial)
    assert data["nodes"] == headline["nodes"] | {"skin": {"layout": loop.LAYOUT}}
    reflex = dict(data["controller"]["reflex"])
    assert reflex.pop("enabled") is True
    assert data["controller"] | {"reflex": reflex} == headline["controller"]
    assert data["effects"] == headline["effects"]


@pytest.mark.parametrize(
    "name", ["loop_slow_wearer", "loop_fast_reflex", "loop_fast_noreflex", "loop_headline"]
)
def test_shipped_loop_scene_is_the_template_with_its_own_speed_and_reflex(name):
    data = tomllib.loads((SCENES / f"{name}.toml").read_text())
    pulled = next(e for e in data["effects"] if e["type"] == "object.pulled")
    reflex = data["controller"]["reflex"]
    trial = loop.Trial(
        data["controller"]["feedback"]["mode"],
        reflex.get("enabled", True),
        pulled["speed_mm_s"],
        data["scene"]["seed"],
        threshold_mm_s=reflex["threshold_mm_s"],
    )
    template = loop.scene_data(trial)
    assert data["effects"] == template["effects"]
    assert data["nodes"] == template["nodes"] | {"skin": {"layout": loop.LAYOUT}}


def test_judging_a_scene_without_the_loop_names_what_it_lacks():
    with pytest.raises(ConfigError, match="skin, emg, belt and hand nodes"):
        loop.judge(load_scene(SCENES / "headline_slip.toml"), build_controllers)


def test_slow_slip_scene_is_stopped_by_the_wearer_without_the_reflex():
    out = loop.judge(load_scene(SCENES / "loop_slow_wearer.toml"), build_controllers)
    assert out.stopped and out.reflex_latency_s is None
    # the wearer answers the slip belt after its reaction time (1.51-1.75 s) and more
    assert out.time_to_stop_s > out.slip_belt_latency_s + 1.51


def test_fast_slip_scenes_the_reflex_stops_it_and_without_the_reflex_it_drops():
    with_reflex = loop.judge(load_scene(SCENES / "loop_fast_reflex.toml"), build_controllers)
    assert with_reflex.stopped and with_reflex.reflex_latency_s is not None
    assert with_reflex.slip_episodes == 1  # the wearer took over before the reflex let go
    without = loop.judge(load_scene(SCENES / "loop_fast_noreflex.toml"), build_controllers)
    assert without.dropped and without.reflex_latency_s is None


# -- the report --------------------------------------------------------------------------------


def test_report_is_written_where_asked_with_a_row_per_mode_and_reflex(tmp_path):
    trials = [
        fast_trial(mode, reflex) for mode in ("off", "slip_speed") for reflex in (False, True)
    ]
    out = tmp_path / "bench"
    results = loop.run_report(
        out, controllers_for=build_controllers, workers=1, log=lambda _: None, trials=trials
    )
    assert {p.name for p in out.iterdir()} == {"loop.md", "loop.json", "loop.png"}
    text = (out / "loop.md").read_text()
    for key in ("none, no reflex", "none, reflex", "slip speed, no reflex", "slip speed, reflex"):
        assert f"| {key} | 1 |" in text
    saved = json.loads((out / "loop.json").read_text())
    assert len(saved["trials"]) == 4
    assert saved["figures"]["rows"]["slip speed, reflex"]["stopped_pct"] == 100.0
    assert results["figures"]["rows"]["none, no reflex"]["dropped_pct"] == 100.0


def test_grid_covers_every_mode_with_and_without_the_reflex_over_the_speeds():
    trials = loop.grid(quick=False)
    rows = {loop.row_key(t) for t in trials}
    assert len(rows) == 2 * len(loop.MODES) + 1
    assert {t.speed_mm_s for t in trials} == set(loop.SPEEDS_MM_S)
    assert len(trials) == len(rows) * len(loop.SPEEDS_MM_S) * len(loop.SEEDS)


def test_cli_refuses_zero_workers_before_running_anything(tmp_path, capsys):
    assert cli_main(["bench", "loop", "--workers", "0", "--out", str(tmp_path / "x")]) == 1
    assert "workers" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()


@pytest.mark.slow
def test_cli_quick_run_writes_the_report_into_out(tmp_path, capsys):
    assert cli_main(["bench", "loop", "--quick", "--out", str(tmp_path)]) == 0
    assert (tmp_path / "loop.md").read_text().count("**Quick run**") == 1
    assert "force + slip, reflex" in capsys.readouterr().out


def test_docs_hold_a_full_run_of_the_current_grid():
    saved = json.loads((ROOT / "docs" / "benchmarks" / "loop.json").read_text())
    assert not saved["quick"], "docs hold a quick run; run `grasplink bench loop`"
    grid = loop.grid(quick=False)
    assert len(saved["trials"]) == len(grid)
    assert {loop.row_key(loop.trial_of(r)) for r in saved["trials"]} == {
        loop.row_key(t) for t in grid
    }

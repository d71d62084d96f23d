"""A recording played to a page, without a socket or a browser: the playback clock in
virtual time, the replay of a `grasplink run` folder through a listening gateway, and a
folder that is not one (named before anything is served)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from grasplink import cli
from grasplink.errors import RecordingError
from grasplink.evaluation.loop_plot import read_loop
from grasplink.surfaces.view.playback import PagePlayback, PlaybackClock
from grasplink.surfaces.view.recording import TRUTH_KIND, Recording, load_recording
from grasplink.surfaces.view.recording_server import page_for, playback_from
from grasplink.surfaces.view.web import HttpError, load_files, parse_head

KINDS = ("skin", "emg", "belt", "hand")


# -- the clock ------------------------------------------------------------------------------
def test_the_clock_moves_at_its_rate_and_stops_at_the_end() -> None:
    clock = PlaybackClock(6.0, at_s=1.0, since_s=100.0, rate=4.0)
    assert clock.position(100.0) == 1.0
    assert clock.position(100.5) == 3.0
    assert clock.position(200.0) == 6.0 and clock.ended(200.0)


def test_pause_holds_the_position_and_play_goes_on_from_it() -> None:
    clock = PlaybackClock(6.0, since_s=0.0)
    clock.pause(2.0)
    assert clock.position(2.0) == clock.position(50.0) == 2.0
    clock.play(50.0)
    assert clock.position(51.0) == 3.0


def test_play_at_the_end_starts_again_and_a_seek_is_held_within_the_run() -> None:
    clock = PlaybackClock(6.0, since_s=0.0)
    clock.play(10.0)  # ended at 6 s
    assert clock.position(10.0) == 0.0
    clock.seek(-3.0, 10.0)
    assert clock.position(10.0) == 0.0
    clock.seek(99.0, 10.0)
    assert clock.position(10.0) == 6.0
    clock.seek(float("nan"), 10.0)
    assert clock.position(10.0) == 0.0


def test_a_speed_change_keeps_the_position_and_only_the_offered_speeds_are_taken() -> None:
    clock = PlaybackClock(60.0, since_s=0.0)
    clock.set_rate(0.25, 4.0)
    assert clock.position(4.0) == 4.0 and clock.position(8.0) == 5.0
    with pytest.raises(ValueError, match=r"rate 2: expected one of 0\.25, 1\.0, 4\.0"):
        clock.set_rate(2.0, 8.0)
    with pytest.raises(ValueError, match="rate 3"):
        PlaybackClock(60.0, rate=3.0)


def test_the_request_keeps_the_stream_query_apart_from_its_path() -> None:
    request = parse_head(b"GET /events?at=1.5&rate=4 HTTP/1.1\r\nHost: 127.0.0.1:8642\r\n\r\n")
    assert (request.path, request.query) == ("/events", "at=1.5&rate=4")
    assert parse_head(b"GET / HTTP/1.1\r\nHost: 127.0.0.1:8642\r\n\r\n").query == ""


def test_the_stream_query_sets_the_page_clock_and_garbage_is_refused_named() -> None:
    clock = playback_from("at=2.5&rate=0.25&paused=1", 6.0, 10.0)
    assert (clock.position(99.0), clock.rate, clock.paused) == (2.5, 0.25, True)
    assert playback_from("", 6.0, 0.0).position(1.0) == 1.0
    for query, problem in (
        ("at=x", "at and rate: expected numbers"),
        ("at=-1", "at: expected seconds >= 0"),
        ("at=nan", "at: expected seconds >= 0"),
        ("rate=2", "rate: expected one of"),
        ("paused=yes", "paused: expected 0 or 1"),
        ("at=1&at=2", "at: given 2 times"),
    ):
        with pytest.raises(HttpError, match=problem) as caught:
            playback_from(query, 6.0, 0.0)
        assert caught.value.status == 400


# -- the replay -------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def recording(headline_run: Path) -> Recording:
    return load_recording(headline_run)


def skin_points(frame: dict[str, Any]) -> list[dict[str, Any]]:
    return [values for _, kind, _, values in frame["points"] if kind == "skin"]


def shown_speed(values: dict[str, Any]) -> float | None:
    """The slip's speed, else the floor of its range (two contacts may leave it open):
    what the belt shows and the view prints."""
    speed = values["slip_speed_mm_s"]
    return values.get("slip_speed_low_mm_s") if speed is None else speed


def first_slip_s(recording: Recording) -> float:
    for message in recording.messages:
        if message.topic.endswith("/node/skin/values"):
            values = json.loads(message.payload)
            if values["slip"] and shown_speed(values):
                return message.t_s
    raise AssertionError("no decoded slip with a speed in the replay")


def test_the_replay_says_where_its_settings_came_from_and_what_it_holds(
    recording: Recording,
) -> None:
    assert recording.settings == "gateway settings as run (summary.json controller_options)"
    assert recording.duration_s == 6.0
    assert recording.gateway_id == "loop-headline"
    assert len(recording.truth_t_s) == 301  # 50 Hz over 6 s


def test_the_replay_shows_the_nodes_operational_and_the_slip_beside_the_truth(
    recording: Recording,
) -> None:
    slip_s = first_slip_s(recording)
    page = PagePlayback(recording, PlaybackClock(recording.duration_s, since_s=0.0))
    frame = page.frame(slip_s)
    gateway = frame["gateways"][recording.gateway_id]
    assert {name: n["phase"] for name, n in gateway["nodes"].items()} == dict.fromkeys(
        KINDS, "operational"
    )
    assert gateway["alarms"] == {} and not gateway["stale"] and frame["broker"]["connected"]
    assert gateway["controls"]["reflex_threshold_mm_s"] == 30.0  # the scene's, not the default
    slipping = [v for v in skin_points(frame) if v["slip"] and shown_speed(v)]
    assert slipping and 0 < shown_speed(slipping[-1]) < 1000
    truth = [(ts, v) for _, kind, ts, v in frame["points"] if kind == TRUTH_KIND]
    assert truth[-1][0] <= round(slip_s * 1000) and truth[-1][1]["speed_mm_s"] > 20.0
    assert frame["recording"]["position_s"] == round(slip_s, 3)
    assert frame["recording"]["folder"] == "loop-headline"


def test_the_replayed_gateway_commands_what_the_run_commanded(
    recording: Recording, headline_run: Path
) -> None:
    """Same settings, same frames at the same times: the same decisions (the bus carries
    them ramped and in whole mN; the snapshot the target)."""
    trace = read_loop(headline_run)
    values = {"belt": [], "hand": []}  # type: dict[str, list[float]]
    for message in recording.messages:
        for kind, key in (("belt", "velocity_mrad_s"), ("hand", "setpoint_n")):
            if message.topic.endswith(f"/node/{kind}/values"):
                value = json.loads(message.payload)[key]
                if value is not None:
                    values[kind].append(value)
    assert min(values["belt"]) == pytest.approx(float(np.min(trace.belt_target_mrad_s)))
    assert max(values["belt"]) == pytest.approx(float(np.max(trace.belt_target_mrad_s)))
    assert max(values["hand"]) == pytest.approx(float(np.max(trace.hand_target_n)), abs=1e-3)


def test_pause_holds_the_page_and_a_seek_back_starts_a_fresh_history(
    recording: Recording,
) -> None:
    slip_s = first_slip_s(recording)
    page = PagePlayback(recording, PlaybackClock(recording.duration_s, since_s=0.0))
    page.frame(slip_s + 0.5)
    page.clock.pause(slip_s + 0.5)
    held = page.frame(slip_s + 30.0)
    assert held["recording"]["position_s"] == round(slip_s + 0.5, 3)
    assert held["recording"]["paused"] and held["points"] == []  # nothing new while paused
    page.seek(0.5, slip_s + 30.0)
    frame = page.frame(slip_s + 31.0)
    assert frame["reset"] and frame["recording"]["position_s"] == 0.5
    assert frame["gateways"][recording.gateway_id]["newest_ts_ms"] <= 500
    assert not any(v["slip"] for v in skin_points(frame))
    # the retained state from before the window is there after the seek
    assert set(frame["gateways"][recording.gateway_id]["nodes"]) == set(KINDS)
    # played on from the seek, the slip comes again
    page.clock.play(0.0)
    page.clock.seek(slip_s, 0.0)
    again = page.frame(0.0)
    assert any(v["slip"] and shown_speed(v) for v in skin_points(again))


def test_the_page_is_told_it_plays_a_recording(recording: Recording) -> None:
    page = page_for(load_files()["/"], recording).decode()
    assert '<meta name="grasplink-recording" content="{&quot;folder&quot;: ' in page
    assert "loop-headline" in page and "&quot;rates&quot;: [0.25, 1.0, 4.0]" in page


# -- not a run folder -------------------------------------------------------------------------
def broken(headline_run: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "run"
    shutil.copytree(headline_run, copy)
    return copy


def test_a_folder_that_is_not_a_run_folder_is_named(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="not a folder"):
        load_recording(tmp_path / "nowhere")
    with pytest.raises(RecordingError, match=r"summary.json: missing: .* is not a folder"):
        load_recording(tmp_path)


@pytest.mark.parametrize("name", ["can.asc", "truth.csv"])
def test_a_missing_log_or_truth_is_named(headline_run: Path, tmp_path: Path, name: str) -> None:
    folder = broken(headline_run, tmp_path)
    (folder / name).unlink()
    with pytest.raises(RecordingError, match=rf"{name}: missing"):
        load_recording(folder)


def test_a_garbled_log_or_truth_is_named_with_its_line(headline_run: Path, tmp_path: Path) -> None:
    folder = broken(headline_run, tmp_path)
    lines = (folder / "truth.csv").read_text().split("\n")
    lines[3] = lines[3].replace(",", ",heavy,", 1)
    (folder / "truth.csv").write_text("\n".join(lines))
    with pytest.raises(RecordingError, match=r"truth.csv:4: .* values, the header names"):
        load_recording(folder)
    shutil.copyfile(headline_run / "truth.csv", folder / "truth.csv")
    text = (folder / "can.asc").read_text()
    (folder / "can.asc").write_text(text[: len(text) // 2])
    with pytest.raises(RecordingError, match=r"can.asc: no 'End TriggerBlock' line"):
        load_recording(folder)


def test_an_empty_log_is_named(headline_run: Path, tmp_path: Path) -> None:
    folder = broken(headline_run, tmp_path)
    (folder / "can.asc").write_text("")
    with pytest.raises(RecordingError, match=r"can.asc: empty file"):
        load_recording(folder)


def test_a_run_replays_with_its_recorded_settings_whatever_its_scene_file_says_now(
    headline_run: Path, tmp_path: Path
) -> None:
    """summary.json keeps the [controller] as run: an edited or removed scene file does
    not change what the replayed gateway commands."""
    folder = broken(headline_run, tmp_path)
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["controller_options"]["reflex"] == {"threshold_mm_s": 30.0}
    summary["path"] = str(tmp_path / "gone.toml")
    (folder / "summary.json").write_text(json.dumps(summary))
    recording = load_recording(folder)
    assert recording.settings == "gateway settings as run (summary.json controller_options)"


def test_a_run_from_before_the_record_falls_back_to_its_scene_file(
    headline_run: Path, tmp_path: Path
) -> None:
    folder = broken(headline_run, tmp_path)
    summary = json.loads((folder / "summary.json").read_text())
    del summary["controller_options"]
    (folder / "summary.json").write_text(json.dumps(summary))
    recording = load_recording(folder)
    assert recording.settings.startswith("gateway settings from ")
    assert recording.settings.endswith("loop_headline.toml [controller]")


def test_a_run_whose_scene_is_gone_plays_with_the_default_settings_said_so(
    headline_run: Path, tmp_path: Path
) -> None:
    folder = broken(headline_run, tmp_path)
    summary = json.loads((folder / "summary.json").read_text())
    del summary["controller_options"]  # a run from before summary.json kept its settings
    summary["path"] = str(tmp_path / "gone.toml")
    (folder / "summary.json").write_text(json.dumps(summary))
    recording = load_recording(folder)
    assert recording.settings == (
        "default gateway settings (the run's scene file was not found): "
        "the belt and hand commands shown may not be the run's"
    )


def test_a_truth_without_the_object_leaves_only_what_it_has(
    headline_run: Path, tmp_path: Path
) -> None:
    folder = broken(headline_run, tmp_path)
    rows = [line.split(",") for line in (folder / "truth.csv").read_text().splitlines()]
    keep = [i for i, name in enumerate(rows[0]) if name in ("t_s", "hand.grip_n")]
    text = "\n".join(",".join(row[i] for i in keep) for row in rows) + "\n"
    (folder / "truth.csv").write_text(text)
    recording = load_recording(folder)
    assert list(recording.truth) == ["grip_n"]
    page = PagePlayback(recording, PlaybackClock(recording.duration_s, since_s=0.0))
    truth = [v for _, kind, _, v in page.frame(1.0)["points"] if kind == TRUTH_KIND]
    assert truth and all(set(v) == {"grip_n"} for v in truth)


# -- the command line -------------------------------------------------------------------------
def test_view_takes_a_folder_or_a_broker_not_both(
    headline_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert cli.main(["view", str(headline_run), "--mqtt", "mqtt://127.0.0.1:1"]) == 1
    assert "view: give DIR (a recording) or --mqtt (a broker), not both: --mqtt given" in (
        capsys.readouterr().err
    )
    assert cli.main(["view"]) == 1
    assert "view: give a broker (--mqtt URL) or a run folder (DIR)" in capsys.readouterr().err
    assert cli.main(["view", str(tmp_path), "--http", "127.0.0.1:0", "--duration", "1"]) == 1
    assert "summary.json: missing" in capsys.readouterr().err

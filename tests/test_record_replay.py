"""`grasplink record` / `grasplink replay`, and the guarantee that a replay decodes as live.

The replay schedule is sans-IO and tested with plain lists and a fake clock;
recording is tested through python-can's own readers; the guarantee is tested
twice: in virtual time (bit-for-bit equal decoder updates) and in real time
through the loopback hub with a `LiveGateway` listening.
"""

from __future__ import annotations

import math
import os
import re
import signal
import subprocess
import sys
import threading
import time
from itertools import count, islice
from pathlib import Path

import can
import pytest

from grasplink.bus import CanHub, open_bus
from grasplink.bus.lockstep import LockstepNetwork
from grasplink.bus.logs import (
    LogPlayer,
    ReplaySchedule,
    from_nodes_only,
    read_log,
    record_bus,
    replay_to_bus,
    scan_log,
)
from grasplink.cli import main
from grasplink.controllers import build_controllers
from grasplink.core.frames import (
    EMCY_BASE,
    HEARTBEAT_BASE,
    NMT_COB_ID,
    RPDO_BASES,
    SDO_RX_BASE,
    SDO_TX_BASE,
    SYNC_COB_ID_DEFAULT,
    TPDO_BASES,
)
from grasplink.decoding.io import read_can_log, read_grip_commands
from grasplink.errors import ConfigError, RecordingError
from grasplink.gateway.live import LiveGateway
from grasplink.gateway.service import Gateway
from grasplink.simulators.engine import Simulation
from grasplink.simulators.recording import Recorder
from grasplink.simulators.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
GRASPLINK = [sys.executable, "-m", "grasplink.cli"]
RUN_S = 3.0  # the headline slip starts at 1 s; the gateway decodes it from ~1.7 s
SKIN_ID = 0x10
_channels = count()


def _channel() -> str:
    return f"virtual:record-replay-{os.getpid()}-{next(_channels)}"


def _msg(t_s: float, can_id: int = 0x190, data: bytes = b"\x01", **kw) -> can.Message:
    return can.Message(timestamp=t_s, arbitration_id=can_id, data=data, is_extended_id=False, **kw)


# -- the schedule (sans-IO) ----------------------------------------------------------------
def test_schedule_puts_each_frame_at_its_log_time_divided_by_the_speed():
    log = [_msg(100.0), _msg(100.25), _msg(101.0)]
    due = [s.due_us for s in ReplaySchedule().timeline(lambda: log)]
    assert due == [0, 250_000, 1_000_000]
    fast = [s.due_us for s in ReplaySchedule(speed=2).timeline(lambda: log)]
    assert fast == [0, 125_000, 500_000]


def test_schedule_sends_a_frame_stepping_back_in_time_at_once_in_file_order():
    log = [_msg(1.0, data=b"a"), _msg(1.5, data=b"b"), _msg(1.2, data=b"c"), _msg(2.0)]
    timeline = list(ReplaySchedule().timeline(lambda: log))
    assert [bytes(s.message.data) for s in timeline[:3]] == [b"a", b"b", b"c"]
    assert [s.due_us for s in timeline] == [0, 500_000, 500_000, 1_000_000]


def test_looping_starts_the_next_pass_one_mean_frame_interval_after_the_last_frame():
    log = [_msg(0.0), _msg(0.1), _msg(0.2)]
    timeline = list(islice(ReplaySchedule(loop=True).timeline(lambda: log), 7))
    assert [s.due_us for s in timeline] == [0, 100_000, 200_000, 300_000, 400_000, 500_000, 600_000]
    assert [s.pass_number for s in timeline] == [1, 1, 1, 2, 2, 2, 3]


def test_filtered_and_error_frames_are_left_out_but_keep_the_time_line():
    log = [
        _msg(5.0, can_id=NMT_COB_ID, data=b"\x82\x00"),
        _msg(5.1, is_error_frame=True),
        _msg(5.3, can_id=TPDO_BASES[0] + SKIN_ID),
    ]
    timeline = list(ReplaySchedule(keep=from_nodes_only(1)).timeline(lambda: log))
    assert [(s.due_us, s.message.arbitration_id) for s in timeline] == [(300_000, 0x190)]


def test_nodes_only_keeps_what_nodes_send_and_drops_what_a_master_sends():
    keep = from_nodes_only(master_id=1)
    node_frames = [TPDO_BASES[0], TPDO_BASES[3], EMCY_BASE, SDO_TX_BASE, HEARTBEAT_BASE]
    master_frames = [RPDO_BASES[0], SDO_RX_BASE]
    assert all(keep(_msg(0, base + SKIN_ID)) for base in node_frames)
    assert not any(keep(_msg(0, base + SKIN_ID)) for base in master_frames)
    assert not keep(_msg(0, NMT_COB_ID)) and not keep(_msg(0, SYNC_COB_ID_DEFAULT, b""))
    assert not keep(_msg(0, HEARTBEAT_BASE + 1))  # the master's own heartbeat
    assert not keep(can.Message(arbitration_id=0x18FF0010, is_extended_id=True))


@pytest.mark.parametrize("speed", [0, -1, float("inf"), float("nan")])
def test_speed_must_be_a_positive_factor(speed):
    with pytest.raises(ConfigError, match="positive"):
        ReplaySchedule(speed=speed)


class FakeClock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


class SentFrames(can.BusABC):
    def __init__(self, clock: FakeClock) -> None:
        self.clock = clock
        self.sent: list[tuple[float, can.Message]] = []
        super().__init__(channel="fake")

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sent.append((self.clock(), msg))

    def _recv_internal(self, timeout):
        return None, False


def test_replay_sends_each_frame_when_it_is_due_stamped_with_the_time_it_went_out():
    clock = FakeClock()
    bus = SentFrames(clock)
    log = [_msg(7.0), _msg(7.5), _msg(9.0)]
    before = time.time()
    stats = replay_to_bus(
        bus, ReplaySchedule().timeline(lambda: log), clock=clock, sleep=clock.sleep
    )
    assert [round(t - 1000.0, 6) for t, _ in bus.sent] == [0.0, 0.5, 2.0]
    assert all(m.timestamp >= before for _, m in bus.sent)  # wall clock, not the log's 7.0
    assert (stats.frames_sent, stats.passes, stats.stopped) == (3, 1, False)


def test_replay_stops_on_request_between_frames():
    clock = FakeClock()
    bus = SentFrames(clock)
    log = [_msg(0.0), _msg(10.0)]
    stats = replay_to_bus(
        bus,
        ReplaySchedule(loop=True).timeline(lambda: log),
        should_stop=lambda: clock.now > 1003.0,
        clock=clock,
        sleep=clock.sleep,
    )
    assert stats.stopped and stats.frames_sent == 1


# -- recording -----------------------------------------------------------------------------
@pytest.mark.parametrize("suffix", [".asc", ".blf", ".log"])
def test_recording_writes_a_complete_log_python_can_reads_back(tmp_path, suffix):
    url = _channel()
    recorder, sender = open_bus(url), open_bus(url)
    frames = [_msg(0, TPDO_BASES[0] + SKIN_ID, bytes([i, 2, 3])) for i in range(20)]
    frames.append(can.Message(arbitration_id=0x710, is_remote_frame=True, is_extended_id=False))
    try:
        for frame in frames:
            sender.send(frame)
        path = tmp_path / f"bus{suffix}"
        stats = record_bus(recorder, path, duration_s=0.3)
    finally:
        recorder.shutdown()
        sender.shutdown()
    assert stats.frames == len(frames)
    back = [m for m in can.LogReader(str(path)) if not m.is_error_frame]
    assert [(m.arbitration_id, bytes(m.data), m.is_remote_frame) for m in back] == [
        (m.arbitration_id, bytes(m.data), m.is_remote_frame) for m in frames
    ]


def test_record_refuses_an_unknown_suffix_a_missing_folder_or_an_existing_file(tmp_path, capsys):
    existing = tmp_path / "old.asc"
    existing.write_text("keep me")
    cases = [
        (tmp_path / "bus.txt", "unknown log format ('.txt')"),
        (tmp_path / "bus", "unknown log format (no suffix)"),
        (tmp_path / "nope" / "bus.asc", "does not exist"),
        (existing, "already exists; use --force"),
    ]
    for path, needle in cases:
        assert main(["record", str(path), "--bus", _channel(), "--duration", "0.1"]) == 1
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and needle in err, err
    assert existing.read_text() == "keep me"
    assert main(["record", str(existing), "--bus", _channel(), "--duration", "0.1", "--force"]) == 0
    assert "End TriggerBlock" in existing.read_text()


# -- reading and replaying logs ------------------------------------------------------------
@pytest.mark.parametrize(
    ("name", "content", "needle"),
    [
        ("garbage.asc", b"hello\nthis is no log\n", "holds no CAN frames"),
        ("empty.log", b"", "holds no CAN frames"),
        ("bad.log", b"(1.0) can0 123#GG\n", "not a readable can-utils candump -L log"),
        ("short.blf", b"LOGG" + b"\x00" * 20, "not a readable Vector BLF log"),
        ("bus.csv", b"timestamp,arbitration_id\n", "unknown log format ('.csv')"),
    ],
)
def test_replay_reports_a_malformed_log_on_one_line(tmp_path, capsys, name, content, needle):
    path = tmp_path / name
    path.write_bytes(content)
    assert main(["replay", str(path), "--bus", _channel()]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and needle in err, err


def test_master_id_without_nodes_only_is_refused(tmp_path, capsys):
    assert main(["replay", str(tmp_path / "a.asc"), "--master-id", "2"]) == 1
    assert "--master-id only applies with --nodes-only" in capsys.readouterr().err


def test_replay_of_a_missing_file_names_it(tmp_path):
    with pytest.raises(RecordingError, match="no such file"):
        scan_log(tmp_path / "gone.asc")


def test_replay_command_sends_every_frame_and_reports_the_count(tmp_path, capsys):
    path = tmp_path / "short.asc"
    with can.ASCWriter(str(path)) as writer:
        for i in range(5):
            writer.on_message_received(_msg(i * 0.01, data=bytes([i])))
    url = _channel()
    listener = open_bus(url)
    try:
        assert main(["replay", str(path), "--bus", url, "--speed", "4"]) == 0
        got = [listener.recv(1.0) for _ in range(5)]
    finally:
        listener.shutdown()
    assert [bytes(m.data) for m in got] == [bytes([i]) for i in range(5)]
    assert "sent 5 frames" in capsys.readouterr().out


# -- replay decodes as live ----------------------------------------------------------------
@pytest.fixture(scope="module")
def loop_run(tmp_path_factory):
    """The closed-loop headline (shortened) with the gateway in the loop: its can.asc and
    every skin decoder update the gateway produced live, with the time it produced it."""
    folder = tmp_path_factory.mktemp("loop")
    text = (ROOT / "scenes" / "loop_headline.toml").read_text()
    scene_path = folder / "loop_short.toml"
    scene_path.write_text(re.sub(r"(?m)^duration_s = .*$", f"duration_s = {RUN_S}", text))
    scene = load_scene(scene_path)
    controllers = build_controllers(scene)
    gateway = controllers[0]
    assert isinstance(gateway, Gateway)
    live: list = []
    gateway.estimate_listeners.append(lambda t_us, estimate: live.append((t_us, estimate)))
    Simulation(scene, Recorder(folder / "out"), controllers=controllers).run()
    return folder / "out" / "can.asc", scene, live


def _replay_in_virtual_time(log: Path, scene, *, keep=None, origin_us: int = 0) -> tuple:
    gateway = build_controllers(scene)[0]  # a fresh gateway, configured as the live one
    updates = _listen(gateway)
    player = LogPlayer(ReplaySchedule(keep=keep).timeline(lambda: read_log(log)))
    network = LockstepNetwork([gateway, player])
    network.t_us = origin_us
    network.start()
    network.run_until(origin_us + round((RUN_S + 1) * 1e6))
    assert player.finished
    return gateway, updates


class _Updates(list):
    """Skin decoder updates (t_us, estimate) and where the gateway's sample grid lay."""

    anchor_us: float | None = None


def _listen(gateway: Gateway) -> _Updates:
    updates = _Updates()

    def listener(t_us: int, estimate) -> None:
        if not updates:  # the stream forgets its grid when the skin is lost at the end
            anchor_s = gateway.skin_frames.anchor_s
            updates.anchor_us = None if anchor_s is None else anchor_s * 1e6
        updates.append((t_us, estimate))

    gateway.estimate_listeners.append(listener)
    return updates


def test_a_replayed_log_decodes_exactly_as_live_in_virtual_time(loop_run):
    log, scene, live = loop_run
    # a speed, or the floor of the range still possible (two contacts leave it open)
    shown = [e.speed_low_mm_s if e.speed_mm_s is None else e.speed_mm_s for _, e in live]
    slips = [e for (_, e), v in zip(live, shown, strict=True) if e.slip and v is not None]
    assert len(live) > 250 and slips, "the run must hold a decoded slip"
    _, replayed = _replay_in_virtual_time(log, scene)
    assert replayed == live  # same updates, same values, at the same gateway times
    # what a gateway hears on a bus: the nodes' frames only (never its own)
    _, nodes_only = _replay_in_virtual_time(log, scene, keep=from_nodes_only(1))
    assert nodes_only == live


def _skin_log(source: Path, out: Path) -> int:
    """The skin node's frames of a run after its boot, written as a new ASC log.

    A run recorded in virtual time holds every node's boot and provisioning at one
    instant (hundreds of frames at t = 0), which no real bus carries; a live gateway
    answering those boot-ups needs tens of ms and would hear the first skin packets,
    5 ms later in the log, too late. On a real bus the skin streams only after the
    gateway has started it, so the real-time replay starts after the boot.
    """
    keep = from_nodes_only(1)
    written = 0
    with can.ASCWriter(str(out)) as writer:
        for msg in read_log(source):
            if keep(msg) and msg.arbitration_id & 0x7F == SKIN_ID and msg.timestamp > 0:
                writer.on_message_received(msg)
                written += 1
    return written


def start_recording(path: Path, url: str) -> subprocess.Popen:
    """`grasplink record PATH --bus URL` in a child process, once it says it records."""
    recorder = subprocess.Popen(
        [*GRASPLINK, "record", str(path), "--bus", url],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )
    assert recorder.stdout is not None and "recording" in recorder.stdout.readline()
    return recorder


@pytest.mark.slow
def test_grasplink_replay_in_real_time_decodes_as_live_through_the_hub(loop_run, tmp_path):
    """`grasplink replay` onto the hub, a `LiveGateway` listening, `grasplink record` too.

    Tolerance: the gateway gives each sample its time from the packet sequence
    (decoding/packets.py), so a skin packet that reaches it late - by up to the heartbeat
    consumer time (300 ms) - keeps its place and its decoder sees the same samples. The
    only other difference is the clock: the decoder updates on a 10 ms grid of the
    gateway's clock, whose phase a real-time run cannot choose. So the real-time updates
    are compared, exactly, with a virtual-time replay anchored at the real-time gateway's
    sample grid, and that replay with live (above). A run in which the machine stalled
    the replay beyond the consumer time (the gateway then starts a new anchor, as on a
    bus silent that long) is tried again, at most three times in all.
    """
    log, scene, _ = loop_run
    skin_log = tmp_path / "skin.asc"
    frames = _skin_log(log, skin_log)
    config = build_controllers(scene)[0].config
    misses = []
    for attempt in range(3):
        with CanHub("127.0.0.1", 0) as hub:
            recorded = tmp_path / f"hub{attempt}.blf"
            recorder = start_recording(recorded, hub.url)
            with LiveGateway(hub.url, config) as live_gateway:
                gateway = live_gateway.gateway
                updates = _listen(gateway)
                replay = subprocess.run(
                    [*GRASPLINK, "replay", str(skin_log), "--bus", hub.url],
                    capture_output=True,
                    text=True,
                    cwd=ROOT,
                    timeout=60,
                )
                time.sleep(0.3)  # the last packets reach the gateway
            recorder.send_signal(signal.SIGTERM)
            out, err = recorder.communicate(timeout=30)
        assert replay.returncode == 0, replay.stderr
        assert f"sent {frames} frames" in replay.stdout
        assert recorder.returncode == 128 + signal.SIGTERM, err
        # the recording, ended by SIGTERM, is complete: every replayed frame is in it
        keep = from_nodes_only(1)
        heard = [
            m
            for m in can.LogReader(str(recorded))
            if keep(m) and m.arbitration_id & 0x7F == SKIN_ID
        ]
        assert len(heard) == frames and "wrote" in out
        stream = gateway.skin_frames.stats
        if stream.resyncs or stream.lost_packets:
            misses.append(replay.stdout.strip().splitlines()[-1])
            continue
        _, probe = _replay_in_virtual_time(skin_log, scene)
        shift_us = round(updates.anchor_us - probe.anchor_us)  # to the real-time sample grid
        _, expected = _replay_in_virtual_time(skin_log, scene, origin_us=shift_us)
        assert [e for _, e in updates] == [e for _, e in expected]
        assert len(updates) > 250
        # and the arrival times agree within the lateness the gateway tolerates
        lags_ms = [(a - b) / 1000 for (a, _), (b, _) in zip(updates, expected, strict=True)]
        assert max(lags_ms) - min(lags_ms) < 300, lags_ms
        return
    pytest.fail(f"the replay stalled beyond the consumer time in every attempt: {misses}")


@pytest.mark.slow
@pytest.mark.parametrize(
    ("suffix", "sig", "exit_code"),
    [(".asc", signal.SIGINT, 0), (".blf", signal.SIGTERM, 143), (".log", signal.SIGTERM, 143)],
)
def test_record_closes_a_complete_file_on_ctrl_c_or_sigterm(tmp_path, suffix, sig, exit_code):
    path = tmp_path / f"bus{suffix}"
    with CanHub("127.0.0.1", 0) as hub:
        recorder = start_recording(path, hub.url)
        sender = open_bus(hub.url)
        try:
            for i in range(50):
                sender.send(_msg(0, TPDO_BASES[0] + SKIN_ID, bytes([i, 0, 0, 0, 0, 0, i])))
            time.sleep(0.5)
            recorder.send_signal(sig)
            out, err = recorder.communicate(timeout=30)
        finally:
            sender.shutdown()
    assert recorder.returncode == exit_code, err
    assert "wrote" in out and "50 frames" in out
    back = list(can.LogReader(str(path)))
    assert [m.data[0] for m in back] == list(range(50))
    if suffix == ".asc":
        assert path.read_text().rstrip().endswith("End TriggerBlock")


def test_log_player_counts_frames_a_classic_frame_cannot_carry():
    log = [
        _msg(0.0),
        can.Message(timestamp=0.001, arbitration_id=0x18FF0010, is_extended_id=True),
        _msg(0.002),
    ]
    player = LogPlayer(ReplaySchedule().timeline(lambda: log))
    assert len(player.start(1_000)) == 1
    assert player.next_deadline_us() == 2_000
    assert len(player.advance(3_000)) == 1
    assert (player.frames_sent, player.skipped, player.finished) == (2, 1, True)


def test_scan_reports_frames_error_frames_and_span(tmp_path):
    path = tmp_path / "bus.asc"
    with can.ASCWriter(str(path)) as writer:
        writer.on_message_received(_msg(1.0))
        writer.on_message_received(can.Message(timestamp=1.5, is_error_frame=True))
        writer.on_message_received(_msg(3.0))
    summary = scan_log(path)
    assert (summary.frames, summary.error_frames) == (2, 1)
    assert math.isclose(summary.span_s, 2.0)


def test_a_recording_thread_stops_on_request(tmp_path):
    url = _channel()
    bus = open_bus(url)
    stop = threading.Event()
    result = {}
    worker = threading.Thread(
        target=lambda: result.update(
            stats=record_bus(bus, tmp_path / "a.log", should_stop=stop.is_set)
        )
    )
    worker.start()
    time.sleep(0.2)
    stop.set()
    worker.join(5)
    bus.shutdown()
    assert not worker.is_alive() and result["stats"].frames == 0


def test_offline_decoding_of_the_log_gives_the_live_gateways_estimates(loop_run):
    """One front end (decoding.skin_frames) for the live gateway and `grasplink decode`:
    the run's can.asc read offline and fed to a decoder configured as the gateway's, in
    the packets' 3-sample chunks, gives every update the gateway made live, bit for bit -
    told the hand's grip commands from the log, as the gateway told its decoder live."""
    log, scene, live = loop_run
    t_s, force_n, stats = read_can_log(log)
    assert stats.malformed == stats.stray == 0
    decoder = build_controllers(scene)[0].decoder  # a fresh one, configured as live
    read_grip_commands(log).feed(decoder)
    offline = []
    for start in range(0, len(t_s), 3):
        offline += decoder.feed(t_s[start : start + 3], force_n[start : start + 3])
    assert offline[: len(live)] == [estimate for _, estimate in live]

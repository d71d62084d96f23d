"""The command line: the demo, nodes as processes over the hub, and bad input."""

from __future__ import annotations

import contextlib
import os
import queue
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import canopen
import pytest

from grasplink.bus import BusDisconnected, CanHub
from grasplink.core.nmt import NmtState
from grasplink.demo import run_demo
from grasplink.profiles import eds_path

GRASPLINK = [sys.executable, "-m", "grasplink.cli"]
ROOT = Path(__file__).resolve().parents[1]
# How long a spawned grasplink process may take to say it is up. Its imports alone took
# 4.4 s at load 8 on 2 cores, and 15 s was not enough at load 15 under xdist; the wait
# ends at the line, so a passing run costs no more and a broken start still fails.
START_WAIT_S = 60.0


def run_cli(*args: str, timeout: float = 30) -> subprocess.CompletedProcess:
    return subprocess.run(
        [*GRASPLINK, *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def assert_clean_error(result: subprocess.CompletedProcess, *needles: str) -> None:
    assert result.returncode != 0
    assert "Traceback" not in result.stderr
    for needle in needles:
        assert needle in result.stderr, result.stderr


@pytest.mark.slow
def test_demo_boots_four_nodes_and_exchanges_pdos_in_both_directions():
    lines: list[str] = []
    figures = run_demo(1.5, out=lines.append)
    assert figures["states"] == dict.fromkeys(("skin", "belt", "emg", "hand"), "OPERATIONAL")
    rates = figures["rates_per_s"]
    assert rates["skin TPDO1"] == pytest.approx(133.3, rel=0.15)
    assert rates["belt RPDO1"] > 5 and rates["hand RPDO1"] > 5
    # the boot's NMT commands over the run, not over the milliseconds they came in
    assert 0 < rates["NMT"] < 20
    assert 0 < figures["bus_load_percent"] <= 25
    assert any(line.startswith("bus load:") for line in lines)


@pytest.mark.slow
def test_unknown_node_type_lists_the_valid_ones():
    result = run_cli("node", "elbow")
    assert_clean_error(result, "invalid choice", "skin", "hand")


@pytest.mark.slow
@pytest.mark.parametrize("node_id", ["0", "128", "0x80", "ten"])
def test_node_id_outside_1_127_is_refused(node_id):
    assert_clean_error(run_cli("node", "skin", "--node-id", node_id), "node-ID")


@pytest.mark.slow
def test_unknown_bus_interface_lists_the_available_ones():
    result = run_cli("node", "skin", "--bus", "nosuchcan:0", "--duration", "1")
    assert_clean_error(result, "unknown CAN interface 'nosuchcan'", "virtual", "socketcan")


@pytest.mark.slow
def test_unreachable_hub_names_the_fix(refused_port):
    port = refused_port
    result = run_cli("node", "belt", "--bus", f"remote:ws://127.0.0.1:{port}/", "--duration", "1")
    assert_clean_error(result, "no CAN hub", f"grasplink bus hub --port {port}")


@pytest.mark.slow
def test_invalid_eds_names_file_section_and_key(tmp_path):
    bad = tmp_path / "bad.eds"
    text = eds_path("belt").read_text().replace("HighLimit=8000", "HighLimit=7000", 1)
    bad.write_text(text)
    result = run_cli("profiles", "check", "--strict", str(bad))
    assert_clean_error(result, "bad.eds", "[", "DefaultValue")


@pytest.mark.slow
def test_profiles_check_accepts_the_shipped_eds_files():
    result = run_cli("profiles", "check", "--strict", *(str(eds_path(k)) for k in ("skin", "belt")))
    assert result.returncode == 0, result.stderr


@pytest.fixture
def hub():
    with CanHub("127.0.0.1", 0) as running:
        yield running


def _spawn_node(kind: str, url: str, *extra: str) -> subprocess.Popen:
    return subprocess.Popen(
        [*GRASPLINK, "node", kind, "--bus", url, "--duration", "20", *extra],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
    )


def _wait_line(proc: subprocess.Popen, needle: str, timeout_s: float = START_WAIT_S) -> str:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if needle in line:
            return line
        if proc.poll() is not None:
            raise AssertionError(f"node exited: {proc.stderr.read()}")
    raise AssertionError(f"no {needle!r} within {timeout_s} s")


def test_nodes_in_separate_processes_talk_through_the_hub(hub):
    procs = [_spawn_node("skin", hub.url), _spawn_node("belt", hub.url)]
    network = canopen.Network()
    try:
        for proc in procs:
            _wait_line(proc, "running on")
        network.connect(interface="remote", channel=hub.url.removeprefix("remote:"))
        skin = network.add_node(0x10, str(eds_path("skin")))
        belt = network.add_node(0x20, str(eds_path("belt")))
        assert skin.sdo[0x1000].raw == 0x00000194
        assert belt.sdo[0x1018][2].raw == 2
        skin.nmt.state = "OPERATIONAL"
        skin.tpdo.read()
        assert skin.tpdo[1].wait_for_reception(timeout=3) is not None
        assert len(skin.tpdo[1].data) == 7  # three 16-bit samples and a sequence number
        skin.nmt.wait_for_heartbeat(timeout=3)
        assert skin.nmt.state == "OPERATIONAL"
    finally:
        network.disconnect()
        for proc in procs:
            proc.terminate()
            proc.wait(10)


def test_second_node_with_the_same_id_refuses_to_start(hub):
    first = _spawn_node("emg", hub.url)
    try:
        _wait_line(first, "running on")
        second = subprocess.run(
            [*GRASPLINK, "node", "hand", "--node-id", "0x30", "--bus", hub.url, "--duration", "3"],
            capture_output=True,
            text=True,
            timeout=30,
            cwd=ROOT,
        )
        assert_clean_error(second, "node-ID 0x30 is already in use")
    finally:
        first.terminate()
        first.wait(10)


# -- a node whose hub goes away ----------------------------------------------------------


class _Lines:
    """A process's output lines, read by a thread so a test can wait without blocking."""

    def __init__(self, stream) -> None:
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        self._thread = threading.Thread(
            target=lambda: [self.lines.put(line) for line in stream], daemon=True
        )
        self._thread.start()

    def wait_for(self, pattern: str, timeout_s: float = START_WAIT_S) -> re.Match:
        deadline = time.monotonic() + timeout_s
        for line in self.seen:
            if found := re.search(pattern, line):
                return found
        while (left := deadline - time.monotonic()) > 0:
            try:
                line = self.lines.get(timeout=left)
            except queue.Empty:
                break
            self.seen.append(line)
            if found := re.search(pattern, line):
                return found
        raise AssertionError(f"no line matching {pattern!r} in {self.seen}")


def _spawn(*args: str) -> tuple[subprocess.Popen, _Lines, _Lines]:
    proc = subprocess.Popen(
        [*GRASPLINK, *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    return proc, _Lines(proc.stdout), _Lines(proc.stderr)


def _hub_process(port: int = 0) -> tuple[subprocess.Popen, int]:
    proc, out, _ = _spawn("bus", "hub", "--port", str(port))
    found = out.wait_for(r"listening on 127\.0\.0\.1:(\d+)")
    return proc, int(found.group(1))


def _end(*procs: subprocess.Popen) -> None:
    for proc in procs:
        if proc.poll() is None:
            proc.kill()
        proc.wait(10)


def _cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _wait_heartbeat(bus, node_id: int, timeout_s: float = 10) -> bytes:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        msg = bus.recv(0.2)
        if msg is not None and msg.arbitration_id == 0x700 + node_id:
            return bytes(msg.data)
    raise AssertionError(f"no heartbeat from node 0x{node_id:02X}")


@pytest.mark.slow
def test_node_reconnects_to_a_hub_restarted_on_the_same_port_and_keeps_its_state():
    hub, port = _hub_process()
    url = f"remote:ws://127.0.0.1:{port}/"
    node, out, err = _spawn("node", "skin", "--bus", url, "--duration", "60")
    restarted = None
    try:
        out.wait_for("running on")
        with closing_bus(url) as master:
            master.send(can.Message(arbitration_id=0x000, data=[0x01, 0x10], is_extended_id=False))
            while _wait_heartbeat(master, 0x10) != bytes([NmtState.OPERATIONAL]):
                pass
        hub.kill()  # no goodbye: the node finds a dead socket
        hub.wait(10)
        err.wait_for(r"lost the bus ws://127\.0\.0\.1:\d+/ .*; reconnecting for up to 60 s")
        err.wait_for(r"reconnect attempt 2 failed \(no CAN hub at .*\); next attempt in 0\.4 s")
        cpu_before, wall_before = _cpu_s(node.pid), time.monotonic()
        time.sleep(2)
        cpu_share = (_cpu_s(node.pid) - cpu_before) / (time.monotonic() - wall_before)
        assert cpu_share < 0.25, f"{cpu_share:.0%} of a core while the hub is down"
        restarted, _ = _hub_process(port)
        err.wait_for(r"back after [\d.]+ s and \d+ failed attempt\(s\); the devices kept", 15)
        with closing_bus(url) as watcher:  # still OPERATIONAL: no reboot, no boot-up
            assert _wait_heartbeat(watcher, 0x10) == bytes([NmtState.OPERATIONAL])
        node.terminate()
        assert node.wait(10) == 0
        out.wait_for(r"stopped: \d+ frames sent")
    finally:
        _end(node, hub, *([restarted] if restarted else []))
    assert not any("Traceback" in line for line in err.seen)


@pytest.mark.slow
def test_node_gives_up_when_the_hub_stays_away_and_exits_1():
    hub, port = _hub_process()
    url = f"remote:ws://127.0.0.1:{port}/"
    node, out, err = _spawn("node", "belt", "--bus", url, "--reconnect-timeout", "1")
    try:
        out.wait_for("running on")
        hub.kill()
        hub.wait(10)
        killed = time.monotonic()
        assert node.wait(15) == 1
        assert 1.0 <= time.monotonic() - killed <= 8
        found = err.wait_for(r"^grasplink: error: lost the bus .* within 1 s \(\d+ attempts; last")
        assert found.string == err.seen[-1]  # one line, the last
    finally:
        _end(node, hub)


@pytest.mark.slow
def test_node_stopped_while_its_hub_is_down_exits_1():
    hub, port = _hub_process()
    url = f"remote:ws://127.0.0.1:{port}/"
    node, out, err = _spawn("node", "emg", "--bus", url)
    try:
        out.wait_for("running on")
        hub.kill()
        hub.wait(10)
        err.wait_for("reconnect attempt 1 failed")
        node.terminate()
        assert node.wait(10) == 1
        err.wait_for(rf"^grasplink: error: stopped while {re.escape(url)} was down \([\d.]+ s\)")
    finally:
        _end(node, hub)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("value", "message"),
    [
        ("-1", "reconnect timeout must be >= 0 seconds, got -1"),
        ("inf", "reconnect timeout must be >= 0 seconds, got inf"),
        ("soon", "'soon' is not a number of seconds"),
    ],
)
def test_reconnect_timeout_must_be_seconds_from_zero(value, message):
    result = run_cli("node", "skin", "--reconnect-timeout", value)
    assert result.returncode == 2
    assert f"argument --reconnect-timeout: {message}" in result.stderr, result.stderr


@contextlib.contextmanager
def closing_bus(url: str):
    from grasplink.bus import open_bus

    bus = open_bus(url)
    try:
        yield bus
    finally:
        bus.shutdown()


class _DeadHubBus:
    """A hub client whose connection closed: every receive says so."""

    def recv(self, timeout: float | None = None):
        raise BusDisconnected("connection to CAN hub ws://127.0.0.1:1/ closed")


def test_node_id_probe_leaves_a_hub_lost_meanwhile_to_the_runner():
    from grasplink.cli import _refuse_if_node_id_taken

    _refuse_if_node_id_taken(_DeadHubBus(), 0x10, "remote:ws://127.0.0.1:1/")  # no exception

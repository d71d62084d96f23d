"""The command line: the demo, nodes as processes over the hub, and bad input."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import canopen
import pytest

from grasplink.bus import CanHub
from grasplink.demo import run_demo
from grasplink.profiles import eds_path

GRASPLINK = [sys.executable, "-m", "grasplink.cli"]
ROOT = Path(__file__).resolve().parents[1]


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
    result = run_cli("profiles", "check", str(bad))
    assert_clean_error(result, "bad.eds", "[", "DefaultValue")


@pytest.mark.slow
def test_profiles_check_accepts_the_shipped_eds_files():
    result = run_cli("profiles", "check", *(str(eds_path(k)) for k in ("skin", "belt")))
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


def _wait_line(proc: subprocess.Popen, needle: str, timeout_s: float = 15) -> str:
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

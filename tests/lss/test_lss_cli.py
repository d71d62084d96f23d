"""`grasplink node --node-id 0xFF` as a process, given its node-ID by python-canopen via the hub."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import canopen
import pytest

from grasplink.bus import CanHub
from grasplink.profiles import eds_path
from grasplink.profiles import objects as obj

GRASPLINK = [sys.executable, "-m", "grasplink.cli"]
ROOT = Path(__file__).resolve().parents[2]
LINE_WAIT_S = 60.0  # a bound: the lines normally come within a second (imports 4 s at load 8)


@pytest.fixture
def hub() -> Iterator[CanHub]:
    with CanHub("127.0.0.1", 0) as running:
        yield running


def wait_line(proc: subprocess.Popen, needle: str) -> str:
    deadline = time.monotonic() + LINE_WAIT_S
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if needle in line:
            return line
        if proc.poll() is not None:
            raise AssertionError(f"node exited: {proc.stderr.read()}")
    raise AssertionError(f"no {needle!r} within {LINE_WAIT_S} s")


def test_an_unconfigured_node_process_takes_the_node_id_an_lss_master_gives(hub):
    args = ["node", "hand", "--node-id", "0xFF", "--serial", "3", "--bus", hub.url]
    proc = subprocess.Popen(
        [*GRASPLINK, *args, "--duration", "60"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    network = canopen.Network()
    try:
        wait_line(proc, "running unconfigured")
        network.connect(interface="remote", channel=hub.url.removeprefix("remote:"))
        found, identity = network.lss.fast_scan()
        assert found and identity is not None and identity[3] == 3
        network.lss.configure_node_id(0x42)
        network.lss.store_configuration()
        network.lss.send_switch_state_global(network.lss.WAITING_STATE)
        wait_line(proc, "node-ID now 0x42")
        hand = network.add_node(0x42, str(eds_path("hand")))
        hand.sdo.RESPONSE_TIMEOUT = 3.0
        assert hand.sdo.upload(obj.IDENTITY, 4) == (3).to_bytes(4, "little")
    finally:
        network.disconnect()
        proc.terminate()
        proc.wait(10)


@pytest.mark.parametrize("serial", ["-1", "0x100000000", "many"])
def test_a_bad_serial_number_is_refused(serial):
    result = subprocess.run(
        [*GRASPLINK, "node", "skin", "--serial", serial, "--duration", "1"],
        capture_output=True,
        text=True,
        timeout=LINE_WAIT_S,
        cwd=ROOT,
    )
    assert result.returncode != 0 and "serial number" in result.stderr

"""Start-up order of `grasplink gateway` (issue 21, item 6): every surface is bound or
connected before the network is touched, so a failure exits having sent no frame;
--duration counts from the moment the gateway is up; --ready-file says when that is.

Each test runs the CLI in this process on a private python-can virtual channel that a
second handle listens on, like a bus analyser: what the gateway sent is what it heard.
"""

from __future__ import annotations

import socket
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from grasplink import cli
from grasplink.core.frames import HEARTBEAT_BASE
from grasplink.core.nmt import NmtState
from grasplink.gateway import live as live_module
from grasplink.profiles import objects as obj

pytestmark = pytest.mark.slow  # threads, sockets, the wall clock

BEAT = HEARTBEAT_BASE + obj.GATEWAY_NODE_ID


@pytest.fixture
def bus() -> Iterator[tuple[str, can.BusABC]]:
    """A private bus URL and an analyser handle on it."""
    channel = f"startup-{uuid.uuid4().hex}"
    analyser = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    yield f"virtual:{channel}", analyser
    analyser.shutdown()


def _sent(analyser: can.BusABC) -> list[can.Message]:
    frames = []
    while (msg := analyser.recv(0)) is not None:
        frames.append(msg)
    return frames


def test_taken_modbus_port_exits_with_a_clear_error_having_sent_no_frame(bus, capsys):
    url, analyser = bus
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = cli.main(["gateway", "--bus", url, "--modbus", f"tcp://127.0.0.1:{port}"])
    assert code == 1
    err = capsys.readouterr().err
    assert f"127.0.0.1:{port}" in err and "in use" in err
    assert _sent(analyser) == []  # before: 196 NMT/SDO frames, then the exit


def test_unreachable_broker_exits_with_a_clear_error_having_sent_no_frame(
    bus, capsys, refused_port
):
    url, analyser = bus
    code = cli.main(["gateway", "--bus", url, "--mqtt", f"mqtt://127.0.0.1:{refused_port}"])
    assert code == 1
    assert f"127.0.0.1:{refused_port}" in capsys.readouterr().err
    assert _sent(analyser) == []


def test_duration_counts_from_the_moment_the_gateway_is_up(bus, monkeypatch):
    # A start-up that takes 1.5 s (a decoder's kernels loading on a slow disk, say) must
    # not eat into --duration 1: the gateway then runs its heartbeat for about 1 s.
    url, analyser = bus
    ready = live_module.prepare_to_go_live

    def slow_prepare(gateways):
        time.sleep(1.5)
        ready(gateways)

    monkeypatch.setattr(live_module, "prepare_to_go_live", slow_prepare)
    assert cli.main(["gateway", "--bus", url, "--duration", "1"]) == 0
    beats = [m for m in _sent(analyser) if m.arbitration_id == BEAT]
    running = [m for m in beats if m.data[0] == NmtState.OPERATIONAL]
    assert beats[0].data[0] == NmtState.INITIALISING
    assert len(running) >= 5  # ~10 in 1 s at 100 ms; before: none (stopped when up)


# How long the gateway stays up: the file says "up" from its boot to its exit, and the
# test must see it in that window however long its own thread waits for the GIL (a fresh
# clone's make test missed a window of about a second once, at load 1-2).
UP_FOR_S = "6"


def _says_up(ready: Path) -> bool:
    """Whether the ready file says "up" now (it may go between a look and a read)."""
    try:
        return ready.read_text().startswith("up")
    except FileNotFoundError:
        return False


def test_ready_file_appears_once_up_and_goes_at_exit(bus, tmp_path):
    url, analyser = bus
    ready = tmp_path / "gateway.ready"
    ready.write_text("stale\n")  # left by an earlier run: must not say "up" for this one
    result: list[int] = []
    run = threading.Thread(
        target=lambda: result.append(
            cli.main(["gateway", "--bus", url, "--duration", UP_FOR_S, "--ready-file", str(ready)])
        )
    )
    run.start()
    try:
        deadline = time.monotonic() + 30
        while not _says_up(ready):
            assert time.monotonic() < deadline, "no ready file within 30 s"
            assert run.is_alive() or ready.exists(), "gateway exited without being ready"
            time.sleep(0.01)
        # up: the bus was open and the gateway had booted (its boot-up heartbeat is out)
        first = analyser.recv(5)
        assert first is not None and first.arbitration_id == BEAT
    finally:
        run.join(30)
    assert result == [0]
    assert not ready.exists()

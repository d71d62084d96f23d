"""A real Modbus peer: mbpoll (Debian) against the live gateway over TCP, and over RTU on a
pseudo-terminal pair bridged to mbpoll's own pseudo-terminal."""

from __future__ import annotations

import os
import select
import shutil
import threading
import time
import tty
import uuid
from collections.abc import Iterator

import pytest

from grasplink.gateway.config import parse_config
from grasplink.gateway.feedback import FeedbackMode
from grasplink.gateway.live import LiveGateway
from grasplink.surfaces.modbus.registers import MAP_VERSION, PHASE_CODES, settings_of
from grasplink.surfaces.modbus.server import ModbusServer
from tests.modbus.conftest import ALL_NODES, RMAP, mbpoll, mbpoll_values, operational, wait_until

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll not installed (make setup)"),
]
UNIT = 7


def commands_executed(gateway) -> int:
    return sum(n for key, n in gateway.counters.items() if key.startswith("command."))


def tcp(server: ModbusServer) -> list[str]:
    return ["-p", str(server.address.port), "127.0.0.1"]


def test_mbpoll_reads_the_whole_input_map(live_modbus):
    live, server = live_modbus
    run = mbpoll("-t", "3", "-r", "0", "-c", str(RMAP.input_count), *tcp(server))
    assert run.returncode == 0, run.stderr
    values = mbpoll_values(run.stdout)
    assert sorted(values) == list(range(RMAP.input_count))
    assert values[RMAP["map_version"].address] == MAP_VERSION
    assert values[RMAP["nodes_operational"].address] == ALL_NODES
    for kind, node in live.config.nodes.items():
        assert values[RMAP[f"nodes.{kind}.node_id"].address] == node.node_id
        assert values[RMAP[f"nodes.{kind}.phase"].address] == PHASE_CODES["operational"]


def test_mbpoll_reads_32_bit_values_with_big_endian_word_order(live_modbus):
    live, server = live_modbus
    run = mbpoll("-t", "3:int", "-B", "-r", str(RMAP["uptime_ms"].address), *tcp(server))
    assert run.returncode == 0, run.stderr
    uptime_ms = mbpoll_values(run.stdout)[RMAP["uptime_ms"].address]
    assert abs(uptime_ms / 1000 - live.gateway.latest.uptime_s) < 2.0
    run = mbpoll("-t", "3:int", "-B", "-r", str(RMAP["skin.position_mm"].address), *tcp(server))
    # No slip on the embedded bus: the position is unknown, the i32 sentinel.
    assert mbpoll_values(run.stdout)[RMAP["skin.position_mm"].address] == -(2**31)


def test_mbpoll_writes_commands_the_gateway_applies(live_modbus):
    live, server = live_modbus
    gateway = live.gateway
    try:
        run = mbpoll("-t", "4", "-r", str(RMAP["feedback_mode"].address), *tcp(server), "1")
        assert run.returncode == 0, run.stderr
        assert gateway.feedback.mode.value == "slip_occurrence"
        run = mbpoll("-t", "4", "-r", str(RMAP["emg_e_min_uv"].address), *tcp(server), "70", "700")
        assert run.returncode == 0, run.stderr
        calibration = gateway.emg_decoder.calibration
        assert (calibration.e_min_uv, calibration.e_max_uv) == (70, 700)
        run = mbpoll("-t", "4", "-r", "0", "-c", str(RMAP.holding_count), *tcp(server))
        assert list(mbpoll_values(run.stdout).values())[:5] == [1, 1, 450, 70, 700]
    finally:
        mbpoll("-t", "4", "-r", "0", *tcp(server), "4")
        mbpoll("-t", "4", "-r", str(RMAP["emg_e_min_uv"].address), *tcp(server), "50", "500")


@pytest.mark.parametrize(
    ("address", "values", "error"),
    [
        ("feedback_mode", ["7"], "Illegal data value"),
        ("reflex_threshold_mm_s", ["65000"], "Illegal data value"),
        ("emg_e_min_uv", ["500", "50"], "Illegal data value"),  # e_min above e_max
        ("emg_e_min_uv", ["80"], "Illegal data address"),  # half the pair
        ("emg_e_max_uv", ["450"], "Illegal data address"),
        ("reflex_enabled", ["1", "450"], "Illegal data address"),  # two commands
        (RMAP.holding_count, ["1"], "Illegal data address"),  # beyond the table
    ],
)
def test_mbpoll_sees_refused_writes_and_the_gateway_state_does_not_change(
    live_modbus, address, values, error
):
    live, server = live_modbus
    start = RMAP[address].address if isinstance(address, str) else address
    before = settings_of(live.gateway)
    commands_before = commands_executed(live.gateway)
    snapshot_before = live.gateway.latest
    run = mbpoll("-t", "4", "-r", str(start), *tcp(server), *values)
    assert run.returncode != 0 and error in run.stderr
    time.sleep(0.1)
    assert settings_of(live.gateway) == before
    wait_until(lambda: live.gateway.latest is not snapshot_before, what="a new snapshot")
    assert live.gateway.latest.belt.mode is FeedbackMode.FORCE_AND_SLIP
    assert commands_executed(live.gateway) == commands_before  # nothing was even posted


# -- RTU over pseudo-terminals ---------------------------------------------------------------


class PtyLine:
    """Two pseudo-terminal pairs joined like a serial cable: the server opens one slave,
    the client the other, and a thread copies bytes between the two masters."""

    def __init__(self) -> None:
        self.server_master, self.server_slave = os.openpty()
        self.client_master, self.client_slave = os.openpty()
        for fd in (self.server_slave, self.client_slave):
            tty.setraw(fd)  # no echo, no line discipline until the opener configures it
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._copy, daemon=True)

    @property
    def server_path(self) -> str:
        return os.ttyname(self.server_slave)

    @property
    def client_path(self) -> str:
        return os.ttyname(self.client_slave)

    def start(self) -> None:
        self._thread.start()

    def _copy(self) -> None:
        ends = {self.server_master: self.client_master, self.client_master: self.server_master}
        while not self._stop.is_set():
            ready, _, _ = select.select(list(ends), [], [], 0.05)
            for fd in ready:
                try:
                    data = os.read(fd, 4096)
                except OSError:
                    continue
                os.write(ends[fd], data)

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(1.0)
        for fd in (self.server_master, self.server_slave, self.client_master, self.client_slave):
            os.close(fd)


def crc16(frame: bytes) -> bytes:
    """Modbus RTU CRC (polynomial 0xA001, low byte first), written out independently."""
    crc = 0xFFFF
    for byte in frame:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc.to_bytes(2, "little")


def exchange(fd: int, request: bytes, wait_s: float = 1.0) -> bytes:
    """Send one framed request on a pty master; the bytes that come back within `wait_s`."""
    os.write(fd, request + crc16(request))
    reply = b""
    deadline = time.monotonic() + wait_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([fd], [], [], 0.05)
        if ready:
            reply += os.read(fd, 256)
        elif reply:
            break  # an RTU frame ends with silence
    return reply


@pytest.fixture
def rtu() -> Iterator[tuple[LiveGateway, PtyLine]]:
    line = PtyLine()
    channel = f"virtual:modbus-rtu-{uuid.uuid4().hex[:12]}"
    url = f"rtu://{line.server_path}?baud=115200&parity=N&unit={UNIT}"
    try:
        with (
            LiveGateway(channel, parse_config({}, "<test>"), with_nodes=True) as live,
            ModbusServer(live.edge, url),
        ):
            wait_until(lambda: operational(live.gateway), what="every node operational")
            yield live, line
    finally:
        line.close()


def test_rtu_frames_on_a_pty_are_answered_for_our_unit_only(rtu):
    live, line = rtu
    read = bytes([UNIT, 0x04, 0x00, 0x00, 0x00, 0x03])  # input registers 0..2
    reply = exchange(line.server_master, read)
    assert len(reply) == 3 + 6 + 2 and reply[:3] == bytes([UNIT, 0x04, 6])
    assert reply[-2:] == crc16(reply[:-2])
    assert int.from_bytes(reply[3:5], "big") == MAP_VERSION
    # Another unit's request, and a broadcast write: silence, nothing applied.
    assert exchange(line.server_master, bytes([UNIT + 1, 0x04, 0, 0, 0, 3]), 0.4) == b""
    assert exchange(line.server_master, bytes([0, 0x06, 0, 0, 0, 0]), 0.4) == b""
    assert live.gateway.feedback.mode.value == "force_and_slip"
    # A frame with a broken CRC is dropped, not answered.
    os.write(line.server_master, read + b"\x00\x00")
    time.sleep(0.3)
    assert exchange(line.server_master, read)[:3] == bytes([UNIT, 0x04, 6])
    # A refused write is an exception frame: function | 0x80, code 03.
    reply = exchange(line.server_master, bytes([UNIT, 0x06, 0x00, 0x00, 0x00, 0x09]))
    assert reply[:3] == bytes([UNIT, 0x86, 0x03]) and reply[3:] == crc16(reply[:3])


def test_mbpoll_over_rtu_reads_and_writes_and_other_units_time_out(rtu):
    live, line = rtu
    line.start()
    serial = ["-m", "rtu", "-b", "115200", "-P", "none", "-o", "0.5"]
    run = mbpoll(*serial, "-a", str(UNIT), "-t", "3", "-r", "0", "-c", "12", line.client_path)
    assert run.returncode == 0, run.stderr
    values = mbpoll_values(run.stdout)
    assert values[0] == MAP_VERSION and values[RMAP["nodes.skin.node_id"].address] == 0x10
    run = mbpoll(*serial, "-a", str(UNIT), "-t", "4", "-r", "0", line.client_path, "3")
    assert run.returncode == 0, run.stderr
    assert live.gateway.feedback.mode.value == "grip_force"
    run = mbpoll(*serial, "-a", str(UNIT), "-t", "4", "-r", "0", line.client_path, "8")
    assert run.returncode != 0 and "Illegal data value" in run.stderr
    run = mbpoll(*serial, "-a", str(UNIT + 1), "-t", "3", "-r", "0", line.client_path)
    assert run.returncode != 0 and "timed out" in (run.stdout + run.stderr).lower()
    assert live.gateway.feedback.mode.value == "grip_force"

"""The Modbus server against a pymodbus client: the live gateway's real values, commands
applied or refused (exception code, nothing applied), a stalled gateway, a busy mailbox,
and start-up errors."""

from __future__ import annotations

import socket
import threading
import time
import uuid

import pytest
from pymodbus.client import ModbusTcpClient

from grasplink.errors import BusError
from grasplink.gateway.commands import Command
from grasplink.gateway.config import parse_config
from grasplink.gateway.edge import MAILBOX_SIZE, GatewayEdge
from grasplink.gateway.service import Gateway
from grasplink.profiles import objects as obj
from grasplink.surfaces.modbus.registers import MAP_VERSION, PHASE_CODES, settings_of
from grasplink.surfaces.modbus.server import ModbusServer
from tests.modbus.conftest import ALL_NODES, RMAP, node_of, operational, wait_until

pytestmark = pytest.mark.slow
DATATYPE = ModbusTcpClient.DATATYPE


@pytest.fixture
def client(live_modbus):
    _, server = live_modbus
    with ModbusTcpClient("127.0.0.1", port=server.address.port, timeout=3) as c:
        yield c


def read_inputs(client) -> dict[str, int | None]:
    response = client.read_input_registers(0, count=RMAP.input_count)
    assert not response.isError(), response
    words = response.registers
    return {r.name: r.decode(words[r.address : r.end]) for r in RMAP.inputs}


def read_holding(client) -> list[int]:
    response = client.read_holding_registers(0, count=RMAP.holding_count)
    assert not response.isError(), response
    return response.registers


def test_one_read_returns_the_whole_map_with_the_live_gateways_values(live_modbus, client):
    live, _ = live_modbus
    values = read_inputs(client)
    snapshot = live.gateway.latest
    assert values["map_version"] == MAP_VERSION
    assert values["nodes_configured"] == values["nodes_live"] == ALL_NODES
    assert values["nodes_operational"] == ALL_NODES
    for kind, node in snapshot.nodes.items():
        assert values[f"nodes.{kind}.node_id"] == node.node_id == live.config.nodes[kind].node_id
        assert values[f"nodes.{kind}.nmt_state"] == 5  # OPERATIONAL
        assert values[f"nodes.{kind}.phase"] == PHASE_CODES["operational"]
        assert values[f"nodes.{kind}.pdos_rx"] > 0
    assert values["belt.mode"] == 4 and values["hand.reflex"] == 0  # force_and_slip, idle
    assert values["alarms"] == 0 == values["alarm_count"]
    # Counters move: the snapshot is replaced every 50 ms.
    time.sleep(0.3)
    later = read_inputs(client)
    assert later["uptime_ms"] > values["uptime_ms"]
    assert later["nodes.skin.pdos_rx"] > values["nodes.skin.pdos_rx"]


def test_32_bit_registers_read_with_pymodbus_big_word_order(live_modbus, client):
    live, _ = live_modbus
    uptime = RMAP["uptime_ms"]
    response = client.read_input_registers(uptime.address, count=2)
    ms = ModbusTcpClient.convert_from_registers(response.registers, DATATYPE.UINT32)
    assert abs(ms / 1000 - live.gateway.latest.uptime_s) < 1.0


def test_writes_apply_commands_and_read_back(live_modbus, client):
    live, _ = live_modbus
    gateway = live.gateway
    try:
        assert not client.write_register(RMAP["feedback_mode"].address, 2).isError()
        assert gateway.feedback.mode.value == "slip_speed"  # answered after it was applied
        assert not client.write_register(RMAP["reflex_threshold_mm_s"].address, 402).isError()
        assert gateway.arbiter.reflex.config.threshold_mm_s == pytest.approx(40.2)
        assert not client.write_register(RMAP["reflex_enabled"].address, 0).isError()
        assert gateway.arbiter.reflex.enabled is False
        response = client.write_registers(RMAP["emg_e_min_uv"].address, [80, 450])
        assert not response.isError()
        assert (
            gateway.emg_decoder.calibration.e_min_uv,
            gateway.emg_decoder.calibration.e_max_uv,
        ) == (80, 450)
        store = node_of(live, "emg").store  # the gateway wrote it to the EMG node over SDO
        wait_until(
            lambda: (
                (store.get(obj.EMG_CALIBRATION, 1), store.get(obj.EMG_CALIBRATION, 2)) == (80, 450)
            ),
            what="calibration on the EMG node",
        )
        assert read_holding(client)[:5] == [2, 0, 402, 80, 450]
        # Function 23 (read/write multiple) writes one command and reads the table back.
        response = client.readwrite_registers(
            read_address=0, read_count=3, write_address=0, values=[3]
        )
        assert not response.isError() and response.registers == [3, 0, 402]
    finally:
        for name, value in (
            ("feedback_mode", 4),
            ("reflex_enabled", 1),
            ("reflex_threshold_mm_s", 450),
        ):
            client.write_register(RMAP[name].address, value)
        client.write_registers(RMAP["emg_e_min_uv"].address, [50, 500])


@pytest.mark.parametrize(
    ("address", "values", "code"),
    [
        (0, [9], 0x03),  # no feedback mode 9
        (1, [2], 0x03),
        (2, [0], 0x03),  # threshold 0 mm/s
        (3, [450, 80], 0x03),  # e_min above e_max
        (3, [80], 0x02),  # half the calibration pair
        (4, [450], 0x02),
        (0, [2, 0], 0x02),  # two commands in one write
        (7, [1], 0x02),  # beyond the table
        (40000, [1], 0x02),
    ],
)
def test_a_refused_write_answers_its_exception_and_changes_nothing(
    live_modbus, client, address, values, code
):
    live, _ = live_modbus
    before = settings_of(live.gateway)
    commands_before = sum(v for k, v in live.gateway.counters.items() if k.startswith("command."))
    if len(values) == 1:
        response = client.write_register(address, values[0])
    else:
        response = client.write_registers(address, values)
    assert response.isError() and response.exception_code == code
    assert settings_of(live.gateway) == before
    time.sleep(0.1)  # had anything been posted, the gateway would have executed it by now
    commands = sum(v for k, v in live.gateway.counters.items() if k.startswith("command."))
    assert commands == commands_before
    assert read_holding(client)[:5] == [4, 1, 450, 50, 500]


def test_reads_beyond_the_tables_and_coils_are_refused(client):
    response = client.read_input_registers(RMAP.input_count - 1, count=2)
    assert response.isError() and response.exception_code == 0x02
    response = client.read_holding_registers(RMAP.holding_count, count=1)
    assert response.isError() and response.exception_code == 0x02
    for address in (0, 1000, 0xFFF0):
        response = client.read_coils(address, count=1)
        assert response.isError() and response.exception_code == 0x01
        response = client.read_discrete_inputs(address, count=8)
        assert response.isError() and response.exception_code == 0x01
    response = client.write_coil(5, True)
    assert response.isError() and response.exception_code == 0x01


def test_restart_node_resets_it_and_the_gateway_brings_it_back(live_modbus, client):
    live, _ = live_modbus
    boots = read_inputs(client)["nodes.hand.boots"]
    assert not client.write_register(RMAP["restart_node"].address, 4).isError()  # hand
    wait_until(lambda: read_inputs(client)["nodes.hand.boots"] == boots + 1, what="hand reboot")
    wait_until(lambda: operational(live.gateway), what="hand back")
    assert read_holding(client)[RMAP["restart_node"].address] == 4  # the last one asked for


@pytest.fixture
def stalled():
    """A gateway nobody runs: its snapshot never comes, its commands are never executed."""
    edge = GatewayEdge(Gateway(parse_config({}, "<stalled>")))
    with ModbusServer(edge, "tcp://127.0.0.1:0", command_timeout_s=0.3) as server:
        yield edge, server


def test_a_stalled_gateway_reads_unknown_and_writes_fail_without_blocking_reads(stalled):
    gateway, server = stalled
    with (
        ModbusTcpClient("127.0.0.1", port=server.address.port, timeout=3) as writer,
        ModbusTcpClient("127.0.0.1", port=server.address.port, timeout=3) as reader,
    ):
        values = read_inputs(reader)
        assert values["map_version"] == MAP_VERSION and values["uptime_ms"] == 0
        assert values["nodes.skin.phase"] is None and values["skin.grip_force_n"] is None
        latencies = []
        done = threading.Event()

        def keep_reading():
            while not done.is_set():
                started = time.perf_counter()
                read_inputs(reader)
                latencies.append(time.perf_counter() - started)

        thread = threading.Thread(target=keep_reading)
        thread.start()
        try:
            response = writer.write_register(0, 2)
        finally:
            done.set()
            thread.join()
        assert response.isError() and response.exception_code == 0x04
        # The server kept answering reads while the write waited for the gateway.
        assert len(latencies) >= 3 and min(latencies) < 0.2
    # The command stays queued: the gateway may still apply it (docs/modbus.md).
    assert len(gateway.mailbox.drain()) == 1


def test_a_full_mailbox_answers_busy_and_queues_nothing_more(stalled):
    gateway, server = stalled
    for _ in range(MAILBOX_SIZE):
        gateway.post(Command("reflex_enabled", True))
    with ModbusTcpClient("127.0.0.1", port=server.address.port, timeout=3) as client:
        response = client.write_register(0, 2)
    assert response.isError() and response.exception_code == 0x06
    assert len(gateway.mailbox.drain()) == MAILBOX_SIZE


def test_the_server_binds_localhost_unless_told_otherwise():
    gateway = GatewayEdge(Gateway(parse_config({}, "<test>")))
    with ModbusServer(gateway, "tcp://:0") as server:
        assert server.address.host == "127.0.0.1" and server.address.port > 0
        assert f"tcp://127.0.0.1:{server.address.port}" in server.describe()


def test_a_port_in_use_is_a_one_line_bus_error():
    gateway = GatewayEdge(Gateway(parse_config({}, "<test>")))
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        with pytest.raises(BusError) as caught:
            ModbusServer(gateway, f"tcp://127.0.0.1:{port}").start()
    message = str(caught.value)
    assert f"127.0.0.1:{port}" in message and "in use" in message and "\n" not in message


def test_a_missing_serial_device_is_a_one_line_bus_error(tmp_path):
    gateway = GatewayEdge(Gateway(parse_config({}, "<test>")))
    device = tmp_path / f"ttyNONE{uuid.uuid4().hex[:6]}"
    with pytest.raises(BusError) as caught:
        ModbusServer(gateway, f"rtu://{device}?unit=1").start()
    assert str(caught.value) == f"modbus: no serial device {device}"

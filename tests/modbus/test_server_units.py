"""One Modbus server for a process that masters several buses: a unit id per gateway, in
bus order; each unit reads its own gateway and its writes reach only that gateway; a unit
id no gateway has is answered 0x0B (TCP)."""

from __future__ import annotations

import shutil
import uuid
from collections.abc import Iterator

import pytest
from pymodbus.client import ModbusTcpClient

from grasplink.errors import BusError
from grasplink.gateway.config import parse_config
from grasplink.gateway.live import LiveGateway
from grasplink.surfaces.modbus.server import ModbusServer
from grasplink.surfaces.modbus.url import parse_modbus_url, unit_ids
from tests.modbus.conftest import RMAP, mbpoll, mbpoll_values, operational, wait_until


def test_one_gateway_keeps_its_unit_rule_and_several_count_up() -> None:
    tcp, rtu = parse_modbus_url("tcp://127.0.0.1:0"), parse_modbus_url("rtu:///dev/ttyX?unit=7")
    assert unit_ids(tcp, 1) == [None]  # every unit id, as before
    assert unit_ids(rtu, 1) == [7]
    assert unit_ids(tcp, 3) == [1, 2, 3]
    assert unit_ids(rtu, 3) == [7, 8, 9]
    with pytest.raises(BusError, match="units up to 248"):
        unit_ids(parse_modbus_url("rtu:///dev/ttyX?unit=246"), 3)


@pytest.fixture(scope="module")
def two_units() -> Iterator[tuple[LiveGateway, ModbusServer]]:
    """A gateway process on two buses (nodes on each) and its one Modbus server."""
    urls = [f"virtual:modbus-units-{uuid.uuid4().hex[:12]}" for _ in range(2)]
    config = parse_config({}, "<test>")
    with (
        LiveGateway(urls[0], config, with_nodes=True, more_buses=urls[1:]) as live,
        ModbusServer(live.edges, "tcp://127.0.0.1:0") as server,
    ):
        wait_until(lambda: all(map(operational, live.gateways)), 20.0, "every node on both buses")
        yield live, server


MODE = RMAP["feedback_mode"].address


def modes(live: LiveGateway) -> list[str]:
    return [g.feedback.mode.value for g in live.gateways]


@pytest.mark.slow
def test_each_unit_is_its_own_buses_gateway(two_units) -> None:
    live, server = two_units
    assert "units 1, 2, a gateway each" in server.describe()
    with ModbusTcpClient("127.0.0.1", port=server.address.port, timeout=3) as client:
        # a write to unit 2 is applied by the second bus's gateway only
        assert not client.write_register(MODE, 2, device_id=2).isError()
        assert modes(live) == ["force_and_slip", "slip_speed"]
        assert client.read_holding_registers(MODE, count=1, device_id=1).registers == [4]
        assert client.read_holding_registers(MODE, count=1, device_id=2).registers == [2]
        # each unit's inputs are its own gateway's snapshot (its own uptime)
        uptime = RMAP["uptime_ms"]
        for unit, gateway in zip((1, 2), live.gateways, strict=True):
            words = client.read_input_registers(uptime.address, count=2, device_id=unit)
            ms = ModbusTcpClient.convert_from_registers(
                words.registers, ModbusTcpClient.DATATYPE.UINT32
            )
            assert abs(ms / 1000 - gateway.latest.uptime_s) < 1.0
        # no gateway at unit 3: exception 0x0B, for a read and for a write; nothing applied
        response = client.read_input_registers(0, count=4, device_id=3)
        assert response.isError() and response.exception_code == 0x0B
        response = client.write_register(MODE, 3, device_id=3)
        assert response.isError() and response.exception_code == 0x0B
        assert modes(live) == ["force_and_slip", "slip_speed"]


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("mbpoll") is None, reason="mbpoll not installed (make setup)")
def test_mbpoll_addresses_a_unit_and_reaches_that_buses_gateway(two_units) -> None:
    live, server = two_units
    port = ["-p", str(server.address.port), "127.0.0.1"]
    done = mbpoll("-a", "1", "-t", "4", "-r", str(MODE), *port, "3")  # write 3 to unit 1
    assert done.returncode == 0, done.stderr
    assert modes(live)[0] == "grip_force" and modes(live)[1] != "grip_force"
    done = mbpoll("-a", "1", "-t", "4", "-r", str(MODE), "-c", "1", *port)
    assert done.returncode == 0, done.stderr
    assert mbpoll_values(done.stdout) == {MODE: 3}
    done = mbpoll("-a", "9", "-t", "4", "-r", str(MODE), "-c", "1", *port)
    assert done.returncode != 0  # no gateway at unit 9


def test_too_many_buses_for_the_units_left_is_refused_before_any_bus_opens(
    capsys, monkeypatch
) -> None:
    from grasplink import cli

    monkeypatch.setattr(LiveGateway, "start", lambda self: pytest.fail("a bus was opened"))
    args = ["gateway", "--bus", "virtual:u1", "--bus", "virtual:u2", "--bus", "virtual:u3"]
    code = cli.main([*args, "--modbus", "rtu:///dev/ttyNONE?unit=246"])
    assert code == cli.EXIT_ERROR
    err = capsys.readouterr().err
    assert "3 gateways from unit 246 need units up to 248; the highest is 247" in err

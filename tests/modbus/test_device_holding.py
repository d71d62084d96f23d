"""A configuration's writable device objects on Modbus (`[[modbus.holding]]`): checked when
the file is read, a client's write sent to the node in its RPDO by the real gateway, served
by the real server to a pymodbus client, documented by `--print-register-map`."""

from __future__ import annotations

import struct
import tomllib
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

from grasplink import cli
from grasplink.bus.lockstep import LockstepNetwork
from grasplink.errors import ConfigError
from grasplink.gateway.commands import Command
from grasplink.gateway.config import GatewayConfig, parse_config
from grasplink.gateway.edge import GatewayEdge
from grasplink.gateway.service import Gateway
from grasplink.gateway.snapshot import NodePhase
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import KINDS
from grasplink.surfaces.modbus.registers import (
    RegisterError,
    register_map,
    register_map_for,
    settings_of,
)
from tests.device_nodes import FSR, fsr_node, served_device, vendor_eds
from tests.live import wait_until

TARGET, CONTROLWORD = obj.HAND_TARGET_GRIP_MN, obj.CONTROLWORD  # RPDO1: 6040h, then 2400h
HOLDING = (
    '[[modbus.holding]]\nnode = "fsr"\nobject = "2400sub0"\naddress = 400\ntype = "uint32"\n'
    '[[modbus.holding]]\nnode = "fsr"\nobject = "6040sub0"\naddress = 402\ntype = "uint16"\n'
)
REAL_TARGET = (
    '[[modbus.holding]]\nnode = "fsr"\nobject = "2400sub0"\naddress = 400\ntype = "float32"\n'
)


def holding_config(folder: Path, extra: str, *, target: str = "") -> GatewayConfig:
    """The device `fsr` alone (tests/device_nodes.py) with `extra`; its target 2400h made
    REAL32 (`target="real"`) or read-only (`"ro"`) in the vendor's file."""
    path = vendor_eds(folder)
    text = path.read_text()
    section = f"[{TARGET:04X}]\nParameterName=Target grip force [mN]\nObjectType=0x7\n"
    assert section + "DataType=0x0007\nAccessType=rw\n" in text
    if target == "real":
        text = text.replace(section + "DataType=0x0007", section + "DataType=0x0008\nUnit=N")
    elif target == "ro":
        text = text.replace(
            section + "DataType=0x0007\nAccessType=rw", section + "DataType=0x0007\nAccessType=ro"
        )
    path.write_text(text)
    off = "".join(f"[nodes.{kind}]\nenabled = false\n" for kind in KINDS)
    toml = off + f'[nodes.fsr]\nnode_id = {FSR}\neds = "vendor/fsr.eds"\n' + extra
    (folder / "gw.toml").write_text(toml)
    return parse_config(tomllib.loads(toml), str(folder / "gw.toml"))


def entry(**keys: object) -> str:
    fields = {"node": '"fsr"', "object": '"2400sub0"', "address": "400", "type": '"uint32"'}
    fields.update({k: str(v) for k, v in keys.items()})
    return "[[modbus.holding]]\n" + "".join(f"{k} = {v}\n" for k, v in fields.items())


def test_entries_become_holding_registers_above_the_fixed_map(tmp_path):
    config = holding_config(tmp_path, HOLDING)
    rmap = register_map_for(config)
    assert [(r.name, r.address, r.end) for r in rmap.device_holding] == [
        ("fsr.2400sub0", 400, 402),
        ("fsr.6040sub0", 402, 403),
    ]
    first = config.modbus_holding[0]
    assert (first.name, first.data_type, first.limits) == (
        "Target grip force [mN]",
        "UNSIGNED32",
        (0, 100000),
    )
    fixed = register_map()
    assert (rmap.holding, rmap.holding_count, rmap.device_registers) == (fixed.holding, 7, ())
    assert rmap.holding_span == 403


@pytest.mark.parametrize(
    ("table", "needle"),
    [
        (entry(node='"hand"'), "modbus.holding[0].node: 'hand' is a loop node"),
        (
            entry(object='"2401sub0"'),
            "modbus.holding[0].object: 2401sub0 is no RPDO-mapped object of ",
        ),
        (entry(object='"2401sub0"'), "(mapped: 6040sub0, 2400sub0)"),
        (
            entry(type='"uint16"'),
            "modbus.holding[0].type: Target grip force [mN] is UNSIGNED32, which uint16 does "
            "not carry (use uint32)",
        ),
        (entry(address=6), "modbus.holding[0].address: 6 is in the fixed map's range (holding"),
        (
            entry() + entry(object='"6040sub0"', address=401, type='"uint16"'),
            "modbus.holding[1].address: 401..401 overlaps modbus.holding[0]",
        ),
        ("[modbus.holding]\nnode = 1\n", "modbus.holding: expected an array of tables"),
    ],
)
def test_a_bad_holding_entry_names_file_and_key_before_anything_starts(tmp_path, table, needle):
    with pytest.raises(ConfigError) as info:
        holding_config(tmp_path, table)
    assert needle in str(info.value) and "gw.toml" in str(info.value)


def test_a_read_only_object_cannot_be_offered_for_writing(tmp_path):
    with pytest.raises(
        ConfigError,
        match=r"modbus.holding\[0\].object: Target grip force \[mN\] "
        r"\(2400sub0\) is ro: a client cannot write it",
    ):
        holding_config(tmp_path, entry(), target="ro")


def running(folder: Path, extra: str, *, target: str = ""):
    """The gateway (behind its live edge's mailbox, as the Modbus server posts to it) and
    the device in virtual time, not started yet."""
    gateway = Gateway(holding_config(folder, extra, target=target))
    device = fsr_node(folder)
    edge = GatewayEdge(gateway)
    return edge, device, LockstepNetwork([edge, device])


def write(edge: GatewayEdge, network: LockstepNetwork, address: int, words: list[int]):
    """A client's write through the map, posted as the server posts it; its answer."""
    future = edge.post(register_map_for(edge.gateway.config).command_for_write(address, words))
    network.run_for(10_000)
    return future.result(timeout=0)


def test_a_write_goes_to_the_node_in_its_rpdo_and_reads_back(tmp_path):
    edge, device, network = running(tmp_path, HOLDING)
    gateway = edge.gateway
    rmap = register_map_for(gateway.config)
    # before the node is operational: refused, nothing sent, nothing queued
    command = rmap.command_for_write(400, [0, 30000])
    result, frames = gateway.execute(command, 0)
    assert not result.accepted and frames == []
    assert result.detail == "write_object: fsr is absent, not operational"
    network.start()
    network.run_until(1_000_000)
    assert gateway.snapshot().nodes["fsr"].phase is NodePhase.OPERATIONAL
    table = rmap.encode_served_holding(settings_of(gateway))
    assert table[400:403] == [0xFFFF, 0xFFFF, 0xFFFF]  # nothing sent yet: unknown
    result = write(edge, network, 400, [0, 30000])
    assert result.accepted and result.detail == "fsr 2400sub0 = 30000 (RPDO1)"
    assert device.store.get(TARGET) == 30000
    assert device.store.get(CONTROLWORD) == 0  # the RPDO's other object: the file's value
    assert write(edge, network, 402, [0x000F]).accepted
    assert (device.store.get(CONTROLWORD), device.store.get(TARGET)) == (0x000F, 30000)
    table = rmap.encode_served_holding(settings_of(gateway))
    assert table[400:403] == [0, 30000, 0x000F]
    assert rmap.read_holding(table, 400, 3) == [0, 30000, 0x000F]
    assert rmap.read_holding(table, 0, 7) == table[:7]  # the fixed map as it was
    for address, count in ((399, 2), (6, 2), (401, 3)):
        with pytest.raises(RegisterError) as info:
            rmap.read_holding(table, address, count)
        assert info.value.code == 0x02
    # the node reboots: its objects are back at their defaults, the registers unknown
    device.power_off()
    network.run_for(100_000)
    network.start_device(device)
    network.run_for(1_000_000)
    table = rmap.encode_served_holding(settings_of(gateway))
    assert table[400:403] == [0xFFFF, 0xFFFF, 0xFFFF] and device.store.get(TARGET) == 0


def test_a_value_the_object_does_not_accept_is_refused_before_it_is_sent(tmp_path):
    edge, device, network = running(tmp_path, HOLDING)
    gateway = edge.gateway
    network.start()
    network.run_until(1_000_000)
    rmap = register_map_for(gateway.config)
    with pytest.raises(RegisterError) as info:  # above its HighLimit (100000 mN)
        rmap.command_for_write(400, [0x0001, 0x86A1])
    assert info.value.code == 0x03
    assert "fsr.2400sub0 (Target grip force [mN]): 100001 is outside 0..100000" in str(info.value)
    with pytest.raises(RegisterError) as info:  # half of a 32-bit object
        rmap.command_for_write(401, [1])
    assert info.value.code == 0x02 and "write_object fsr.2400sub0 400..401" in str(info.value)
    # the gateway checks again (a JSON command comes without the map's check)
    result, frames = gateway.execute(
        Command("write_object", {"node": "fsr", "object": "2400sub0", "value": 200000}),
        network.t_us,
    )
    assert not result.accepted and frames == [] and "outside 0..100000" in result.detail
    result, _ = gateway.execute(
        Command("write_object", {"node": "fsr", "object": "2401sub0", "value": 1}), network.t_us
    )
    assert result.detail == (
        "write_object: fsr 2401sub0 is not offered for writing; offered: fsr 2400sub0, "
        "fsr 6040sub0 ([[modbus.holding]])"
    )
    assert device.store.get(TARGET) == 0


def test_float32_is_two_registers_high_word_first_and_must_be_finite(tmp_path):
    edge, device, network = running(tmp_path, REAL_TARGET, target="real")
    network.start()
    network.run_until(1_000_000)
    words = list(struct.unpack(">HH", struct.pack(">f", 12.5)))
    assert write(edge, network, 400, words).accepted
    assert device.store.get(TARGET) == 12.5
    rmap = register_map_for(edge.gateway.config)
    assert rmap.encode_served_holding(settings_of(edge))[400:402] == words
    for bad in (float("nan"), float("inf")):
        with pytest.raises(RegisterError, match="not a finite number"):
            rmap.command_for_write(400, list(struct.unpack(">HH", struct.pack(">f", bad))))


def test_print_register_map_documents_the_writable_device_objects(tmp_path, capsys):
    holding_config(tmp_path, HOLDING)
    assert cli.main(["gateway", "--config", str(tmp_path / "gw.toml"), "--print-register-map"]) == 0
    text = capsys.readouterr().out
    assert "## Device objects (holding registers, this configuration)" in text
    assert (
        "| 400–401 | `fsr.2400sub0` | uint32 |  | 2400h:00 Target grip force [mN] | UNSIGNED32 "
        "| 0..100000 | fsr |" in text
    )
    assert (
        "| 402 | `fsr.6040sub0` | uint16 |  | 6040h:00 Controlword | UNSIGNED16 | 0..65535 |"
        in (text)
    )


@pytest.mark.slow
def test_a_modbus_client_writes_a_device_object_live(tmp_path):
    """The live gateway and the device on one virtual bus, the Modbus server on a free port,
    a pymodbus client writing the target (float32) and reading it back."""
    config = holding_config(tmp_path, REAL_TARGET, target="real")
    device = fsr_node(tmp_path)
    with served_device(config, device) as (_live, server):
        assert "holding registers 0..6, fsr.2400sub0 at 400" in server.describe()
        with ModbusTcpClient("127.0.0.1", port=server.address.port, timeout=3) as client:
            words = ModbusTcpClient.convert_to_registers(12.5, ModbusTcpClient.DATATYPE.FLOAT32)
            response = client.write_registers(400, words)
            assert not response.isError(), response
            wait_until(lambda: device.store.get(TARGET) == 12.5, what="the target on CAN")
            response = client.read_holding_registers(400, count=2)
            assert not response.isError() and response.registers == words
            value = ModbusTcpClient.convert_from_registers(
                response.registers, ModbusTcpClient.DATATYPE.FLOAT32
            )
            assert value == 12.5
            response = client.write_registers(400, [0x7FC0, 0])  # NaN
            assert response.isError() and response.exception_code == 0x03
            response = client.write_register(401, 1)  # half of it
            assert response.isError() and response.exception_code == 0x02
            response = client.read_holding_registers(0, count=7)
            assert not response.isError()  # the fixed map, as before
    assert device.store.get(TARGET) == 12.5

"""A configuration's device objects on Modbus (`[[modbus.registers]]`): checked when the file
is read, encoded from the real gateway's snapshot, served by the real server to pymodbus
and mbpoll, documented by `--print-register-map`; the fixed map stays as it is."""

from __future__ import annotations

import math
import shutil
import struct
from pathlib import Path

import pytest
from pymodbus.client import ModbusTcpClient

from grasplink import cli
from grasplink.errors import ConfigError
from grasplink.gateway.snapshot import NodePhase
from grasplink.surfaces.modbus.docgen import render_modbus_markdown
from grasplink.surfaces.modbus.registers import (
    RegisterError,
    float32_words,
    register_map,
    register_map_for,
)
from tests.device_nodes import (
    GRIP,
    STATUSWORD,
    device_config,
    fsr_node,
    running,
    served_device,
)
from tests.live import wait_until
from tests.modbus.conftest import mbpoll, mbpoll_values

ENTRIES = (
    '[[modbus.registers]]\nnode = "fsr"\nobject = "2401sub0"\naddress = 300\ntype = "float32"\n'
    '[[modbus.registers]]\nnode = "fsr"\nobject = "6041"\naddress = 302\ntype = "uint16"\n'
    '[[modbus.registers]]\nnode = "fsr"\nobject = "6041sub0"\naddress = 310\ntype = "int32"\n'
)


def entry(**keys: object) -> str:
    fields = {"node": '"fsr"', "object": '"6041sub0"', "address": "300", "type": '"uint16"'}
    fields.update({k: str(v) for k, v in keys.items()})
    return "[[modbus.registers]]\n" + "".join(f"{k} = {v}\n" for k, v in fields.items())


def test_entries_become_input_registers_above_the_fixed_map(tmp_path):
    config = device_config(tmp_path, ENTRIES)
    rmap = register_map_for(config)
    assert [(r.name, r.address, r.end) for r in rmap.device_registers] == [
        ("fsr.2401sub0", 300, 302),
        ("fsr.6041sub0", 302, 303),
        ("fsr.6041sub0", 310, 312),
    ]
    first = config.modbus_registers[0]
    assert (first.name, first.data_type, first.unit) == ("Measured force", "REAL32", "N")
    fixed = register_map()
    assert (rmap.inputs, rmap.holding, rmap.input_count) == (
        fixed.inputs,
        fixed.holding,
        fixed.input_count,
    )
    assert rmap.input_span == 312
    assert register_map_for(device_config(tmp_path)) is fixed  # none configured: the fixed map


@pytest.mark.parametrize(
    ("table", "needle"),
    [
        (entry(node='"skin"'), "modbus.registers[0].node: 'skin' is a loop node"),
        (
            entry(node='"wrist"'),
            "modbus.registers[0].node: 'wrist' is no such node; device nodes: fsr",
        ),
        (
            entry(object='"2402sub0"'),
            "modbus.registers[0].object: 2402sub0 is no TPDO-mapped object",
        ),
        (entry(object='"64x"'), "modbus.registers[0].object: '64x' is not an object"),
        (
            entry(object='"2401sub0"', type='"int16"'),
            "modbus.registers[0].type: Measured force is REAL32, which int16 does not carry "
            "(use float32)",
        ),
        (entry(type='"int16"'), "Statusword is UNSIGNED16, which int16 does not carry"),
        (entry(type='"float64"'), "modbus.registers[0].type:"),
        (entry(address=40), "modbus.registers[0].address: 40 is in the fixed map's range"),
        (entry(address=65535, type='"uint32"'), "uint32 at 65535 takes 2 registers, past 65535"),
        (
            entry(address=300, type='"uint32"') + entry(address=301),
            "modbus.registers[1].address: 301..301 overlaps modbus.registers[0] "
            "(fsr 6041sub0 at 300..301)",
        ),
        (entry(unit='"mV"'), "modbus.registers[0].unit: unknown key"),
        ("[modbus.registers]\nnode = 1\n", "modbus.registers: expected an array of tables"),
    ],
)
def test_a_bad_entry_names_file_and_key_before_anything_starts(tmp_path, table, needle):
    with pytest.raises(ConfigError) as info:
        device_config(tmp_path, table)
    assert needle in str(info.value) and "gw.toml" in str(info.value)


def test_values_are_encoded_from_the_snapshot_and_unknown_reads_the_sentinel(tmp_path):
    gateway, device, network = running(tmp_path, seconds=0.0)
    rmap = register_map_for(device_config(tmp_path, ENTRIES))
    before = rmap.encode_served_inputs(gateway.snapshot())  # not operational yet
    assert before[300:303] == [0x7FC0, 0x0000, 0xFFFF] and before[310:312] == [0x8000, 0]
    network.run_until(1_000_000)
    device.store.set(GRIP, 0, -12.5)
    device.store.set(STATUSWORD, 0, 0x0237)
    network.run_for(200_000)
    snap = gateway.snapshot()
    assert snap.nodes["fsr"].phase is NodePhase.OPERATIONAL
    table = rmap.encode_served_inputs(snap)
    assert table[: rmap.input_count] == rmap.encode_inputs(snap)  # the fixed map as it was
    assert struct.unpack(">f", struct.pack(">HH", *table[300:302]))[0] == -12.5
    assert table[302] == 0x0237 and table[310:312] == [0, 0x0237]
    assert rmap.read_inputs(table, 300, 3) == table[300:303]
    assert rmap.read_inputs(table, 0, rmap.input_count) == table[: rmap.input_count]
    for address, count in ((300, 4), (303, 1), (rmap.input_count - 1, 2), (299, 2), (311, 2)):
        with pytest.raises(RegisterError) as info:
            rmap.read_inputs(table, address, count)
        assert info.value.code == 0x02


def test_float32_is_ieee_754_high_word_first_nan_when_unknown():
    assert float32_words(1.0) == [0x3F80, 0x0000]
    assert float32_words(None) == [0x7FC0, 0x0000]
    assert float32_words(1e300) == [0x7F80, 0x0000] and float32_words(-1e300) == [0xFF80, 0]


def test_print_register_map_documents_a_configurations_device_objects(tmp_path, capsys):
    device_config(tmp_path, ENTRIES)
    assert cli.main(["gateway", "--config", str(tmp_path / "gw.toml"), "--print-register-map"]) == 0
    text = capsys.readouterr().out
    assert "## Device objects (input registers, this configuration)" in text
    assert (
        "| 300–301 | `fsr.2401sub0` | float32 | N | 2401h:00 Measured force | REAL32 | fsr |"
        in (text)
    )
    fixed = render_modbus_markdown()
    assert text.startswith(fixed[: fixed.index("## Holding registers")].split("\n### Codes")[0])


@pytest.fixture
def served(tmp_path: Path):
    """The live gateway and the device on one virtual bus, the Modbus server on a free port."""
    config = device_config(tmp_path, ENTRIES)
    device = fsr_node(tmp_path, values={(GRIP, 0): 4.75, (STATUSWORD, 0): 0x0237})
    with served_device(config, device) as served:
        yield served


@pytest.mark.slow
def test_a_modbus_client_reads_a_device_object_live(served):
    _live, server = served
    assert "fsr.2401sub0 at 300" in server.describe()
    with ModbusTcpClient("127.0.0.1", port=server.address.port, timeout=3) as client:

        def force() -> float:
            response = client.read_input_registers(300, count=2)
            assert not response.isError(), response
            return ModbusTcpClient.convert_from_registers(
                response.registers, ModbusTcpClient.DATATYPE.FLOAT32
            )

        assert wait_until(lambda: force() == 4.75, what="the force on Modbus")
        response = client.read_input_registers(300, count=3)
        assert not response.isError() and response.registers[2] == 0x0237
        for address, count in ((299, 2), (302, 2), (400, 1)):
            response = client.read_input_registers(address, count=count)
            assert response.isError() and response.exception_code == 0x02
        response = client.read_input_registers(0, count=server.map.input_count)
        assert not response.isError()  # the fixed map, one read, as before
    if shutil.which("mbpoll"):
        run = mbpoll(
            "-t", "3:float", "-B", "-r", "300", "-p", str(server.address.port), "127.0.0.1"
        )
        assert run.returncode == 0, run.stderr
        assert math.isclose(float(run.stdout.split("[300]:")[1].split()[0]), 4.75)
        run = mbpoll("-t", "3", "-r", "302", "-p", str(server.address.port), "127.0.0.1")
        assert run.returncode == 0 and mbpoll_values(run.stdout) == {302: 0x0237}

"""A `device` node (a vendor's file, mastered, not in the loop) in the telemetry: its own JSON
subtree (state, values by object key, the objects' descriptions) and a Sparkplug device
typed from its EDS, born when operational, data on change, dead when lost; sans-IO, with
the real gateway's snapshots in virtual time."""

from __future__ import annotations

import dataclasses
import json

from grasplink.gateway.snapshot import NodePhase
from grasplink.surfaces.telemetry.buffer import Sample
from grasplink.surfaces.telemetry.json_tree import JsonTree
from grasplink.surfaces.telemetry.protocol import same_report
from grasplink.surfaces.telemetry.sparkplug import (
    FLOAT,
    STRING,
    UINT16,
    UINT64,
    SparkplugSession,
    datatype_of_eds,
)
from tests.device_nodes import GRIP, GRIP_KEY, STATUS_KEY, STATUSWORD, running
from tests.telemetry.host import SparkplugHost
from tests.telemetry.test_sparkplug import send

EXTRA = {"controls": {}, "telemetry": {}}
BASE = "grasplink/gw/node/fsr"


def test_the_snapshot_carries_a_devices_tpdo_objects_described_from_its_file(tmp_path) -> None:
    gateway, device, network = running(tmp_path)
    device.store.set(GRIP, 0, 12.5)
    network.run_for(200_000)
    snap = gateway.snapshot()
    assert snap.nodes["fsr"].phase is NodePhase.OPERATIONAL
    fsr = snap.devices["fsr"]
    described = [(o.key, o.index, o.subindex, o.name, o.data_type, o.unit) for o in fsr.objects]
    assert described == [
        (STATUS_KEY, STATUSWORD, 0, "Statusword", "UNSIGNED16", ""),
        (GRIP_KEY, GRIP, 0, "Measured force", "REAL32", "N"),
    ]
    assert fsr.values == (0, 12.5)
    assert snap.to_dict()["devices"] == {"fsr": {STATUS_KEY: 0, GRIP_KEY: 12.5}}
    assert gateway.snapshot().devices["fsr"].objects is fsr.objects  # described once


def test_a_device_is_a_json_subtree_state_values_by_key_and_its_objects(tmp_path) -> None:
    gateway, device, network = running(tmp_path)
    tree = JsonTree("gw")
    first = {m.topic: m for m in tree.update([Sample(1000, gateway.snapshot())], EXTRA)}
    state = json.loads(first[f"{BASE}/state"].payload)
    assert state["phase"] == "operational" and state["live"] and first[f"{BASE}/state"].retain
    assert json.loads(first[f"{BASE}/values"].payload) == {
        "ts_ms": 1000,
        STATUS_KEY: 0,
        GRIP_KEY: 0.0,
    }
    objects = json.loads(first[f"{BASE}/objects"].payload)
    assert first[f"{BASE}/objects"].retain
    assert objects["objects"] == [
        {
            "key": STATUS_KEY,
            "index": STATUSWORD,
            "subindex": 0,
            "name": "Statusword",
            "type": "UNSIGNED16",
            "unit": "",
        },
        {
            "key": GRIP_KEY,
            "index": GRIP,
            "subindex": 0,
            "name": "Measured force",
            "type": "REAL32",
            "unit": "N",
        },
    ]
    health = json.loads(first["grasplink/gw/health"].payload)
    assert health["nodes_live"] == ["fsr"]
    # a changed value goes out at once; the objects are not repeated
    before = gateway.snapshot()
    device.store.set(GRIP, 0, 3.25)
    network.run_for(100_000)
    later = {m.topic: m for m in tree.update([Sample(1050, gateway.snapshot())], EXTRA)}
    assert json.loads(later[f"{BASE}/values"].payload)[GRIP_KEY] == 3.25
    assert f"{BASE}/objects" not in later and f"{BASE}/state" not in later
    assert not same_report(before, gateway.snapshot())  # a device's value is news


def test_a_device_is_a_sparkplug_device_typed_from_its_eds(tmp_path) -> None:
    gateway, device, network = running(tmp_path)
    session, host = SparkplugSession("grp", "gw"), SparkplugHost("grp", "gw")
    session.will(900)
    first, _ = session.on_connect(900)
    send(session, host, first)
    send(session, host, session.update([Sample(1000, gateway.snapshot())], EXTRA))
    assert host.kinds()[1] == "DBIRTH/fsr"
    birth = next(m for m in host.messages if m.kind == "DBIRTH")
    types = {m.name: m.datatype for m in birth.payload.metrics}
    assert types[STATUS_KEY] == UINT16 and types[GRIP_KEY] == FLOAT
    assert types["State/phase"] == STRING and types["State/pdos_rx"] == UINT64
    described = {
        m.name: dict(
            zip(m.properties.keys, [v.string_value for v in m.properties.values], strict=True)
        )
        for m in birth.payload.metrics
        if m.name in (STATUS_KEY, GRIP_KEY)
    }
    assert described == {
        STATUS_KEY: {"Documentation": "Statusword", "edsDataType": "UNSIGNED16"},
        GRIP_KEY: {"Documentation": "Measured force", "edsDataType": "REAL32", "engUnit": "N"},
    }
    # the device's aliases follow the edge node's and the loop kinds': unique across all
    fixed = {a for table in host.aliases.values() for a in table}
    assert len(fixed) == sum(len(t) for t in host.aliases.values())
    # data on change, by alias
    device.store.set(GRIP, 0, 7.5)
    network.run_for(100_000)
    send(session, host, session.update([Sample(1100, gateway.snapshot())], EXTRA))
    data = [m for m in host.messages if m.kind == "DDATA"]
    assert data and data[-1].device == "fsr" and data[-1].metrics()[GRIP_KEY] == 7.5
    # lost: DDEATH; back: born again with the same aliases
    lost = gateway.snapshot()
    nodes = dict(lost.nodes)
    nodes["fsr"] = dataclasses.replace(nodes["fsr"], phase=NodePhase.LOST)
    send(
        session, host, session.update([Sample(1150, dataclasses.replace(lost, nodes=nodes))], EXTRA)
    )
    assert "DDEATH/fsr" in host.kinds()[-2:] and "fsr" not in host.born
    aliases = host.aliases["fsr"]
    send(session, host, session.update([Sample(1200, gateway.snapshot())], EXTRA))
    assert "DBIRTH/fsr" in host.kinds()[-2:] and "fsr" in host.born
    assert host.aliases["fsr"] == aliases
    assert not host.errors


def test_eds_data_types_map_to_sparkplug_types() -> None:
    expected = {
        "BOOLEAN": 11,
        "INTEGER8": 1,
        "INTEGER16": 2,
        "INTEGER24": 3,
        "INTEGER32": 3,
        "INTEGER64": 4,
        "UNSIGNED8": 5,
        "UNSIGNED16": 6,
        "UNSIGNED32": 7,
        "UNSIGNED64": 8,
        "REAL32": 9,
        "REAL64": 10,
        "VISIBLE_STRING": 12,
        "OCTET_STRING": 12,
    }
    assert {name: datatype_of_eds(name) for name in expected} == expected

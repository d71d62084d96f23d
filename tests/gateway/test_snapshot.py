"""The typed snapshot: the one contract between the gateway and its surfaces."""

from __future__ import annotations

import dataclasses
import json

import pytest

from grasplink.core.frames import HEARTBEAT_BASE, Frame
from grasplink.core.nmt import NmtState
from grasplink.gateway.config import load_config
from grasplink.gateway.plausibility import REJECTION_KEYS
from grasplink.gateway.service import Gateway
from grasplink.gateway.snapshot import (
    NodePhase,
    NodeSnapshot,
    Rejected,
    SkinSnapshot,
    Snapshot,
    check_path,
    node_sections,
    section_fields,
    wire_kind,
)
from grasplink.surfaces.modbus import registers
from grasplink.surfaces.modbus.registers import PHASE_CODES, U16, _Table
from grasplink.surfaces.telemetry import protocol, sparkplug


def fresh() -> Snapshot:
    return Gateway(load_config(None)).snapshot()


def test_to_dict_is_json_ready_with_enums_by_name_and_the_emcy_code_as_text():
    snap = fresh()
    skin = dataclasses.replace(snap.nodes["skin"], nmt_state=NmtState.OPERATIONAL, last_emcy=0x8130)
    snap = dataclasses.replace(snap, nodes={**snap.nodes, "skin": skin})
    data = snap.to_dict()
    json.dumps(data, allow_nan=False)  # plain JSON, nothing left to convert
    node = data["nodes"]["skin"]
    assert (node["phase"], node["nmt_state"], node["last_emcy"]) == (
        "absent",
        "OPERATIONAL",
        "0x8130",
    )
    assert type(data["belt"]["mode"]) is str and data["belt"]["belt"] == "none"
    assert data["hand"]["reflex"] == "idle" and data["hand"]["source"] is None
    assert "lost_packets" in node and "lost_packets" not in data["nodes"]["belt"]
    assert snap.to_dict() is data, "made once per snapshot"


def test_heartbeat_age_is_on_the_gateways_clock_from_each_nodes_last_heartbeat():
    """None before a node is heard; its boot-up and each heartbeat start it again; a silent
    node's age goes on past the consumer time, when the node is lost (virtual time)."""
    gateway = Gateway(load_config(None))
    skin = gateway.by_kind["skin"].node_id
    consumer_ms = gateway.snapshot().nodes["skin"].heartbeat_consumer_ms
    assert consumer_ms == gateway.node_consumer_us // 1000 == 500  # 3 x 100 ms + 200 ms
    gateway.start(0)
    gateway.advance(400_000)
    assert {n.heartbeat_age_s for n in gateway.snapshot().nodes.values()} == {None}
    gateway.receive(Frame(HEARTBEAT_BASE + skin, bytes([NmtState.INITIALISING])), 1_000_000)
    gateway.advance(1_250_000)
    ages = {kind: node.heartbeat_age_s for kind, node in gateway.snapshot().nodes.items()}
    assert ages == {"skin": 0.25, "emg": None, "belt": None, "hand": None}
    gateway.receive(Frame(HEARTBEAT_BASE + skin, bytes([NmtState.PRE_OPERATIONAL])), 1_300_000)
    gateway.advance(1_300_000)
    assert gateway.snapshot().nodes["skin"].heartbeat_age_s == 0.0
    gateway.advance(1_300_000 + consumer_ms * 1000)
    node = gateway.snapshot().nodes["skin"]
    assert node.heartbeat_age_s == consumer_ms / 1000 and node.phase is not NodePhase.LOST
    gateway.advance(4_300_000)
    node = gateway.snapshot().nodes["skin"]
    assert node.heartbeat_age_s == 3.0 and node.phase is NodePhase.LOST
    assert gateway.snapshot().to_dict()["nodes"]["skin"]["heartbeat_age_s"] == 3.0


def test_every_snapshot_field_has_a_wire_kind():
    for section in (Snapshot, NodeSnapshot, *node_sections().values(), Rejected):
        for name in section_fields(section):
            if section is Snapshot and name not in ("uptime_s",):
                continue  # sections, not values
            assert wire_kind(section, name) in ("float", "bool", "int", "uint32", "uint64", "str")
    assert wire_kind(NodeSnapshot, "phase") == wire_kind(NodeSnapshot, "last_emcy") == "str"
    assert wire_kind(NodeSnapshot, "pdos_rx") == "uint64"
    assert wire_kind(SkinSnapshot, "slip_direction") == "int"


def test_the_rejected_section_has_the_plausibility_keys_in_order():
    assert section_fields(Rejected) == REJECTION_KEYS


def test_the_surfaces_field_lists_are_the_snapshot_classes_fields():
    assert {
        kind: section_fields(cls) for kind, cls in node_sections().items()
    } == protocol.VALUE_FIELDS
    assert protocol.STATE_FIELDS == (
        "node_id",
        "phase",
        "nmt_state",
        "boots",
        "last_emcy",
        "failure",
        "heartbeat_consumer_ms",
    )
    state = [name for name, _ in sparkplug.STATE_METRICS + sparkplug.COUNTER_STATE_METRICS]
    assert state == list(section_fields(NodeSnapshot))
    # an age changes with every snapshot: Sparkplug sends it once a period, like a counter
    assert ("heartbeat_age_s", sparkplug.DOUBLE) in sparkplug.COUNTER_STATE_METRICS
    assert ("heartbeat_consumer_ms", sparkplug.UINT32) in sparkplug.STATE_METRICS
    skin = {spec.name: spec.datatype for spec in sparkplug.DEVICE_METRICS["skin"]}
    assert skin["slip"] == sparkplug.BOOLEAN and skin["grip_force_n"] == sparkplug.DOUBLE
    assert "State/lost_packets" in skin
    assert "State/lost_packets" not in {s.name for s in sparkplug.DEVICE_METRICS["belt"]}
    assert list(PHASE_CODES) == [p.value for p in NodePhase]


def test_a_misspelt_path_fails_naming_the_field():
    check_path(("nodes", "skin", "phase"))
    check_path(("loop", "percepts"))
    with pytest.raises(ValueError, match="SkinSnapshot has no field 'grip_force_N'"):
        check_path(("skin", "grip_force_N"))
    with pytest.raises(ValueError, match="is a section"):
        check_path(("skin",))


def test_an_input_register_with_a_misspelt_path_fails_naming_the_register():
    table = _Table(of_snapshot=True)
    table.add("loop.percepts", U16, "ok", path=("loop", "percepts"))
    with pytest.raises(ValueError, match=r"input register loop\.percept: .*no field 'percept'"):
        table.add("loop.percept", U16, "misspelt", path=("loop", "percept"))
    assert registers.register_map().input_count > 0  # the shipped map passes the check

"""The node-kind registry (grasplink/profiles/kinds.py): one place lists the kinds.

Adding a kind is an entry in the registry plus the kind's piece in each layer's one
per-kind table, which the layer checks against the registry at import; every ordered
per-kind output keeps the order it had before the registry (the committed docs pin it).
"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from grasplink.devices.factory import CODES_BY_KIND, DEVICES, build_node
from grasplink.errors import ConfigError
from grasplink.evaluation.loop import LOOP_KINDS
from grasplink.gateway import config as gateway_config
from grasplink.profiles import eds_path, edsgen, load_profile
from grasplink.profiles import objects as obj
from grasplink.profiles.dbc import NODE_NAMES, node_ids_with
from grasplink.profiles.kinds import BY_NODE_ID, KINDS, NODE_KINDS, node_kind, per_kind
from grasplink.simulators.bindings import BINDINGS
from grasplink.simulators.scene import parse_scene

ROOT = Path(__file__).resolve().parents[1]
# The kinds before the registry, in the order of today's Modbus bits and blocks: they keep
# their slots; a new kind comes after them.
TODAY = ("skin", "emg", "belt", "hand")

# Each layer's per-kind table: what adding a kind fills in, besides the registry.
TABLES = {
    "profiles/edsgen.py DEVICES": edsgen.DEVICES,
    "profiles/edsgen.py BUILDERS": edsgen.BUILDERS,
    "devices/factory.py DEVICES": DEVICES,
    "devices/factory.py CODES_BY_KIND (from DEVICES)": CODES_BY_KIND,
    "simulators/bindings.py BINDINGS": BINDINGS,
    "gateway/config.py _PARSERS": gateway_config._PARSERS,
}


# -- the orders of today's outputs -------------------------------------------------------------
def test_the_index_order_is_the_order_of_the_modbus_bits_blocks_and_codes():
    """docs/modbus.md is generated and compared with the live map (tests/modbus): its node
    bits, alarm bits, per-node blocks and restart codes follow the registry's index."""
    assert KINDS[: len(TODAY)] == TODAY
    assert [node_kind(k).index for k in TODAY] == [0, 1, 2, 3]
    doc = (ROOT / "docs" / "modbus.md").read_text()
    bits = ", ".join(f"{k.index} {k.name}" for k in NODE_KINDS)
    assert doc.count(f"bits: {bits} |") == 3  # nodes_configured, nodes_live, nodes_operational
    alarms = re.search(r"`alarms` .*?bits: ([^|]*)\|", doc)
    assert alarms is not None
    pairs = [(int(b), key.split(".")[0]) for b, key in re.findall(r"(\d+) (\w+\.\w+)", alarms[1])]
    assert [kind for _, kind in sorted(pairs)] == [k for k in KINDS for _ in range(4)]
    assert re.findall(r"^### nodes\.(\w+)$", doc, re.M) == list(KINDS)
    codes = ", ".join(f"{k.index + 1} {k.name}" for k in NODE_KINDS)
    assert f"| `restart_node` | u16 |  | 1 | {codes} |" in doc


def test_the_gateway_masters_its_nodes_in_index_order():
    """config.nodes is the order of the snapshot's nodes, the JSON and the Sparkplug births."""
    assert tuple(gateway_config.parse_config({}, "<defaults>").nodes) == KINDS


def test_profile_documents_list_the_kinds_by_default_node_id():
    assert [k for k in BY_NODE_ID if k in TODAY] == ["skin", "belt", "emg", "hand"]
    doc = (ROOT / "docs" / "profiles.md").read_text()
    assert re.findall(r"^## (\w+):", doc, re.M) == list(BY_NODE_ID)
    assert list(obj.DEFAULT_NODE_IDS.items()) == [(k, node_kind(k).node_id) for k in BY_NODE_ID]


def test_the_registry_keeps_todays_node_ids_files_and_names():
    assert {k: node_kind(k).node_id for k in TODAY} == {
        "skin": 0x10,
        "emg": 0x30,
        "belt": 0x20,
        "hand": 0x40,
    }
    assert all(k.node_id != obj.GATEWAY_NODE_ID for k in NODE_KINDS)
    assert all(eds_path(k).is_file() and eds_path(k).name == f"{k}.eds" for k in KINDS)
    assert {k: NODE_NAMES[k] for k in TODAY} == {
        "skin": "Skin",
        "emg": "EMG",
        "belt": "Belt",
        "hand": "Hand",
    }


# -- one place per layer ---------------------------------------------------------------------------
@pytest.mark.parametrize("name", TABLES)
def test_every_layer_has_one_entry_per_registered_kind_in_index_order(name):
    assert tuple(TABLES[name]) == KINDS


def test_a_table_missing_a_kind_or_holding_an_unregistered_one_is_refused_by_name():
    *known, last = KINDS
    table = dict.fromkeys(known, 1)
    with pytest.raises(ValueError, match=rf"^layer X: no entry for {last} \(node kinds: "):
        per_kind("layer X", table)
    with pytest.raises(ValueError, match=rf"no entry for {last}; unregistered 'elbow'"):
        per_kind("layer X", table | {"elbow": 1})
    assert list(per_kind("layer X", dict.fromkeys(reversed(KINDS), 1))) == list(KINDS)


ADD_A_KIND = """
import grasplink.profiles.kinds as k
new = k.NodeKind("newkind", "New", index=len(k.KINDS), node_id=0x7E, eds="newkind.eds")
k.NODE_KINDS += (new,)
k._BY_NAME["newkind"] = new
k.KINDS += ("newkind",)
k.BY_NODE_ID += ("newkind",)
import {module}
"""


@pytest.mark.parametrize(
    ("module", "table"),
    [
        ("grasplink.profiles.edsgen", "profiles/edsgen.py DEVICES"),
        ("grasplink.devices.factory", "devices/factory.py DEVICES"),
    ],
)
def test_a_kind_added_to_the_registry_alone_stops_the_import_naming_the_table(module, table):
    done = subprocess.run(
        [sys.executable, "-c", ADD_A_KIND.format(module=module)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        check=False,
    )
    assert done.returncode == 1
    assert f"ValueError: {table}: no entry for newkind" in done.stderr


def test_the_closed_loop_names_registered_kinds_only():
    assert set(LOOP_KINDS) <= set(KINDS)


# -- one error for an unknown kind -----------------------------------------------------------------
def test_an_unknown_kind_gets_the_same_error_naming_the_kinds_everywhere():
    message = f"unknown node kind 'elbow'; the kinds are {', '.join(KINDS)}"
    for refuse in (
        lambda: node_kind("elbow"),
        lambda: eds_path("elbow"),
        lambda: load_profile("elbow", 0x10),
        lambda: build_node("elbow"),
        lambda: gateway_config.parse_config({"nodes": {"elbow": {}}}, "gw.toml"),
        lambda: parse_scene(tomllib.loads("[scene]\nduration_s = 1\n[nodes.elbow]\n"), "s.toml"),
        lambda: node_ids_with({"elbow": 3}),
    ):
        with pytest.raises(ConfigError) as info:
            refuse()
        assert message in str(info.value)

"""The node kinds of a grasplink network: the one place that lists them.

Each layer with a piece per kind (the device application, the simulator
binding, the gateway's configuration parser) keeps one table keyed by kind
name and passes it through `per_kind`, which fails at import when the table
and this registry disagree. Adding a kind therefore starts here, and the
imports then name every table still missing it (docs/architecture.md,
"Adding a node kind").

A kind's `index` is its slot in every per-kind ordered output: the Modbus
node and alarm bits, register blocks and restart codes, the order of the
gateway's nodes in snapshots, JSON and Sparkplug. Clients depend on those
positions, so an index never changes once given and a new kind takes the
next one. Profile documents (the object reference, the DBC, the demo's node
table) list kinds by default node-ID instead: `BY_NODE_ID`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TypeVar

from grasplink.errors import ConfigError

__all__ = ["BY_NODE_ID", "KINDS", "NODE_KINDS", "NodeKind", "node_kind", "per_kind"]


@dataclass(frozen=True, slots=True)
class NodeKind:
    name: str  # in configuration, scenes, MQTT topics, Modbus register names
    title: str  # for people and CAN tools (the DBC's node names)
    index: int  # slot in every per-kind ordered output; stable (module docstring)
    node_id: int  # default node-ID
    eds: str  # the shipped EDS, a file beside this module


# In index order; `_check` refuses any other.
NODE_KINDS: tuple[NodeKind, ...] = (
    NodeKind("skin", "Skin", index=0, node_id=0x10, eds="skin.eds"),
    NodeKind("emg", "EMG", index=1, node_id=0x30, eds="emg.eds"),
    NodeKind("belt", "Belt", index=2, node_id=0x20, eds="belt.eds"),
    NodeKind("hand", "Hand", index=3, node_id=0x40, eds="hand.eds"),
)


def _check(kinds: tuple[NodeKind, ...]) -> None:
    if [k.index for k in kinds] != list(range(len(kinds))):
        raise ValueError("NODE_KINDS: indices must be 0, 1, 2, ... in declaration order")
    for field in ("name", "node_id", "eds"):
        values = [getattr(k, field) for k in kinds]
        if len(set(values)) != len(values):
            raise ValueError(f"NODE_KINDS: two kinds share a {field}")


_check(NODE_KINDS)
_BY_NAME = {k.name: k for k in NODE_KINDS}

#: kind names by index: the order of every per-kind ordered output
KINDS: tuple[str, ...] = tuple(_BY_NAME)
#: kind names by default node-ID: the order of the profile documents
BY_NODE_ID: tuple[str, ...] = tuple(k.name for k in sorted(NODE_KINDS, key=lambda k: k.node_id))


def unknown_kind(name: object) -> str:
    """The one message for a name that is not a kind."""
    return f"unknown node kind {name!r}; the kinds are {', '.join(KINDS)}"


def node_kind(name: str) -> NodeKind:
    """The registry entry of `name`; ConfigError naming the kinds there are."""
    try:
        return _BY_NAME[name]
    except (KeyError, TypeError):
        raise ConfigError(unknown_kind(name)) from None


_Piece = TypeVar("_Piece")


def per_kind(what: str, table: Mapping[str, _Piece]) -> dict[str, _Piece]:
    """`table` in index order, after checking it has exactly one entry per registered kind.

    A layer calls this at import on its per-kind table, so a kind added to the registry
    only (or removed from it only) fails at once with the table's name (`what`).
    """
    missing = [k for k in KINDS if k not in table]
    extra = [k for k in table if k not in _BY_NAME]
    if missing or extra:
        problems = [f"no entry for {', '.join(missing)}"] if missing else []
        problems += [f"unregistered {', '.join(map(repr, extra))}"] if extra else []
        raise ValueError(f"{what}: {'; '.join(problems)} (node kinds: grasplink/profiles/kinds.py)")
    return {k: table[k] for k in KINDS}

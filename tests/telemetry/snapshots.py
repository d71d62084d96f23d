"""Gateway snapshots for the sans-IO tests, made by the real `Gateway.snapshot()`."""

from __future__ import annotations

import dataclasses
import typing
from enum import Enum
from typing import Any

from grasplink.core.nmt import NmtState
from grasplink.gateway.config import load_config
from grasplink.gateway.service import Gateway
from grasplink.gateway.snapshot import NodePhase, Snapshot

_TEMPLATE = Gateway(load_config(None)).snapshot()


def _typed(section: Any, values: dict[str, Any]) -> dict[str, Any]:
    """`values` as the section's field types: a phase, mode, ... given by its name."""
    hints = typing.get_type_hints(type(section))
    out = {}
    for name, value in values.items():
        hint = hints[name]
        options = typing.get_args(hint) or (hint,)
        enum = next((t for t in options if isinstance(t, type) and issubclass(t, Enum)), None)
        if enum is NmtState and isinstance(value, str):
            value = NmtState[value]
        elif enum is not None and isinstance(value, str):
            value = enum(value)
        out[name] = value
    return out


def snapshot(uptime_s: float = 1.0, *, phase: str = "operational", **changes: Any) -> Snapshot:
    """Every node in `phase`; `changes` like skin={"slip": True} or nodes={"skin": {...}}
    (enums may be given by their names, as the JSON carries them), alarms={...}."""
    state = NmtState.OPERATIONAL if phase == "operational" else None
    nodes = {
        kind: dataclasses.replace(node, phase=NodePhase(phase), nmt_state=state)
        for kind, node in _TEMPLATE.nodes.items()
    }
    fields: dict[str, Any] = {"uptime_s": uptime_s}
    for section, values in changes.items():
        if section == "nodes":
            for kind, node_values in values.items():
                nodes[kind] = dataclasses.replace(nodes[kind], **_typed(nodes[kind], node_values))
        elif isinstance(values, dict) and section != "alarms":
            current = getattr(_TEMPLATE, section)
            fields[section] = dataclasses.replace(current, **_typed(current, values))
        else:
            fields[section] = values
    return dataclasses.replace(_TEMPLATE, nodes=nodes, **fields)

"""Gateway snapshots for the sans-IO tests, shaped by the real `Gateway.snapshot()`."""

from __future__ import annotations

import copy
from typing import Any

from grasplink.gateway.config import load_config
from grasplink.gateway.service import Gateway

_TEMPLATE = Gateway(load_config(None)).snapshot()


def snapshot(uptime_s: float = 1.0, *, phase: str = "operational", **changes: Any) -> dict:
    """Every node in `phase`; `changes` like skin={"slip": True} or nodes={"skin": {...}}."""
    snap = copy.deepcopy(_TEMPLATE)
    snap["uptime_s"] = uptime_s
    for node in snap["nodes"].values():
        node["phase"] = phase
        node["nmt_state"] = "OPERATIONAL" if phase == "operational" else None
    for section, values in changes.items():
        if section == "nodes":
            for kind, fields in values.items():
                snap["nodes"][kind].update(fields)
        elif isinstance(values, dict):
            snap[section].update(values)
        else:
            snap[section] = values
    return snap

"""Helpers for tests that run a live gateway in real time (threads, buses, servers)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from grasplink.gateway.snapshot import NodePhase


def wait_until(predicate: Callable[[], Any], timeout_s: float = 15.0, what: str = "") -> Any:
    """Poll `predicate` until it is truthy (2 shared cores: be patient, never flaky)."""
    deadline = time.monotonic() + timeout_s
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out waiting for {what or predicate}")
        time.sleep(0.02)


def operational(gateway) -> bool:
    """Every node of the gateway's latest snapshot is operational (a gateway or its edge)."""
    snapshot = gateway.latest
    return snapshot is not None and all(
        n.phase is NodePhase.OPERATIONAL for n in snapshot.nodes.values()
    )

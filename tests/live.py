"""Helpers for tests that run a live gateway in real time (threads, buses, servers)."""

from __future__ import annotations

import queue
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


def first_from(items: queue.Queue, timeout_s: float, wanted: Callable[[Any], Any]) -> Any:
    """What `wanted` makes of the first item a reader thread queues within timeout_s for
    which it is truthy (None if none came); the items before it are taken off the queue."""
    deadline = time.monotonic() + timeout_s
    while (left_s := deadline - time.monotonic()) > 0:
        try:
            item = items.get(timeout=left_s)
        except queue.Empty:
            return None
        found = wanted(item)
        if found:
            return found
    return None


def operational(gateway) -> bool:
    """Every node of the gateway's latest snapshot is operational (a gateway or its edge)."""
    snapshot = gateway.latest
    return snapshot is not None and all(
        n.phase is NodePhase.OPERATIONAL for n in snapshot.nodes.values()
    )

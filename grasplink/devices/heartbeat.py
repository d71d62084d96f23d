"""Heartbeat producer (1017h) and consumer (1016h), CiA 301 7.2.8.3.2."""

from __future__ import annotations

from dataclasses import dataclass

from grasplink.core.frames import HEARTBEAT_BASE
from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.devices.store import ObjectStore, Value
from grasplink.profiles import objects as obj

US_PER_MS = 1000


class HeartbeatProducer:
    """Emits the NMT state every 1017h ms; 0 disables it."""

    def __init__(self, store: ObjectStore):
        self.store = store
        self._next_us: int | None = None
        store.add_listener(self._on_change, (obj.HEARTBEAT_PRODUCER_MS,))
        self.now_us = 0

    def restart(self, t_us: int) -> None:
        self.now_us = t_us
        period = self.period_us
        self._next_us = t_us + period if period else None

    @property
    def period_us(self) -> int:
        return int(self.store.get(obj.HEARTBEAT_PRODUCER_MS)) * US_PER_MS

    def due(self, t_us: int) -> bool:
        """True (and schedules the next one) when a heartbeat is due at t_us."""
        self.now_us = t_us
        if self._next_us is None or t_us < self._next_us:
            return False
        period = self.period_us
        # Keep the grid (no drift); if we fell far behind, skip missed beats.
        missed = (t_us - self._next_us) // period
        self._next_us += (missed + 1) * period
        return True

    def next_deadline_us(self) -> int | None:
        return self._next_us

    def _on_change(self, index: int, subindex: int, value: Value) -> None:
        if index == obj.HEARTBEAT_PRODUCER_MS:
            self.restart(self.now_us)


@dataclass(slots=True)
class _Monitor:
    node_id: int
    timeout_us: int
    last_us: int | None = None  # None: not armed until the first heartbeat
    timed_out: bool = False


class HeartbeatConsumer:
    """Watches other nodes' heartbeats; reports each node whose beat stops.

    Monitoring of a node starts with its first heartbeat (CiA 301), and a
    boot-up from it disarms the monitor until its next heartbeat.
    """

    def __init__(self, store: ObjectStore):
        self.store = store
        self._monitors: dict[int, _Monitor] = {}
        # The heartbeat CAN-IDs 1016h watches (a new set on every change, so a holder can
        # tell by identity): a node's acceptance filter needs no other node's beats.
        self.watched_can_ids: frozenset[int] = frozenset()
        store.add_validator(obj.HEARTBEAT_CONSUMER, self._validate)
        store.add_listener(self._on_change, (obj.HEARTBEAT_CONSUMER,))
        self.reload()

    def reload(self) -> None:
        """Rebuild the monitors from 1016h, keeping the state of unchanged ones."""
        old = self._monitors
        self._monitors = {}
        for sub in self._subindices():
            node_id, time_ms = _split(int(self.store.get(obj.HEARTBEAT_CONSUMER, sub)))
            if node_id and time_ms:
                monitor = old.get(node_id)
                if monitor is None or monitor.timeout_us != time_ms * US_PER_MS:
                    monitor = _Monitor(node_id, time_ms * US_PER_MS)
                self._monitors[node_id] = monitor
        self.watched_can_ids = frozenset(HEARTBEAT_BASE + n for n in self._monitors)

    def reset(self) -> None:
        """NMT reset node / communication: forget every monitor's state, so that
        monitoring restarts with each node's first heartbeat (CiA 301 7.2.8.3.2)."""
        self._monitors = {}
        self.reload()

    def watches(self, node_id: int) -> bool:
        return node_id in self._monitors

    def on_heartbeat(self, node_id: int, state: int, t_us: int) -> bool:
        """Feed a heartbeat; True when it ends a timeout (the node is back)."""
        monitor = self._monitors.get(node_id)
        if monitor is None:
            return False
        recovered = monitor.timed_out
        monitor.timed_out = False
        monitor.last_us = None if state == 0 else t_us
        return recovered

    def expired(self, t_us: int) -> list[int]:
        """Node-IDs whose heartbeat just timed out (each reported once)."""
        lost = []
        for monitor in self._monitors.values():
            if monitor.last_us is not None and t_us > monitor.last_us + monitor.timeout_us:
                monitor.last_us = None
                monitor.timed_out = True
                lost.append(monitor.node_id)
        return lost

    def any_timed_out(self) -> bool:
        return any(m.timed_out for m in self._monitors.values())

    def next_deadline_us(self) -> int | None:
        earliest = None
        for m in self._monitors.values():
            if m.last_us is not None:
                deadline = m.last_us + m.timeout_us + 1
                if earliest is None or deadline < earliest:
                    earliest = deadline
        return earliest

    def _subindices(self) -> list[int]:
        if not self.store.has(obj.HEARTBEAT_CONSUMER, 0):  # optional (CiA 301): no watch
            return []
        parent = self.store.entry(obj.HEARTBEAT_CONSUMER, 0).var.parent
        return sorted(s for s in parent.subindices if s) if parent is not None else []

    def _validate(self, index: int, subindex: int, value: Value) -> None:
        node_id, time_ms = _split(int(value))
        if not (node_id and time_ms):
            return
        if node_id > 127:
            raise SdoAbort(AbortCode.INVALID_VALUE, f"node-ID {node_id} outside 1..127")
        for sub in self._subindices():
            if sub == subindex:
                continue
            other_id, other_ms = _split(int(self.store.get(obj.HEARTBEAT_CONSUMER, sub)))
            if other_id == node_id and other_ms:
                raise SdoAbort(
                    AbortCode.PARAMETER_INCOMPATIBLE,
                    f"node 0x{node_id:02X} is already monitored by 1016h:{sub:02X}",
                )

    def _on_change(self, index: int, subindex: int, value: Value) -> None:
        if index == obj.HEARTBEAT_CONSUMER:
            self.reload()


def _split(entry: int) -> tuple[int, int]:
    """1016h entry -> (node-ID, consumer time in ms)."""
    return (entry >> 16) & 0xFF, entry & 0xFFFF

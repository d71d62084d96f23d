"""Bounded queues between the gateway and the broker; both drop the oldest and count it.

- `SnapshotQueue`: snapshots waiting for the next publish tick. Whoever fills it
  never waits: when full the oldest snapshot goes.
- `Outbox`: the messages of one broker connection, in order, bounded in bytes.
  It is the send queue while connected and the store-and-forward buffer while
  the broker is away: nothing is removed until the broker took it, what the
  bound pushes out is counted (messages and bytes) and reported.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from grasplink.gateway.snapshot import Snapshot

# What one buffered message costs beyond its topic and payload (the Message, its bytes and
# str objects and the deque slot, measured with tracemalloc: benchmarks/bench_telemetry.py).
MESSAGE_OVERHEAD_BYTES = 220
SNAPSHOT_QUEUE_SIZE = 256  # 12.8 s of 20 Hz snapshots: far beyond any sane publish period


@dataclass(slots=True)
class Message:
    """One MQTT publication; `meta` is for the protocol that made it (Sparkplug: session,
    kind, device, so it can sequence the message when it is actually sent)."""

    topic: str
    payload: bytes
    qos: int = 0
    retain: bool = False
    meta: Any = None

    @property
    def size_bytes(self) -> int:
        return len(self.topic) + len(self.payload) + MESSAGE_OVERHEAD_BYTES


@dataclass(frozen=True, slots=True)
class Sample:
    """A gateway snapshot and when it was made (wall clock, ms since the epoch)."""

    ts_ms: int
    snapshot: Snapshot


class SnapshotQueue:
    """Snapshots for the next publish tick; full: the oldest is dropped and counted."""

    def __init__(self, size: int = SNAPSHOT_QUEUE_SIZE):
        self._items: deque[Sample] = deque(maxlen=size)
        self.dropped = 0

    def put(self, sample: Sample) -> None:
        if len(self._items) == self._items.maxlen:
            self.dropped += 1
        self._items.append(sample)

    def drain(self) -> list[Sample]:
        items = list(self._items)
        self._items.clear()
        return items

    def __len__(self) -> int:
        return len(self._items)


class Outbox:
    """Messages in order, at most `max_bytes` (topic + payload + overhead each)."""

    def __init__(self, max_bytes: int):
        if max_bytes <= 0:
            raise ValueError("max_bytes must be positive")
        self.max_bytes = max_bytes
        self._items: deque[Message] = deque()
        self.bytes = 0
        self.dropped_messages = 0
        self.dropped_bytes = 0
        self.peak_bytes = 0
        self._reported = (0, 0)

    def push(self, message: Message) -> None:
        """Append; the oldest messages go (counted) while the bound is exceeded."""
        self._items.append(message)
        self.bytes += message.size_bytes
        self._trim()

    def extend(self, messages: Iterable[Message]) -> None:
        for message in messages:
            self.push(message)

    def requeue(self, messages: list[Message]) -> None:
        """Put messages taken but not delivered back in front, in their order."""
        for message in reversed(messages):
            self._items.appendleft(message)
            self.bytes += message.size_bytes
        self._trim()

    def take(self, count: int) -> list[Message]:
        """The oldest `count` messages (fewer if there are fewer), removed."""
        taken: list[Message] = []
        while self._items and len(taken) < count:
            message = self._items.popleft()
            self.bytes -= message.size_bytes
            taken.append(message)
        return taken

    def drops_since_report(self) -> tuple[int, int]:
        """(messages, bytes) dropped since the last call: for one log line per outage."""
        before = self._reported
        self._reported = (self.dropped_messages, self.dropped_bytes)
        return self.dropped_messages - before[0], self.dropped_bytes - before[1]

    def _trim(self) -> None:
        while self.bytes > self.max_bytes and self._items:
            message = self._items.popleft()
            self.bytes -= message.size_bytes
            self.dropped_messages += 1
            self.dropped_bytes += message.size_bytes
        self.peak_bytes = max(self.peak_bytes, self.bytes)

    def __len__(self) -> int:
        return len(self._items)

    def __bool__(self) -> bool:
        return bool(self._items)

"""The live edge of one gateway: what a sans-IO `Gateway` must not do itself.

The `Gateway` is fed time and frames and never reads a clock or meets another thread.
Live, a runner drives a `GatewayEdge` around it instead, which adds the two things
that need the world outside:

- a **mailbox** for commands from other threads (MQTT, Modbus): `post` queues one
  and returns a Future; the edge hands the queued commands to `Gateway.execute` on
  the gateway's own thread at its next `advance`, so the gateway's state is only
  ever touched by that thread. A full mailbox refuses at once ("too many commands
  waiting"), so a flood of writes cannot queue without bound;
- the **loop latency**: the wall-clock time the gateway takes from a skin TPDO to the
  RPDOs it causes, measured here and handed to the gateway as an input
  (`Gateway.loop_latency_us`, which its snapshot reports).

Surfaces take the edge where they used to take the gateway: `latest` is the gateway's
latest snapshot, `post` the mailbox.
"""

from __future__ import annotations

import queue
import time
from concurrent.futures import Future

from grasplink.core.frames import TPDO_BASES, Frame
from grasplink.gateway.commands import Command, CommandResult
from grasplink.gateway.service import Gateway
from grasplink.gateway.snapshot import Snapshot

MAILBOX_SIZE = 64  # commands waiting for the gateway's thread; more is a flood, refused
FULL = "too many commands waiting"


class Mailbox:
    """Commands posted from other threads, taken on the gateway's."""

    def __init__(self, size: int = MAILBOX_SIZE):
        self._queue: queue.Queue[tuple[Command, Future[CommandResult]]] = queue.Queue(size)

    def post(self, command: Command) -> Future[CommandResult]:
        """Queue a command; the Future resolves when the gateway has executed or refused it."""
        future: Future[CommandResult] = Future()
        try:
            self._queue.put_nowait((command, future))
        except queue.Full:
            future.set_result(CommandResult(command.name, False, FULL))
        return future

    def drain(self) -> list[tuple[Command, Future[CommandResult]]]:
        items = []
        while True:
            try:
                items.append(self._queue.get_nowait())
            except queue.Empty:
                return items

    def __bool__(self) -> bool:
        return not self._queue.empty()


class GatewayEdge:
    """A `Gateway` as a live runner drives it (a sans-IO device like the gateway itself),
    with its mailbox and its wall-clock loop latency; see module docstring."""

    def __init__(self, gateway: Gateway, *, mailbox_size: int = MAILBOX_SIZE):
        self.gateway = gateway
        self.node_id = gateway.node_id
        self.mailbox = Mailbox(mailbox_size)
        skin = gateway.by_kind.get("skin")
        # the frames whose processing is timed: the skin's TPDOs
        self._timed = frozenset(
            () if skin is None else (base + skin.node_id for base in TPDO_BASES)
        )

    @property
    def latest(self) -> Snapshot | None:
        """The gateway's latest snapshot (replaced whole on its thread: read without locks)."""
        return self.gateway.latest

    def post(self, command: Command) -> Future[CommandResult]:
        """Thread-safe: queue a command for the gateway's thread."""
        return self.mailbox.post(command)

    # -- the sans-IO device a runner drives --------------------------------------------------
    def start(self, t_us: int) -> list[Frame]:
        return self.gateway.start(t_us)

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        if frame.can_id not in self._timed:
            return self.gateway.receive(frame, t_us)
        started_ns = time.perf_counter_ns()
        frames = self.gateway.receive(frame, t_us)
        if frames:
            self.gateway.loop_latency_us.append((time.perf_counter_ns() - started_ns) / 1000)
        return frames

    def advance(self, t_us: int) -> list[Frame]:
        frames: list[Frame] = []
        for command, future in self.mailbox.drain():
            result, sent = self.gateway.execute(command, t_us)
            frames += sent
            future.set_result(result)
        return frames + self.gateway.advance(t_us)

    def stream_can_ids(self) -> frozenset[int]:
        """The gateway's counted streams (`StreamConsumer`): the runner drops none of them."""
        return self.gateway.stream_can_ids()

    def next_deadline_us(self) -> int | None:
        due = self.gateway.next_deadline_us()
        if self.mailbox:  # a command waits: now
            now = self.gateway.now_us
            return now if due is None else min(due, now)
        return due

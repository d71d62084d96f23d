"""The writer of one broker connection: drains its `Outbox` through aiomqtt's `publish`.

Store-and-forward: a message leaves the outbox when it is handed to the client and is
counted sent only once the broker took it (QoS 1: its PUBACK; QoS 0: written to the
socket); whatever the broker had not taken when the connection ends goes back in front
of the outbox, in order, for the next connection. Order: publications start in the order
they were queued (asyncio runs new tasks first in, first out, and each hands its message
to paho at its first step). Back-pressure: at most `window` messages in flight; the rest
wait in the bounded outbox, which drops its oldest when full.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
import time
from collections.abc import Callable
from functools import partial

import aiomqtt

from grasplink.surfaces.telemetry.buffer import Message, Outbox
from grasplink.surfaces.telemetry.protocol import TelemetryProtocol

# Publications in flight at most. MQTT 5 brokers say in CONNACK how many unacknowledged
# QoS 1 publications they take (Receive Maximum; mosquitto's default is 20) and aiomqtt does
# not expose it, so the window is one no broker we know of refuses.
WINDOW = 20


class Writer:
    """Publishes what the protocol queued, while attached to a connected client."""

    def __init__(
        self,
        protocol: TelemetryProtocol,
        outbox: Outbox,
        *,
        window: int = WINDOW,
        on_failure: Callable[[], None] = lambda: None,
    ):
        self.protocol = protocol
        self.outbox = outbox
        self.window = window
        self.on_failure = on_failure  # a publication failed: the session ends the connection
        self.sent = 0
        self.failure: BaseException | None = None
        self.paused = False  # a new session is coming: nothing more from the outbox
        self.progress_at = 0.0  # monotonic time the broker last took a message
        self._client: aiomqtt.Client | None = None
        self._in_flight: dict[int, Message] = {}  # in order; as made (finalized again if resent)
        self._tasks: dict[int, asyncio.Task[None]] = {}
        self._count = 0
        self._empty = asyncio.Event()
        self._empty.set()

    @property
    def in_flight(self) -> int:
        """Publications handed to the client, not yet taken by the broker."""
        return len(self._in_flight)

    def attach(self, client: aiomqtt.Client) -> None:
        self._client = client
        self.failure = None
        self.paused = False
        self.progress_at = time.monotonic()

    async def detach(self) -> None:
        """Stop publishing; what the broker did not take goes back in front of the outbox."""
        self._client = None
        tasks = list(self._tasks.values())
        for task in tasks:
            task.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        if self._in_flight:
            self.outbox.requeue(list(self._in_flight.values()))
            self._in_flight.clear()
        self._empty.set()

    def push(self, messages: list[Message]) -> None:
        """Queue messages behind what waits, and publish what the window has room for."""
        self.outbox.extend(messages)
        self.drain()

    def send_now(self, messages: list[Message]) -> None:
        """Publish ahead of the outbox and beyond the window (births, replies that must
        lead, a goodbye); without a connection they wait in front of the outbox."""
        client = self._client
        if client is None:
            self.outbox.requeue(messages)
            return
        for message in messages:
            self._publish(client, message)

    def drain(self) -> None:
        """Publish from the outbox while the window has room (attached, not holding)."""
        client = self._client
        if client is None or self.paused or self.protocol.holding or not self.outbox:
            return
        room = self.window - len(self._in_flight)
        if room > 0:
            for message in self.outbox.take(room):
                self._publish(client, message)

    def stalled(self, now: float, after_s: float) -> bool:
        """Whether publications wait and the broker took none for `after_s`."""
        return bool(self._in_flight) and now - self.progress_at > after_s

    async def settled(self, timeout_s: float) -> None:
        """Wait (at most `timeout_s`) until the broker took everything in flight."""
        with contextlib.suppress(TimeoutError):
            await asyncio.wait_for(self._empty.wait(), timeout_s)

    def _publish(self, client: aiomqtt.Client, message: Message) -> None:
        final = self.protocol.finalize(message)
        if final is None:
            return
        if not self._in_flight:
            self.progress_at = time.monotonic()
        key = self._count
        self._count += 1
        self._in_flight[key] = message
        self._empty.clear()
        # timeout=inf: aiomqtt then awaits the acknowledgement without a task and a timer of
        # its own per message; the session's watch ends a connection that stopped taking
        task = asyncio.create_task(
            client.publish(final.topic, final.payload, final.qos, final.retain, timeout=math.inf)
        )
        self._tasks[key] = task
        task.add_done_callback(partial(self._done, key))

    def _done(self, key: int, task: asyncio.Task[None]) -> None:
        self._tasks.pop(key, None)
        if task.cancelled():
            return
        error = task.exception()
        if error is not None:  # the connection is gone: the message stays, to be requeued
            if self.failure is None:
                self.failure = error
                self._empty.set()  # nothing more will be taken: whoever waits, stop
                self.on_failure()
            return
        if self._in_flight.pop(key, None) is None:
            return
        self.sent += 1
        self.progress_at = time.monotonic()
        if len(self._in_flight) <= self.window // 2:
            self.drain()  # refilled half a window at a time: writes go out together
        if not self._in_flight:
            self._empty.set()

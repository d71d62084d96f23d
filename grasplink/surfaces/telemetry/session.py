"""The session of one broker connection: connect with the protocol's Will, subscribe, hand
the client to the `Writer`, reconnect with back-off, say goodbye on a clean stop.

Only aiomqtt's public API: a new `aiomqtt.Client` per attempt (the Will is fixed at
construction, and Sparkplug's changes with each CONNECT: its bdSeq), entered as an async
context manager (CONNECT, then DISCONNECT on the way out), `subscribe`, `messages`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import socket
import ssl
import time
from collections.abc import Callable

import aiomqtt
from paho.mqtt.subscribeoptions import SubscribeOptions

from grasplink.errors import BrokerError
from grasplink.surfaces.telemetry.protocol import TelemetryProtocol
from grasplink.surfaces.telemetry.url import BrokerUrl
from grasplink.surfaces.telemetry.writer import WINDOW, Writer

CONNECT_TIMEOUT_S = 5.0  # CONNACK, SUBACK, births; and a broker taking nothing this long
BACKOFF_MIN_S, BACKOFF_MAX_S = 0.5, 10.0
FLUSH_S = 2.0  # a clean stop sends what is buffered for at most this long
STILL_DOWN_S = 30.0  # while the broker stays away, a reminder this often
WATCH_S = 2.0  # a connected session looks at the writer's progress this often
PROTOCOL = aiomqtt.ProtocolVersion.V5  # for retain-as-published on the command topics
# Commands: the retain flag as the publisher set it, also on a message forwarded live (MQTT
# 5; MQTT 3.1.1 clears it), so a retained command is refused however it arrives.
COMMAND_OPTIONS = SubscribeOptions(qos=1, retainAsPublished=True)
Log = Callable[[str], None]
# paho's own messages (socket errors on a lost broker) stay out of the terminal: the session
# logs what matters in one line; an application that configures logging still gets them.
MQTT_LOGGER = logging.getLogger("grasplink.telemetry.mqtt")
MQTT_LOGGER.addHandler(logging.NullHandler())


def now_ms() -> int:
    return time.time_ns() // 1_000_000


class Session:
    """Keeps one protocol's connection up until stopped; the first failure to connect ends
    it (`first` carries the BrokerError: a start-up error)."""

    def __init__(
        self,
        protocol: TelemetryProtocol,
        writer: Writer,
        url: BrokerUrl,
        client_id: str,
        tls: ssl.SSLContext | None,
        log: Log,
        on_message: Callable[[str, bytes, bool], None],
        *,
        backoff_s: tuple[float, float] = (BACKOFF_MIN_S, BACKOFF_MAX_S),
        on_will: Callable[[], None] | None = None,
    ):
        self.protocol = protocol
        self.writer = writer
        self.url = url
        self.client_id = client_id
        self.tls = tls
        self.log = log
        self.on_message = on_message  # (topic, payload, retain) of a subscribed topic
        self.backoff_s = backoff_s
        self.on_will = on_will  # after each will(): Sparkplug saves the bdSeq it will use
        self.connected = False
        self.connections = 0
        self.down_since: float | None = None
        self.last_error = ""
        self.first: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self.stopping = asyncio.Event()
        self._wake = asyncio.Event()
        self._reconnect = ""  # why the protocol asked for a new MQTT session
        self._reported_down_at: float | None = None
        writer.on_failure = self._wake.set

    def stop(self) -> None:
        self.stopping.set()
        self._wake.set()

    def reconnect(self, why: str) -> None:
        """End this MQTT session with a goodbye and start a new one at once."""
        self._reconnect = why
        self.writer.paused = True
        self._wake.set()

    async def run(self) -> None:
        low, high = self.backoff_s
        delay = low
        connect_sent = True
        while not self.stopping.is_set():
            client = self._client(new_connect=connect_sent)
            entered = False
            try:
                async with client:
                    entered = True
                    self._up()
                    delay = low
                    await self._connected(client)
            except aiomqtt.MqttError as exc:
                self.last_error = str(exc) or type(exc).__name__
                # A refusal (CONNACK) or a CONNACK that never came followed a CONNECT; a
                # refused TCP connection or a failed TLS handshake did not.
                connect_sent = (
                    entered or isinstance(exc, aiomqtt.MqttCodeError) or "timed out" in str(exc)
                )
            else:
                connect_sent = True
            finally:
                self._down()
            if not self.first.done():
                self.first.set_exception(BrokerError(self._refusal()))
                return
            if self.stopping.is_set():
                break
            if self._reconnect:  # asked for by the protocol: at once, no back-off
                self.log(f"telemetry {self.protocol.name}: {self._reconnect}; new MQTT session")
                self._reconnect = ""
                continue
            self._report_down(delay)
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self.stopping.wait(), delay * random.uniform(0.8, 1.0))
            delay = min(high, delay * 2)
        if self.writer.outbox:
            self.log(
                f"telemetry {self.protocol.name}: stopped with "
                f"{len(self.writer.outbox)} messages unsent"
            )

    def _client(self, *, new_connect: bool) -> aiomqtt.Client:
        will = self.protocol.will(now_ms(), new_connect=new_connect)
        if self.on_will is not None:
            self.on_will()
        client = aiomqtt.Client(
            self.url.host,
            self.url.port,
            username=self.url.username,
            password=self.url.password,
            identifier=self.client_id,
            will=aiomqtt.Will(will.topic, will.payload, will.qos, will.retain),
            keepalive=self.url.keepalive_s,
            tls_context=self.tls,
            timeout=CONNECT_TIMEOUT_S,
            logger=MQTT_LOGGER,
            # Small messages in a row: without this, Nagle holds each behind the broker's
            # delayed ACK (40 ms on Linux).
            socket_options=((socket.IPPROTO_TCP, socket.TCP_NODELAY, 1),),
            protocol=PROTOCOL,
            # MQTT 5 (Sparkplug 3.0 asks the same of an edge node): a new session at every
            # connection, none kept after it (session expiry interval 0: unset)
            clean_start=True,
            max_inflight_messages=WINDOW,
        )
        # births and a replay go out beside the window: no warning for those
        client.pending_calls_threshold = 4 * WINDOW
        return client

    async def _connected(self, client: aiomqtt.Client) -> None:
        for topic in self.protocol.subscriptions():
            await client.subscribe(topic, options=COMMAND_OPTIONS)
        self._reconnect = ""
        writer = self.writer
        writer.attach(client)
        try:
            first, after = self.protocol.on_connect(now_ms())
            writer.send_now(first)
            await writer.settled(CONNECT_TIMEOUT_S)
            self._check(None)
            writer.push(after)
            if not self.first.done():  # start() returns (and snapshots flow) once births are out
                self.first.set_result(None)
            receiver = asyncio.create_task(self._receive(client))
            receiver.add_done_callback(lambda _: self._wake.set())
            try:
                await self._watch(receiver)
                if self.stopping.is_set() or self._reconnect:
                    writer.paused = True
                    writer.send_now(self.protocol.goodbye(now_ms()))
                    await writer.settled(FLUSH_S)
            finally:
                receiver.cancel()
                await asyncio.gather(receiver, return_exceptions=True)
        finally:
            await writer.detach()

    async def _watch(self, receiver: asyncio.Task[None]) -> None:
        """While connected: wait for the end (stop, a lost connection, a failed publication,
        a broker that stopped taking them, a new session asked for). A clean stop first
        sends what is buffered, for at most FLUSH_S."""
        while not (self.stopping.is_set() or self._reconnect):
            self._check(receiver)
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), WATCH_S)
        if self.stopping.is_set() and not self._reconnect:
            await self.writer.settled(FLUSH_S)

    def _check(self, receiver: asyncio.Task[None] | None) -> None:
        """MqttError if the connection cannot go on."""
        if receiver is not None and receiver.done():
            raise aiomqtt.MqttError(self._receiver_error(receiver))
        writer = self.writer
        if writer.failure is not None:
            raise aiomqtt.MqttError(str(writer.failure) or type(writer.failure).__name__)
        if writer.stalled(time.monotonic(), CONNECT_TIMEOUT_S):
            raise aiomqtt.MqttError(f"{writer.in_flight} publications not acknowledged")

    async def _receive(self, client: aiomqtt.Client) -> None:
        async for message in client.messages:
            payload = message.payload  # paho hands it over as bytes
            data = payload if isinstance(payload, bytes) else str(payload or "").encode()
            self.on_message(message.topic.value, data, bool(message.retain))

    @staticmethod
    def _receiver_error(receiver: asyncio.Task[None]) -> str:
        if receiver.cancelled():
            return "receiver cancelled"
        exc = receiver.exception()
        cause = exc.__cause__ if exc is not None and exc.__cause__ is not None else exc
        return str(cause) if cause is not None else "connection closed"

    # -- what the log says ---------------------------------------------------------------
    def _up(self) -> None:
        self._reported_down_at = None
        self.connected = True
        self.connections += 1
        if self.connections == 1:
            return
        outbox = self.writer.outbox
        outage = time.monotonic() - self.down_since if self.down_since else 0.0
        dropped, dropped_bytes = outbox.drops_since_report()
        line = (
            f"telemetry {self.protocol.name}: back on {self.url.display} after {outage:.1f} s; "
            f"replaying {len(outbox)} messages ({outbox.bytes / 1024:.0f} KiB)"
        )
        if dropped:
            line += (
                f"; dropped the {dropped} oldest ({dropped_bytes / 1024:.0f} KiB) over the "
                f"{outbox.max_bytes // 1024} KiB bound"
            )
        self.log(line)

    def _down(self) -> None:
        if self.connected:
            self.down_since = time.monotonic()
        self.connected = False

    def _report_down(self, delay: float) -> None:
        """One line when the broker goes, then one every STILL_DOWN_S while it stays away."""
        now = time.monotonic()
        outbox = self.writer.outbox
        if self._reported_down_at is None:
            self.log(
                f"telemetry {self.protocol.name}: lost {self.url.display} ({self.last_error}); "
                f"buffering up to {outbox.max_bytes // 1024} KiB, retrying in {delay:.1f} s"
            )
        elif now - self._reported_down_at >= STILL_DOWN_S:
            away = now - (self.down_since or now)
            self.log(
                f"telemetry {self.protocol.name}: {self.url.display} still away after "
                f"{away:.0f} s ({self.last_error}); {len(outbox)} messages buffered "
                f"({outbox.bytes / 1024:.0f} KiB)"
            )
        else:
            return
        self._reported_down_at = now

    def _refusal(self) -> str:
        error = self.last_error
        if "code:" in error or "Not authorized" in error or "not authorised" in error:
            return f"MQTT broker {self.url.display} refused the connection: {error}"
        return f"cannot reach MQTT broker {self.url.display}: {error}"

"""The MQTT edge: aiomqtt in its own thread and event loop, never on the gateway's thread.

`TelemetryPublisher` reads `gateway.latest` (a `Snapshot` replaced whole at 20 Hz, so
reading it needs no lock), stamps each new snapshot with the wall-clock time it
was made, and queues it (`SnapshotQueue`: bounded, drop-oldest, counted). At
most `rate_hz` times a second the queued snapshots go through each protocol
(JSON tree, Sparkplug session) into that connection's `Outbox`, the bounded
store-and-forward buffer a sender drains while the broker is there. A lost
broker is retried with back-off; on its return the buffer is replayed in order
and what the bound dropped is logged and published (health, Telemetry/ metrics).
Commands read from the broker are posted to the gateway's mailbox (`gateway.post`, the
live edge `grasplink.gateway.edge.GatewayEdge`), their
results answered by the protocol that received them.

One connection per protocol: each has its own Will (JSON `status` offline,
Sparkplug NDEATH), which MQTT allows only one of per connection.

A window of messages is handed to paho and then written at once, on this thread, in one
system call: one TCP segment for the window rather than one per message, and no trip
through the event loop's self-pipe to register the socket for writing (what aiomqtt does
for every first publication after an idle spell). Messages are sent straight from the
pump's callback (`push`), so a snapshot's messages cost no task switch
(benchmarks/bench_telemetry.py). Once a connection is caught up, the event loop stops
watching its socket and the pump's ticks read it (`MqttLink.poll_reads`): a thread that
wakes costs its work several times over on cold caches, so wake-ups are kept to the ticks.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import random
import select
import socket
import ssl
import threading
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any, Protocol

import aiomqtt
import paho.mqtt.client as paho
from paho.mqtt.subscribeoptions import SubscribeOptions

from grasplink.errors import BrokerError
from grasplink.gateway.commands import Command, CommandResult
from grasplink.gateway.service import SNAPSHOT_PERIOD_US
from grasplink.gateway.snapshot import Snapshot
from grasplink.surfaces.telemetry.buffer import Message, Outbox, Sample, SnapshotQueue
from grasplink.surfaces.telemetry.json_tree import JsonTree
from grasplink.surfaces.telemetry.protocol import (
    CommandRequest,
    TelemetryProtocol,
    apply_result,
    same_report,
)
from grasplink.surfaces.telemetry.sparkplug import SparkplugSession
from grasplink.surfaces.telemetry.state import BdSeqFile
from grasplink.surfaces.telemetry.url import BrokerUrl

DEFAULT_RATE_HZ = 20.0
CONNECT_TIMEOUT_S = 5.0
COMMAND_TIMEOUT_S = 2.0  # the gateway answers at its next advance(), normally within 100 ms
BACKOFF_MIN_S, BACKOFF_MAX_S = 0.5, 10.0
WINDOW = 64  # messages published before waiting for the broker's acknowledgements
FLUSH_S = 2.0  # a clean stop sends what is buffered for at most this long
STILL_DOWN_S = 30.0  # while the broker stays away, a reminder this often
POLL_S = 0.001  # looking for the next snapshot once it is due
FIRST_SNAPSHOT_S = 1.0  # the first connection waits at most this for the gateway's first snapshot
WATCH_S = 2.0  # a session checks its acknowledgements this often (CONNECT_TIMEOUT_S)
READ_EVERY_S = 0.2  # steady state: the socket read this often (sooner, the window half full)
SNAPSHOT_PERIOD_S = SNAPSHOT_PERIOD_US / 1e6
PUBACK_TYPE = 0x40  # fixed header of a PUBACK (then its length: 2 the ID, 3-4 with a reason)
PROTOCOL = aiomqtt.ProtocolVersion.V5  # for retain-as-published on the command topics
# Commands: the retain flag as the publisher set it, also on a message forwarded live (MQTT
# 5; MQTT 3.1.1 clears it), so a retained command is refused however it arrives.
COMMAND_OPTIONS = SubscribeOptions(qos=1, retainAsPublished=True)
TOPIC_CACHE = 256  # encoded topics kept (gateway topics, and replies to commands' names)
# what the fast write and read paths use of paho's client (paho-mqtt 2.1/2.2, with aiomqtt 2.5.1)
PAHO_INTERNALS = (
    "_out_packet",
    "_out_messages",
    "_out_message_mutex",
    "_inflight_messages",
    "_max_inflight_messages",
    "_update_inflight",
    "_in_packet",
    "_sock_recv",
    "_last_msg_out",
    "_last_bytes_received",
    "_call_socket_unregister_write",
    "_mid_generate",
    "_sock",
    "_protocol",
)

RATE_BURST = 1.5  # publish credit kept: a snapshot a little early (jitter) still goes at once
Log = Callable[[str], None]
# paho's own messages (socket errors on a lost broker) stay out of the terminal: the links
# log what matters in one line; an application that configures logging still gets them.
MQTT_LOGGER = logging.getLogger("grasplink.telemetry.mqtt")
MQTT_LOGGER.addHandler(logging.NullHandler())


class GatewayLike(Protocol):
    """What telemetry needs of a gateway (its live edge, `grasplink.gateway.edge.GatewayEdge`)."""

    @property
    def latest(self) -> Snapshot | None: ...

    def post(self, command: Command) -> Future[CommandResult]: ...


def now_ms() -> int:
    return time.time_ns() // 1_000_000


def _cork(sock: Any, on: bool) -> bool:
    """TCP_CORK on or off (Linux); False where it cannot be set (then writes go as they are)."""
    try:
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_CORK, 1 if on else 0)
    except (AttributeError, OSError):
        return False
    return True


class _Written:
    """The `info` of a packet queued by `MqttLink._queue_packets`: paho marks a written QoS 0
    packet published through it; nobody waits on it (the link tracks its messages by ID)."""

    __slots__ = ()

    def _set_as_published(self) -> None:
        pass


_WRITTEN = _Written()


def _remaining_length(length: int) -> bytes:
    """MQTT's variable-length integer (1 to 4 bytes, 7 bits each, least significant first)."""
    if length < 0x80:
        return bytes((length,))
    out = bytearray()
    while True:
        digit, length = length & 0x7F, length >> 7
        out.append(digit | 0x80 if length else digit)
        if not length:
            return bytes(out)


class SnapshotClock:
    """When a snapshot was made, on the wall clock, from its `uptime_s`.

    The gateway's clock and ours are both monotonic: the smallest `seen - uptime`
    so far is the gateway's start to within the quickest poll's delay, so stamps
    do not carry the polling delay. A jump of more than `RESTART_S` is a new gateway.
    """

    RESTART_S = 0.5

    def __init__(self) -> None:
        self.origin_s: float | None = None

    def stamp_ms(self, uptime_s: float, seen_mono_s: float, wall_minus_mono_s: float) -> int:
        origin = seen_mono_s - uptime_s
        if self.origin_s is None or origin < self.origin_s or origin - self.origin_s > 0.5:
            self.origin_s = origin
        return round((self.origin_s + uptime_s + wall_minus_mono_s) * 1000)


class MqttLink:
    """One broker connection for one protocol: connect, reconnect, send, receive."""

    def __init__(
        self,
        protocol: TelemetryProtocol,
        url: BrokerUrl,
        client_id: str,
        tls: ssl.SSLContext | None,
        log: Log,
        execute: Callable[[Command], Awaitable[CommandResult]],
        *,
        backoff_s: tuple[float, float] = (BACKOFF_MIN_S, BACKOFF_MAX_S),
        on_will: Callable[[], None] | None = None,
    ):
        self.protocol = protocol
        self.on_will = on_will  # after each will(): Sparkplug saves the bdSeq it will use
        self.url = url
        self.client_id = client_id
        self.tls = tls
        self.log = log
        self.execute = execute
        self.backoff_s = backoff_s
        self.outbox = Outbox(url.buffer_bytes)
        self.connected = False
        self.connections = 0
        self.sent = 0
        self.down_since: float | None = None
        self.last_error = ""
        self.first: asyncio.Future[None] = asyncio.get_running_loop().create_future()
        self.stopping = asyncio.Event()
        self._wake = asyncio.Event()
        self._answers: set[asyncio.Task[None]] = set()
        self._reported_down_at: float | None = None
        # Published, not yet taken by the broker (QoS 1: PUBACK; QoS 0: written), in order:
        # paho message ID -> the message as made (finalized again if it must be resent).
        self._inflight: dict[int, Message] = {}
        self._progress_at = 0.0  # when the broker last took one (or the window was empty)
        self._inner: paho.Client | None = None  # while a session runs
        self._client: aiomqtt.Client | None = None
        self._batching = False  # a window is being handed to paho: _flush writes it
        self._fast = False  # paho's internals are the ones the fast paths know
        self._register_write: Callable[..., None] | None = None  # aiomqtt's own
        self._reconnect = ""  # why the protocol asked for a new MQTT session
        self._refill: asyncio.Handle | None = None
        self._settling = False  # _settled waits for the window to empty
        self._topics: dict[str, bytes] = {}  # topic -> its UTF-8 with the length in front
        self._reader: Callable[[], None] | None = None  # reads what the broker sent
        self._read_acks: Callable[[], bool] | None = None  # PUBACKs read without paho
        self._readable: tuple[int, select.poll] | None = None  # (fd, a poll object for it)
        self._steady = False  # set up, not stopping: the pump's ticks may read the socket
        self._polled: int | None = None  # the fd the ticks read (the loop does not watch it)
        self._polled_at = 0.0
        # messages in flight at most: WINDOW, or fewer if the broker's CONNACK says it
        # takes fewer unacknowledged (MQTT 5 Receive Maximum; paho does not apply it)
        self.window = WINDOW
        self._v5 = False  # the session speaks MQTT 5 (PUBLISH packets carry properties)

    def push(self, messages: list[Message]) -> None:
        """Queue messages and, connected, publish at once (on this thread, no task switch).
        With nothing waiting ahead of them and room in the window they go straight out:
        the outbox is for what must wait (and whatever `_publish_now` cannot send goes
        back into it)."""
        if not messages:
            return
        if (
            not self.outbox
            and self._inner is not None
            and len(self._inflight) + len(messages) <= self.window
            and not self.protocol.holding
            and not self._reconnect
        ):
            self._publish_now(messages)
            return
        self.outbox.extend(messages)
        self._drain()

    def read_acknowledgements(self) -> None:
        """Read the broker's PUBACKs now if they are already there (a poll(2), no wait): a
        window's acknowledgements come a fraction of a millisecond after it was written,
        and reading them at the end of the tick that wrote it, while its code and data are
        still in the CPU's caches, spares the event loop a wake-up for them. If they are
        not there yet, the loop's reader takes them. In steady state the ticks read the
        socket instead (`poll_reads`)."""
        if self._inflight and self._polled is None:
            self._read_if_readable()

    def poll_reads(self, now: float) -> None:
        """The pump's tick. In steady state (connected, births out, nothing waiting in the
        outbox) the event loop stops watching the socket, and a tick reads what came every
        READ_EVERY_S, or once half the window waits for its PUBACKs: acknowledgements
        taken a dozen at a time (one poll and one recv), commands, pings and a closed
        connection seen within READ_EVERY_S. The JSON tree's PUBACKs, read at the end of
        each tick or by a wake-up of the loop when late, cost its thread about 2.2
        wake-ups per snapshot and 11 % of its CPU in the slipping scene (interleaved
        runs: 0.95 -> 0.84 % of a core, wake-ups 42 -> 25 a second). QoS stays 1 and a
        window is still resent if the connection dies before it was acknowledged. A
        backlog (a replay after an outage) is read as it arrives, to refill the window."""
        inner = self._inner
        if inner is None or not self._fast or self._reader is None:
            return
        if self._polled is None:
            sock = inner.socket()
            if self._steady and not self.outbox and sock is not None:
                self._polled = sock.fileno()
                self._polled_at = now
                asyncio.get_running_loop().remove_reader(self._polled)
            return
        if self.outbox or not self._steady:
            self._watch_reads()
            return
        if len(self._inflight) >= self.window // 2 or now - self._polled_at >= READ_EVERY_S:
            self._polled_at = now
            self._read_if_readable(always=True)

    def _watch_reads(self) -> None:
        """Back to the event loop watching the socket (aiomqtt's reader), if the ticks read it."""
        fd, self._polled = self._polled, None
        inner, reader = self._inner, self._reader
        sock = inner.socket() if inner is not None else None
        if fd is None or sock is None or sock.fileno() != fd or reader is None:
            return  # closed meanwhile: the next connection's socket is watched by aiomqtt
        asyncio.get_running_loop().add_reader(fd, reader)
        reader()  # whatever came since the last tick

    def _read_if_readable(self, *, always: bool = False) -> None:
        inner, reader = self._inner, self._reader
        if inner is None or reader is None or not self._fast:
            return
        sock = inner.socket()
        if sock is None:
            return
        fd = sock.fileno()
        if self._readable is None or self._readable[0] != fd:
            poller = select.poll()
            poller.register(fd, select.POLLIN)
            self._readable = (fd, poller)
        tls_pending = getattr(sock, "pending", None) if always else None  # decrypted, unread
        readable = self._readable[1].poll(0) or (tls_pending is not None and tls_pending())
        if readable and not (self._read_acks and self._read_acks()):
            reader()

    def stop(self) -> None:
        """On the loop's thread: the flush's acknowledgements are read as they come."""
        self.stopping.set()
        self._steady = False
        self._watch_reads()
        self._wake.set()

    async def run(self) -> None:
        """Connect until stopped; the first failure ends it (a start-up error)."""
        low, high = self.backoff_s
        delay = low
        connect_sent = True
        while not self.stopping.is_set():
            will = self.protocol.will(now_ms(), new_connect=connect_sent)
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
                # MQTT 5 (Sparkplug 3.0 asks the same of an edge node): a new session at
                # every connection, none kept after it (session expiry interval 0: unset)
                clean_start=True,
                max_inflight_messages=WINDOW,
            )
            client.pending_calls_threshold = 4 * WINDOW
            self._hook_paho(client)
            entered = False
            try:
                async with client:
                    entered = True
                    self._up()
                    delay = low
                    await self._session(client)
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
        if self.outbox:
            self.log(
                f"telemetry {self.protocol.name}: stopped with {len(self.outbox)} messages unsent"
            )

    def _report_down(self, delay: float) -> None:
        """One line when the broker goes, then one every STILL_DOWN_S while it stays away."""
        now = time.monotonic()
        if self._reported_down_at is None:
            self.log(
                f"telemetry {self.protocol.name}: lost {self.url.display} ({self.last_error}); "
                f"buffering up to {self.outbox.max_bytes // 1024} KiB, retrying in {delay:.1f} s"
            )
        elif now - self._reported_down_at >= STILL_DOWN_S:
            away = now - (self.down_since or now)
            self.log(
                f"telemetry {self.protocol.name}: {self.url.display} still away after "
                f"{away:.0f} s ({self.last_error}); {len(self.outbox)} messages buffered "
                f"({self.outbox.bytes / 1024:.0f} KiB)"
            )
        else:
            return
        self._reported_down_at = now

    def _refusal(self) -> str:
        error = self.last_error
        if "code:" in error or "Not authorized" in error or "not authorised" in error:
            return f"MQTT broker {self.url.display} refused the connection: {error}"
        return f"cannot reach MQTT broker {self.url.display}: {error}"

    def _up(self) -> None:
        self._reported_down_at = None
        self.connected = True
        self.connections += 1
        if self.connections == 1:
            return
        outage = time.monotonic() - self.down_since if self.down_since else 0.0
        dropped, dropped_bytes = self.outbox.drops_since_report()
        line = (
            f"telemetry {self.protocol.name}: back on {self.url.display} after {outage:.1f} s; "
            f"replaying {len(self.outbox)} messages ({self.outbox.bytes / 1024:.0f} KiB)"
        )
        if dropped:
            line += (
                f"; dropped the {dropped} oldest ({dropped_bytes / 1024:.0f} KiB) over the "
                f"{self.outbox.max_bytes // 1024} KiB bound"
            )
        self.log(line)

    def _down(self) -> None:
        if self.connected:
            self.down_since = time.monotonic()
        self.connected = False

    async def _session(self, client: aiomqtt.Client) -> None:
        for topic in self.protocol.subscriptions():
            await client.subscribe(topic, options=COMMAND_OPTIONS)
        self._reconnect = ""
        self._inner = client._client  # aiomqtt 2.5.1 (pinned) keeps its paho client here
        self._client = client
        self._progress_at = time.monotonic()
        try:
            first, after = self.protocol.on_connect(now_ms())
            self._publish_now(first)
            await self._settled(CONNECT_TIMEOUT_S)
            self.outbox.extend(after)
            self._drain()
            if not self.first.done():  # start() returns (and snapshots flow) once births are out
                self.first.set_result(None)
            receiver = asyncio.create_task(self._receive(client))
            try:
                self._steady = not self.stopping.is_set()
                try:
                    await self._watch(receiver)
                finally:
                    self._steady = False
                    self._watch_reads()  # the goodbye's acknowledgements wake the loop
                if self.stopping.is_set() or self._reconnect:
                    self._publish_now(self.protocol.goodbye(now_ms()))
                    await self._settled(FLUSH_S)
            finally:
                receiver.cancel()
                await asyncio.gather(receiver, return_exceptions=True)
        finally:
            self._steady, self._polled = False, None
            self._inner = self._client = None
            if self._inflight:  # not taken by the broker: first in line for the next session
                self.outbox.requeue(list(self._inflight.values()))
                self._inflight.clear()

    async def _watch(self, receiver: asyncio.Task[None]) -> None:
        """While connected: sending happens in `push` and paho's callbacks; this waits for
        the end (stop, lost receiver, a broker that stopped acknowledging, a new session)."""
        flush_until: float | None = None
        while True:
            if receiver.done():
                raise aiomqtt.MqttError(self._receiver_error(receiver))
            if self._reconnect:
                return
            now = time.monotonic()
            if self._inflight and now - self._progress_at > CONNECT_TIMEOUT_S:
                raise aiomqtt.MqttError(f"{len(self._inflight)} publications not acknowledged")
            if self.stopping.is_set():
                flush_until = flush_until or now + FLUSH_S
                idle = not self._inflight and (not self.outbox or self.protocol.holding)
                if idle or now > flush_until:
                    return
            self._wake.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._wake.wait(), WATCH_S)

    async def _settled(self, timeout_s: float) -> None:
        """Wait until the broker took what is in flight (births, a goodbye)."""
        deadline = time.monotonic() + timeout_s
        self._settling = True
        try:
            while self._inflight and self._inner is not None and time.monotonic() < deadline:
                self._wake.clear()
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(self._wake.wait(), deadline - time.monotonic())
        finally:
            self._settling = False

    @staticmethod
    def _receiver_error(receiver: asyncio.Task[None]) -> str:
        if receiver.cancelled():
            return "receiver cancelled"
        exc = receiver.exception()
        cause = exc.__cause__ if exc is not None and exc.__cause__ is not None else exc
        return str(cause) if cause is not None else "connection closed"

    def _hook_paho(self, client: aiomqtt.Client) -> None:
        """Hear paho's "published" callbacks (PUBACK for QoS 1, written for QoS 0) beside
        aiomqtt's own, and let `_flush` write a window. Messages are published with paho's
        `publish` and tracked here: aiomqtt's `publish` costs a Task, an Event and a
        `wait_for` per message, three times paho's own work at this rate."""
        inner = client._client  # aiomqtt 2.5.1 (pinned) keeps its paho client here
        aiomqtt_on_publish = inner.on_publish
        assert aiomqtt_on_publish is not None  # aiomqtt's Client.__init__ sets it

        def on_publish(*args: Any) -> None:
            aiomqtt_on_publish(*args)
            self._taken(args[2])

        inner.on_publish = on_publish
        aiomqtt_on_connect = inner.on_connect
        assert aiomqtt_on_connect is not None

        def on_connect(*args: Any) -> None:
            properties = args[4] if len(args) > 4 else None
            receive_maximum = getattr(properties, "ReceiveMaximum", None)
            self.window = min(WINDOW, receive_maximum or WINDOW)
            aiomqtt_on_connect(*args)

        inner.on_connect = on_connect
        self.window = WINDOW
        # aiomqtt registers the socket for writing through call_soon_threadsafe (paho may
        # ask from the thread that connects): a registration that lands after `_flush` has
        # written everything leaves a writer paho no longer knows of, woken on every turn
        # of the loop. On the loop's thread it is registered here, at once.
        loop = asyncio.get_running_loop()
        loop_thread = threading.get_ident()

        def writer() -> None:
            try:
                inner.loop_write()
            except Exception as exc:  # a broken connection, as aiomqtt handles it
                if not client._disconnected.done():
                    client._disconnected.set_exception(exc)

        def reader() -> None:  # what aiomqtt's reader does when the socket is readable
            try:
                while True:
                    inner.loop_read()
                    pending = getattr(inner._sock, "pending", None)  # TLS: decrypted, unread
                    if pending is None or not pending():
                        break
            except Exception as exc:  # a broken connection, as aiomqtt handles it
                if not client._disconnected.done():
                    client._disconnected.set_exception(exc)

        self._reader = reader

        def register_write(_client: Any, _userdata: Any, sock: Any) -> None:
            if threading.get_ident() == loop_thread:
                loop.add_writer(sock.fileno(), writer)
            else:
                loop.call_soon_threadsafe(loop.add_writer, sock.fileno(), writer)

        def on_socket_register_write(*args: Any) -> None:
            if not self._batching:  # a window is written by _flush right after
                register_write(*args)

        self._register_write = register_write
        inner.on_socket_register_write = on_socket_register_write
        # The fast paths below use paho 2.x internals; another paho keeps its own paths.
        self._fast = all(hasattr(inner, name) for name in PAHO_INTERNALS)
        self._v5 = getattr(inner, "_protocol", None) == paho.MQTTv5
        if self._fast:
            self._buffer_reads(inner)

    def _buffer_reads(self, inner: paho.Client) -> None:
        """paho reads a packet a few bytes per system call (type, length, rest: three for a
        PUBACK); read what the socket has in one and hand it out from memory. Whatever is
        left in memory when paho's read loop stops is read at once, not when the socket
        next becomes readable (it may not). PUBACKs (40 02 and the message ID; MQTT 5 may
        add a success reason code below 0x80 and an empty property length: 40 03, 40 04)
        are taken here, at a packet boundary, as paho's own handler would (the message
        leaves paho's in-flight table, its info says published, the window moves on),
        without the reason-code and properties objects paho builds for each."""
        sock_recv, loop_read = inner._sock_recv, inner.loop_read
        pending = bytearray()

        def puback_size() -> int:
            """Bytes of the successful PUBACK at the front of `pending` (0: none there)."""
            if len(pending) < 4 or pending[0] != PUBACK_TYPE:
                return 0
            size = pending[1] + 2
            if size == 4:
                return 4
            if size in (5, 6) and len(pending) >= size and pending[4] < 0x80:
                return size if size == 5 or pending[5] == 0 else 0  # no properties
            return 0  # an error reason, or properties: paho reads it

        def acknowledgements() -> None:
            while size := puback_size():
                mid = pending[2] << 8 | pending[3]
                del pending[:size]
                inner._last_bytes_received = time.monotonic()  # paho's keep-alive clock
                with inner._out_message_mutex:
                    message = inner._out_messages.pop(mid, None)
                    if message is not None:  # published through paho (else: _queue_packets)
                        message.info._set_as_published()
                        if message.qos > 0:
                            inner._inflight_messages -= 1
                            if inner._max_inflight_messages > 0:
                                inner._update_inflight()  # paho sends what it queued, if any
                self._taken(mid)

        def buffered_recv(size: int) -> bytes:
            while True:
                if not pending:
                    data = sock_recv(1 << 16)  # BlockingIOError: nothing (paho: EAGAIN)
                    if not data:
                        return data  # the broker closed the connection
                    pending.extend(data)
                if size == 1 and inner._in_packet["command"] == 0:  # a packet's first byte
                    acknowledgements()
                if pending:
                    break
            out = bytes(pending[:size])
            del pending[:size]
            return out

        def read_all(max_packets: int = 1) -> paho.MQTTErrorCode:
            rc = loop_read(max_packets)
            while pending and rc == paho.MQTT_ERR_SUCCESS and inner.socket() is not None:
                rc = loop_read(max_packets)
            return rc

        def read_acknowledgements() -> bool:
            """At a packet boundary, read what the socket has and take its PUBACKs without
            going through paho's read loop; False when paho must read (something else came,
            or an error, or the connection closed: paho meets it as it would)."""
            if pending or inner._in_packet["command"] != 0:
                return False
            try:
                data = sock_recv(1 << 16)
            except BlockingIOError:  # nothing after all (paho turns TLS's wants into this)
                return True
            except OSError:
                return False
            if not data:
                return False
            pending.extend(data)
            acknowledgements()
            tls_pending = getattr(inner._sock, "pending", None)  # decrypted, not yet read
            return not pending and not (tls_pending is not None and tls_pending())

        inner._sock_recv = buffered_recv  # type: ignore[method-assign,assignment]
        inner.loop_read = read_all  # type: ignore[method-assign]
        self._read_acks = read_acknowledgements

    def _taken(self, mid: int) -> None:
        """The broker took a message (QoS 1: PUBACK; QoS 0: written to the socket)."""
        if self._inflight.pop(mid, None) is None:
            return
        self.sent += 1
        self._progress_at = time.monotonic()
        if not self._inflight and (self._settling or self.stopping.is_set()):
            self._wake.set()  # only when someone waits for it: a wake-up is a task step
        if self.outbox and self._refill is None and len(self._inflight) <= self.window // 2:
            # not from inside paho's callback: on the loop's next turn
            self._refill = asyncio.get_running_loop().call_soon(self._drain)

    def _drain(self) -> None:
        """Publish from the outbox while the window has room (connected, not holding)."""
        self._refill = None
        if self._inner is None or self.protocol.holding or self._reconnect:
            return
        room = self.window - len(self._inflight)
        if room > 0 and self.outbox:
            self._publish_now(self.outbox.take(room))

    def _publish_now(self, messages: list[Message]) -> None:
        """Hand messages to paho in order and write them at once; what paho refuses (the
        connection is gone) goes back in front of the outbox, in order."""
        inner = self._inner
        if inner is None:
            self.outbox.requeue(messages)
            return
        if not self._inflight:
            self._progress_at = time.monotonic()
        if self._fast:
            self._queue_packets(inner, messages)
            self._flush(inner)
            return
        self._batching = True
        try:
            for index, message in enumerate(messages):
                final = self.protocol.finalize(message)
                if final is None:
                    continue
                info = inner.publish(final.topic, final.payload, final.qos, final.retain)
                if info.rc != paho.MQTT_ERR_SUCCESS:
                    self.outbox.requeue(messages[index:])
                    self._wake.set()  # _watch sees the lost receiver
                    break
                self._inflight[info.mid] = message
        finally:
            self._batching = False
        self._flush(inner)

    def _queue_packets(self, inner: paho.Client, messages: list[Message]) -> None:
        """What `paho.Client.publish` does for a message (the MQTT 5 PUBLISH packet,
        an ID from paho's own sequence, the packet in paho's write queue), without the
        message and info objects, the lock, the checks and the log call it makes for each:
        the link tracks its messages itself (`_inflight`), and PUBACKs are read by
        `_buffer_reads`. What paho's queue holds is written by `_flush` (or paho)."""
        if inner._sock is None:  # the connection is gone (paho: MQTT_ERR_NO_CONN)
            self.outbox.requeue(messages)
            self._wake.set()  # _watch sees the lost receiver
            return
        queue, topics, mid_generate = inner._out_packet, self._topics, inner._mid_generate
        v5 = int(self._v5)  # MQTT 5: a property length (0, none) before the payload
        properties = b"\x00" if v5 else b""
        for message in messages:
            final = self.protocol.finalize(message)
            if final is None:
                continue
            topic = topics.get(final.topic)
            if topic is None:
                if len(topics) >= TOPIC_CACHE:
                    topics.clear()
                encoded = final.topic.encode()
                if not encoded or b"+" in encoded or b"#" in encoded:
                    raise ValueError(f"invalid topic for a publication: {final.topic!r}")
                topic = topics[final.topic] = len(encoded).to_bytes(2, "big") + encoded
            qos, mid = final.qos, mid_generate()
            length = len(topic) + len(final.payload) + (2 if qos else 0) + v5
            command = paho.PUBLISH | qos << 1 | bool(final.retain)
            packet = b"".join(
                (
                    bytes((command,)),
                    _remaining_length(length),
                    topic,
                    mid.to_bytes(2, "big") if qos else b"",
                    properties,
                    final.payload,
                )
            )
            queue.append(
                {
                    "command": command,
                    "mid": mid,
                    "qos": qos,
                    "pos": 0,
                    "to_process": len(packet),
                    "packet": packet,
                    "info": _WRITTEN,  # type: ignore[typeddict-item]  # has what paho calls
                }
            )
            self._inflight[mid] = message

    def _flush(self, inner: paho.Client) -> None:
        """Write the window paho holds in one system call: one TCP segment, not one per
        message (paho writes packet by packet). A QoS 0 message is taken once written, as
        paho would say, without its per-message callback objects. Anything but publications
        in the queue, or an error, and paho writes it itself, into a corked socket; what the
        socket cannot take yet is left to the event loop (the writer)."""
        sock = inner.socket()
        if sock is None or not inner.want_write():
            return
        if not self._fast:
            self._paho_write(inner, sock)
            return
        queue = inner._out_packet  # paho 2.x: dicts of command, mid, qos, pos, to_process, …
        if not all(packet["command"] & 0xF0 == paho.PUBLISH for packet in queue):
            self._paho_write(inner, sock)
            return
        data = b"".join(memoryview(packet["packet"])[packet["pos"] :] for packet in queue)
        try:
            written = sock.send(data)
        except (BlockingIOError, ssl.SSLWantReadError, ssl.SSLWantWriteError):
            written = 0
        except OSError:
            self._paho_write(inner, sock)  # paho meets the error and reports the lost link
            return
        while queue and written > 0:
            packet = queue[0]
            step = min(written, packet["to_process"])
            packet["pos"] += step
            packet["to_process"] -= step
            written -= step
            if packet["to_process"]:
                break
            queue.popleft()
            if packet["qos"] == 0:
                if packet["info"] is not None:
                    packet["info"]._set_as_published()
                self._taken(packet["mid"])
        inner._last_msg_out = time.monotonic()  # paho's keep-alive clock (time.monotonic)
        if queue and self._register_write is not None:
            # paho believes the writer registered (it asked while the window was handed
            # over): register it for real, or the rest would wait for the next window
            self._register_write(inner, None, sock)
        else:
            inner._call_socket_unregister_write()  # and it knows none is needed

    def _paho_write(self, inner: paho.Client, sock: Any) -> None:
        corked = _cork(sock, True)
        try:
            inner.loop_write()  # a lost connection: paho's on_disconnect, seen by aiomqtt
        finally:
            if corked:
                _cork(sock, False)
        sock = inner.socket()
        if sock is not None and inner.want_write() and self._register_write is not None:
            self._register_write(inner, None, sock)

    async def _receive(self, client: aiomqtt.Client) -> None:
        try:
            async for message in client.messages:
                incoming = self.protocol.receive(  # aiomqtt's payload is paho's, always bytes
                    message.topic.value, bytes(message.payload), bool(message.retain), now_ms()
                )
                if incoming.reconnect:
                    self._reconnect = incoming.reconnect
                    self._wake.set()
                if incoming.urgent:  # ahead of what is buffered (births after a wait)
                    self._publish_now(incoming.urgent)
                self.push(incoming.messages)
                for request in incoming.requests:
                    task = asyncio.create_task(self._answer(request))
                    self._answers.add(task)
                    task.add_done_callback(self._answers.discard)
        finally:
            self._wake.set()

    async def _answer(self, request: CommandRequest) -> None:
        if request.command is None:
            result = CommandResult(request.name, False, request.refused)
        else:
            result = await self.execute(request.command)
        self.push(self.protocol.reply(request, result, now_ms()))


class Pump:
    """Polls the gateway for snapshots (just after each is due) and publishes at most at
    the rate (a token bucket: at the default rate every snapshot goes out as soon as it
    is seen). A timer callback on the event loop rather than a task: a look at a gateway
    at rest is one timer and a comparison, not a future, a timer and a task step."""

    def __init__(self, publisher: TelemetryPublisher):
        self.publisher = publisher
        self.loop = asyncio.get_running_loop()
        self.rate_hz = 1.0 / publisher.period_s
        self.seen_at = -1.0
        self.credit, self.credit_at = RATE_BURST, time.monotonic()
        self.handle: asyncio.TimerHandle | asyncio.Handle = self.loop.call_soon(self.tick)

    def tick(self) -> None:
        publisher = self.publisher
        now = time.monotonic()
        for link in publisher.links:
            link.poll_reads(now)
        if publisher._look(now):
            self.seen_at = now
        self.credit = min(RATE_BURST, self.credit + (now - self.credit_at) * self.rate_hz)
        self.credit_at = now
        queued = len(publisher.queue)
        if queued and self.credit >= 1.0:
            publisher._publish(now)
            self.credit -= 1.0
            queued = 0
        # Next look: shortly before the next snapshot is due, then every POLL_S.
        due = self.seen_at + SNAPSHOT_PERIOD_S - POLL_S / 2
        wake = due if due > now else now + (POLL_S if now - self.seen_at < 1.0 else 0.02)
        if queued:
            wake = min(wake, now + (1.0 - self.credit) / self.rate_hz)
        self.handle = self.loop.call_at(max(wake, time.monotonic() + 0.0005), self.tick)

    def cancel(self) -> None:
        self.handle.cancel()


class TelemetryPublisher:
    """The gateway's telemetry over MQTT, in a background thread; a context manager."""

    def __init__(
        self,
        gateway: GatewayLike,
        url: BrokerUrl,
        gateway_id: str,
        *,
        tls: ssl.SSLContext | None = None,
        rate_hz: float = DEFAULT_RATE_HZ,
        controls: dict[str, Any] | None = None,
        log: Log | None = None,
        json_tree: bool = True,
        sparkplug: bool = True,
        backoff_s: tuple[float, float] = (BACKOFF_MIN_S, BACKOFF_MAX_S),
        primary_host_id: str | None = None,
        state_dir: Path | None = None,
        first_snapshot_s: float = FIRST_SNAPSHOT_S,
    ):
        if not rate_hz > 0:
            raise ValueError("rate_hz must be positive")
        self.gateway = gateway
        self.url = url
        self.gateway_id = gateway_id
        self.tls = tls
        self.period_s = 1.0 / rate_hz
        self.controls = dict(controls or {})
        self.log: Log = log or (lambda line: None)
        self.protocols: list[TelemetryProtocol] = []
        if json_tree:
            self.protocols.append(JsonTree(gateway_id))
        # the bdSeq a previous run used, kept in the state directory (None: not kept)
        self.bdseq_file = (
            None if state_dir is None else BdSeqFile(state_dir, url.group, gateway_id, self.log)
        )
        if sparkplug:
            last = self.bdseq_file.load() if self.bdseq_file is not None else None
            self.protocols.append(
                SparkplugSession(
                    url.group, gateway_id, primary_host_id=primary_host_id, last_bdseq=last
                )
            )
        self.backoff_s = backoff_s
        # 0 for a gateway not yet running (connected before the network is touched)
        self.first_snapshot_s = first_snapshot_s
        self.queue = SnapshotQueue()
        self.clock = SnapshotClock()
        self.links: list[MqttLink] = []
        self.published_snapshots = 0
        self.skipped_snapshots = 0  # like the one before: nothing to publish (_has_news)
        self._last_snapshot: Snapshot | None = None
        self._counted_seen = -1
        self._controls_seen: dict[str, Any] = {}
        self._thread: threading.Thread | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._stop: asyncio.Event | None = None
        self._ready = threading.Event()
        self._start_error: BaseException | None = None

    @classmethod
    def controls_of(cls, config: Any) -> dict[str, Any]:
        """The settable values a gateway starts with (`GatewayConfig`)."""
        controls: dict[str, Any] = {
            "reflex_enabled": config.reflex.enabled,
            "reflex_threshold_mm_s": config.reflex.threshold_mm_s,
        }
        emg = config.nodes.get("emg")
        if emg is not None:
            controls["emg_e_min_uv"] = emg.e_min_uv
            controls["emg_e_max_uv"] = emg.e_max_uv
        return controls

    # -- life cycle (any thread) -----------------------------------------------------------
    def __enter__(self) -> TelemetryPublisher:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def start(self) -> TelemetryPublisher:
        """Connect every protocol's link; BrokerError if the broker is not there or refuses."""
        self._thread = threading.Thread(
            target=lambda: asyncio.run(self._main()), name="grasplink-telemetry", daemon=True
        )
        self._thread.start()
        self._ready.wait()
        if self._start_error is not None:
            self._thread.join()
            raise self._start_error
        return self

    def stop(self, timeout_s: float = FLUSH_S + 3.0) -> None:
        loop, stop = self._loop, self._stop
        if loop is not None and stop is not None and not loop.is_closed():
            with contextlib.suppress(RuntimeError):  # the loop has just closed
                loop.call_soon_threadsafe(stop.set)
        if self._thread is not None:
            self._thread.join(timeout_s)

    # -- what it did -----------------------------------------------------------------------
    def stats(self) -> dict[str, Any]:
        return {
            "snapshots_dropped": self.queue.dropped,
            "published_snapshots": self.published_snapshots,
            "skipped_snapshots": self.skipped_snapshots,
            "links": {
                link.protocol.name: {
                    "connected": link.connected,
                    "connections": link.connections,
                    "sent": link.sent,
                    "buffered_messages": len(link.outbox),
                    "buffered_bytes": link.outbox.bytes,
                    "dropped_messages": link.outbox.dropped_messages,
                    "dropped_bytes": link.outbox.dropped_bytes,
                }
                for link in self.links
            },
        }

    def status_line(self) -> str:
        parts = []
        for link in self.links:
            state = "up" if link.connected else "DOWN"
            if link.connected and link.protocol.holding:
                host = getattr(link.protocol, "primary_host_id", None)
                state = f"up, waiting for primary host {host}"
            part = f"{link.protocol.name} {state} {link.sent} sent"
            if link.outbox:
                part += f", {len(link.outbox)} buffered"
            if link.outbox.dropped_messages:
                part += f", {link.outbox.dropped_messages} dropped"
            parts.append(part)
        return f"telemetry {self.url.display}: " + "; ".join(parts)

    # -- the telemetry thread --------------------------------------------------------------
    async def _main(self) -> None:
        self._loop = asyncio.get_running_loop()
        self._stop = asyncio.Event()
        client_ids = {p.name: f"grasplink-{self.gateway_id}-{p.name}" for p in self.protocols}
        try:
            await self._first_snapshot()
            self.links = [
                MqttLink(
                    protocol,
                    self.url,
                    client_ids.get(protocol.name, protocol.name),
                    self.tls,
                    self.log,
                    self._execute,
                    backoff_s=self.backoff_s,
                    on_will=self._on_will(protocol),
                )
                for protocol in self.protocols
            ]
            runs = [asyncio.create_task(link.run()) for link in self.links]
            results = await asyncio.gather(
                *(link.first for link in self.links), return_exceptions=True
            )
            errors = [r for r in results if isinstance(r, BaseException)]
            if errors:
                self._start_error = errors[0]
                for link in self.links:
                    link.stop()
                await asyncio.gather(*runs, return_exceptions=True)
                return
            self._ready.set()
            pump = Pump(self)
            await self._stop.wait()
            pump.cancel()
            self._publish(time.monotonic())  # the last snapshots still go out
            for link in self.links:
                link.stop()
            await asyncio.gather(*runs, return_exceptions=True)
        except BaseException as exc:  # a bug: never leave start() waiting
            self._start_error = self._start_error or exc
            raise
        finally:
            self._ready.set()

    async def _first_snapshot(self) -> None:
        """Before the first connection: wait (at most FIRST_SNAPSHOT_S; a gateway makes one
        every 50 ms from its start) for the gateway's first snapshot and prime the Sparkplug
        session with it, so the first NBIRTH reports the gateway's values and controls."""
        deadline = time.monotonic() + self.first_snapshot_s
        while self.gateway.latest is None and time.monotonic() < deadline:
            await asyncio.sleep(POLL_S * 10)
        snapshot = self.gateway.latest
        if snapshot is None:
            return
        sample = self._sample(snapshot, time.monotonic())
        for protocol in self.protocols:
            if isinstance(protocol, SparkplugSession):
                protocol.prime(sample, {"controls": self.controls, "telemetry": {}})

    def _on_will(self, protocol: TelemetryProtocol) -> Callable[[], None] | None:
        """Sparkplug: save the bdSeq of the Will about to be registered (before CONNECT)."""
        store = self.bdseq_file
        if store is None or not isinstance(protocol, SparkplugSession):
            return None
        return lambda: store.save(protocol.bdseq)

    def _look(self, now: float) -> bool:
        """Take the gateway's snapshot if it is a new one; True when it was."""
        snapshot = self.gateway.latest
        if snapshot is None or snapshot is self._last_snapshot:
            return False
        previous, self._last_snapshot = self._last_snapshot, snapshot
        sample = self._sample(snapshot, now)
        if self._has_news(previous, sample):
            self.queue.put(sample)
        else:
            self.skipped_snapshots += 1
            if not len(self.queue):
                for protocol in self.protocols:
                    protocol.latest = sample
        return True

    def _sample(self, snapshot: Snapshot, now: float) -> Sample:
        """The snapshot stamped with the wall-clock time it was made (seen at monotonic `now`)."""
        return Sample(self.clock.stamp_ms(snapshot.uptime_s, now, time.time() - now), snapshot)

    def _has_news(self, previous: Snapshot | None, sample: Sample) -> bool:
        """Whether a snapshot may change what a protocol publishes; compared before any
        encoding, so a gateway at rest costs a comparison per snapshot, not two encodings.
        Lossless: a snapshot like the one before (values, states, alarms; counters aside)
        says nothing new until a protocol's periodic report is due (`next_due_ms`), and
        what telemetry itself counts (drops, connections, controls) is compared too."""
        # what telemetry itself counts only grows: a sum changes whenever one of them does
        counted = self.queue.dropped
        for link in self.links:
            counted += link.outbox.dropped_messages + link.connections
            counted += getattr(link.protocol, "historical_dropped", 0)
        if counted != self._counted_seen or self.controls != self._controls_seen:
            self._counted_seen, self._controls_seen = counted, dict(self.controls)
            return True
        if previous is None or not same_report(previous, sample.snapshot):
            return True
        return sample.ts_ms >= min(protocol.next_due_ms for protocol in self.protocols)

    def _publish(self, now: float) -> None:
        batch = self.queue.drain()
        if not batch:
            return
        self.published_snapshots += len(batch)
        # every protocol's messages first, then the writes back to back: the broker, woken by
        # the first, is still awake for the second (one wake-up of its process, not two)
        made = [
            link.protocol.update(
                batch, {"controls": self.controls, "telemetry": self._telemetry(link)}
            )
            for link in self.links
        ]
        for link, messages in zip(self.links, made, strict=True):
            link.push(messages)
        for link in self.links:  # the first link's PUBACKs may be in by now
            link.read_acknowledgements()

    def _telemetry(self, link: MqttLink) -> dict[str, Any]:
        stats = {
            "snapshots_dropped": self.queue.dropped,
            "buffer_dropped_messages": link.outbox.dropped_messages,
            "buffer_dropped_bytes": link.outbox.dropped_bytes,
            "buffer_bound_bytes": link.outbox.max_bytes,
            "connections": link.connections,
        }
        if isinstance(link.protocol, SparkplugSession):
            stats["historical_dropped"] = link.protocol.historical_dropped
        return stats

    async def _execute(self, command: Command) -> CommandResult:
        """Post to the gateway's thread and wait (never cancelling its Future)."""
        future = asyncio.wrap_future(self.gateway.post(command))
        done, _ = await asyncio.wait({future}, timeout=COMMAND_TIMEOUT_S)
        if not done:
            return CommandResult(
                command.name, False, f"the gateway did not answer within {COMMAND_TIMEOUT_S:g} s"
            )
        result = future.result()
        apply_result(self.controls, command, result)
        return result

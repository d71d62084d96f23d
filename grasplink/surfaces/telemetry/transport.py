"""The MQTT edge: aiomqtt in its own thread and event loop, never on the gateway's thread.

`TelemetryPublisher` reads `gateway.latest` (a `Snapshot` replaced whole at 20 Hz, so
reading it needs no lock), stamps each new snapshot with the wall-clock time it
was made, and queues it (`SnapshotQueue`: bounded, drop-oldest, counted). At
most `rate_hz` times a second the queued snapshots go through each protocol
(JSON tree, Sparkplug session) into that connection's `Outbox`, the bounded
store-and-forward buffer its `Writer` drains while the broker is there. Its
`Session` keeps the connection: a lost broker is retried with back-off; on its
return the buffer is replayed in order and what the bound dropped is logged and
published (health, Telemetry/ metrics). Commands read from the broker are posted
to the gateway's mailbox (`gateway.post`, the live edge
`grasplink.gateway.edge.GatewayEdge`), their results answered by the protocol
that received them.

One connection per protocol: each has its own Will (JSON `status` offline,
Sparkplug NDEATH), which MQTT allows only one of per connection.
"""

from __future__ import annotations

import asyncio
import contextlib
import ssl
import threading
import time
from collections.abc import Awaitable, Callable
from concurrent.futures import Future
from pathlib import Path
from typing import Any, Protocol

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
from grasplink.surfaces.telemetry.session import (
    BACKOFF_MAX_S,
    BACKOFF_MIN_S,
    FLUSH_S,
    Log,
    Session,
    now_ms,
)
from grasplink.surfaces.telemetry.sparkplug import SparkplugSession
from grasplink.surfaces.telemetry.state import BdSeqFile
from grasplink.surfaces.telemetry.url import BrokerUrl
from grasplink.surfaces.telemetry.writer import Writer

DEFAULT_RATE_HZ = 20.0
COMMAND_TIMEOUT_S = 2.0  # the gateway answers at its next advance(), normally within 100 ms
POLL_S = 0.001  # looking for the next snapshot once it is due
FIRST_SNAPSHOT_S = 1.0  # the first connection waits at most this for the gateway's first snapshot
SNAPSHOT_PERIOD_S = SNAPSHOT_PERIOD_US / 1e6
RATE_BURST = 1.5  # publish credit kept: a snapshot a little early (jitter) still goes at once


class GatewayLike(Protocol):
    """What telemetry needs of a gateway (its live edge, `grasplink.gateway.edge.GatewayEdge`)."""

    @property
    def latest(self) -> Snapshot | None: ...

    def post(self, command: Command) -> Future[CommandResult]: ...


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
    """One protocol's broker connection: a `Session` keeping it up, a `Writer` draining its
    outbox, and the commands it receives answered."""

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
        self.outbox = Outbox(url.buffer_bytes)
        self.writer = Writer(protocol, self.outbox)
        self.session = Session(
            protocol,
            self.writer,
            url,
            client_id,
            tls,
            log,
            self._received,
            backoff_s=backoff_s,
            on_will=on_will,
        )
        self.execute = execute
        self._answers: set[asyncio.Task[None]] = set()

    @property
    def connected(self) -> bool:
        return self.session.connected

    @property
    def connections(self) -> int:
        return self.session.connections

    @property
    def sent(self) -> int:
        """Messages the broker took (QoS 1: acknowledged; QoS 0: written)."""
        return self.writer.sent

    @property
    def in_flight(self) -> int:
        return self.writer.in_flight

    @property
    def first(self) -> asyncio.Future[None]:
        """Done once the first connection's births are out; its exception: a start-up error."""
        return self.session.first

    def push(self, messages: list[Message]) -> None:
        self.writer.push(messages)

    def stop(self) -> None:
        self.session.stop()

    async def run(self) -> None:
        await self.session.run()

    def _received(self, topic: str, payload: bytes, retain: bool) -> None:
        incoming = self.protocol.receive(topic, payload, retain, now_ms())
        if incoming.reconnect:
            self.session.reconnect(incoming.reconnect)
        if incoming.urgent:  # ahead of what is buffered (births after a wait)
            self.writer.send_now(incoming.urgent)
        self.writer.push(incoming.messages)
        for request in incoming.requests:
            task = asyncio.create_task(self._answer(request))
            self._answers.add(task)
            task.add_done_callback(self._answers.discard)

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
        if publisher.look(now):
            self.seen_at = now
        self.credit = min(RATE_BURST, self.credit + (now - self.credit_at) * self.rate_hz)
        self.credit_at = now
        queued = len(publisher.queue)
        if queued and self.credit >= 1.0:
            publisher.publish(now)
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
            self.publish(time.monotonic())  # the last snapshots still go out
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

    def look(self, now: float) -> bool:
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

    def publish(self, now: float) -> None:
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

"""NodeRunner: the IO edge that runs sans-IO devices on a python-can bus in real time."""

from __future__ import annotations

import contextlib
import copy
import logging
import selectors
import threading
import time
from collections import Counter, deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field

import can

from grasplink.bus.priority import raise_thread_nice, raise_thread_priority
from grasplink.bus.reconnect import DEFAULT_RECONNECT_TIMEOUT_S, FIRST_DELAY_US, Backoff
from grasplink.bus.url import BusDisconnected, frame_to_message, message_to_frame
from grasplink.core.frames import NODE_ID_MASK, RPDO_BASES, TPDO_BASES, Frame
from grasplink.core.protocol import SansIoDevice, StreamConsumer
from grasplink.errors import BusError

logger = logging.getLogger(__name__)

DEVICE_BACKOFF_US = 100_000
# Frames delivered per step before due timers run. A late thread (GIL, a slow device, a
# loaded machine) finds what the bus queued meanwhile - heartbeats among it - and must
# hear it before a heartbeat consumer judges loss; bounded so timers (own heartbeat,
# SDO timeouts) still run while a backlog lasts. 128 frames is ~0.4 s of a set's traffic.
MAX_BATCH = 128
# Behind by more than a batch (a starved host: the queue grows faster than the devices
# read it), the runner reads the whole backlog at once and delivers it in order, but for
# PDOs a newer frame of the same COB-ID in it supersedes: process data that is state, of
# which a control loop wants the newest. Service frames (NMT, SYNC, EMCY, TIME, SDO,
# heartbeat, LSS) are never dropped: an SDO answer queued behind a flood of PDOs is heard
# before its client's timeout runs. Nor are a counted stream's PDOs (`StreamConsumer`: the
# skin's packets, each its own samples): a gap in them changes what the decoder reads
# (docs/buses.md).
MAX_CATCH_UP = 65_536  # frames read in one catch-up (memory stays bounded)
BEHIND_LOG_EVERY_US = 10_000_000
# The pacer serves urgent timers only while the runner's thread makes progress: a heartbeat
# stands for a living gateway, so a thread stuck this long lets the nodes' consumers fire.
DEFAULT_STALL_LIMIT_S = 2.0
PACER_STALL_POLL_S = 0.01


def monotonic_us() -> int:
    """The runner's default clock: integer microseconds, monotonic."""
    return time.monotonic_ns() // 1000


@dataclass
class RunnerStats:
    """Counters a `NodeRunner` keeps; `NodeRunner.stats` returns a snapshot copy."""

    frames_rx: int = 0  # CANopen frames received from the bus
    frames_tx: int = 0  # frames sent on the bus (devices' and submitted ones)
    rx_by_cob_id: Counter[int] = field(default_factory=Counter)
    tx_by_cob_id: Counter[int] = field(default_factory=Counter)
    tx_by_node: Counter[int] = field(default_factory=Counter)  # frames each device emitted
    injected: int = 0  # frames taken from submit()
    ignored: int = 0  # bus frames CANopen cannot carry (error, 29-bit, FD) or own echoes
    dropped: int = 0  # submit() queue full, or a reply cascade over the limit
    send_errors: int = 0
    bus_errors: int = 0  # bus.recv() failures
    device_errors: int = 0  # exceptions raised by a device
    offline_drops: int = 0  # frames not sent because the bus was down
    reconnects: int = 0  # outages that ended with the bus back
    urgent_between_frames: int = 0  # urgent timers the runner's thread served amid a batch
    superseded: int = 0  # PDOs of a backlog dropped for a newer one of their COB-ID
    superseded_by_cob_id: Counter[int] = field(default_factory=Counter)
    catch_ups: int = 0  # steps that found more than a batch queued and read it all
    urgent_paced: int = 0  # urgent timers the pacer thread served
    stalls: int = 0  # times the pacer withheld urgent timers: the runner's thread was stuck


class NodeRunner:
    """Run sans-IO devices on one python-can bus in a background thread.

    Every frame a device returns is sent on the bus and also delivered to the
    runner's other devices (a bus never echoes a sender's own frames, yet
    devices sharing a runner must hear each other). Frames from the bus go to
    every device. Timers run from ``clock_us`` (default: monotonic µs); the
    thread (at ``nice``, if given and the host allows it) waits on ``bus.recv`` until the
    earliest device deadline, at most
    ``max_wait_s``, which also bounds how late a `submit`-ted frame goes out.
    Each step delivers every frame that has already arrived (up to
    ``max_batch``, each one's replies sent before the next is read) before it
    runs due timers: after a stall the heartbeats queued meanwhile reach a
    heartbeat consumer before its timer can declare their senders lost. A backlog longer
    than that (a host too slow for the traffic) is read at once and delivered in order
    with every PDO that a newer frame of its COB-ID supersedes dropped and counted
    (``supersede``, on by default): latency stays bounded instead of growing with the
    queue, and no service frame (SDO, heartbeat, EMCY, NMT, SYNC) is ever dropped.

    ``urgent`` devices hold timers that must never wait behind received frames (the
    master's own heartbeat, `gateway.master.HeartbeatProducer`): they are started with
    the devices, hear no frames, and are served whenever due - before the next frame of
    a batch, not only after it - so the work ahead of one is at most one frame's. With
    ``pace_urgent`` a thread of their own (the pacer, at real-time priority where the
    host allows it: `bus.priority`) serves them on time even while this thread is busy
    in a long device call; what it sends goes to the bus at once and to the devices
    through `submit`. The pacer serves only while this thread makes progress (a step
    within ``stall_limit_s``): a thread stuck for good must let the heartbeat stop.

    The bus should not echo own frames (``receive_own_messages=False``);
    echoes that python-can marks as such (``is_rx=False``) are ignored.
    The caller owns the bus: `stop` does not shut it down.

    A bus that fails is an outage, logged once. The devices keep running on
    their own timers, as a node's firmware does while its CAN controller is
    cut off; what they send meanwhile is dropped, not queued (stale data
    would flood the bus when it returns). The runner retries with bounded
    exponential back-off (`bus.reconnect.Backoff`), logging each attempt
    and the delay to the next: a bus handle that is gone for good
    (`BusDisconnected`, a closed hub connection) is replaced by ``reopen()``,
    any other failing bus is simply read again. When the bus is back the
    devices carry on with the state they have (no reboot, like a CAN node
    whose bus returns); after ``reconnect_timeout_s`` without it, or at once
    for a dead handle with no ``reopen``, the thread ends and `failure`
    holds a `BusError` saying why. While the bus is down the thread sleeps
    until the next device deadline or attempt: it never polls a dead bus.
    Buses ``reopen`` returned are the runner's, shut down by `stop`.
    """

    def __init__(
        self,
        bus: can.BusABC,
        devices: Sequence[SansIoDevice],
        *,
        clock_us: Callable[[], int] | None = None,
        max_wait_s: float = 0.02,
        submit_queue_size: int = 256,
        cascade_limit: int = 1000,
        max_batch: int = MAX_BATCH,
        name: str = "grasplink-node-runner",
        reopen: Callable[[], can.BusABC] | None = None,
        reconnect_timeout_s: float = DEFAULT_RECONNECT_TIMEOUT_S,
        first_retry_s: float = FIRST_DELAY_US / 1e6,
        urgent: Sequence[SansIoDevice] = (),
        pace_urgent: bool = False,
        stall_limit_s: float = DEFAULT_STALL_LIMIT_S,
        nice: int | None = None,
        supersede: bool = True,
    ) -> None:
        if not devices:
            raise ValueError("NodeRunner needs at least one device")
        if not 0 <= reconnect_timeout_s < float("inf") or not first_retry_s > 0:
            raise ValueError("reconnect_timeout_s must be >= 0 and first_retry_s > 0")
        if max_batch < 1:
            raise ValueError("max_batch must be >= 1")
        self.bus = bus
        self.devices = list(devices)
        self._clock = clock_us or monotonic_us
        self._max_wait_s = max_wait_s
        self._max_wait_us = round(max_wait_s * 1e6)
        self._cascade_limit = cascade_limit
        self._max_batch = max_batch
        self._name = name
        # Submitted frames: appended under `_submit_lock` (any thread, bounded), taken by
        # the runner's thread alone without a lock (deque appends and pops are atomic), so
        # a step with nothing submitted costs a truth test, not a queue's mutex and Empty.
        # (frame, to the bus, the device it comes from: it does not hear it back)
        self._submitted: deque[tuple[Frame, bool, SansIoDevice | None]] = deque()
        self._submit_size = submit_queue_size
        self._submit_lock = threading.Lock()
        self._stats = RunnerStats()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._booted = threading.Event()
        self._thread: threading.Thread | None = None
        self._send_failing = False
        self._backoff_until: dict[int, int] = {}  # id(device) -> µs; after it raised
        self._reopen = reopen
        self._reconnect_timeout_us = round(reconnect_timeout_s * 1e6)
        self._first_retry_us = max(1, round(first_retry_s * 1e6))
        self._outage: Backoff | None = None  # set while the bus is down
        self._due_us: int | None = None  # earliest device deadline after the last step
        self._checked_us = 0  # when the timers were last looked at
        self._backlog = False  # the last step stopped at max_batch frames
        self._supersede = supersede
        self._behind_logged_us: int | None = None
        self._bus_dead = False  # the current handle is gone for good: only reopen() helps
        self._last_bus_error = ""
        self._owned: can.BusABC | None = None  # the bus reopen() gave us, ours to shut down
        self.failure: BusError | None = None  # why the runner gave up on its bus
        self.urgent = list(urgent)
        # An urgent device is part of the device with its node-ID (the master's heartbeat):
        # that one does not hear its frames, as no CAN node hears its own.
        self._owner = {
            id(u): next((d for d in self.devices if _node_id(d) == _node_id(u)), u)
            for u in self.urgent
        }
        self._urgent_lock = threading.Lock()  # urgent devices: the runner's or the pacer's
        self._send_lock = threading.Lock()  # bus.send from the runner's and the pacer's thread
        self._urgent_due_us: int | None = None  # earliest urgent deadline
        self._pace = pace_urgent and bool(self.urgent)
        self._stall_us = round(stall_limit_s * 1e6)
        self._progress_us = 0  # when the runner's thread last stepped or delivered a frame
        self._pacer: threading.Thread | None = None
        self.pacer_priority: str | None = None  # what the host granted the pacer thread
        self._nice = nice  # the thread's nice value, if it should run ahead of ordinary work
        self.priority: str | None = None  # what the host granted the runner's thread

    # -- control (any thread) -------------------------------------------------

    def start(self, timeout: float = 5.0) -> NodeRunner:
        """Start the thread; returns once every device's boot-up has been sent."""
        self._thread = _start_thread(self, self._run, timeout)
        self._start_pacer()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread and wait for it (idempotent)."""
        self._stop.set()
        pacer = self._pacer
        if pacer is not None and pacer is not threading.current_thread():
            pacer.join(timeout)
        if not _stop_thread(self, timeout):
            return
        owned, self._owned = self._owned, None
        if owned is not None:
            owned.shutdown()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    @property
    def outage_s(self) -> float | None:
        """Seconds the bus has been down, or None while it works."""
        outage = self._outage
        return None if outage is None else outage.down_us(self._clock()) / 1e6

    def submit(self, frame: Frame, *, to_bus: bool = True) -> bool:
        """Inject a frame from another thread, as if a local tool transmitted it.

        The runner delivers it to all its devices and, if ``to_bus``, sends it
        on the bus. Returns False (and counts it dropped) if the bounded queue
        is full.
        """
        if not isinstance(frame, Frame):
            raise TypeError(f"submit() takes a Frame, not {type(frame).__name__}")
        return self._enqueue(frame, to_bus, None)

    def _enqueue(self, frame: Frame, to_bus: bool, source: SansIoDevice | None) -> bool:
        with self._submit_lock:
            if len(self._submitted) < self._submit_size:
                self._submitted.append((frame, to_bus, source))
                return True
        with self._lock:
            self._stats.dropped += 1
        return False

    @property
    def stats(self) -> RunnerStats:
        """A consistent snapshot of the counters."""
        with self._lock:
            return copy.deepcopy(self._stats)

    def __enter__(self) -> NodeRunner:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    # -- the runner thread ------------------------------------------------------

    def power_on(self) -> None:
        """Start every device and send their boot-up frames (the thread's first act).

        Public, with `step`, for a caller that drives the runner itself (a test on a
        virtual clock); never while the thread runs.
        """
        self._not_threaded("power_on")
        self._power_on()

    def step(self) -> None:
        """One cycle of the thread: wait for the bus (until the earliest deadline, at
        most ``max_wait_s``), deliver what arrived and what was submitted, run due timers.
        """
        self._not_threaded("step")
        self._step()

    def _not_threaded(self, what: str) -> None:
        if self._thread is not None and self._thread.is_alive():
            raise RuntimeError(f"{what}() while the runner's thread runs")

    def _power_on(self) -> None:
        now = self._clock()
        boot: list[tuple[Frame, SansIoDevice | None, bool]] = []
        for device in self.devices:  # power every device on before anyone hears a frame
            boot.extend((f, device, True) for f in self._call(device, "start", now))
        for device in self.urgent:
            boot.extend((f, device, True) for f in self._call(device, "start", now))
        self._dispatch(boot, now)
        self._due_us = self._earliest_deadline()
        self._urgent_due_us = self._urgent_deadline()
        self._checked_us = self._progress_us = now

    def _run(self) -> None:
        try:
            self.priority = _raise_nice(self._name, self._nice)
            self._power_on()
        finally:
            self._booted.set()
        while not self._stop.is_set() and self.failure is None:
            try:
                self._step()
            except Exception:  # never let one bad cycle kill the node
                logger.exception("%s: unexpected error", self._name)
                self._stop.wait(self._max_wait_s)

    def _step(self, *, block: bool = True) -> None:
        """One cycle; ``block=False`` (a `MultiRunner` waited already): never wait or sleep."""
        now = self._progress_us = self._clock()
        outage = self._outage
        if outage is not None and self._bus_dead and outage.due(now):
            self._reopen_bus(outage, now)
            if self.failure is not None:
                return
            now = self._clock()
        wait_s = 0.0
        if block and not self._submitted and not self._backlog:
            wait_s = self._max_wait_s
            for due in (self._due_us, self._urgent_due_us):
                if due is not None:
                    wait_s = min(wait_s, max(0, due - now) / 1e6)
        outage = self._outage
        if outage is None or (not self._bus_dead and outage.due(now)):
            msg = self._recv(wait_s)
        else:  # the bus is down: sleep until a device deadline or the next attempt
            if block:
                self._stop.wait(min(wait_s, max(0, outage.next_attempt_us - now) / 1e6))
            msg = None
        delivered = 0
        self._backlog = False
        while msg is not None:  # everything that has arrived, before any timer runs
            delivered += 1
            if not self._deliver_in_turn(msg):
                break
            if delivered >= self._max_batch:
                self._backlog = True  # more may wait: the next step does not wait
                break
            msg = self._recv(0.0)
        if self._backlog and self._supersede and self._outage is None and not self.failure:
            self._catch_up()
        now = self._clock()
        if self._urgent_due_us is not None and now >= self._urgent_due_us:
            self._serve_urgent(now)
        work: list[tuple[Frame, SansIoDevice | None, bool]] = []
        submitted = self._submitted
        while submitted:  # this thread alone takes: not empty, popleft cannot fail
            frame, to_bus, source = submitted.popleft()
            work.append((frame, source, to_bus))
        if work:
            with self._lock:
                self._stats.injected += len(work)
        if not block and not delivered and not work and now < self._timers_due_us():
            return  # polled by a MultiRunner with nothing new: the deadlines still hold
        self._dispatch(work, now)
        self._checked_us = now
        pending: list[int] = []
        advanced = False
        for device in self.devices:
            deadline = self._effective_deadline(device)
            if deadline is not None and deadline <= now:
                out = self._call(device, "advance", now)
                self._dispatch([(f, device, True) for f in out], now)
                advanced = True
            elif deadline is not None:
                pending.append(deadline)
        # The next wait: the deadlines just read hold until a device hears or runs again
        # (one next_deadline_us() per device and step; a command another thread posts to
        # a device is seen at the next frame or within max_wait_s, as before).
        self._due_us = self._earliest_deadline() if advanced else min(pending, default=None)

    def _timers_due_us(self) -> int:
        """When the timers must run again: the earliest deadline, and at least every
        ``max_wait_s`` (a command another thread posted to a device shows only there)."""
        every = self._checked_us + self._max_wait_us
        for due in (self._due_us, self._urgent_due_us):
            if due is not None and due < every:
                every = due
        return every

    def _wake_us(self) -> int | None:
        """When this runner needs its next step without a frame (for a `MultiRunner`)."""
        if self.failure is not None:
            return None
        if self._backlog or self._submitted:
            return 0
        outage = self._outage
        if outage is not None:
            return min(outage.next_attempt_us, self._timers_due_us())
        return self._timers_due_us()

    def _deliver(self, msg: can.Message) -> None:
        """One frame from the bus to every device; their replies go out at once."""
        frame = message_to_frame(msg) if msg.is_rx else None
        with self._lock:
            if frame is None:
                self._stats.ignored += 1
                return
            self._stats.frames_rx += 1
            self._stats.rx_by_cob_id[frame.can_id] += 1
        # `_dispatch([(frame, None, False)])` without its queue: most frames get no reply
        now = self._progress_us = self._clock()
        replies = self._replies(frame, None, now)
        if replies:
            self._dispatch(replies, now)

    def _deliver_in_turn(self, msg: can.Message) -> bool:
        """One received frame after any urgent timer now due (before the next frame, not
        after the batch); False once the bus is down or the runner has given up."""
        urgent = self._urgent_due_us
        if urgent is not None and self._clock() >= urgent:
            self._serve_urgent(self._clock(), between_frames=True)
        self._deliver(msg)
        return self._outage is None and not self.failure

    def _catch_up(self) -> None:
        """Read everything queued; deliver it in order but the superseded PDOs (`MAX_CATCH_UP`)."""
        queued: list[can.Message] = []
        while len(queued) < MAX_CATCH_UP and (msg := self._recv(0.0)) is not None:
            queued.append(msg)
        streams = frozenset().union(
            *(d.stream_can_ids() for d in self.devices if isinstance(d, StreamConsumer))
        )
        pdo = [_is_pdo(m) and m.arbitration_id not in streams for m in queued]
        newest = {m.arbitration_id: i for i, m in enumerate(queued) if pdo[i]}
        superseded: Counter[int] = Counter()
        for i, msg in enumerate(queued):
            if pdo[i] and newest[msg.arbitration_id] != i:
                superseded[msg.arbitration_id] += 1
                continue
            if not self._deliver_in_turn(msg):
                break
        self._backlog = len(queued) >= MAX_CATCH_UP
        dropped = sum(superseded.values())
        with self._lock:
            self._stats.catch_ups += 1
            self._stats.superseded += dropped
            self._stats.superseded_by_cob_id.update(superseded)
            total = self._stats.superseded
        now = self._clock()
        last = self._behind_logged_us
        if dropped and (last is None or now - last >= BEHIND_LOG_EVERY_US):
            self._behind_logged_us = now
            logger.warning(
                "%s: behind the bus by %d frames; dropped %d PDOs a newer one superseded "
                "(%d so far; service frames all delivered)",
                self._name,
                self._max_batch + len(queued),
                dropped,
                total,
            )

    def _earliest_deadline(self) -> int | None:
        deadlines = [d for d in map(self._effective_deadline, self.devices) if d is not None]
        return min(deadlines) if deadlines else None

    def _urgent_deadline(self) -> int | None:
        deadlines = [d for d in map(self._effective_deadline, self.urgent) if d is not None]
        return min(deadlines) if deadlines else None

    # -- urgent timers -----------------------------------------------------------------

    def _serve_urgent(self, now: int, *, between_frames: bool = False) -> None:
        """Run the urgent timers due at `now` (the runner's thread): sent, and delivered to
        the devices like any device's frames."""
        with self._urgent_lock:
            out = self._advance_urgent(now)
        if out:
            with self._lock:
                if between_frames:
                    self._stats.urgent_between_frames += 1
            self._dispatch(out, now)

    def _advance_urgent(self, now: int) -> list[tuple[Frame, SansIoDevice | None, bool]]:
        """Under `_urgent_lock`: the due urgent devices advanced, the next deadline kept."""
        out: list[tuple[Frame, SansIoDevice | None, bool]] = []
        for device in self.urgent:
            deadline = self._effective_deadline(device)
            if deadline is not None and deadline <= now:
                owner = self._owner[id(device)]
                out += [(f, owner, True) for f in self._call(device, "advance", now)]
        self._urgent_due_us = self._urgent_deadline()
        return out

    def _start_pacer(self) -> None:
        if self._pace and self._pacer is None:
            self._pacer = threading.Thread(
                target=self._pace_loop, name=f"{self._name} pacer", daemon=True
            )
            self._pacer.start()

    def _pace_loop(self) -> None:
        """The pacer thread: sleep until the next urgent deadline, serve it, repeat."""
        realtime, self.pacer_priority = raise_thread_priority()
        log = logger.info if realtime else logger.warning
        log("%s: urgent timers (heartbeat) on a thread of their own at %s",
            self._name, self.pacer_priority)  # fmt: skip
        stalled = False
        while not self._stop.is_set() and self.failure is None:
            due, now = self._urgent_due_us, self._clock()
            wait_us = self._max_wait_us if due is None else min(self._max_wait_us, due - now)
            if wait_us > 0 and self._stop.wait(wait_us / 1e6):
                return
            now = self._clock()
            if self._urgent_due_us is None or now < self._urgent_due_us:
                continue
            stuck_us = now - self._progress_us
            if stuck_us > self._stall_us:
                if not stalled:
                    stalled = True
                    with self._lock:
                        self._stats.stalls += 1
                    logger.error(
                        "%s: its thread has made no progress for %.1f s: heartbeat withheld "
                        "until it does (the nodes' consumers will time out)",
                        self._name,
                        stuck_us / 1e6,
                    )
                self._stop.wait(PACER_STALL_POLL_S)
                continue
            stalled = False
            with self._urgent_lock:
                out = self._advance_urgent(now)
            for frame, owner, _ in out:
                self._send(frame, paced=True)
                if any(d is not owner for d in self.devices):
                    self._enqueue(frame, False, owner)  # the others hear it at their next step
            if out:
                with self._lock:
                    self._stats.urgent_paced += 1
            due = self._urgent_due_us
            if due is not None and due <= self._clock():
                self._stop.wait(0.001)  # a device that failed: never spin at this priority

    def _effective_deadline(self, device: SansIoDevice) -> int | None:
        """The device's deadline, held back for a while after the device raised."""
        deadline = self._call_deadline(device)
        backoff = self._backoff_until.get(id(device))
        if backoff is None:
            return deadline
        if self._clock() >= backoff:
            del self._backoff_until[id(device)]
            return deadline
        return None if deadline is None else max(deadline, backoff)

    def _recv(self, wait_s: float) -> can.Message | None:
        try:
            msg = self.bus.recv(timeout=wait_s)
        except Exception as exc:
            with self._lock:
                self._stats.bus_errors += 1
            self._bus_failed(exc)
            return None
        if self._outage is not None:
            self._bus_back(self._outage, self._clock())
        return msg

    # -- outages ---------------------------------------------------------------------

    def _bus_label(self) -> str:
        return str(getattr(self.bus, "channel", "") or self.bus)

    def _bus_failed(self, exc: Exception) -> None:
        """A receive or send failed: start an outage, or count a failed attempt."""
        now = self._clock()
        self._bus_dead = self._bus_dead or isinstance(exc, BusDisconnected)
        self._last_bus_error = str(exc) or type(exc).__name__
        if self._bus_dead and self._reopen is None:
            self._give_up(
                f"lost the bus {self._bus_label()} ({self._last_bus_error}) and cannot reopen it"
            )
            return
        if self._outage is None:
            self._outage = Backoff(now, self._reconnect_timeout_us, self._first_retry_us)
            how = "reconnecting" if self._bus_dead else "retrying"
            logger.error(
                "%s: lost the bus %s (%s); %s for up to %g s",
                self._name,
                self._bus_label(),
                self._last_bus_error,
                how,
                self._reconnect_timeout_us / 1e6,
            )
            return
        self._attempt_failed(self._outage, now)

    def _attempt_failed(self, outage: Backoff, now: int) -> None:
        delay_us = outage.failed(now)
        if delay_us is None:
            self._give_up(
                f"lost the bus {self._bus_label()} and could not get it back within "
                f"{self._reconnect_timeout_us / 1e6:g} s ({outage.attempts} attempts; "
                f"last: {self._last_bus_error})"
            )
            return
        logger.warning(
            "%s: reconnect attempt %d failed (%s); next attempt in %.1f s",
            self._name,
            outage.attempts,
            self._last_bus_error,
            delay_us / 1e6,
        )

    def _reopen_bus(self, outage: Backoff, now: int) -> None:
        assert self._reopen is not None
        try:
            bus = self._reopen()
        except Exception as exc:
            self._last_bus_error = str(exc) or type(exc).__name__
            self._attempt_failed(outage, now)
            return
        with self._send_lock:
            old, self.bus = self.bus, bus
        if self._owned is old:
            try:
                old.shutdown()
            except Exception:
                logger.debug("%s: shutting down the lost bus failed", self._name, exc_info=True)
        self._owned = bus
        self._bus_dead = False
        self._bus_back(outage, self._clock())

    def _bus_back(self, outage: Backoff, now: int) -> None:
        self._outage = None
        with self._lock:
            self._stats.reconnects += 1
        logger.warning(
            "%s: bus %s back after %.1f s and %d failed attempt(s); the devices kept their state",
            self._name,
            self._bus_label(),
            outage.down_us(now) / 1e6,
            outage.attempts,
        )

    def _give_up(self, why: str) -> None:
        self.failure = BusError(why)
        logger.info("%s: giving up: %s", self._name, why)

    def _dispatch(self, work: Iterable[tuple[Frame, SansIoDevice | None, bool]], now: int) -> None:
        """Send frames and deliver them locally; replies join the same work list."""
        pending = deque(work)
        handled = 0
        while pending:
            if handled >= self._cascade_limit:
                logger.error(
                    "%s: more than %d frames in one reply cascade; dropping %d",
                    self._name,
                    self._cascade_limit,
                    len(pending),
                )
                with self._lock:
                    self._stats.dropped += len(pending)
                return
            handled += 1
            frame, source, to_bus = pending.popleft()
            if to_bus:
                self._send(frame)
            pending.extend(self._replies(frame, source, now))

    def _replies(
        self, frame: Frame, source: SansIoDevice | None, now: int
    ) -> list[tuple[Frame, SansIoDevice | None, bool]]:
        """`frame` delivered to every device but its source; their replies, in device order,
        each to go on the bus and to the others."""
        replies: list[tuple[Frame, SansIoDevice | None, bool]] = []
        for device in self.devices:
            if device is not source:
                out = self._call(device, "receive", frame, now)
                if out:
                    replies += [(f, device, True) for f in out]
        return replies

    def _send(self, frame: Frame, *, paced: bool = False) -> None:
        """Send one frame; `paced` from the pacer thread, whose failures are only counted:
        outages are the runner's thread's to notice and handle."""
        if self._outage is not None or self.failure is not None:
            with self._lock:
                self._stats.offline_drops += 1
            return
        try:
            with self._send_lock:
                self.bus.send(frame_to_message(frame))
        except Exception as exc:
            with self._lock:
                self._stats.send_errors += 1
            if paced:
                logger.debug("%s: pacer sending 0x%03X failed: %s", self._name, frame.can_id, exc)
            elif isinstance(exc, BusDisconnected):
                self._bus_failed(exc)
            else:
                log = logger.debug if self._send_failing else logger.warning
                log("%s: sending 0x%03X failed: %s", self._name, frame.can_id, exc)
                self._send_failing = True
            return
        if not paced:
            self._send_failing = False
        with self._lock:
            self._stats.frames_tx += 1
            self._stats.tx_by_cob_id[frame.can_id] += 1

    def _call(self, device: SansIoDevice, method: str, *args: object) -> list[Frame]:
        try:
            out = getattr(device, method)(*args)
            if not out:
                return []
            frames = list(out)
            bad = [f for f in frames if not isinstance(f, Frame)]
            if bad:
                raise TypeError(f"{method}() returned {type(bad[0]).__name__}, not Frame")
        except Exception:
            logger.exception("device node %s: %s() failed", _node_id(device), method)
            self._device_failed(device)
            return []
        if frames:
            with self._lock:
                self._stats.tx_by_node[_node_id(device)] += len(frames)
        return frames

    def _call_deadline(self, device: SansIoDevice) -> int | None:
        try:
            return device.next_deadline_us()
        except Exception:
            if id(device) not in self._backoff_until:
                logger.exception("device node %s: next_deadline_us() failed", _node_id(device))
                self._device_failed(device)
            return None

    def _device_failed(self, device: SansIoDevice) -> None:
        # A device that raises at its deadline would otherwise be retried in a
        # tight loop; give it 100 ms before its timers run again.
        self._backoff_until[id(device)] = self._clock() + DEVICE_BACKOFF_US
        with self._lock:
            self._stats.device_errors += 1


class MultiRunner:
    """Several `NodeRunner`s (each its own bus and devices) served by one thread.

    Why: N gateways in one process on N runner threads each wake per frame and
    pass the GIL back and forth, and a thread that got the GIL late finds its
    peers' timers due too. One thread waits on every bus at once (``select``
    on the buses' file descriptors: SocketCAN, socket links), then steps only
    the runners whose bus has frames or whose timers are due, each exactly as
    its own thread would (frames first, then timers; outages, back-off and
    reopening per runner). A bus without a file descriptor (python-can's
    virtual bus, the hub client) is polled every ``poll_s``. A runner that
    gives up on its bus (`NodeRunner.failure`) is dropped; the others go on.
    The runners must not be started themselves; `stop` stops them all.

    ``tick_s`` > 0 wakes for timers only on a grid of that period, as a
    firmware's RTOS tick does: timers of many devices that fall due within one
    tick run in one wake-up (a process simulating many node sets wakes at most
    1/tick_s times a second for them instead of once per TPDO), each at most
    one tick late. Frames still wake the thread at once.
    """

    def __init__(
        self,
        runners: Sequence[NodeRunner],
        *,
        name: str = "grasplink-multi-runner",
        max_wait_s: float = 0.02,
        poll_s: float = 0.001,
        tick_s: float = 0.0,
        nice: int | None = None,
    ) -> None:
        if not runners:
            raise ValueError("MultiRunner needs at least one runner")
        if not 0.0 <= tick_s <= max_wait_s:
            raise ValueError("tick_s must be within [0, max_wait_s]")
        if any(r._thread is not None for r in runners):
            raise ValueError("a MultiRunner's runners must not have their own thread")
        self.runners = list(runners)
        self._name = name
        self._max_wait_s = max_wait_s
        self._poll_s = poll_s
        self._tick_us = round(tick_s * 1e6)
        self._nice = nice
        self.priority: str | None = None  # what the host granted the thread
        self._selector = selectors.DefaultSelector()
        self._registered: dict[int, int] = {}  # id(runner) -> the fd registered for it
        self._stop = threading.Event()
        self._booted = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self, timeout: float = 5.0) -> MultiRunner:
        """Start the thread; returns once every runner's devices have booted."""
        self._thread = _start_thread(self, self._run, timeout)
        for runner in self.runners:
            runner._start_pacer()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the thread, then every runner (idempotent)."""
        if not _stop_thread(self, timeout):
            return
        for runner in self.runners:
            runner.stop()
        self._selector.close()

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def __enter__(self) -> MultiRunner:
        return self.start()

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def power_on(self) -> None:
        """Boot every runner's devices (the thread's first act; public like `step`)."""
        for runner in self.runners:
            runner.power_on()

    def step(self) -> None:
        """One cycle: wait for any bus (until the earliest deadline), step who needs it."""
        if self._thread is not None and self._thread.is_alive():
            raise RuntimeError("step() while the MultiRunner's thread runs")
        self._cycle()

    def _run(self) -> None:
        try:
            self.priority = _raise_nice(self._name, self._nice)
            for runner in self.runners:
                runner._power_on()
        finally:
            self._booted.set()
        while not self._stop.is_set() and any(r.failure is None for r in self.runners):
            try:
                self._cycle()
            except Exception:  # never let one bad cycle stop every bus
                logger.exception("%s: unexpected error", self._name)
                self._stop.wait(self._max_wait_s)

    def _cycle(self) -> None:
        for runner in self.runners:
            if runner.failure is not None and id(runner) in self._registered:
                self._unregister(runner)  # its bus may stay readable (EOF) for ever
        live = [r for r in self.runners if r.failure is None]
        for runner in live:  # this thread is alive for each of them (their pacers look)
            runner._progress_us = runner._clock()
        polled = [r for r in live if not self._watch(r)]
        timeout = self._poll_s if polled else self._max_wait_s
        due: list[NodeRunner] = []
        for runner in live:
            wake = runner._wake_us()
            if wake is None:
                continue
            left_us = wake - runner._clock()
            if left_us <= 0:
                due.append(runner)
            timeout = min(timeout, max(0, left_us) / 1e6)
        if self._tick_us and not due and live:
            timeout = on_tick(live[0]._clock(), timeout, self._tick_us)
        ready = {key.data for key, _ in self._selector.select(0.0 if due else timeout)}
        for runner in live:
            if id(runner) in ready or runner in polled or runner in due:
                runner._step(block=False)
            elif (wake := runner._wake_us()) is not None and wake <= runner._clock():
                runner._step(block=False)  # its deadline passed while we waited

    def _watch(self, runner: NodeRunner) -> bool:
        """Keep the runner's bus registered with the selector; False if it cannot be."""
        fd = -1
        if runner._outage is None:
            try:
                fd = runner.bus.fileno()
            except (NotImplementedError, AttributeError, OSError):
                fd = -1
        old = self._registered.get(id(runner))
        if old == fd:
            return fd >= 0
        self._unregister(runner)
        self._registered[id(runner)] = fd
        if fd >= 0:
            try:
                self._selector.register(fd, selectors.EVENT_READ, id(runner))
            except (KeyError, ValueError, OSError):
                self._registered[id(runner)] = -1
                return False
        return fd >= 0

    def _unregister(self, runner: NodeRunner) -> None:
        old = self._registered.pop(id(runner), -1)
        if old >= 0:
            with contextlib.suppress(KeyError, ValueError, OSError):
                self._selector.unregister(old)


def _raise_nice(name: str, nice: int | None) -> str:
    """The calling runner thread at `nice` (None: left as it is); what it got, logged."""
    if nice is None:
        return "normal priority"
    granted, what = raise_thread_nice(nice)
    (logger.info if granted else logger.warning)("%s: thread at %s", name, what)
    return what


def on_tick(now_us: int, wait_s: float, tick_us: int) -> float:
    """The wait that ends at the first multiple of ``tick_us`` at or after ``now + wait_s``."""
    wake_us = now_us + round(wait_s * 1e6)
    return (-(-wake_us // tick_us) * tick_us - now_us) / 1e6


def _node_id(device: object) -> int:
    node_id = getattr(device, "node_id", -1)
    return node_id if isinstance(node_id, int) else -1


def _start_thread(
    owner: NodeRunner | MultiRunner, run: Callable[[], None], timeout: float
) -> threading.Thread:
    """The owner's one thread, started; returns once the owner says it has booted."""
    if owner._thread is not None:
        raise RuntimeError(f"{type(owner).__name__} can only be started once")
    thread = threading.Thread(target=run, name=owner._name, daemon=True)
    thread.start()
    owner._booted.wait(timeout)
    return thread


def _stop_thread(owner: NodeRunner | MultiRunner, timeout: float) -> bool:
    """Ask the owner's thread to stop and wait for it; False if it is still running."""
    owner._stop.set()
    thread = owner._thread
    if thread is not None and thread is not threading.current_thread():
        thread.join(timeout)
        if thread.is_alive():
            logger.warning("%s did not stop within %.1f s", owner._name, timeout)
            return False
    return True


_PDO_BASES = frozenset(TPDO_BASES + RPDO_BASES)


def _is_pdo(msg: can.Message) -> bool:
    """A classic data frame on a predefined-connection-set PDO CAN-ID (181h-57Fh)."""
    if msg.is_extended_id or msg.is_error_frame or msg.is_remote_frame or msg.is_fd:
        return False
    can_id = msg.arbitration_id
    return can_id & NODE_ID_MASK != 0 and can_id & ~NODE_ID_MASK in _PDO_BASES

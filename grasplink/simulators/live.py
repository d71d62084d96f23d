"""A scene on a live CAN bus: its nodes and physics in real time, beside whatever else is there.

The lock-step network runs the bus in virtual time after each chunk's physics. On a
real bus (python-can: virtual, the loopback hub, SocketCAN, any adapter) time is the
wall clock's and the bus runs in a `NodeRunner` thread. Its first device, the
`PhysicsStepper`, steps the physics of each chunk through the same
`Simulation.step_physics` the lock-step run calls, as soon as the runner's time reaches
the chunk: it hears every frame and runs before every timer, so no node samples into a
chunk before its physics exists. Nodes and physics are touched by the runner's thread
alone; the caller's thread only waits for the clock and watches.

Scene time is the runner's clock: microseconds since `start`, held at the scene's last
microsecond once the scene is over, so a node never samples past its physics.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import can

from grasplink.bus.lockstep import Tap
from grasplink.bus.reconnect import DEFAULT_RECONNECT_TIMEOUT_S
from grasplink.bus.runner import NodeRunner
from grasplink.core.frames import Frame
from grasplink.core.protocol import SansIoDevice

# The bus's thread runs ahead of ordinary work, as the gateway's does (a loaded host must
# not stall the nodes' heartbeats and TPDOs), but not real-time: its physics can grow.
SCENE_NICE = -10
# The caller's thread looks at the clock at least this often (a stop request, a lost bus).
WATCH_PERIOD_S = 0.05


@dataclass(frozen=True)
class LiveBus:
    """An open python-can bus for a scene, its URL, and how to get it back if lost."""

    bus: can.BusABC
    url: str
    reopen: Callable[[], can.BusABC] | None = None
    reconnect_timeout_s: float = DEFAULT_RECONNECT_TIMEOUT_S


class PhysicsStepper:
    """The scene's physics as a participant of a live bus: each chunk stepped when it begins.

    Not a node (it sends nothing); it hears every frame on the bus and every frame the
    runner's nodes send, and hands them to the taps (the recorder) at their bus time.
    """

    node_id = 0  # NMT's "all nodes" address: no node has it

    def __init__(
        self, step: Callable[[int], None], chunk_us: int, duration_us: int, taps: list[Tap]
    ) -> None:
        self._step = step
        self._chunk_us = chunk_us
        self._duration_us = duration_us
        self._next_us: int | None = 0 if duration_us > 0 else None
        self.taps = taps
        self.stepped_to_us = 0  # the physics exists up to here
        self.chunks = 0
        self.late_chunks = 0  # chunks stepped more than one chunk after they began
        self.max_late_us = 0  # the latest a chunk's physics was stepped after it began
        self.failure: Exception | None = None  # what the physics raised; no chunk after it

    def catch_up(self, t_us: int) -> None:
        """Step every chunk that has begun by `t_us`."""
        while self._next_us is not None and self._next_us <= t_us:
            late_us = t_us - self._next_us
            self.max_late_us = max(self.max_late_us, late_us)
            self.late_chunks += late_us > self._chunk_us
            end_us = min(self._next_us + self._chunk_us, self._duration_us)
            try:
                self._step(end_us)
            except Exception as exc:  # the caller's thread raises it: a bug, not the bus's
                self.failure = exc
                self._next_us = None
                return
            self.chunks += 1
            self.stepped_to_us = end_us
            self._next_us = end_us if end_us < self._duration_us else None

    def start(self, t_us: int) -> list[Frame]:
        self.catch_up(t_us)
        return []

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        self.catch_up(t_us)
        for tap in self.taps:
            tap(t_us, frame, None)
        return []

    def advance(self, t_us: int) -> list[Frame]:
        self.catch_up(t_us)
        return []

    def next_deadline_us(self) -> int | None:
        return self._next_us


class LiveNetwork:
    """The scene's participants on a live bus in real time, with the physics stepped in step.

    Offers what the engine uses of the lock-step network: `taps`, `start`, `run_until`
    (here: wait until the bus's time gets there), plus `stop`, which the engine calls
    when the run ends (the caller owns the bus).
    """

    def __init__(
        self,
        live: LiveBus,
        devices: Sequence[SansIoDevice],
        step: Callable[[int], None],
        *,
        chunk_us: int,
        duration_us: int,
        name: str,
    ) -> None:
        self.url = live.url
        self.taps: list[Tap] = []
        self.stepper = PhysicsStepper(step, chunk_us, duration_us, self.taps)
        self._last_us = max(0, duration_us - 1)
        self._t0_ns: int | None = None
        self.runner = NodeRunner(
            live.bus,
            [self.stepper, *devices],
            clock_us=self.clock_us,
            name=name,
            reopen=live.reopen,
            reconnect_timeout_s=live.reconnect_timeout_s,
            nice=SCENE_NICE,
        )

    def clock_us(self) -> int:
        """Scene time: µs since `start`, held at the scene's last µs once it is over."""
        if self._t0_ns is None:
            return 0
        return min((time.monotonic_ns() - self._t0_ns) // 1000, self._last_us)

    @property
    def t_us(self) -> int:
        return self.clock_us()

    def start(self) -> None:
        """Scene time 0 is now: the physics of the first chunk, then the nodes' boot-up."""
        self._t0_ns = time.monotonic_ns()
        self.runner.start()

    def run_until(self, t_us: int) -> None:
        """Wait until the bus's time reaches `t_us`; raises the runner's `BusError` if it
        gave up on its bus, or what the physics raised on the bus's thread."""
        while True:
            if self.runner.failure is not None:
                raise self.runner.failure
            if self.stepper.failure is not None:
                raise self.stepper.failure
            left_us = min(t_us, self._last_us) - self.clock_us()
            if left_us <= 0:
                return
            time.sleep(min(left_us / 1e6, WATCH_PERIOD_S))

    def stop(self) -> None:
        self.runner.stop()

    def timing(self) -> dict:
        """How well real time was kept, for the summary."""
        stats = self.runner.stats
        stepper = self.stepper
        return {
            "chunks": stepper.chunks,
            "late_chunks": stepper.late_chunks,
            "max_late_ms": round(stepper.max_late_us / 1000, 3),
            "frames_sent": stats.frames_tx,
            "frames_received": stats.frames_rx,
            "send_errors": stats.send_errors,
            "device_errors": stats.device_errors,
            "reconnects": stats.reconnects,
        }

"""A deterministic in-memory CAN network in virtual time.

Sans-IO devices exchange frames in a fixed order; time jumps from one
device deadline to the next, so tests and scenes run as fast as the machine
allows and give the same result every run. Taps observe every frame
(logging, bus load); `inject` plays an external tool on the bus. An optional
`FaultyLink` delays, jitters or drops frames and raises error frames.

A device that says which CAN-IDs concern it (`FilteringDevice`: the grasplink nodes)
receives only those frames, as behind a CAN controller's acceptance filter: in a loop
most frames are other nodes' process data, and a call per node per frame was most of
what the bus cost. Every other device (a master, a log player) receives every frame.

A device that can tell its next ticks ahead (`StreamingDevice`: a sensor node streaming
packets) is asked for a span of them in one call when its deadline comes; each tick's
frames then go out at its own time, in its turn among the devices due then, as if
`advance` had been called there. Before anything reaches the device (a frame its filter
accepts, a restart) and at the end of every run the bus tells it how many ticks happened
(`commit_stream`): the rest are dropped and told again later, so every participant, tap
and recording sees the frames the per-tick path sends, at the same times, in the same
order (`stream=False` takes that path).
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from collections.abc import Callable, Iterable

from grasplink.bus.faults import ErrorFrame, FaultyLink
from grasplink.core.frames import UNCONFIGURED_NODE_ID, Frame
from grasplink.core.protocol import FilteringDevice, SansIoDevice, StreamingDevice
from grasplink.errors import ConfigError

Tap = Callable[[int, Frame | ErrorFrame, object], None]  # (t_us, frame, sender or None)
MAX_STEPS_AT_ONE_TIME = 100_000


class LockstepNetwork:
    def __init__(
        self,
        devices: Iterable[SansIoDevice] = (),
        link: FaultyLink | None = None,
        *,
        stream: bool = True,
    ):
        self.devices: list[SansIoDevice] = []
        # Per device, its acceptance filter (`FilteringDevice.accepted_can_ids`) or None.
        self._filters: list[Callable[[], frozenset[int]] | None] = []
        # Per device, itself if it tells its ticks ahead (and `stream` is on), else None;
        # the spans told and not yet settled (device index -> span).
        self.stream = stream
        self._streamers: list[StreamingDevice | None] = []
        self._spans: dict[int, _Span] = {}
        self._declined: set[int] = set()  # told nothing up to this run's end: not asked
        self.t_us = 0
        self.taps: list[Tap] = []
        self.frames_delivered = 0
        self.link = link
        # Frames in flight on a slow link: (deliver_at_us, order, sender, frame).
        self._in_flight: list[tuple[int, int, object, Frame]] = []
        self._order = itertools.count()
        # A sans-IO device's deadline changes only when it is called, so within a
        # run it is asked again only then (device index -> deadline; missing = ask).
        # Each run starts afresh: callers may have changed devices in between.
        self._deadlines: dict[int, int | None] = {}
        # The deadline each device last gave, kept when called since: where a span told
        # ahead should end is a guess (a frame ends it anyway), and asking a master again
        # after every frame it hears would cost more than the span saves.
        self._last_deadlines: dict[int, int | None] = {}
        for device in devices:
            self.add(device)

    def add(self, device: SansIoDevice) -> None:
        # Unconfigured nodes (FFh) share their "node-ID" until LSS gives them theirs.
        if device.node_id != UNCONFIGURED_NODE_ID and any(
            d.node_id == device.node_id for d in self.devices
        ):
            raise ConfigError(f"two nodes with node-ID 0x{device.node_id:02X} on one bus")
        self.devices.append(device)
        self._filters.append(
            device.accepted_can_ids if isinstance(device, FilteringDevice) else None
        )
        self._streamers.append(
            device
            if self.stream and isinstance(device, StreamingDevice) and device.streaming
            else None
        )

    def start(self) -> None:
        for device in self.devices:
            self.start_device(device)

    def start_device(self, device: SansIoDevice) -> None:
        """Power one device (again) at the current time."""
        index = self.devices.index(device)
        self._settle(index)
        self._deadlines.pop(index, None)
        self._deliver(device, device.start(self.t_us))

    def inject(self, frame: Frame) -> list[Frame]:
        """Send a frame as an external tool would; returns every frame it caused."""
        caused: list[Frame] = []
        self._deliver(None, [frame], caused)
        return caused[1:]

    def run_until(self, t_end_us: int) -> None:
        self._deadlines.clear()
        self._declined.clear()
        try:
            self._run(t_end_us)
        finally:
            for index in list(self._spans):
                self._settle(index)

    def _run(self, t_end_us: int) -> None:
        deadlines = self._deadlines
        steps_at_t = 0
        while True:
            # Every device's deadline (asked again only of those called since), and the
            # earliest: this loop runs once per tick of any device.
            due: list[tuple[int, int]] = []
            t_next: int | None = None
            for i in range(len(self.devices)):
                t = deadlines[i] if i in deadlines else self._ask_deadline(i)
                if t is not None:
                    due.append((t, i))
                    if t_next is None or t < t_next:
                        t_next = t
            t_next = _earliest(t_next, self._in_flight[0][0] if self._in_flight else None)
            t_error = self.link.next_error_us(self.t_us) if self.link else None
            t_next = _earliest(t_next, t_error)
            if t_next is None or t_next > t_end_us:
                self.t_us = max(self.t_us, t_end_us)
                return
            if t_next <= self.t_us:
                steps_at_t += 1
                if steps_at_t > MAX_STEPS_AT_ONE_TIME:
                    raise RuntimeError(f"devices make no progress at t={self.t_us} us")
            else:
                steps_at_t = 0
            self.t_us = max(self.t_us, t_next)
            if self.link is not None and t_error is not None and t_error <= self.t_us:
                self.link.take_error()
                for tap in self.taps:
                    tap(self.t_us, ErrorFrame(), None)
            while self._in_flight and self._in_flight[0][0] <= self.t_us:
                _, _, sender, frame = heapq.heappop(self._in_flight)
                self._arrive(sender, frame)
            for t, i in due:
                if t <= self.t_us:
                    device = self.devices[i]
                    self._deadlines.pop(i, None)
                    self._deliver(device, self._tick(i, device, t_end_us))

    def _tick(self, index: int, device: SansIoDevice, t_end_us: int) -> list[Frame]:
        """The frames device `index` sends at its deadline now: its span's next tick, or a
        new span's first, or those of `advance`. A span is told up to the run's end or
        the next time another device acts (any frame could concern it and end the span:
        ticks told beyond are often told in vain), whichever is first."""
        span = self._spans.get(index)
        if span is not None:
            frames = span.take()
            if span.taken == len(span.ticks):
                self._settle(index)
            return frames
        streamer = self._streamers[index]
        if streamer is not None and index not in self._declined:
            reach_us = streamer.stream_until_us(self.t_us)
            if reach_us is None:  # it cannot stream now (it may once started)
                return device.advance(self.t_us)
            if reach_us > t_end_us:
                # Too few ticks before the run's end, whatever the other devices do: asked,
                # it would tell nothing to the run's end (declined below). Saves the bound
                # over every device and the node's own checks at each of its ticks.
                self._declined.add(index)
                return device.advance(self.t_us)
            until_us = t_end_us
            deadlines, last = self._deadlines, self._last_deadlines
            for i in range(len(self.devices)):
                if i == index:
                    continue
                t = deadlines[i] if i in deadlines else last.get(i)
                if i not in deadlines and (t is None or t <= self.t_us):
                    t = self._ask_deadline(i)  # called since it gave one, which is now
                if t is not None and self.t_us < t < until_us:
                    until_us = t
            if self._in_flight:
                until_us = max(self.t_us, min(until_us, self._in_flight[0][0]))
            ticks = streamer.stream_ahead(self.t_us, until_us)
            if not ticks and until_us == t_end_us:
                # Nothing to tell up to the run's end: later in the run there is less.
                self._declined.add(index)
            if ticks:
                span = self._spans[index] = _Span(ticks)
                frames = span.take()
                if len(ticks) == 1:
                    self._settle(index)
                return frames
        return device.advance(self.t_us)

    def _ask_deadline(self, index: int) -> int | None:
        """Device `index`'s deadline, asked now (its span's next tick while it has one),
        kept for this run and as the last it gave."""
        span = self._spans.get(index)
        t = span.next_us() if span else self.devices[index].next_deadline_us()
        self._deadlines[index] = self._last_deadlines[index] = t
        return t

    def _settle(self, index: int) -> None:
        """Tell device `index` how much of its span happened; the rest is dropped."""
        span = self._spans.pop(index, None)
        if span is not None:
            streamer = self._streamers[index]
            assert streamer is not None
            streamer.commit_stream(span.taken)

    def run_for(self, duration_us: int) -> None:
        self.run_until(self.t_us + duration_us)

    def _deliver(
        self, sender: SansIoDevice | None, frames: list[Frame], caused: list[Frame] | None = None
    ) -> None:
        """Put frames on the bus; replies cascade at once (or later on a slow link)."""
        if not frames:
            return  # most ticks send nothing
        queue: deque[tuple[SansIoDevice | None, Frame]] = deque((sender, f) for f in frames)
        while queue:
            origin, frame = queue.popleft()
            self.frames_delivered += 1
            if caused is not None:
                caused.append(frame)
            for tap in self.taps:
                tap(self.t_us, frame, origin)
            delay = self.link.delay_us(frame) if self.link is not None else 0
            if delay is None:
                continue  # lost on the wire: nobody receives it
            if delay:
                entry = (self.t_us + delay, next(self._order), origin, frame)
                heapq.heappush(self._in_flight, entry)
                continue
            queue.extend(self._replies(origin, frame))

    def _replies(self, origin: object, frame: Frame) -> list[tuple[SansIoDevice, Frame]]:
        replies: list[tuple[SansIoDevice, Frame]] = []
        can_id = frame.can_id
        for i, device in enumerate(self.devices):
            if device is origin:
                continue
            accepted = self._filters[i]
            if accepted is not None and can_id not in accepted():
                continue  # its filter drops the frame: nothing in it changes
            self._deadlines.pop(i, None)
            if i in self._spans:
                self._settle(i)  # it is as the ticks so far left it, no further
            sent = device.receive(frame, self.t_us)
            if sent:
                replies.extend([(device, f) for f in sent])
        return replies

    def _arrive(self, origin: object, frame: Frame) -> None:
        """A delayed frame reaches the receivers; their replies go on the bus."""
        for device, reply in self._replies(origin, frame):
            self._deliver(device, [reply])


class _Span:
    """A streaming device's ticks told ahead, and how many of them went out."""

    __slots__ = ("taken", "ticks")

    def __init__(self, ticks: list[tuple[int, list[Frame]]]):
        self.ticks = ticks
        self.taken = 0

    def next_us(self) -> int:
        return self.ticks[self.taken][0]

    def take(self) -> list[Frame]:
        frames = self.ticks[self.taken][1]
        self.taken += 1
        return frames


def _earliest(a: int | None, b: int | None) -> int | None:
    if a is None:
        return b
    return a if b is None else min(a, b)

"""A deterministic in-memory CAN network in virtual time.

Sans-IO devices exchange frames in a fixed order; time jumps from one
device deadline to the next, so tests and scenes run as fast as the machine
allows and give the same result every run. Taps observe every frame
(logging, bus load); `inject` plays an external tool on the bus. An optional
`FaultyLink` delays, jitters or drops frames and raises error frames.
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from collections.abc import Callable, Iterable

from grasplink.bus.faults import ErrorFrame, FaultyLink
from grasplink.core.frames import UNCONFIGURED_NODE_ID, Frame
from grasplink.core.protocol import SansIoDevice
from grasplink.errors import ConfigError

Tap = Callable[[int, Frame | ErrorFrame, object], None]  # (t_us, frame, sender or None)
MAX_STEPS_AT_ONE_TIME = 100_000


class LockstepNetwork:
    def __init__(self, devices: Iterable[SansIoDevice] = (), link: FaultyLink | None = None):
        self.devices: list[SansIoDevice] = []
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
        for device in devices:
            self.add(device)

    def add(self, device: SansIoDevice) -> None:
        # Unconfigured nodes (FFh) share their "node-ID" until LSS gives them theirs.
        if device.node_id != UNCONFIGURED_NODE_ID and any(
            d.node_id == device.node_id for d in self.devices
        ):
            raise ConfigError(f"two nodes with node-ID 0x{device.node_id:02X} on one bus")
        self.devices.append(device)

    def start(self) -> None:
        for device in self.devices:
            self.start_device(device)

    def start_device(self, device: SansIoDevice) -> None:
        """Power one device (again) at the current time."""
        self._deadlines.pop(self.devices.index(device), None)
        self._deliver(device, device.start(self.t_us))

    def _deadline(self, i: int) -> int | None:
        if i not in self._deadlines:
            self._deadlines[i] = self.devices[i].next_deadline_us()
        return self._deadlines[i]

    def inject(self, frame: Frame) -> list[Frame]:
        """Send a frame as an external tool would; returns every frame it caused."""
        caused: list[Frame] = []
        self._deliver(None, [frame], caused)
        return caused[1:]

    def run_until(self, t_end_us: int) -> None:
        self._deadlines.clear()
        steps_at_t = 0
        while True:
            due = [(t, i) for i in range(len(self.devices)) if (t := self._deadline(i)) is not None]
            t_next = min((t for t, _ in due), default=None)
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
                    self._deliver(device, device.advance(self.t_us))

    def run_for(self, duration_us: int) -> None:
        self.run_until(self.t_us + duration_us)

    def _deliver(
        self, sender: SansIoDevice | None, frames: list[Frame], caused: list[Frame] | None = None
    ) -> None:
        """Put frames on the bus; replies cascade at once (or later on a slow link)."""
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
        for i, device in enumerate(self.devices):
            if device is not origin:
                self._deadlines.pop(i, None)
                replies.extend((device, f) for f in device.receive(frame, self.t_us))
        return replies

    def _arrive(self, origin: object, frame: Frame) -> None:
        """A delayed frame reaches the receivers; their replies go on the bus."""
        for device, reply in self._replies(origin, frame):
            self._deliver(device, [reply])


def _earliest(a: int | None, b: int | None) -> int | None:
    if a is None:
        return b
    return a if b is None else min(a, b)

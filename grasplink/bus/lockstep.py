"""A deterministic in-memory CAN network in virtual time.

Sans-IO devices exchange frames instantly and in a fixed order; time jumps
from one device deadline to the next, so tests and scenes run as fast as
the machine allows and give the same result every run. Taps observe every
frame (logging, bus load); `inject` plays an external tool on the bus.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable

from grasplink.devices.frames import Frame
from grasplink.devices.protocol import SansIoDevice
from grasplink.errors import ConfigError

Tap = Callable[[int, Frame, object], None]  # (t_us, frame, sender or None)
MAX_STEPS_AT_ONE_TIME = 100_000


class LockstepNetwork:
    def __init__(self, devices: Iterable[SansIoDevice] = ()):
        self.devices: list[SansIoDevice] = []
        self.t_us = 0
        self.taps: list[Tap] = []
        self.frames_delivered = 0
        for device in devices:
            self.add(device)

    def add(self, device: SansIoDevice) -> None:
        if any(d.node_id == device.node_id for d in self.devices):
            raise ConfigError(f"two nodes with node-ID 0x{device.node_id:02X} on one bus")
        self.devices.append(device)

    def start(self) -> None:
        for device in self.devices:
            self._deliver(device, device.start(self.t_us))

    def start_device(self, device: SansIoDevice) -> None:
        """Power one device (again) at the current time."""
        self._deliver(device, device.start(self.t_us))

    def inject(self, frame: Frame) -> list[Frame]:
        """Send a frame as an external tool would; returns every frame it caused."""
        caused: list[Frame] = []
        self._deliver(None, [frame], caused)
        return caused[1:]

    def run_until(self, t_end_us: int) -> None:
        steps_at_t = 0
        while True:
            deadlines = [(d.next_deadline_us(), i) for i, d in enumerate(self.devices)]
            due = [(t, i) for t, i in deadlines if t is not None]
            t_next = min((t for t, _ in due), default=None)
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
            for t, i in due:
                if t <= self.t_us:
                    device = self.devices[i]
                    self._deliver(device, device.advance(self.t_us))

    def run_for(self, duration_us: int) -> None:
        self.run_until(self.t_us + duration_us)

    def _deliver(
        self, sender: SansIoDevice | None, frames: list[Frame], caused: list[Frame] | None = None
    ) -> None:
        queue: deque[tuple[SansIoDevice | None, Frame]] = deque((sender, f) for f in frames)
        while queue:
            origin, frame = queue.popleft()
            self.frames_delivered += 1
            if caused is not None:
                caused.append(frame)
            for tap in self.taps:
                tap(self.t_us, frame, origin)
            for device in self.devices:
                if device is not origin:
                    queue.extend((device, f) for f in device.receive(frame, self.t_us))

"""The sans-IO contract every simulated device (and the runners) agree on."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

from grasplink.core.frames import Frame


class SansIoDevice(Protocol):
    """A device fed integer-microsecond time and frames; it returns frames to send.

    Time only moves forward; `t_us` is the caller's clock (virtual or wall).
    A runner calls `advance` no later than `next_deadline_us()` so timers
    (heartbeat, event timers, sampling) fire on time, and `receive` for every
    frame seen on the bus. The device never sleeps or touches a socket.
    """

    node_id: int

    def start(self, t_us: int) -> list[Frame]:
        """Power on: initialise and return the boot-up frame."""
        ...

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        """Handle one frame from the bus."""
        ...

    def advance(self, t_us: int) -> list[Frame]:
        """Run timers and device behaviour up to `t_us`."""
        ...

    def next_deadline_us(self) -> int | None:
        """The earliest time `advance` has something to do, or None."""
        ...


@runtime_checkable
class FilteringDevice(SansIoDevice, Protocol):
    """A device that says which frames can concern it, as a CAN controller's acceptance
    filter does: a frame on any other CAN-ID would change nothing in it and make it send
    nothing, so a bus may leave it out of `receive` (the lock-step network does; a runner
    may keep calling `receive` for every frame).
    """

    def accepted_can_ids(self) -> frozenset[int]:
        """The CAN-IDs `receive` may act on now (a superset); it changes only when the
        device is called (start, receive, advance) or its configuration is written."""
        ...

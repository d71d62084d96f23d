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


@runtime_checkable
class StreamConsumer(SansIoDevice, Protocol):
    """A device that takes counted streams of PDOs: each frame carries samples of its own
    (the skin's packets), so a newer frame of the CAN-ID does not stand for an older one
    as a newer state does. A runner behind its bus delivers every frame of them."""

    def stream_can_ids(self) -> frozenset[int]:
        """The CAN-IDs of the streams it takes now."""
        ...


@runtime_checkable
class StreamingDevice(FilteringDevice, Protocol):
    """A device whose next ticks can be told ahead: a sensor node streaming packets.

    Until a frame it accepts reaches it, what its `advance` returns at each of its
    deadlines depends on nothing a bus does, so a bus may ask for a span of ticks in one
    call and deliver each tick's frames at its own time, merged with everyone else's: a
    call per packet and the store writes of every packet were most of what a stream cost.
    The device's state moves only when the bus says how much of the span happened
    (`commit_stream`), which it must do before any other call to the device, so a frame
    reaching it mid-span (an SDO read, NMT, SYNC, an RPDO) finds it exactly as the
    per-tick path would have left it. A real-time runner just calls `advance`.
    """

    @property
    def streaming(self) -> bool:
        """Whether it ever tells ticks ahead (a node whose application cannot: False, and
        a bus treats it as any other device); constant for the device's life."""
        ...

    def stream_until_us(self, t_us: int) -> int | None:
        """How far a span from `t_us` must reach before `stream_ahead` can tell anything:
        for any `until_us` before this (and always when None) it tells nothing. A cheap
        necessary condition, so a bus whose run ends sooner ticks the device one by one
        without asking (a closed loop's 10 ms chunks hold fewer packets than a span)."""
        ...

    def stream_ahead(self, t_us: int, until_us: int) -> list[tuple[int, list[Frame]]]:
        """What `advance` would return at each of the device's deadlines from `t_us` (its
        deadline now) up to `until_us`, if nothing reached it meanwhile: (time, frames)
        per tick, in time order. Empty when it cannot tell (then `advance` as usual).
        Changes nothing until `commit_stream`."""
        ...

    def commit_stream(self, ticks: int) -> None:
        """The first `ticks` ticks of the last `stream_ahead` happened (their frames went
        out at their times), the rest did not: the device is as if `advance` had run at
        each of those. 0 drops the span."""
        ...

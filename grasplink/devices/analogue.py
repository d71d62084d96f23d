"""An analogue input channel of a generic module (CiA 401 6401h) fed by a sample source.

A scene wires a sensor (the FSR) to one input of a vendor's I/O module built from its
file (`factory.build_from_file`). The module converts continuously at `rate_hz`; the
input object holds the latest conversion, in counts (`units_per_unit` per unit of the
signal, plus `zero`), rounded and held at the object's range as an ADC rails. Its TPDO
carries whatever the object holds when the PDO goes, as its communication parameters
say: on SYNC (types 1-240, what a master sets for a sampled input), or, left event-driven
(255), at each conversion that changes the value, its inhibit time permitting.
"""

from __future__ import annotations

import math

from grasplink.core.frames import Frame
from grasplink.devices.app import DeviceApp
from grasplink.devices.sampling import SampleClock
from grasplink.devices.sources import ConstantSource, SampleSource


class AnalogueInputApp(DeviceApp):
    """See module docstring. `limits` is the input object's (low, high) in counts."""

    def __init__(
        self,
        key: tuple[int, int],
        rate_hz: int,
        units_per_unit: float,
        zero: float,
        limits: tuple[float, float],
        source: SampleSource | None = None,
    ) -> None:
        if rate_hz <= 0:
            raise ValueError(f"an input converts at > 0 Hz, got {rate_hz}")
        self.key = key
        self.rate_hz = rate_hz
        self.units_per_unit = units_per_unit
        self.zero = zero
        self.low, self.high = limits
        self.source = source or ConstantSource(0.0)
        self.clock: SampleClock | None = None
        self.conversions = 0

    def on_reset(self, t_us: int) -> None:
        self.clock = SampleClock(self.rate_hz, t_us)

    def counts(self, value: float) -> int:
        """The input object's value for a signal value; an unreadable (NaN) input reads zero."""
        raw = self.zero if math.isnan(value) else self.zero + value * self.units_per_unit
        return int(min(max(round(raw), self.low), self.high))

    def advance(self, t_us: int) -> list[Frame]:
        clock = self.clock
        if clock is None:
            return []
        due = clock.due_until(t_us)
        if due <= clock.next_index:
            return []
        # Only the latest conversion is ever read: earlier ones are overwritten unseen.
        value = float(self.source.samples(clock.t0_us, due - 1, 1, clock.rate_hz)[0])
        self.conversions += due - clock.next_index
        clock.next_index = due
        self.store.set(self.key[0], self.key[1], self.counts(value))
        return []

    def next_deadline_us(self) -> int | None:
        clock = self.clock
        return None if clock is None else clock.time_of(clock.next_index)

"""Exact sample timing on an integer-microsecond clock.

Sample k of a stream started at t0 falls at t0 + floor(k * 1e6 / rate):
no float accumulates, so hours of samples stay on the grid.
"""

from __future__ import annotations

US_PER_S = 1_000_000


class SampleClock:
    def __init__(self, rate_hz: int, t0_us: int):
        self.rate_hz = rate_hz
        self.t0_us = t0_us
        self.next_index = 0  # first sample not yet taken

    def time_of(self, index: int) -> int:
        return self.t0_us + index * US_PER_S // self.rate_hz

    def due_until(self, t_us: int) -> int:
        """How many samples have come due by t_us (the index after the last one due)."""
        if t_us < self.t0_us:
            return 0
        # floor(k * 1e6 / rate) <= d  <=>  k < (d + 1) * rate / 1e6
        return ((t_us - self.t0_us + 1) * self.rate_hz + US_PER_S - 1) // US_PER_S

"""What the host let a plain timer thread do while a device ran beside it.

Live conformance checks time a device's timers on the wall clock; a loaded 2-core host
delays any thread, the device's among them. These checks judge the device against a
plain thread on the same grid over the same span, so a host that was late is not taken
for a device that is (the exact periods are checked in virtual time,
tests/test_device_runtime.py).
"""

from __future__ import annotations

import threading
import time
from itertools import pairwise
from statistics import median

import pytest

from tests.conformance.conftest import Dut, cob

ATTEMPTS = 5


class GridTicker(threading.Thread):
    """A plain thread ticking on a fixed grid, missed periods skipped (as the device's event
    timer does), stamped on the bus's clock: what this host let a timer thread do while the
    device ran beside it, so a live check is judged by the scheduling that really happened."""

    def __init__(self, period_s: float) -> None:
        super().__init__(daemon=True)
        self.period_s = period_s
        self.ticks: list[float] = []
        self._stop_event = threading.Event()

    def run(self) -> None:
        due = time.time() + self.period_s
        while not self._stop_event.wait(max(0.0, due - time.time())):
            now = time.time()
            self.ticks.append(now)
            due += ((now - due) // self.period_s + 1) * self.period_s

    def stop(self) -> None:
        self._stop_event.set()
        self.join()

    def median_gap(self, start: float, end: float) -> float:
        inside = [t for t in self.ticks if start <= t <= end]
        return median(b - a for a, b in pairwise(inside)) if len(inside) > 1 else 0.0

    def silent(self, start: float, end: float, at_least_s: float) -> bool:
        """Did the ticker also go `at_least_s` without a tick somewhere in [start, end]?"""
        inside = [start, *(t for t in self.ticks if start < t < end), end]
        return any(b - a >= at_least_s for a, b in pairwise(inside))


def heartbeats_on_a_kept_grid(dut: Dut, period_s: float, count: int) -> list:
    """`count` heartbeats of the device, from an attempt (up to `ATTEMPTS`) in which a plain
    thread ticking on the same period kept it (no gap of 1.5 periods): a median gap judged on
    those is the device's period, not the host's scheduling. Fewer frames than `count` are
    returned as they are (the caller's count check fails)."""
    longest: list[float] = []
    for _ in range(ATTEMPTS):
        ticker = GridTicker(period_s)
        ticker.start()
        try:
            mark = dut.log.mark()
            frames = dut.log.wait_count(cob(dut.heartbeat_id), count, since=mark)
        finally:
            ticker.stop()
        if len(frames) < count:
            return frames
        start, end = frames[0].timestamp, frames[-1].timestamp
        if not ticker.silent(start, end, 1.5 * period_s):
            return frames
        inside = [start, *(t for t in ticker.ticks if start < t < end), end]
        longest.append(round(max(b - a for a, b in pairwise(inside)), 3))
    pytest.fail(f"the host never kept a {period_s * 1000:g} ms timer thread on time: {longest}")

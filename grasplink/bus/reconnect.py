"""When to retry a lost bus and when to give up: bounded exponential back-off, sans-IO.

A plain object fed integer-microsecond time (as the device engines are), so
the schedule is tested without sockets or sleeping; `bus.runner.NodeRunner`
does the reconnecting. Attempt n comes ``first_delay * 2**(n-1)`` after the
previous one, at most ``max_delay`` apart, and the last one exactly at the
give-up deadline (so a short timeout still gets its attempt).
"""

from __future__ import annotations

from dataclasses import dataclass

DEFAULT_RECONNECT_TIMEOUT_S = 60.0
FIRST_DELAY_US = 100_000
MAX_DELAY_US = 5_000_000


@dataclass
class Backoff:
    """One outage of a bus: when it began, how many attempts failed, when to try next."""

    lost_at_us: int
    timeout_us: int
    first_delay_us: int = FIRST_DELAY_US
    max_delay_us: int = MAX_DELAY_US
    attempts: int = 0  # failed attempts so far
    next_attempt_us: int = 0

    def __post_init__(self) -> None:
        if self.timeout_us < 0 or self.first_delay_us <= 0 or self.max_delay_us <= 0:
            raise ValueError("back-off times must be positive (timeout may be 0)")
        self.next_attempt_us = min(self.lost_at_us + self.first_delay_us, self.deadline_us)

    @property
    def deadline_us(self) -> int:
        """After an attempt failed at or past this time, give up."""
        return self.lost_at_us + self.timeout_us

    def due(self, t_us: int) -> bool:
        return t_us >= self.next_attempt_us

    def failed(self, t_us: int) -> int | None:
        """An attempt at t_us failed: µs until the next one, or None to give up."""
        self.attempts += 1
        if t_us >= self.deadline_us:
            return None
        exponent = min(self.attempts, 40)  # 2**40 µs is beyond any max_delay
        delay = min(self.first_delay_us * 2**exponent, self.max_delay_us)
        self.next_attempt_us = min(t_us + delay, self.deadline_us)
        return self.next_attempt_us - t_us

    def down_us(self, t_us: int) -> int:
        return t_us - self.lost_at_us

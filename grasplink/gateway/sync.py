"""The SYNC producer (CiA 301 7.2.5; 1005h, 1006h, 1019h in a master's dictionary).

Synchronous TPDOs (transmission types 1-240) go out on SYNC: an analogue module
samples its inputs on it, and nodes whose PDOs are synchronous answer together, so
the gateway handles a cycle's frames at once instead of one wake-up per frame.
Sans-IO: the gateway asks for the frames due; missed periods are skipped on the
grid, never sent in a burst (a burst of SYNCs would be a burst of samples).
"""

from __future__ import annotations

from collections import deque

from grasplink.core.frames import SYNC_COB_ID_DEFAULT, Frame


class SyncProducer:
    """SYNC every `period_us` from start; with `counter_overflow` (2-240) each SYNC carries
    a counter 1..overflow (1019h), so nodes can spread their synchronous PDOs."""

    def __init__(self, period_us: int, counter_overflow: int = 0):
        if period_us <= 0:
            raise ValueError(f"a SYNC period must be > 0 us, got {period_us}")
        if counter_overflow and not 2 <= counter_overflow <= 240:
            raise ValueError(
                f"a SYNC counter overflows at 2-240 (or 0: none), got {counter_overflow}"
            )
        self.period_us = period_us
        self.counter_overflow = counter_overflow
        self.sent = 0
        self.index = -1  # grid index of the last SYNC sent (periods since start, minus one)
        self.skipped = 0  # periods missed whole (the host stalled), not sent late
        self._next_us: int | None = None
        self._counter = 0

    def start(self, t_us: int) -> None:
        self._next_us = t_us + self.period_us
        self._counter = 0
        self.index = -1

    def next_deadline_us(self) -> int | None:
        return self._next_us

    def advance(self, t_us: int) -> list[Frame]:
        if self._next_us is None or t_us < self._next_us:
            return []
        missed = (t_us - self._next_us) // self.period_us
        self.skipped += missed
        self._next_us += (missed + 1) * self.period_us
        self.index += missed + 1
        self.sent += 1
        if not self.counter_overflow:
            return [Frame(SYNC_COB_ID_DEFAULT, b"")]
        self._counter = self._counter % self.counter_overflow + 1
        return [Frame(SYNC_COB_ID_DEFAULT, bytes([self._counter]))]


class SyncNumbers:
    """Numbers for the replies of a synchronous TPDO that carries none (an analogue input
    sampled on SYNC): the SYNC each answered, on the producer's grid, every `every`-th.

    A reply takes the older of the last two SYNCs sent that are not yet answered, so one
    late by up to a period keeps its SYNC's time; periods a stalled host skipped were never
    sent, so their samples are missing, not squeezed together; a reply with none left
    repeats the last number (a stream drops it as a repeat). Fed in the order things
    happen: `sent` as each SYNC goes, `answer` as each reply comes.
    """

    def __init__(self, every: int = 1):
        if not 1 <= every <= 240:
            raise ValueError(f"a synchronous TPDO goes every 1-240 SYNCs, got {every}")
        self.every = every
        self.last = -1  # the number given the last reply
        self._sent: deque[int] = deque(maxlen=2)

    def sent(self, index: int) -> None:
        """A SYNC went out; `index` is its place on the grid (SyncProducer.index)."""
        number = index // self.every
        if not self._sent or self._sent[-1] != number:
            self._sent.append(number)

    def answer(self) -> int:
        unanswered = [n for n in self._sent if n > self.last]
        if unanswered:
            self.last = unanswered[0]
        return self.last

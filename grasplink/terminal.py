"""What long-running commands share at the terminal: a progress bar and a clean stop.

A command stopped by Ctrl-C or SIGTERM should finish the unit of work it
is in and leave complete files behind, not die mid-write; `StopSignals`
turns both signals into a flag the work loop polls.
"""

from __future__ import annotations

import signal
import sys
import threading
import time
from types import FrameType, TracebackType
from typing import TextIO

EXIT_INTERRUPTED = {signal.SIGINT: 130, signal.SIGTERM: 143}  # 128 + signal number


class StopSignals:
    """Within the `with` block, SIGINT and SIGTERM set `.received` instead of killing us."""

    def __init__(self) -> None:
        self.received: signal.Signals | None = None
        self._previous: dict[signal.Signals, object] = {}

    def __call__(self) -> bool:
        return self.received is not None

    def __enter__(self) -> StopSignals:
        if threading.current_thread() is threading.main_thread():
            for sig in EXIT_INTERRUPTED:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]

    def _handle(self, number: int, frame: FrameType | None) -> None:
        if self.received is not None:  # a second signal: stop at once
            raise KeyboardInterrupt
        self.received = signal.Signals(number)

    @property
    def exit_code(self) -> int:
        return EXIT_INTERRUPTED.get(self.received, 1) if self.received else 0


class ProgressBar:
    """`[#####.....]  52 %  5.2 / 10 s` redrawn in place on a terminal, at most 5 times a second.

    Off a terminal (a pipe, a log file, CI) it draws nothing: progress bars in logs are noise.
    """

    WIDTH = 30
    MIN_INTERVAL_S = 0.2

    def __init__(self, label: str, stream: TextIO | None = None, *, force: bool = False):
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = force or self.stream.isatty()
        self._last_draw = 0.0
        self._drawn = False

    def __call__(self, done_us: int, total_us: int) -> None:
        if not self.enabled:
            return
        now = time.monotonic()
        if now - self._last_draw < self.MIN_INTERVAL_S and done_us < total_us:
            return
        self._last_draw = now
        share = done_us / total_us if total_us else 1.0
        filled = round(share * self.WIDTH)
        bar = "#" * filled + "." * (self.WIDTH - filled)
        self.stream.write(
            f"\r{self.label} [{bar}] {100 * share:3.0f} %  {done_us / 1e6:g} / {total_us / 1e6:g} s"
        )
        self.stream.flush()
        self._drawn = True

    def close(self) -> None:
        if self._drawn:
            self.stream.write("\n")
            self.stream.flush()

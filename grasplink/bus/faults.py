"""Bus faults for the virtual-time network: latency, jitter, frame drop, error frames.

A `FaultyLink` decides, for each frame a device sends, whether and when the
other devices receive it. Drops and delays are drawn from a seeded generator
so a scene replays identically. Error frames are bus events without data;
they reach the taps (logs, bus load) and no device.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from grasplink.core.frames import Frame

# An error frame: 6 dominant bits of error flag, up to 6 of echo, 8 delimiter, 3 intermission.
ERROR_FRAME_BITS = 23


@dataclass(frozen=True, slots=True)
class ErrorFrame:
    """Marker the taps see for an error frame (not a CANopen frame)."""

    length: int = 0
    rtr: bool = False
    can_id: int = -1


class FaultyLink:
    def __init__(
        self,
        rng: np.random.Generator,
        *,
        latency_us: int = 0,
        jitter_us: int = 0,
        drop_probability: float = 0.0,
        error_frames_per_s: float = 0.0,
    ):
        self.rng = rng
        self.latency_us = latency_us
        self.jitter_us = jitter_us
        self.drop_probability = drop_probability
        self.error_frames_per_s = error_frames_per_s
        self.dropped = 0
        self.error_frames = 0
        self._next_error_us: int | None = None

    def delay_us(self, frame: Frame) -> int | None:
        """Delivery delay for one frame, or None when the frame is lost."""
        if self.drop_probability and self.rng.random() < self.drop_probability:
            self.dropped += 1
            return None
        jitter = int(self.rng.integers(0, self.jitter_us + 1)) if self.jitter_us else 0
        return self.latency_us + jitter

    def next_error_us(self, t_us: int) -> int | None:
        """When the next error frame occurs (Poisson process), scheduling it if needed."""
        if not self.error_frames_per_s:
            return None
        if self._next_error_us is None:
            gap_s = self.rng.exponential(1.0 / self.error_frames_per_s)
            self._next_error_us = t_us + max(1, round(gap_s * 1e6))
        return self._next_error_us

    def take_error(self) -> None:
        self.error_frames += 1
        self._next_error_us = None

"""What the gateway's decision logic is fed: one timestamped reading of the skin.

The feedback controller and the grip reflex take a `Percept`, not a decoder's
`SlipEstimate`, so they do not depend on which decoder (or which sensor) made
it, and time is the gateway's integer-microsecond clock. A percept may carry
NaN or infinite values (a sensor fault, a decoder bug): `clean()` turns them
into None (unknown), so no NaN ever reaches a command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from grasplink.gateway.decoding.base import SlipEstimate

US_PER_S = 1_000_000


def finite_or_none(value: float | None) -> float | None:
    """The value if it is a finite number, else None (unknown)."""
    if value is None or isinstance(value, bool):
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        return None
    return number if math.isfinite(number) else None


@dataclass(frozen=True, slots=True)
class Percept:
    """One skin reading at `t_us`: grip force, slip occurring, slip speed, confidence.

    `slip_speed_mm_s` is signed (+ from the first ridge towards the last); its
    magnitude is what feedback and reflex use. None means the decoder cannot
    tell. `confidence` is the decoder's trust in its slip answer, 0..1.
    """

    t_us: int
    grip_force_n: float | None
    slipping: bool
    slip_speed_mm_s: float | None = None
    confidence: float = 1.0

    @classmethod
    def from_estimate(
        cls, estimate: SlipEstimate, *, t0_us: int = 0, t_us: int | None = None
    ) -> Percept:
        """A decoder update as a percept at `t_us` (by default the estimate's time, with
        `t0_us` the gateway time of the decoder's t = 0)."""
        return cls(
            t_us=t0_us + round(estimate.t_s * US_PER_S) if t_us is None else t_us,
            grip_force_n=estimate.force_n,
            slipping=bool(estimate.slip),
            slip_speed_mm_s=estimate.speed_mm_s,
            confidence=estimate.confidence,
        )

    def clean(self) -> Percept:
        """The same reading with every unusable number made unknown and confidence in 0..1."""
        confidence = finite_or_none(self.confidence)
        return Percept(  # (not dataclasses.replace: a few times a decoder update, 4x its cost)
            self.t_us,
            finite_or_none(self.grip_force_n),
            bool(self.slipping),
            finite_or_none(self.slip_speed_mm_s),
            0.0 if confidence is None else min(1.0, max(0.0, confidence)),
        )

    def speed_magnitude_mm_s(self, min_confidence: float = 0.0) -> float | None:
        """|slip speed| if known and trusted at least `min_confidence`, else None."""
        clean = self.clean()
        if clean.slip_speed_mm_s is None or clean.confidence < min_confidence:
            return None
        return abs(clean.slip_speed_mm_s)


class Clock:
    """Refuses time running backwards: every input of a controller is at or after the last."""

    def __init__(self, owner: str):
        self.owner = owner
        self.now_us: int | None = None

    def tick(self, t_us: int) -> int:
        if isinstance(t_us, bool) or not isinstance(t_us, int):
            raise TypeError(f"{self.owner}: time must be integer microseconds, got {t_us!r}")
        if self.now_us is not None and t_us < self.now_us:
            raise ValueError(f"{self.owner}: time went backwards ({t_us} us < {self.now_us} us)")
        self.now_us = t_us
        return t_us

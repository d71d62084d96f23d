"""What the gateway's decision logic is fed: one timestamped reading of the skin.

The feedback controller and the grip reflex take a `Percept`, not a decoder's
`SlipEstimate`, so they do not depend on which decoder (or which sensor) made
it, and time is the gateway's integer-microsecond clock. A percept may carry
NaN or infinite values (a sensor fault, a decoder bug): `clean()` turns them
into None (unknown), so no NaN ever reaches a command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from grasplink.decoding.base import SlipEstimate

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
    """One skin reading at `t_us`: grip force, slip occurring, slip speed and direction.

    Speed and direction are separate (the decoders' output contract, docs/decoding.md):

    * `slip_speed_mm_s`: |speed| (>= 0), None while the decoder cannot tell it;
    * `slip_speed_low_mm_s`, `slip_speed_high_mm_s`: the range of speeds still possible
      (a bound while the speed itself is unknown; None: not bounded that side);
    * `slip_direction`: +1 from the first ridge towards the last, -1 back, None: not told,
      with `slip_direction_confidence`, P(that way);
    * `confidence`: the decoder's trust in its slip answer, 0..1.

    Feedback and reflex act on the speed, or while only a bound is known on its lower
    end (`speed_floor_mm_s`): a bound is acted on, and never overstated. Neither needs
    the direction.
    """

    t_us: int
    grip_force_n: float | None
    slipping: bool
    slip_speed_mm_s: float | None = None
    confidence: float = 1.0
    slip_speed_low_mm_s: float | None = None
    slip_speed_high_mm_s: float | None = None
    slip_direction: int | None = None
    slip_direction_confidence: float | None = None
    # set on what `clean()` returns: cleaning it again gives it back as it is (the gateway
    # cleans a decoder update once; the feedback controller and the reflex each ask again)
    _clean: bool = field(default=False, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        for name in ("slip_speed_mm_s", "slip_speed_low_mm_s", "slip_speed_high_mm_s"):
            value = getattr(self, name)
            if isinstance(value, int | float) and -math.inf < value < 0:  # NaN, inf: clean()
                raise ValueError(
                    f"percept {name} is a magnitude, got {value}: give the sign as slip_direction"
                )
        if self.slip_direction not in (None, 1, -1):
            direction = self.slip_direction
            raise ValueError(f"percept slip_direction must be +1, -1 or None, got {direction!r}")

    @classmethod
    def from_estimate(
        cls, estimate: SlipEstimate, *, t0_us: int = 0, t_us: int | None = None
    ) -> Percept:
        """A decoder update as a percept at `t_us` (by default the estimate's time, with
        `t0_us` the gateway time of the decoder's t = 0)."""
        return cls(
            t0_us + round(estimate.t_s * US_PER_S) if t_us is None else t_us,
            estimate.force_n,
            bool(estimate.slip),
            estimate.speed_mm_s,
            estimate.confidence,
            estimate.speed_low_mm_s,
            estimate.speed_high_mm_s,
            estimate.direction,
            estimate.direction_confidence,
        )

    def clean(self) -> Percept:
        """The same reading with every unusable number made unknown, confidences in 0..1,
        and a direction only with a usable confidence (and none without)."""
        if self._clean:
            return self
        confidence = finite_or_none(self.confidence)
        direction = self.slip_direction
        way = finite_or_none(self.slip_direction_confidence)
        if direction is None or way is None:
            direction = way = None
        else:
            way = min(1.0, max(0.0, way))
        clean = Percept(  # (not dataclasses.replace: a few times a decoder update, 4x its cost)
            self.t_us,
            finite_or_none(self.grip_force_n),
            bool(self.slipping),
            finite_or_none(self.slip_speed_mm_s),
            0.0 if confidence is None else min(1.0, max(0.0, confidence)),
            finite_or_none(self.slip_speed_low_mm_s),
            finite_or_none(self.slip_speed_high_mm_s),
            direction,
            way,
        )
        object.__setattr__(clean, "_clean", True)  # (frozen: the dataclass idiom)
        return clean

    @property
    def velocity_mm_s(self) -> float | None:
        """The signed speed (+ towards the last ridge), when speed and direction are told."""
        speed = finite_or_none(self.slip_speed_mm_s)
        if speed is None or self.slip_direction is None:
            return None
        return self.slip_direction * speed

    def speed_magnitude_mm_s(self, min_confidence: float = 0.0) -> float | None:
        """|slip speed| if known and trusted at least `min_confidence`, else None."""
        return finite_or_none(self.slip_speed_mm_s) if self._trusted(min_confidence) else None

    def speed_floor_mm_s(self, min_confidence: float = 0.0) -> float | None:
        """The slowest the object may slip: the speed if known, else the lower bound of its
        range; None when neither is known or the reading is trusted less than
        `min_confidence`. What the belt shows and the reflex acts on: never more than
        the decoder vouches for."""
        if not self._trusted(min_confidence):
            return None
        speed = finite_or_none(self.slip_speed_mm_s)
        return finite_or_none(self.slip_speed_low_mm_s) if speed is None else speed

    def speed_ceiling_mm_s(self, min_confidence: float = 0.0) -> float | None:
        """The fastest the object may slip: the speed if known, else the upper bound of its
        range (None as for `speed_floor_mm_s`): a slip is known to be slower than a limit
        only when this is."""
        if not self._trusted(min_confidence):
            return None
        speed = finite_or_none(self.slip_speed_mm_s)
        return finite_or_none(self.slip_speed_high_mm_s) if speed is None else speed

    def _trusted(self, min_confidence: float) -> bool:
        confidence = finite_or_none(self.confidence)  # as clean() reads it
        return (0.0 if confidence is None else min(1.0, max(0.0, confidence))) >= min_confidence

    @property
    def speed_is_bound(self) -> bool:
        """Only a bound is known: no speed, a usable lower bound."""
        return (
            finite_or_none(self.slip_speed_mm_s) is None
            and finite_or_none(self.slip_speed_low_mm_s) is not None
        )


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

"""Slip encodings for external stimulators: the thesis's electrotactile and vibrotactile codes.

The belt is this project's display; the thesis also drove stimulators that a
deployment may attach instead or besides. The gateway computes their codes
alongside the belt command from the same (debounced) slip state:

- electrotactile slip occurrence (ch. 2.3.3): 68 Hz while slipping, off otherwise;
- electrotactile slip speed (ch. 2.3.3): d = 22.85·|v| − 37.14 Hz, clamped to
  the electrode's 4…100 Hz (the thesis's set H = {4, 36, 68, 100} Hz);
- vibrotactile pulse train (ch. 4.5.2): slip frequency f = |v| / D (ch. 4.4)
  mapped linearly from the 1…20 Hz slip band (ch. 4.5.1) onto 1…150 Hz pulse
  trains of constant pulse width.

Every encoder is a pure function of (slipping, speed); a frequency of 0 Hz
means the stimulator is off. The speed is a magnitude: the slip speed, or
while the decoder knows only a range of speeds its lower end (what the belt
shows, `FeedbackController`); no encoding needs the direction.
docs/feedback.md gives the formulas and what happens outside the thesis's
ranges.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from grasplink.errors import ConfigError
from grasplink.gateway.percept import finite_or_none

ELECTROTACTILE_SET_HZ = (4.0, 36.0, 68.0, 100.0)  # H, ch. 2.3.3
ELECTROTACTILE_OCCURRENCE_HZ = 68.0  # f_b, "close to the median of the set"
ELECTROTACTILE_SLOPE_HZ_PER_MM_S = 22.85
ELECTROTACTILE_INTERCEPT_HZ = -37.14
THESIS_SPEEDS_MM_S = (1.8, 3.2, 4.6, 6.0)  # V, ch. 2.3.3: where the formula was designed
US_PER_S = 1_000_000


@dataclass(frozen=True, slots=True)
class Stimulus:
    """A stimulation frequency; 0 Hz = off. `saturated`: the input was outside the
    encoding's range and the frequency was clamped. `speed_known`: False when a slip
    of unknown speed is shown at the occurrence frequency."""

    frequency_hz: float
    saturated: bool = False
    speed_known: bool = True

    @property
    def on(self) -> bool:
        return self.frequency_hz > 0


@dataclass(frozen=True, slots=True)
class PulseTrain:
    """Pulses of constant width at `frequency_hz` (0 Hz = no pulses)."""

    frequency_hz: float
    pulse_width_us: int
    saturated: bool = False
    speed_known: bool = True

    @property
    def on(self) -> bool:
        return self.frequency_hz > 0

    @property
    def period_us(self) -> int | None:
        return round(US_PER_S / self.frequency_hz) if self.on else None


OFF = Stimulus(0.0)


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise ConfigError(message)


def _finite(*values: float) -> bool:
    return all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in values
    )


@dataclass(frozen=True, slots=True)
class ElectrotactileOccurrence:
    """Slip occurrence (ch. 2.3.3): b = f_b while slipping, 0 otherwise."""

    frequency_hz: float = ELECTROTACTILE_OCCURRENCE_HZ

    def __post_init__(self) -> None:
        _require(
            _finite(self.frequency_hz) and self.frequency_hz > 0,
            f"electrotactile occurrence frequency must be > 0 Hz, got {self.frequency_hz!r}",
        )

    def encode(self, slipping: bool, speed_mm_s: float | None = None) -> Stimulus:
        return Stimulus(self.frequency_hz) if slipping else OFF


@dataclass(frozen=True, slots=True)
class ElectrotactileSpeed:
    """Slip speed (ch. 2.3.3): d = slope·|v| + intercept, clamped to min_hz..max_hz.

    The defaults are the thesis's formula (1.8 → 4, 3.2 → 36, 4.6 → 68, 6.0 → 100 Hz).
    While slipping, a speed below the range (including 0) gives min_hz and one above
    gives max_hz, both flagged `saturated`: a slip is never shown as "off", and a
    faster slip is never shown slower. A slip of unknown speed is shown at
    `unknown_speed_hz` (the occurrence code). `levels_hz`: snap to the nearest of
    these frequencies (the thesis's discrete d ∈ H); None = continuous.
    `for_speed_range` spreads another speed range (e.g. this project's 10…45 mm/s)
    over the same electrode range.
    """

    slope_hz_per_mm_s: float = ELECTROTACTILE_SLOPE_HZ_PER_MM_S
    intercept_hz: float = ELECTROTACTILE_INTERCEPT_HZ
    min_hz: float = ELECTROTACTILE_SET_HZ[0]
    max_hz: float = ELECTROTACTILE_SET_HZ[-1]
    unknown_speed_hz: float = ELECTROTACTILE_OCCURRENCE_HZ
    levels_hz: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        name = "electrotactile speed encoding"
        _require(
            _finite(self.slope_hz_per_mm_s, self.intercept_hz, self.min_hz, self.max_hz),
            f"{name}: slope, intercept, min_hz and max_hz must be finite numbers",
        )
        _require(self.slope_hz_per_mm_s > 0, f"{name}: slope must be > 0 Hz per mm/s")
        _require(
            0 < self.min_hz < self.max_hz,
            f"{name}: need 0 < min_hz < max_hz, got {self.min_hz}..{self.max_hz} Hz",
        )
        _require(
            _finite(self.unknown_speed_hz) and self.min_hz <= self.unknown_speed_hz <= self.max_hz,
            f"{name}: unknown_speed_hz {self.unknown_speed_hz!r} is outside "
            f"{self.min_hz}..{self.max_hz} Hz",
        )
        if self.levels_hz is not None:
            _require(len(self.levels_hz) > 0, f"{name}: levels_hz is empty")
            for k, level in enumerate(self.levels_hz, start=1):
                _require(
                    _finite(level) and self.min_hz <= level <= self.max_hz,
                    f"{name}: levels_hz entry {k} ({level!r}) is outside "
                    f"{self.min_hz}..{self.max_hz} Hz",
                )

    @classmethod
    def for_speed_range(
        cls,
        low_mm_s: float,
        high_mm_s: float,
        *,
        min_hz: float = ELECTROTACTILE_SET_HZ[0],
        max_hz: float = ELECTROTACTILE_SET_HZ[-1],
    ) -> ElectrotactileSpeed:
        """The linear map sending low_mm_s → min_hz and high_mm_s → max_hz."""
        _require(
            _finite(low_mm_s, high_mm_s) and 0 <= low_mm_s < high_mm_s,
            f"electrotactile speed range must be 0 <= low < high mm/s, got {low_mm_s}..{high_mm_s}",
        )
        slope = (max_hz - min_hz) / (high_mm_s - low_mm_s)
        return cls(slope, min_hz - slope * low_mm_s, min_hz, max_hz, (min_hz + max_hz) / 2)

    def raw_hz(self, speed_mm_s: float) -> float:
        """The unclamped formula at |v|."""
        return self.slope_hz_per_mm_s * abs(speed_mm_s) + self.intercept_hz

    def encode(self, slipping: bool, speed_mm_s: float | None) -> Stimulus:
        if not slipping:
            return OFF
        speed = finite_or_none(speed_mm_s)
        if speed is None:
            return Stimulus(self.unknown_speed_hz, speed_known=False)
        raw = self.raw_hz(speed)
        hz = min(self.max_hz, max(self.min_hz, raw))
        saturated = raw < self.min_hz or raw > self.max_hz
        if self.levels_hz is not None:
            hz = min(self.levels_hz, key=lambda level: (abs(level - hz), level))
        return Stimulus(hz, saturated=saturated)


@dataclass(frozen=True, slots=True)
class Vibrotactile:
    """Slip frequency → pulse train (ch. 4.5.2), pulses of constant width.

    Slip frequency f = |v| / D (ch. 4.4), D = `ridge_spacing_mm` (4.0 mm, the
    thesis's best uniform skin; on a non-uniform skin the contact rate changes from
    ridge to ridge, so the decoded speed over a reference spacing is used and the
    stimulus follows speed, not layout). f is mapped linearly from
    slip_low_hz..slip_high_hz (1…20 Hz, the band where ch. 4.5.1 classified slip)
    onto pulse_low_hz..pulse_high_hz (1…150 Hz) and clamped there, flagged
    `saturated`. A slip of unknown speed pulses at `unknown_speed_hz`.
    """

    ridge_spacing_mm: float = 4.0
    slip_low_hz: float = 1.0
    slip_high_hz: float = 20.0
    pulse_low_hz: float = 1.0
    pulse_high_hz: float = 150.0
    pulse_width_us: int = 2000
    unknown_speed_hz: float = 75.5  # the middle of 1…150 Hz, as f_b is of H

    def __post_init__(self) -> None:
        name = "vibrotactile encoding"
        _require(
            _finite(self.ridge_spacing_mm) and self.ridge_spacing_mm > 0,
            f"{name}: ridge spacing must be > 0 mm, got {self.ridge_spacing_mm!r}",
        )
        _require(
            _finite(self.slip_low_hz, self.slip_high_hz) and self.slip_low_hz >= 0,
            f"{name}: slip band must be finite and >= 0 Hz",
        )
        _require(
            self.slip_low_hz < self.slip_high_hz,
            f"{name}: slip band {self.slip_low_hz}..{self.slip_high_hz} Hz is empty",
        )
        _require(
            _finite(self.pulse_low_hz, self.pulse_high_hz)
            and 0 < self.pulse_low_hz < self.pulse_high_hz,
            f"{name}: need 0 < pulse_low_hz < pulse_high_hz, got "
            f"{self.pulse_low_hz}..{self.pulse_high_hz} Hz",
        )
        period_us = US_PER_S / self.pulse_high_hz
        _require(
            isinstance(self.pulse_width_us, int)
            and not isinstance(self.pulse_width_us, bool)
            and 0 < self.pulse_width_us < period_us,
            f"{name}: pulse width {self.pulse_width_us!r} us must be > 0 and shorter than "
            f"the {period_us:.0f} us period at {self.pulse_high_hz} Hz",
        )
        _require(
            _finite(self.unknown_speed_hz)
            and self.pulse_low_hz <= self.unknown_speed_hz <= self.pulse_high_hz,
            f"{name}: unknown_speed_hz {self.unknown_speed_hz!r} is outside the pulse range",
        )

    def slip_frequency_hz(self, speed_mm_s: float) -> float:
        """f = |v| / D."""
        return abs(speed_mm_s) / self.ridge_spacing_mm

    def encode(self, slipping: bool, speed_mm_s: float | None) -> PulseTrain:
        if not slipping:
            return PulseTrain(0.0, self.pulse_width_us)
        speed = finite_or_none(speed_mm_s)
        if speed is None:
            return PulseTrain(self.unknown_speed_hz, self.pulse_width_us, speed_known=False)
        f = self.slip_frequency_hz(speed)
        scale = (self.pulse_high_hz - self.pulse_low_hz) / (self.slip_high_hz - self.slip_low_hz)
        raw = self.pulse_low_hz + (f - self.slip_low_hz) * scale
        hz = min(self.pulse_high_hz, max(self.pulse_low_hz, raw))
        saturated = raw < self.pulse_low_hz or raw > self.pulse_high_hz
        return PulseTrain(hz, self.pulse_width_us, saturated=saturated)


@dataclass(frozen=True, slots=True)
class Stimuli:
    """Every external stimulator's code for one moment."""

    electrotactile_occurrence: Stimulus
    electrotactile_speed: Stimulus
    vibrotactile: PulseTrain


@dataclass(frozen=True, slots=True)
class StimulusEncoder:
    """The three encodings, configured once, applied together."""

    occurrence: ElectrotactileOccurrence = field(default_factory=ElectrotactileOccurrence)
    electrotactile: ElectrotactileSpeed = field(default_factory=ElectrotactileSpeed)
    vibrotactile: Vibrotactile = field(default_factory=Vibrotactile)

    def encode(self, slipping: bool, speed_mm_s: float | None) -> Stimuli:
        return Stimuli(
            self.occurrence.encode(slipping),
            self.electrotactile.encode(slipping, speed_mm_s),
            self.vibrotactile.encode(slipping, speed_mm_s),
        )

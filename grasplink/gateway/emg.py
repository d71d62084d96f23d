"""EMG intent: the envelope the EMG node reports becomes a level e0..e5 and a grip setpoint.

The EMG node rectifies and averages its raw signal over the window the
gateway configures (150-250 ms, thesis ch. 2.3) and reports the envelope.
The gateway owns the calibration: [e_min, e_max] splits into four equal
levels e1..e4, e0 lies below e_min and e5 above e_max. Two ways to turn
that into grip: `levels` (each level commands a fixed grip force, the
thesis's discrete control) and `proportional` (grip rises linearly from
e_min to e_max). A calibration phase records rest and a maximum comfortable
contraction; a calibration that cannot separate them (flat or saturated
signal, e_max <= e_min) is refused with the reason and the previous one
stays in force.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from grasplink.errors import ConfigError

LEVELS = 4  # e1..e4 between e_min and e_max
TOP_LEVEL = LEVELS + 1  # e5
ENVELOPE_FULL_SCALE_UV = 65535  # U16 envelope object: a reading here is saturated
CALIBRATION_SAMPLES = 6000  # envelope updates kept per phase (60 s at 100 Hz)
REST_PERCENTILE = 95.0  # e_min sits above almost all of rest
MIN_SPREAD_UV = 1.0  # below this a phase is flat: no signal (electrode off?)
FLAT_UV = 0.5  # an envelope below this is no signal: resting muscle still reads a few uV
FAULT_AFTER_US = 500_000  # flat or saturated this long: the EMG cannot be trusted


@dataclass(frozen=True)
class EmgCalibration:
    e_min_uv: float
    e_max_uv: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.e_min_uv) and math.isfinite(self.e_max_uv)):
            raise ConfigError(
                f"EMG calibration must be finite, got {self.e_min_uv}, {self.e_max_uv}"
            )
        if self.e_min_uv < 0:
            raise ConfigError(f"EMG e_min must be >= 0 uV, got {self.e_min_uv:g}")
        if not self.e_max_uv > self.e_min_uv:
            raise ConfigError(
                f"EMG e_max ({self.e_max_uv:g} uV) must be above e_min ({self.e_min_uv:g} uV)"
            )

    def level(self, envelope_uv: float) -> int:
        """0 (e0) .. 5 (e5); NaN reads as rest."""
        if not envelope_uv >= self.e_min_uv:
            return 0
        if envelope_uv > self.e_max_uv:
            return TOP_LEVEL
        share = (envelope_uv - self.e_min_uv) / (self.e_max_uv - self.e_min_uv)
        return min(LEVELS, 1 + int(share * LEVELS))

    def share(self, envelope_uv: float) -> float:
        """Where the envelope lies in [e_min, e_max], clipped to 0..1 (NaN reads as 0)."""
        if not math.isfinite(envelope_uv):
            return 0.0
        share = (envelope_uv - self.e_min_uv) / (self.e_max_uv - self.e_min_uv)
        return min(1.0, max(0.0, share))


@dataclass(frozen=True)
class EmgIntent:
    t_us: int
    envelope_uv: float
    level: int
    grip_n: float
    saturated: bool


class EmgIntentDecoder:
    """Envelope updates -> level and grip setpoint, in `levels` or `proportional` mode."""

    def __init__(
        self,
        calibration: EmgCalibration,
        *,
        mode: str = "levels",
        grip_levels_n: Sequence[float] = (0.0, 2.0, 4.0, 6.0, 8.0, 40.0),
        grip_max_n: float = 20.0,
    ):
        if mode not in ("levels", "proportional"):
            raise ConfigError(f"EMG grip mode {mode!r}: expected 'levels' or 'proportional'")
        levels = tuple(float(g) for g in grip_levels_n)
        if (
            len(levels) != TOP_LEVEL + 1
            or any(not math.isfinite(g) or g < 0 for g in levels)
            or any(b < a for a, b in itertools.pairwise(levels))
        ):
            raise ConfigError(f"grip_levels_n: expected 6 non-decreasing forces >= 0, got {levels}")
        if not (math.isfinite(grip_max_n) and grip_max_n >= 0):
            raise ConfigError(f"grip_max_n must be >= 0 N, got {grip_max_n}")
        self.calibration = calibration
        self.mode = mode
        self.grip_levels_n = levels
        self.grip_max_n = float(grip_max_n)
        self.saturated_updates = 0
        self.rejected_updates = 0
        self._faulty_since_us: int | None = None  # flat or saturated since then
        self.last_flat = False

    def update(self, t_us: int, envelope_uv: float) -> EmgIntent | None:
        """One envelope reading; None (and counted) for a reading that is not a number."""
        if not math.isfinite(envelope_uv) or envelope_uv < 0:
            self.rejected_updates += 1
            return None
        saturated = envelope_uv >= ENVELOPE_FULL_SCALE_UV
        self.saturated_updates += saturated
        if saturated or envelope_uv < FLAT_UV:
            if self._faulty_since_us is None:
                self._faulty_since_us = t_us
        else:
            self._faulty_since_us = None
        level = self.calibration.level(envelope_uv)
        if self.mode == "levels":
            grip_n = self.grip_levels_n[level]
        else:
            grip_n = self.grip_max_n * self.calibration.share(envelope_uv)
        self.last_flat = envelope_uv < FLAT_UV
        return EmgIntent(t_us, float(envelope_uv), level, grip_n, saturated)

    def fault(self, t_us: int) -> str | None:
        """Why the signal cannot be trusted now: flat (no muscle ever reads exactly nothing:
        an electrode is off) or saturated for `FAULT_AFTER_US`; None while it looks alive."""
        since = self._faulty_since_us
        if since is None or t_us - since < FAULT_AFTER_US:
            return None
        return "EMG flat: electrode off?" if self.last_flat else "EMG saturated"


class CalibrationRecorder:
    """Records envelopes during a rest phase and a maximum-contraction phase (bounded)."""

    def __init__(self, capacity: int = CALIBRATION_SAMPLES):
        self.rest: deque[float] = deque(maxlen=capacity)
        self.maximum: deque[float] = deque(maxlen=capacity)
        self.phase: str | None = None

    def begin(self, phase: str) -> None:
        if phase not in ("rest", "maximum"):
            raise ConfigError(f"calibration phase {phase!r}: expected 'rest' or 'maximum'")
        self.phase = phase
        (self.rest if phase == "rest" else self.maximum).clear()

    def add(self, envelope_uv: float) -> None:
        if self.phase is not None and math.isfinite(envelope_uv):
            (self.rest if self.phase == "rest" else self.maximum).append(envelope_uv)

    def result(self) -> EmgCalibration:
        """e_min just above rest, e_max at the typical maximum; ConfigError saying why not."""
        self.phase = None
        for name, values in (("rest", self.rest), ("maximum", self.maximum)):
            if len(values) < 10:
                raise ConfigError(f"calibration: only {len(values)} {name} readings (need 10)")
        rest, top = np.asarray(self.rest), np.asarray(self.maximum)
        if np.median(top) >= ENVELOPE_FULL_SCALE_UV:
            raise ConfigError("calibration: the maximum contraction saturates the EMG envelope")
        if np.ptp(top) < MIN_SPREAD_UV and np.ptp(rest) < MIN_SPREAD_UV and np.median(top) <= 0:
            raise ConfigError("calibration: flat EMG in both phases (electrode off?)")
        e_min = float(np.percentile(rest, REST_PERCENTILE))
        e_max = float(np.median(top))
        if not e_max > e_min + MIN_SPREAD_UV:
            raise ConfigError(
                f"calibration: maximum contraction ({e_max:.0f} uV) is not above rest "
                f"({e_min:.0f} uV); contract harder or check the electrode"
            )
        return EmgCalibration(e_min, e_max)

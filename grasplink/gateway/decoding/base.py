"""What every skin decoder promises: its input, its output, and how it streams.

A decoder is a sans-IO object fed timestamped FSR samples (`feed`) that
returns estimates on a fixed time grid (`update_period_s`, default 10 ms,
aligned to multiples of the period), so feeding a recording in chunks or in
one piece gives the same estimates. Unknown values are None, never NaN.
Bad samples (NaN, Inf, time not increasing) are rejected and counted; they
never reach the decoder's state.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from grasplink.errors import ConfigError

DEFAULT_UPDATE_S = 0.01


@dataclass(frozen=True, slots=True)
class SlipEstimate:
    """One decoder update (the output contract of `grasplink decode`)."""

    t_s: float
    slip: bool
    speed_mm_s: float | None  # signed: + from the first ridge towards the last
    position_mm: float | None  # the leading edge, from the first ridge
    force_n: float | None  # static grip force
    confidence: float  # 0..1

    def as_dict(self) -> dict:
        return {
            "t_s": round(self.t_s, 6),
            "slip": self.slip,
            "speed_mm_s": _clean(self.speed_mm_s),
            "position_mm": _clean(self.position_mm),
            "force_n": _clean(self.force_n),
            "confidence": round(float(self.confidence), 4),
        }


def _clean(value: float | None) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), 4)


class SkinGeometry:
    """Ridge positions of a layout: ridge i at x_i = sum of the first i spacings."""

    def __init__(self, spacings_mm: Sequence[float]):
        spacings = np.asarray(spacings_mm, dtype=np.float64)
        if spacings.ndim != 1 or len(spacings) == 0:
            raise ConfigError("a skin layout needs at least one spacing")
        if not np.all(np.isfinite(spacings)) or np.any(spacings <= 0):
            raise ConfigError(f"ridge spacings must be finite and > 0 mm, got {list(spacings)}")
        self.spacings_mm = spacings
        self.ridges_mm = np.concatenate([[0.0], np.cumsum(spacings)])
        self.length_mm = float(self.ridges_mm[-1])

    @property
    def ridge_count(self) -> int:
        return len(self.ridges_mm)


@dataclass
class InputStats:
    accepted: int = 0
    rejected_nonfinite: int = 0
    rejected_time: int = 0  # not after the previous sample
    gaps: int = 0  # jumps longer than GAP_PERIODS sample periods


GAP_PERIODS = 3.0


class Decoder:
    """Base class: input guard, update grid, static force; subclasses decode slip."""

    name: ClassVar[str] = "base"

    def __init__(
        self, layout_mm: Sequence[float], fs_hz: float, *, update_period_s: float = DEFAULT_UPDATE_S
    ):
        if not (math.isfinite(fs_hz) and fs_hz > 0):
            raise ConfigError(f"sample rate must be a positive number of Hz, got {fs_hz}")
        if not (math.isfinite(update_period_s) and update_period_s > 0):
            raise ConfigError(f"update period must be > 0 s, got {update_period_s}")
        self.geometry = SkinGeometry(layout_mm)
        self.fs_hz = float(fs_hz)
        self.update_period_s = float(update_period_s)
        self.stats = InputStats()
        self._last_t: float | None = None
        self._next_update: int | None = None  # index of the next update on the grid

    def feed(self, t_s: np.ndarray, force_n: np.ndarray) -> list[SlipEstimate]:
        """Take samples (any chunking) and return the updates that fell due."""
        t = np.asarray(t_s, dtype=np.float64).ravel()
        x = np.asarray(force_n, dtype=np.float64).ravel()
        if t.shape != x.shape:
            raise ValueError(f"{len(t)} times for {len(x)} samples")
        t, x = self._guard(t, x)
        if not len(t):
            return []
        return self.process(t, x)

    def _guard(self, t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        finite = np.isfinite(t) & np.isfinite(x)
        self.stats.rejected_nonfinite += int(np.count_nonzero(~finite))
        t, x = t[finite], x[finite]
        if not len(t):
            return t, x
        previous = -np.inf if self._last_t is None else self._last_t
        running = np.maximum.accumulate(np.concatenate([[previous], t]))[:-1]
        increasing = t > running
        self.stats.rejected_time += int(np.count_nonzero(~increasing))
        t, x = t[increasing], x[increasing]
        if len(t):
            steps = np.diff(np.concatenate([[previous], t]))
            self.stats.gaps += int(
                np.count_nonzero(steps[np.isfinite(steps)] > GAP_PERIODS / self.fs_hz)
            )
            self._last_t = float(t[-1])
            self.stats.accepted += len(t)
        return t, x

    def update_points(self, t: np.ndarray) -> list[tuple[int, float]]:
        """Updates due within this chunk: (samples of the chunk at or before it, update time).

        Updates fall on multiples of the update period, from the first sample on;
        an update at time g reflects every sample with t <= g. The grid does not
        depend on how the input is chunked.
        """
        period = self.update_period_s
        if self._next_update is None:
            self._next_update = math.ceil(t[0] / period - 1e-9)
        last = math.floor(t[-1] / period + 1e-9)
        if last < self._next_update:
            return []
        grid = np.arange(self._next_update, last + 1) * period
        self._next_update = last + 1
        counts = np.searchsorted(t, grid + 1e-12, side="right")
        return list(zip(counts.tolist(), grid.tolist(), strict=True))

    def process(self, t: np.ndarray, x: np.ndarray) -> list[SlipEstimate]:
        """Decode accepted samples (finite, strictly increasing, after earlier ones)."""
        raise NotImplementedError


class StaticForce:
    """Static grip force: the FSR signal low-passed (2nd-order Butterworth, SOS, carried state).

    The corner (default 2 Hz) sits below the ridge-contact rates of a slip
    (v/D >= ~2 Hz for the thesis speeds), so pulses average out and grip
    steps come through within a few hundred ms. Starts settled on the first sample.
    """

    def __init__(self, fs_hz: float, corner_hz: float = 2.0):
        from scipy.signal import butter, sosfilt_zi

        corner = min(corner_hz, 0.45 * fs_hz)
        self._sos = butter(2, corner, fs=fs_hz, output="sos")
        self._zi_unit = sosfilt_zi(self._sos)
        self._zi: np.ndarray | None = None

    def filter(self, x: np.ndarray) -> np.ndarray:
        from scipy.signal import sosfilt

        if self._zi is None:
            self._zi = self._zi_unit * x[0]
        y, self._zi = sosfilt(self._sos, x, zi=self._zi)
        return y

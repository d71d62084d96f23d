"""Dynamic time warping against the reference, fast enough to run live.

The thesis (ch. 5.5) tried dynamic time warping - the MMSE decoder's
reference comparison without its constant-speed assumption - and dropped it
as too slow. This decoder makes it cheap by warping only around an
alignment it already has:

1. Coarse alignment: the MMSE search (`mmse.ReferenceSearch`, same window,
   references - `references=`, supplied by the caller as for mmse - and
   z-normalised MSE) over a geometric speed grid (ratio
   `speed_ratio` 1.1 from `v_low` 5 to `v_high` 250 mm/s, 43 speeds) on a
   0.5 mm reference grid, then a finer one (steps of speed_ratio^(1/4),
   +-3 steps) around each direction's best: speed v0, direction, offset.
   Speeds at which the window covers less than `min_mm` (15 mm) are left
   out: a short stretch fits anything.
2. Subsequence DTW in a Sakoe-Chiba band: the window warped at v0 (one sample
   per grid step), z-normalised, against the z-normalised reference around
   the coarse alignment, the path kept within `band_mm` (1 mm) of it and
   free to start and end anywhere in the band (open begin and end). Step
   pattern: Sakoe-Chiba's symmetric steps with slope constraint P = 1
   ((1,1), (1,2), (2,1)): the local speed may range over 0.5-2 x v0 (speed
   dips at the ridges). Each row of the band is one vectorised numpy step (a
   row depends on the two before): the work is rows x band, not rows x
   reference.
3. Speed = reference distance over warped time: v0 times the slope of a
   least-squares line through the path (its free ends wander within the
   band, the line does not); position = the reference position where that
   line ends (the window's last sample); direction = the reference's.

Speed/accuracy settings: `resolution_mm` (grid), `speed_ratio` (search
grid), `band_mm` (warping freedom), `hop_s` (200 ms between matches,
extrapolated in between; 100 ms doubles the cost, and only helps when the
speed varies), `window_s` (up to 5 s from 0.25 s before the slip's first
pulse). `warp_refine=False` keeps the search alone.

Accuracy and CPU per sample, per setting (speed grid, hop; the search
dominates the cost), with speed dips and tip contacts too:
docs/benchmarks/decoding.md (rows `dtw`). On constant-speed signals the
search alone (`warp_refine=False`) is a little more accurate; the warping
pays off where the speed varies.

Slip flag and windows as the MMSE decoder (`mmse.WindowDecoder`).
Confidence: how much better than a straight line the path explains the
window, scaled down when the search found a clearly different answer
(other direction, position > `distinct_mm` away) nearly as good, when v0 is
at the slow or fast end of the admissible speeds, and when the path's
slope strays far from v0.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import ClassVar

import numpy as np

from grasplink.decoding.base import DEFAULT_UPDATE_S
from grasplink.decoding.mmse import (
    Candidate,
    ReferenceSearch,
    ReferenceSlip,
    WindowDecoder,
    edge_factor,
    explained,
    require_references,
    rivalry,
    warp_window,
)
from grasplink.errors import ConfigError

INF = np.inf
# The slowest admissible speed moves with the window (min_mm of travel): an answer
# within this factor of it may be a slower slip the window cannot resolve yet.
EDGE_MARGIN = 1.25


def coarse_speeds(low: float = 4.0, high: float = 250.0, ratio: float = 1.25) -> np.ndarray:
    count = math.ceil(math.log(high / low) / math.log(ratio)) + 1
    return low * ratio ** np.arange(count)


def banded_dtw(
    query: np.ndarray, ref: np.ndarray, band: int
) -> tuple[float, list[tuple[int, int]]]:
    """Subsequence DTW of `query` (n) against `ref` (n + 2 band), within the band.

    Cell (i, k) aligns query[i] with ref[i + k], k in 0..2 band (the band
    around the diagonal k = band). Steps (symmetric, slope constraint P = 1):
    (i-1, j-1); (i-1, j-2) through (i, j-1); (i-2, j-1) through (i-1, j).
    Open begin (any k at i = 0) and open end (best k at i = n - 1). Returns
    the accumulated cost per query sample and the path [(i, j), ...].
    """
    n = len(query)
    width = 2 * band + 1
    cost = (query[:, None] - _band_view(ref, n, width)) ** 2  # (n, width)
    acc = np.full((n, width), INF)
    move = np.zeros((n, width), dtype=np.int8)  # 0 diag, 1 via (i, j-1), 2 via (i-1, j)
    acc[0] = cost[0]
    shift = np.full(width, INF)
    for i in range(1, n):
        diag = acc[i - 1]
        # (i-1, j-2) then (i, j-1): band index k-1 at row i-1, plus cost[i, k-1]
        shift[0] = INF
        shift[1:] = acc[i - 1, :-1] + cost[i, :-1]
        best = np.minimum(diag, shift)
        which = np.where(shift < diag, 1, 0)
        if i >= 2:
            # (i-2, j-1) then (i-1, j): band index k+1 at row i-2, plus cost[i-1, k+1]
            up = np.full(width, INF)
            up[:-1] = acc[i - 2, 1:] + cost[i - 1, 1:]
            better = up < best
            best = np.where(better, up, best)
            which = np.where(better, 2, which)
        acc[i] = cost[i] + best
        move[i] = which
    k = int(np.argmin(acc[n - 1]))
    total = float(acc[n - 1, k])
    path = [(n - 1, n - 1 + k)]
    i = n - 1
    while i > 0:
        m = move[i, k]
        if m == 0:
            i -= 1
        elif m == 1:
            path.append((i, i + k - 1))
            i, k = i - 1, k - 1
        else:
            path.append((i - 1, i - 1 + k + 1))
            i, k = i - 2, k + 1
        path.append((i, i + k))
    path.reverse()
    return total / n, path


def _band_view(ref: np.ndarray, n: int, width: int) -> np.ndarray:
    return np.lib.stride_tricks.sliding_window_view(ref, width)[:n]


def _znorm(a: np.ndarray) -> np.ndarray:
    sd = a.std()
    return (a - a.mean()) / sd if sd > 1e-9 else np.zeros_like(a)


class DtwDecoder(WindowDecoder):
    name = "dtw"
    needs_references: ClassVar[bool] = True

    def __init__(
        self,
        layout_mm: Sequence[float],
        fs_hz: float,
        *,
        update_period_s: float = DEFAULT_UPDATE_S,
        window_s: float = 5.0,
        references: Sequence[ReferenceSlip] | None = None,
        resolution_mm: float = 0.5,
        band_mm: float = 1.0,
        min_mm: float = 15.0,
        v_low: float = 5.0,
        v_high: float = 250.0,
        speed_ratio: float = 1.1,
        hop_s: float = 0.2,
        min_correlation: float = 0.5,
        distinct_mm: float = 10.0,
        warp_refine: bool = True,
        **front,
    ):
        references = require_references(self.name, references)
        super().__init__(
            layout_mm,
            fs_hz,
            update_period_s=update_period_s,
            window_s=window_s,
            hop_s=hop_s,
            **front,
        )
        self.warp_refine = bool(warp_refine)
        for label, value in (
            ("resolution_mm", resolution_mm),
            ("band_mm", band_mm),
            ("min_mm", min_mm),
        ):
            if not (math.isfinite(value) and value > 0):
                raise ConfigError(f"{label} must be > 0, got {value}")
        if not (0 < v_low < v_high and speed_ratio > 1):
            raise ConfigError(
                f"need 0 < v_low < v_high and speed_ratio > 1, got {v_low}, {v_high}, {speed_ratio}"
            )
        self.resolution_mm = float(resolution_mm)
        self.band = max(1, round(band_mm / resolution_mm))
        self.min_cells = max(8, round(min_mm / resolution_mm))
        self.min_correlation = float(min_correlation)
        self.distinct_mm = float(distinct_mm)
        self._fine = speed_ratio ** (np.arange(-3, 4) / 4.0)
        self.searcher = ReferenceSearch(
            self.geometry.spacings_mm,
            coarse_speeds(v_low, v_high, speed_ratio),
            window_s=window_s,
            references=references,
            resolution_mm=resolution_mm,
        )

    def match(self, t: np.ndarray, x: np.ndarray) -> tuple[float, float | None, float] | None:
        candidates = self.searcher.search(t, x, self.min_cells)
        if not candidates:
            return None
        # coarse to fine: around the best speed of each direction, steps of ratio^(1/4)
        fine_speeds = []
        for direction in (1, -1):
            best = next((c for c in candidates if np.sign(c.speed) == direction), None)
            if best is not None:
                fine_speeds.append(abs(best.speed) * self._fine)
        if fine_speeds:
            fine = self.searcher.search(
                t, x, self.min_cells, np.unique(np.concatenate(fine_speeds))
            )
            candidates = sorted(candidates + fine, key=lambda c: c.mse)
        coarse = candidates[0]
        if 1.0 - coarse.mse / 2.0 < self.min_correlation:
            return None
        trust = rivalry(candidates, self.distinct_mm) * edge_factor(candidates, EDGE_MARGIN)
        if not self.warp_refine:
            return coarse.speed, coarse.position, explained(coarse.mse, t, x) * trust
        refined = self.refine(coarse, t, x)
        if refined is None:
            return None
        speed, position, rho = refined
        if rho < self.min_correlation:
            return None
        # a path whose overall slope strays far from the coarse speed means the coarse
        # alignment was poor: trust falls to 0 at a factor of 2 (the slope limit)
        agreement = 1.0 - abs(math.log(abs(speed) / abs(coarse.speed))) / math.log(2.0)
        trust *= float(np.clip(agreement, 0.1, 1.0))
        return speed, position, float(np.clip(explained(2.0 * (1.0 - rho), t, x) * trust, 0.0, 1.0))

    def refine(
        self, coarse: Candidate, t: np.ndarray, x: np.ndarray
    ) -> tuple[float, float, float] | None:
        """Banded DTW of the window around the coarse alignment: (speed, position, rho)."""
        v0 = abs(coarse.speed)
        warped = warp_window(t, x, v0, self.resolution_mm, self.searcher.max_len)
        n = len(warped)
        if n < 8:
            return None
        query = _znorm(warped)
        ref = coarse.reference
        end = coarse.offset + coarse.length - 1  # padded index under the window's end
        first = end - (n - 1) - self.band
        last = end + self.band
        if first < 0 or last >= len(ref.values):
            return None
        segment = _znorm(ref.values[first : last + 1])
        cost, path = banded_dtw(query, segment, self.band)
        # reference distance over warped time: a least-squares line through the path
        # (its free ends wander within the band; the line does not)
        steps = np.asarray(path, dtype=np.float64)
        i, j = steps[:, 0], steps[:, 1]
        di = i - i.mean()
        spread = float(di @ di)
        if spread <= 0:
            return None
        slope = float(di @ (j - j.mean())) / spread
        j_end = j.mean() + slope * (n - 1 - i.mean())
        speed = ref.direction * v0 * slope
        position = float(ref.position(first + j_end))
        rho = 1.0 - cost / 2.0
        return float(speed), position, rho

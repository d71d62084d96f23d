"""The thesis' MMSE decoder (ch. 5.4.3): match the live window against a reference.

A reference signal r recorded at a known speed v_ref over the whole skin
(`ReferenceSlip`, one per direction so both directions can be told apart;
the caller supplies them as `references=` - the gateway records nothing and
simulates nothing: `grasplink.evaluation.decoders.reference_slips` makes the
thesis-like pair, a noise-free simulated slip at 20 mm/s at the decoder's
sample rate, for `grasplink decode` and the benchmark) is kept as a function
of the leading edge's position (its ground truth) on a grid of
`resolution_mm` (0.25 mm), padded before the skin with the reference's
resting level and after it with its last value, so a window may hang over
either end. For each candidate speed v in [`v_lower`,
`v_upper`] step `v_step` (5-150 mm/s step 5, the thesis' grid) the live
window s - from 0.25 s before the slip's first pulse to now, 1 to
`window_s` (5) seconds, the thesis' "from the time of initial slippage to
the present" - is time-warped by k = v_ref / v (resampled at the times the
object needs to cover one grid step at v; averaged over each step where a
step spans several samples) and slid along r; the mean squared error
between the z-normalised (zero-mean, unit-variance) window and the
z-normalised reference segment is computed at every offset whose window
end lies within 30 mm of the skin. The overall minimum gives the speed (v,
signed by the reference's direction) and the position (the reference
position under the window's last sample). A window longer than the skin
plus margins keeps its recent part.

Faithful brute force: every speed, every offset, both directions - so the
speed is quantised to the grid (33 mm/s reads 35). Vectorised: all warped
windows at once, the sliding dot products through one FFT per direction,
the sliding means and variances by cumulative sums (the same numbers as the
thesis' loop, `mse_profile_bruteforce`, checks that). Recomputed every
`hop_s` (50 ms, on the update grid), extrapolated at the decoded speed in
between.

Slip (the thesis' algorithm assumes it): flagged by ridge pulses (the ratio
decoder's band-pass and peak detector, `filters.PeakActivity`: on at two
pulses within 1.5 s, off when none came for 1.5x the time the widest
spacing takes at the decoded speed). Estimates only while slip is flagged
and the best match correlates >= `min_correlation`. Confidence: how much of
the error a straight line leaves the match removes (the slow coverage ramp
makes every rising stretch correlate), scaled down when a clearly different
answer (the other direction, or a position more than `distinct_mm` away)
has less than twice the best's error, and x0.3 when the best speed is an
end of the searched range (the truth may lie beyond).

Accuracy and CPU per sample: docs/benchmarks/decoding.md (rows `mmse`). On
the speed grid it is near exact (the reference comes from the same
simulator); off the grid it fails badly: a warp off by half a step
misaligns a long window, and a wrong direction can win.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from grasplink.decoding.base import DEFAULT_UPDATE_S, Decoder, SlipEstimate
from grasplink.decoding.filters import (
    PeakActivity,
    PulseFrontEnd,
    interleave,
    pulse_events,
)
from grasplink.errors import ConfigError

FLAT_N = 1e-4  # a segment with a std below this (N) is flat: it z-normalises to zeros


@dataclass(frozen=True, eq=False)
class ReferenceSlip:
    """A slip over the whole skin at a known constant speed: what the window matchers match.

    The decoder's caller records (or simulates) one per direction and hands
    them over, so the gateway itself needs neither a simulator nor a
    recording session. Samples are those taken while the object slipped.
    """

    speed_mm_s: float  # signed: + from the first ridge towards the last
    position_mm: np.ndarray  # the leading edge at each sample (mm from the first ridge)
    force_n: np.ndarray  # the sensor's force at those samples
    rest_force_n: float  # the force before the slip started

    def __post_init__(self) -> None:
        x = np.asarray(self.position_mm, dtype=np.float64)
        f = np.asarray(self.force_n, dtype=np.float64)
        if not (math.isfinite(self.speed_mm_s) and self.speed_mm_s != 0):
            raise ConfigError(f"reference slip: speed must be non-zero, got {self.speed_mm_s}")
        if x.ndim != 1 or x.shape != f.shape or len(x) < 2:
            raise ConfigError(
                "reference slip: position_mm and force_n must be 1-D, of equal length, "
                f"with >= 2 samples (got shapes {x.shape} and {f.shape})"
            )
        if not (np.isfinite(x).all() and np.isfinite(f).all() and math.isfinite(self.rest_force_n)):
            raise ConfigError("reference slip: every position and force must be a finite number")
        if np.ptp(x) <= 0:
            raise ConfigError("reference slip: the object does not move")
        object.__setattr__(self, "position_mm", x)
        object.__setattr__(self, "force_n", f)

    @property
    def direction(self) -> int:
        return 1 if self.speed_mm_s > 0 else -1


def require_references(
    name: str, references: ReferenceSlip | Sequence[ReferenceSlip] | None
) -> tuple[ReferenceSlip, ...]:
    """The references as a tuple; a window matcher without any cannot run: say what it needs."""
    if isinstance(references, ReferenceSlip):
        references = (references,)
    refs = tuple(references or ())
    if not refs:
        raise ConfigError(
            f"decoder {name!r} needs reference slips (references=[forward, reverse]): "
            "a slip over the whole skin at a known speed in each direction; "
            "grasplink decode and the decoding benchmark simulate them"
        )
    for ref in refs:
        if not isinstance(ref, ReferenceSlip):
            raise ConfigError(
                f"decoder {name!r}: references must be ReferenceSlip, got {type(ref).__name__}"
            )
    return refs


class Reference:
    """A reference slip on the search grid, as force against leading-edge position.

    `values[j]` is the force with the edge at `start_mm + direction * (j - pad)
    * resolution_mm`; `pad` grid points before (the resting level before the
    slip) and after (the last value) the travel.
    """

    def __init__(self, slip: ReferenceSlip, *, resolution_mm: float, pad: int):
        direction = slip.direction
        x = slip.position_mm
        f = slip.force_n
        along = direction * x  # increasing along the travel
        order = np.argsort(along, kind="stable")
        along, f = along[order], f[order]
        grid = np.arange(along[0], along[-1] + 1e-9, resolution_mm)
        core = np.interp(grid, along, f)
        self.direction = direction
        self.resolution_mm = resolution_mm
        self.start_mm = float(direction * grid[0])
        self.pad = pad
        # Before the slip the reference is at rest: the window's pre-slip part matches
        # the recording's resting level, whatever the simulator makes of it.
        self.values = np.concatenate(
            [np.full(pad, float(slip.rest_force_n)), core, np.full(pad, core[-1])]
        )

    def position(self, end_index: int | np.ndarray) -> float | np.ndarray:
        """Edge position for a window ending at padded index `end_index`."""
        return self.start_mm + self.direction * (end_index - self.pad) * self.resolution_mm


class WindowDecoder(Decoder):
    """Common streaming for the window matchers (mmse, dtw).

    Front end (band-pass, peaks, static force) as the ratio decoder; a buffer
    of the last `window_s` seconds of raw samples since the last restart; a
    match every `hop_s` while slip is flagged, extrapolated in between. The
    window matched runs from `lead_s` before the slip's first pulse to now
    (the thesis: "from the time of initial slippage to the present"), at
    least `min_window_s`, at most `window_s`.
    Subclasses implement `match(t, x) -> (speed, position at t[-1], confidence)`
    or None.
    """

    def __init__(
        self,
        layout_mm: Sequence[float],
        fs_hz: float,
        *,
        update_period_s: float = DEFAULT_UPDATE_S,
        window_s: float = 5.0,
        min_window_s: float = 1.0,
        lead_s: float = 0.25,
        hop_s: float = 0.05,
        min_fill: float = 0.5,
        pair_s: float = 1.5,
        hold_factor: float = 1.5,
        threshold_n: float = 0.05,
        false_peaks_per_min: float = 1.0,
    ):
        super().__init__(layout_mm, fs_hz, update_period_s=update_period_s)
        if not window_s > 0:
            raise ConfigError(f"window_s must be > 0, got {window_s}")
        if not hop_s > 0:
            raise ConfigError(f"hop_s must be > 0, got {hop_s}")
        self.window_s = float(window_s)
        self.min_window_s = min(float(min_window_s), self.window_s)
        self.lead_s = float(lead_s)
        self.hop = max(1, round(hop_s / self.update_period_s))
        self.min_samples = max(4, round(min_fill * self.min_window_s * self.fs_hz))
        self.front = PulseFrontEnd(
            self.fs_hz, threshold_n=threshold_n, false_peaks_per_min=false_peaks_per_min
        )
        self.activity = PeakActivity(
            self.geometry.spacings_mm, pair_s=pair_s, hold_factor=hold_factor
        )
        self._t = np.zeros(0)
        self._x = np.zeros(0)
        self._force: float | None = None
        self._match: tuple[float, float | None, float, float] | None = None  # v, x, conf, t

    def match(self, t: np.ndarray, x: np.ndarray) -> tuple[float, float | None, float] | None:
        raise NotImplementedError

    def process(self, t: np.ndarray, x: np.ndarray) -> list[SlipEstimate]:
        segments = self.front(t, x)
        events = pulse_events(segments)
        force = np.concatenate([seg.force_n for seg in segments])
        restarts = np.array(
            [start for start, seg in _segment_starts(segments) if seg.after_gap], dtype=np.int64
        )
        all_t = np.concatenate([self._t, t])
        all_x = np.concatenate([self._x, x])
        offset = len(self._t)
        out = []
        for count, g in interleave(events, self.update_points(t), self._apply):
            if count:
                self._force = float(force[count - 1])
            begin = self._window_begin(all_t, restarts, offset, count)
            out.append(
                self._estimate(g, all_t[begin : offset + count], all_x[begin : offset + count])
            )
        begin = self._window_begin(all_t, restarts, offset, len(t))
        self._t, self._x = all_t[begin:], all_x[begin:]
        self._force = float(force[-1])
        return out

    def _window_begin(
        self, all_t: np.ndarray, restarts: np.ndarray, offset: int, count: int
    ) -> int:
        end = offset + count
        if end == 0:
            return 0
        begin = int(np.searchsorted(all_t, all_t[end - 1] - self.window_s, side="right"))
        k = int(np.searchsorted(restarts, count - 1, side="right"))
        if k:
            begin = max(begin, offset + int(restarts[k - 1]))
        return begin

    def _apply(self, event: tuple) -> None:
        if event[1] is None:
            self.activity.reset()
            self._match = None
        else:
            self.activity.peak(event[1].t_s)

    def _estimate(self, g: float, t: np.ndarray, x: np.ndarray) -> SlipEstimate:
        previous = self._match
        if not self.activity.active(g, previous[0] if previous else None):
            self._match = None
            return SlipEstimate(g, False, None, None, self._force, 0.0)
        step = round(g / self.update_period_s)
        if step % self.hop == 0 and len(t) >= self.min_samples:
            start = self.activity.episode_start
            span = self.window_s
            if start is not None:  # the thesis' window: from the slip's start to now
                span = min(self.window_s, max(self.min_window_s, t[-1] - start + self.lead_s))
            keep = t >= t[-1] - span
            found = self.match(t[keep], x[keep])
            self._match = None if found is None else (*found, float(t[-1]))
        m = self._match
        if m is None:
            return SlipEstimate(g, True, None, None, self._force, 0.0)
        speed, position, confidence, t_end = m
        if position is not None:
            position = position + speed * (g - t_end)
        # the sign of the best match is its direction, told with the match's confidence
        return SlipEstimate.from_velocity(g, True, speed, position, self._force, confidence)


def _segment_starts(segments):
    start = 0
    for seg in segments:
        yield start, seg
        start += len(seg.t)


@dataclass(frozen=True, slots=True)
class Candidate:
    """The best offset for one (direction, speed): what the MMSE search found."""

    mse: float
    speed: float  # signed mm/s
    offset: int  # padded reference index where the warped window starts
    length: int  # warped window length (grid steps)
    reference: Reference
    warped: np.ndarray

    @property
    def position(self) -> float:
        return float(self.reference.position(self.offset + self.length - 1))


class ReferenceSearch:
    """The thesis' MMSE search: every speed, every offset, both directions.

    For each candidate speed the window is warped onto the reference grid
    (`warp_window`), z-normalised and compared with the z-normalised
    reference segment at every offset. Vectorised: all warped windows in
    one batch, sliding dot products through one FFT per direction, sliding
    means and variances by cumulative sums - the same numbers as the loop
    `mse_profile_bruteforce`.
    """

    def __init__(
        self,
        layout_mm: Sequence[float] | np.ndarray,
        speeds: np.ndarray,
        *,
        window_s: float,
        references: Sequence[ReferenceSlip],
        resolution_mm: float,
        end_margin_mm: float = 30.0,
    ):
        self.speeds = np.asarray(speeds, dtype=np.float64)
        self.resolution_mm = float(resolution_mm)
        self.margin = max(0, round(end_margin_mm / self.resolution_mm))
        # a window longer than the skin (plus margins) compares padding: keep its recent part
        longest_mm = min(
            float(self.speeds.max()) * window_s, float(sum(layout_mm)) + 2 * end_margin_mm
        )
        self.max_len = math.floor(longest_mm / resolution_mm) + 1
        self.references = [
            Reference(slip, resolution_mm=self.resolution_mm, pad=self.max_len)
            for slip in references
        ]
        n = max(len(ref.values) for ref in self.references)
        self.nfft = 1 << math.ceil(math.log2(n))
        self._spectra = []
        self._sums = []
        for ref in self.references:
            r = np.zeros(self.nfft)
            r[: len(ref.values)] = ref.values
            self._spectra.append(np.fft.rfft(r))
            self._sums.append(
                (
                    np.concatenate([[0.0], np.cumsum(ref.values)]),
                    np.concatenate([[0.0], np.cumsum(ref.values**2)]),
                )
            )

    def warp(
        self, t: np.ndarray, x: np.ndarray, speeds: np.ndarray | None = None
    ) -> list[np.ndarray]:
        """The window resampled at one grid step per sample, for every candidate speed."""
        speeds = self.speeds if speeds is None else speeds
        return warp_batch(
            t, x, np.asarray(speeds, dtype=np.float64), self.resolution_mm, self.max_len
        )

    def profiles(self, warped: list[np.ndarray]) -> list[list[tuple[int, np.ndarray]]]:
        """MSE of each z-normalised warped window: [direction][speed] -> (first offset, MSE).

        Offset o compares the window with reference[o : o + L]; for z-normalised
        signals MSE = 2 (1 - rho), rho the Pearson correlation. Only offsets whose
        window end lies within `end_margin_mm` of the skin are scored (the pads
        exist so a window can hang over the skin's ends, not to end far away).
        """
        batch = np.zeros((len(warped), self.nfft))
        stds = []
        for k, w in enumerate(warped):
            centred = w - w.mean()
            std = float(np.sqrt(np.mean(centred**2)))
            stds.append(std)
            if std > FLAT_N:
                batch[k, : len(w)] = centred / std
        spectra = np.fft.rfft(batch, axis=1)
        result = []
        for ref, spectrum, (s1, s2) in zip(self.references, self._spectra, self._sums, strict=True):
            corr = np.fft.irfft(np.conj(spectra) * spectrum, self.nfft, axis=1)
            rows = []
            n = len(s1) - 1
            lo_end, hi_end = ref.pad - self.margin, n - 1 - ref.pad + self.margin
            for k, w in enumerate(warped):
                length = len(w)
                first = max(0, lo_end - length + 1)
                stop = min(n - length, hi_end - length + 1) + 1
                if stop <= first:
                    rows.append((first, np.full(1, 2.0)))
                    continue
                mean = (s1[first + length : stop + length] - s1[first:stop]) / length
                var = (s2[first + length : stop + length] - s2[first:stop]) / length - mean**2
                sd = np.sqrt(np.maximum(var, 0.0))
                flat = sd <= FLAT_N
                if stds[k] <= FLAT_N:  # a flat window (z-normalised: zeros) against z(r)
                    rows.append((first, np.where(flat, 0.0, 1.0)))
                    continue
                with np.errstate(divide="ignore", invalid="ignore"):
                    rho = np.where(flat, 0.5, corr[k, first:stop] / (length * sd))
                # a flat segment z-normalises to zeros: MSE 1 against a unit window
                rows.append((first, 2.0 * (1.0 - rho)))
            result.append(rows)
        return result

    def search(
        self, t: np.ndarray, x: np.ndarray, min_length: int = 2, speeds: np.ndarray | None = None
    ) -> list[Candidate]:
        """The best offset per (direction, speed), best first.

        `speeds`: the candidates (default: the grid). Speeds whose warped window
        is shorter than `min_length` grid steps (the window covers too little
        travel at that speed) are left out.
        """
        if len(t) < 2 or t[-1] - t[0] <= 0:
            return []
        speeds = self.speeds if speeds is None else np.asarray(speeds, dtype=np.float64)
        warped = self.warp(t, x, speeds)
        keep = [k for k, w in enumerate(warped) if len(w) >= min_length]
        speeds = speeds[keep]
        warped = [warped[k] for k in keep]
        if not warped:
            return []
        out = []
        for ref, rows in zip(self.references, self.profiles(warped), strict=True):
            for v, (first, mse), w in zip(speeds, rows, warped, strict=True):
                o = int(np.argmin(mse))
                out.append(
                    Candidate(float(mse[o]), ref.direction * float(v), first + o, len(w), ref, w)
                )
        out.sort(key=lambda c: c.mse)
        return out


EDGE_TRUST = 0.3  # confidence factor when the best speed is the searched range's end


def edge_factor(candidates: list[Candidate], margin: float = 1.0) -> float:
    """The best speed at an end of the speeds searched says only "this slow or slower".

    The searched range is what was admissible: the grid, less the speeds at
    which the window covered too little travel; "at an end" is within a
    factor `margin` of it.
    """
    speeds = [abs(c.speed) for c in candidates]
    v = speeds[0]
    slow = v <= min(speeds) * margin * (1 + 1e-9)
    fast = v >= max(speeds) / margin * (1 - 1e-9)
    return EDGE_TRUST if slow or fast else 1.0


def explained(best_mse: float, t: np.ndarray, x: np.ndarray) -> float:
    """How much better than a straight line the match explains the window (0..1).

    The slow rise as the object covers the sensor makes every rising stretch
    of the reference correlate well with any window; what counts is the
    error left against the error of a line fitted to the window.
    """
    sd_t, sd_x = float(np.std(t)), float(np.std(x))
    if sd_t <= 0 or sd_x <= 0:
        return 0.0
    rho = float(np.mean((t - t.mean()) * (x - x.mean()))) / (sd_t * sd_x)
    line_mse = 2.0 * (1.0 - abs(rho))
    if line_mse <= 0:
        return 0.0
    return float(np.clip(1.0 - best_mse / line_mse, 0.0, 1.0))


def rivalry(candidates: list[Candidate], distinct_mm: float) -> float:
    """Confidence factor: how clearly the best beats a different answer (0.1..1).

    A different answer is the other direction, or a position more than
    `distinct_mm` away. Full trust when its MSE is at least twice the best's,
    falling linearly to 0.1 as the two become equal (an ambiguous skin).
    """
    best = candidates[0]
    rivals = [
        c
        for c in candidates[1:]
        if (c.speed > 0) != (best.speed > 0) or abs(c.position - best.position) > distinct_mm
    ]
    if not rivals or rivals[0].mse <= 0:
        return 1.0
    margin = 1.0 - best.mse / rivals[0].mse
    return float(np.clip(margin / 0.5, 0.1, 1.0))


class MmseDecoder(WindowDecoder):
    name = "mmse"
    needs_references: ClassVar[bool] = True

    def __init__(
        self,
        layout_mm: Sequence[float],
        fs_hz: float,
        *,
        update_period_s: float = DEFAULT_UPDATE_S,
        window_s: float = 5.0,
        references: Sequence[ReferenceSlip] | None = None,
        v_lower: float = 5.0,
        v_upper: float = 150.0,
        v_step: float = 5.0,
        resolution_mm: float = 0.25,
        hop_s: float = 0.05,
        min_correlation: float = 0.5,
        distinct_mm: float = 10.0,
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
        if not 0 < v_lower <= v_upper or not v_step > 0:
            raise ConfigError(
                f"need 0 < v_lower <= v_upper and v_step > 0, got {v_lower}, {v_upper}, {v_step}"
            )
        if not resolution_mm > 0:
            raise ConfigError(f"resolution_mm must be > 0, got {resolution_mm}")
        self.min_correlation = float(min_correlation)
        self.distinct_mm = float(distinct_mm)
        self.searcher = ReferenceSearch(
            self.geometry.spacings_mm,
            np.arange(v_lower, v_upper + 1e-9 * v_upper, v_step),
            window_s=window_s,
            references=references,
            resolution_mm=resolution_mm,
        )

    def match(self, t: np.ndarray, x: np.ndarray) -> tuple[float, float | None, float] | None:
        candidates = self.searcher.search(t, x)
        if not candidates:
            return None
        best = candidates[0]
        rho = 1.0 - best.mse / 2.0
        if rho < self.min_correlation:
            return None
        confidence = (
            explained(best.mse, t, x)
            * rivalry(candidates, self.distinct_mm)
            * edge_factor(candidates)
        )
        return best.speed, best.position, float(np.clip(confidence, 0.0, 1.0))


def warp_window(
    t: np.ndarray, x: np.ndarray, speed: float, step_mm: float, max_len: int
) -> np.ndarray:
    """Resample (t, x) at one sample per `step_mm` of travel at `speed`, ending at t[-1]."""
    duration = float(t[-1] - t[0])
    dt = step_mm / speed
    length = max(2, min(max_len, math.floor(duration / dt) + 1))
    times = t[-1] - (length - 1 - np.arange(length)) * dt
    if len(t) < 2 or dt <= 1.5 * duration / (len(t) - 1):
        return np.interp(times, t, x)
    # box average over [time - dt/2, time + dt/2] by the integral of the linear interpolant
    area = np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t))])
    lo = np.clip(times - dt / 2, t[0], t[-1])
    hi = np.clip(times + dt / 2, t[0], t[-1])
    a_lo = _integral(t, x, area, lo)
    a_hi = _integral(t, x, area, hi)
    width = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(width > 0, (a_hi - a_lo) / width, np.interp(times, t, x))


def warp_batch(
    t: np.ndarray, x: np.ndarray, speeds: np.ndarray, step_mm: float, max_len: int
) -> list[np.ndarray]:
    """`warp_window` for many speeds at once (one interpolation over all of them)."""
    if len(t) < 2:
        return [warp_window(t, x, v, step_mm, max_len) for v in speeds]
    duration = float(t[-1] - t[0])
    dts = step_mm / speeds
    lengths = np.maximum(2, np.minimum(max_len, np.floor(duration / dts).astype(np.int64) + 1))
    starts = np.concatenate([[0], np.cumsum(lengths)])
    owner = np.repeat(np.arange(len(speeds)), lengths)
    back = (starts[owner + 1] - 1) - np.arange(starts[-1])  # steps before the window's end
    dt = dts[owner]
    times = t[-1] - back * dt
    values = np.interp(times, t, x)
    boxed = dt > 1.5 * duration / (len(t) - 1)
    if boxed.any():
        area = np.concatenate([[0.0], np.cumsum(0.5 * (x[1:] + x[:-1]) * np.diff(t))])
        tb, db = times[boxed], dt[boxed]
        lo = np.clip(tb - db / 2, t[0], t[-1])
        hi = np.clip(tb + db / 2, t[0], t[-1])
        width = hi - lo
        mean = (_integral(t, x, area, hi) - _integral(t, x, area, lo)) / np.where(
            width > 0, width, 1.0
        )
        values[boxed] = np.where(width > 0, mean, values[boxed])
    return np.split(values, starts[1:-1])


def _integral(t: np.ndarray, x: np.ndarray, area: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Integral of the linear interpolant of (t, x) from t[0] to `at`."""
    k = np.clip(np.searchsorted(t, at, side="right") - 1, 0, len(t) - 2)
    dt = at - t[k]
    slope = (x[k + 1] - x[k]) / (t[k + 1] - t[k])
    return area[k] + x[k] * dt + 0.5 * slope * dt * dt


def mse_profile_bruteforce(window: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """The thesis' loop for one warped window: z-normalised MSE at every offset."""

    def z(a: np.ndarray) -> np.ndarray:
        sd = a.std()
        return (a - a.mean()) / sd if sd > FLAT_N else np.zeros_like(a)

    length = len(window)
    w = z(window)
    return np.array(
        [
            np.mean((w - z(reference[o : o + length])) ** 2)
            for o in range(len(reference) - length + 1)
        ]
    )

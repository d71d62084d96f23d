"""Streaming signal blocks shared by the skin decoders, all chunk-invariant.

* `SosFilter` -- the one streaming filter every decoder uses (band-passes,
  the static-force low-pass, the contact detector's FIR kernels): second-order
  sections with carried state, starting settled on the first sample (a DC
  offset of +50 N gives no start-up transient). Second-order sections, not a
  transfer function:
  a 4th-order 0.3-3 Hz band-pass at 1 kHz has poles within ~1e-3 of z = 1,
  and the (b, a) polynomial form loses them to rounding (see
  `transfer_function_is_unstable` and tests/decoding/test_stability.py).
* `PeakDetector` -- maxima protruding by a threshold above their
  surroundings on both sides (hysteresis, reported as soon as the signal
  has dropped), the time refined by a parabola through the three samples
  around the maximum. Carries a bounded state (the running extremum and its
  neighbours) so a peak straddling a chunk boundary is found exactly once,
  at the same time, however the input is chunked.
* `NoiseEstimator` -- white-noise sigma from the median absolute deviation
  (MAD) of first differences, on blocks aligned to the sample count since
  the last reset (so the estimate does not depend on chunking), robust to
  the ridge pulses and immune to DC and drift.
* `PulseFrontEnd` -- the pulse decoders' common front: band-pass, static
  force (base.StaticForce), noise-scaled peak threshold and peaks, restarted
  after gaps; `pulse_events` orders its output by the time each peak became
  known. `PeakLag` -- how far past a ridge its band-passed pulse peaks.
  `PeakActivity` -- the slip flag from pulses, with hysteresis.

Every block processes samples in order and changes state only per sample or
per fixed-size block, which is what makes feeding a recording in pieces give
bit-identical results to feeding it in one piece.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from scipy import signal

from grasplink.decoding.kernels.detector import fir_run, sos_run
from grasplink.errors import ConfigError

MAD_TO_SIGMA = 1.4826  # sigma of a normal distribution per median absolute deviation


def bandpass_sos(low_hz: float, high_hz: float, fs_hz: float, order: int = 2) -> np.ndarray:
    """Butterworth band-pass as second-order sections (`order` per edge, 2*order poles).

    The upper corner is kept below 0.45 fs and above the lower corner, so a
    decoder configured for 400 Hz still builds a valid filter at 100 Hz.
    """
    high = min(high_hz, 0.45 * fs_hz)
    low = min(low_hz, 0.5 * high)
    return signal.butter(order, [low, high], btype="bandpass", fs=fs_hz, output="sos")


def transfer_function_is_unstable(b: np.ndarray, a: np.ndarray) -> bool:
    """True when the (b, a) form's poles left the unit circle through rounding."""
    return bool(np.max(np.abs(np.roots(a))) >= 1.0)


class SosFilter:
    """The decoders' one streaming filter: second-order sections with carried state.

    IIR designs (Butterworth band-pass, the static-force low-pass) run as a
    cascade of second-order sections (direct form II transposed); FIR
    kernels (`SosFilter.fir`: the contact detector's slope and level
    kernels) are the all-zero case, run as one direct-form II transposed
    filter with a = 1 (scipy's `lfilter` sample loop, compiled:
    `kernels.detector.fir_run`; a 33-tap kernel needs no factoring into 16
    sections). Either way the state is carried and the
    work is done sample by sample, so feeding a signal in pieces gives
    bit-identical output to feeding it at once. The filter starts settled
    on the first sample it sees (a DC offset of +50 N gives no start-up
    transient); `reset` forgets the state (after a gap).

    An IIR cascade runs compiled too (`kernels.detector.sos_run`): scipy's
    `sosfilt` sample loop, operation for operation, so the bits are sosfilt's,
    without the argument checks it spends more on than on the arithmetic of
    the 1-3 samples a CAN frame brings.
    """

    def __init__(self, sos: np.ndarray, *, fir_taps: np.ndarray | None = None):
        self.sos = np.ascontiguousarray(np.atleast_2d(np.asarray(sos, dtype=np.float64)))
        if self.sos.ndim != 2 or self.sos.shape[1] != 6 or not len(self.sos):
            raise ValueError(f"sos must have shape (sections, 6), got {self.sos.shape}")
        if not (self.sos[:, 3] == 1.0).all():
            raise ValueError(f"sos sections must be normalised (a0 = 1), got a0 {self.sos[:, 3]}")
        self._fir = fir_taps
        if fir_taps is None:
            self._zi_unit = signal.sosfilt_zi(self.sos)
        else:  # a = [1, 0]: lfilter's sample loop (a = [1] would convolve, chunk-dependent)
            self._zi_unit = signal.lfilter_zi(fir_taps, np.array([1.0, 0.0]))
        self._zi: np.ndarray | None = None

    @classmethod
    def fir(cls, taps: np.ndarray) -> SosFilter:
        """An FIR filter: y[n] = sum taps[k] x[n - k]."""
        taps = np.asarray(taps, dtype=np.float64)
        if taps.ndim != 1 or not len(taps):
            raise ValueError("FIR taps must be a non-empty 1-D array")
        if len(taps) == 1:
            return cls(np.array([[taps[0], 0.0, 0.0, 1.0, 0.0, 0.0]]))
        sos = signal.tf2sos(taps, np.concatenate([[1.0], np.zeros(len(taps) - 1)]))
        return cls(sos, fir_taps=np.ascontiguousarray(taps))

    @property
    def is_fir(self) -> bool:
        """Runs as one FIR (`fir` with two taps or more): `fir_state` applies."""
        return self._fir is not None

    def fir_state(self, first: float) -> tuple[np.ndarray, np.ndarray]:
        """An FIR filter's taps and carried state, settled on `first` if not yet: for a
        kernel that runs the filter in place (`kernels.detector.fir_run`, as `__call__`
        does) within a larger step - one crossing into compiled code, not one per filter."""
        if self._fir is None:
            raise ValueError("fir_state: not an FIR filter of two taps or more")
        if self._zi is None:
            self._zi = self._zi_unit * first
        return self._fir, self._zi

    @property
    def sections(self) -> int:
        return len(self.sos)

    def reset(self) -> None:
        """Forget the state; the next sample settles the filter again (after a gap)."""
        self._zi = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if not len(x):
            return np.zeros(0)
        if self._zi is None:
            self._zi = self._zi_unit * x[0]
        if self._fir is not None:
            y = np.empty(len(x))
            fir_run(self._fir, self._zi, x, y)  # lfilter's sample loop, state in place
            return y
        y = np.empty(len(x))
        sos_run(self.sos, self._zi, x, y)  # sosfilt's sample loop, state in place
        return y


@dataclass(frozen=True, slots=True)
class Peak:
    t_s: float  # interpolated time of the maximum
    height: float  # interpolated height (band-passed units)
    index: int  # sample index since the last reset
    t_confirm: float  # time of the sample that confirmed it (the drop below the peak)


class PeakDetector:
    """Streaming peak detector with hysteresis and parabolic refinement.

    A peak is a maximum that protrudes by at least `threshold` above the
    lowest value since the previous peak AND is followed by a drop of at
    least `threshold` below it (the thesis' "protrudes beyond its immediate
    surroundings by some predetermined threshold"; Billauer's peakdet). It
    is reported as soon as the drop happens, so the delay is set by the
    signal, not by a window. The time comes from a parabola through the
    samples either side of the maximum (sub-sample); the first sample of a
    plateau wins. State (mode, running extremum, neighbours) is carried, so
    a peak straddling chunk boundaries is found once, identically. The
    threshold may change between calls; a call applies one threshold.
    """

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        self._seeking_max = False  # first a rise of `threshold` above a minimum
        self._min = math.inf
        self._max = -math.inf
        self._max_t = self._before_t = self._after_t = math.nan
        self._before = self._after = math.nan  # samples either side of the running max
        self._after_pending = False
        self._prev_t = math.nan
        self._prev = math.nan
        self._index = 0  # samples since reset
        self._max_index = 0

    def __call__(self, t: np.ndarray, y: np.ndarray, threshold: float) -> list[Peak]:
        peaks: list[Peak] = []
        seeking_max, lo, hi = self._seeking_max, self._min, self._max
        prev_t, prev = self._prev_t, self._prev
        index = self._index
        for tk, yk in zip(t.tolist(), y.tolist(), strict=True):
            if self._after_pending:
                self._after, self._after_t = yk, tk
                self._after_pending = False
            if seeking_max:
                if yk > hi:
                    hi = yk
                    self._max_t, self._max_index = tk, index
                    self._before, self._before_t = prev, prev_t
                    self._after_pending = True
                elif yk <= hi - threshold:
                    peaks.append(self._refined(hi, tk))
                    seeking_max, lo = False, yk
            elif yk < lo:
                lo = yk
            elif yk >= lo + threshold:
                seeking_max, hi = True, yk
                self._max_t, self._max_index = tk, index
                self._before, self._before_t = prev, prev_t
                self._after_pending = True
            prev_t, prev = tk, yk
            index += 1
        self._seeking_max, self._min, self._max = seeking_max, lo, hi
        self._prev_t, self._prev, self._index = prev_t, prev, index
        return peaks

    def _refined(self, top: float, t_confirm: float) -> Peak:
        y0, y2 = self._before, self._after
        t1 = self._max_t
        if not (math.isfinite(y0) and math.isfinite(y2)):
            return Peak(t1, top, self._max_index, t_confirm)
        denom = y0 - 2.0 * top + y2
        delta = 0.0 if denom >= 0 else 0.5 * (y0 - y2) / denom
        delta = min(0.5, max(-0.5, delta))
        step = (self._after_t - t1) if delta >= 0 else (t1 - self._before_t)
        return Peak(t1 + delta * step, top - 0.25 * (y0 - y2) * delta, self._max_index, t_confirm)


class NoiseEstimator:
    """Robust noise sigma from the median absolute deviation, per aligned block.

    Each complete block of `block` samples gives sigma_b = 1.4826 MAD of the
    block (`differences=False`: of the values, for a band-passed signal whose
    pulses are sparse; `running_centre=True`: about the median of the last
    `history` block medians rather than the block's own, so slow noise (drift
    the band lets through) counts while a steady offset (a ramp through a
    high-pass) does not) or of its first differences divided by
    sqrt(2) (`differences=True`: white noise only, immune to DC, drift and
    slow pulses); the estimate is the median of the last `history` blocks.
    MADs are `lattice_median`s (ADC steps do not pin them). A block whose
    raw samples (`raw`, else the values themselves) sit on a rail
    (`on_rail`) shows no noise and is left out; so is a block the caller
    calls `busy` (signal in it, not only noise: censored as in a CFAR
    detector) - unless `busy_limit` busy blocks come in a row: then the
    change has lasted longer than any slip and is the noise now. Until a
    block counts, `sigma` is None.
    Block boundaries count from the last reset, so the estimate does not
    depend on chunking.
    """

    def __init__(
        self,
        block: int = 200,
        history: int = 8,
        *,
        differences: bool = True,
        running_centre: bool = False,
        busy_limit: int | None = None,
    ):
        self.block = max(8, int(block))
        self.busy_limit = busy_limit
        self.differences = differences
        self.running_centre = running_centre
        self._centres: list[float] = []  # recent block medians (running_centre)
        self.history = max(1, int(history))
        self._blocks: list[float] = []
        self._busy_blocks: list[float] = []  # the last busy blocks of a run (left out so far)
        self._busy_run = 0  # busy blocks in a row
        self.reset()

    def reset(self, keep_history: bool = True) -> None:
        self._pending = np.zeros(0)  # samples of the block being filled
        self._pending_raw = np.zeros(0)
        self._pending_busy = False
        self._pending_settling = False
        if not keep_history:
            self._blocks = []
            self._busy_blocks = []
            self._busy_run = 0

    @property
    def room(self) -> int:
        """Samples still needed to complete the current block."""
        return self.block - len(self._pending)

    @property
    def sigma(self) -> float | None:
        if not self._blocks:
            return None
        return float(np.median(self._blocks))

    @property
    def centre(self) -> float:
        """What the spread is measured about (`running_centre`; else 0)."""
        return float(np.median(self._centres)) if self._centres else 0.0

    def __call__(
        self,
        x: np.ndarray,
        raw: np.ndarray | None = None,
        busy: bool = False,
        settling: bool = False,
    ) -> None:
        """Take samples; `busy`: the caller saw signal in them; `settling`: a filter's
        start-up transient is in them (not noise: the block is left out)."""
        pending = np.concatenate([self._pending, x])
        pending_raw = np.concatenate([self._pending_raw, x if raw is None else raw])
        self._pending_busy |= bool(busy)
        self._pending_settling |= bool(settling)
        full = len(pending) // self.block
        for b in range(full):
            chunk = pending[b * self.block : (b + 1) * self.block]
            busy_block, self._pending_busy = self._pending_busy, False
            settling_block, self._pending_settling = self._pending_settling, False
            if settling_block or on_rail(pending_raw[b * self.block : (b + 1) * self.block]):
                continue
            if self.differences:
                sigma = mad_sigma(np.diff(chunk)) / math.sqrt(2.0)
            elif self.running_centre:
                self._centres = [*self._centres, float(np.median(chunk))][-self.history :]
                centre = float(np.median(self._centres))
                sigma = MAD_TO_SIGMA * lattice_median(np.abs(chunk - centre), floor=0.0)
            else:
                sigma = mad_sigma(chunk)
            if busy_block:
                self._busy_run += 1
                self._busy_blocks = [*self._busy_blocks, sigma][-self.history :]
                if self.busy_limit is None or self._busy_run < self.busy_limit:
                    continue
                self._blocks = list(self._busy_blocks)  # it has lasted: the new noise
            else:
                self._busy_run = 0
                self._busy_blocks = []
                self._blocks.append(sigma)
            del self._blocks[: -self.history]
        self._pending = pending[full * self.block :].copy()
        self._pending_raw = pending_raw[full * self.block :].copy()


def mad_sigma(x: np.ndarray) -> float:
    """Robust sigma of a sample: 1.4826 x the median |x - median(x)| (`lattice_median`)."""
    x = np.asarray(x, dtype=np.float64)
    if not len(x):
        return 0.0
    return MAD_TO_SIGMA * lattice_median(np.abs(x - np.median(x)), floor=0.0)


def lattice_median(values: np.ndarray, floor: float | None = None) -> float:
    """The median, kept continuous where the values sit on a lattice (quantised input).

    An ADC's samples, and any fixed combination of a few of them (first
    differences, a short slope kernel), take values on a lattice. Their
    plain median jumps from one lattice point to the next: with white noise
    of about one ADC step, the median |difference| sits on half a step or
    one step, so a noise estimate from it is ~30 % low or high, and on a
    nearly flat stretch it is 0. Here the values tied with the median are
    taken as spread evenly over their lattice cell (as wide as the gap to
    the nearest other value; not below `floor`, e.g. 0 for absolute
    values) and the median is interpolated within it - the median of
    grouped data. Continuous data (no ties) gives the plain median.
    """
    v = np.sort(np.asarray(values, dtype=np.float64).ravel())
    n = len(v)
    if not n:
        return 0.0
    if v[-1] != v[-1]:  # NaN (sorted last): np.median's rules
        m = float(np.median(v))
    else:  # np.median's number off the sorted values (it partitions again): the mean
        # (np.add.reduce, over the count) of the middle one or two
        middle = v[(n - 1) // 2 : n // 2 + 1]
        m = float(np.add.reduce(middle) / len(middle))
    tol = 1e-9 * max(abs(float(v[0])), abs(float(v[-1])))
    lo = int(v.searchsorted(m - tol, side="left"))
    hi = int(v.searchsorted(m + tol, side="right"))
    ties = hi - lo
    gaps = ([m - float(v[lo - 1])] if lo > 0 else []) + ([float(v[hi]) - m] if hi < n else [])
    if ties <= 1 or not gaps:  # continuous data, or every value the same (no spread to see)
        return m
    width = min(gaps)
    cell_lo, cell_hi = m - 0.5 * width, m + 0.5 * width
    if floor is not None:
        cell_lo = max(cell_lo, floor)
    return cell_lo + (0.5 * n - lo) / ties * (cell_hi - cell_lo)


RAIL_SHARE = 0.2  # share of a block's samples at one extreme value that makes it a rail


def on_rail(x: np.ndarray) -> bool:
    """Whether a block of samples sits on a range limit (sensor saturation, ADC rail at 0).

    A rail shows as a pile-up: at least `RAIL_SHARE` of the samples exactly
    at the block's minimum (or maximum), and at least twice as many as at
    any other single value. Noise there is cut off, so the block's spread
    says nothing about the noise: a noise estimate from it would be near 0
    and make every poke above the rail look significant. Free noise, even
    quantised, thins out towards its extremes instead; a ramp across ADC
    steps fills them about evenly.
    """
    x = np.asarray(x, dtype=np.float64)
    if len(x) < 2:
        return False
    v = np.sort(x.ravel())
    if v[-1] != v[-1]:  # NaN: np.unique's rules (NaNs count as one value)
        counts = np.unique(x, return_counts=True)[1]
    else:  # np.unique's counts without its wrappers: the runs of the sorted values
        bounds = np.empty(len(v) + 1, np.int64)
        change = (v[1:] != v[:-1]).nonzero()[0]
        bounds[0], bounds[1 : len(change) + 1], bounds[len(change) + 1] = 0, change + 1, len(v)
        counts = np.diff(bounds[: len(change) + 2])
    if len(counts) == 1:
        return True  # constant: nothing of the noise shows
    need = max(RAIL_SHARE * len(x), 2.0)
    for end, others in ((0, counts[1:]), (len(counts) - 1, counts[:-1])):
        if counts[end] >= need and counts[end] >= 2 * others.max():
            return True
    return False


def resolution(x: np.ndarray) -> float:
    """The smallest non-zero step between consecutive samples: the ADC step on quantised
    input (about 0 on continuous input). Its uniform rounding error, step / sqrt(12) per
    sample, is noise no detector can see below."""
    d = np.abs(np.diff(np.asarray(x, dtype=np.float64)))
    d = d[d > 1e-12 * max(1.0, float(np.max(np.abs(x))))] if len(d) else d
    return float(d.min()) if len(d) else 0.0


def peak_threshold(
    sigma: float, step_sigma: float, fs_hz: float, false_peaks_per_s: float
) -> float:
    """The hysteresis that zero-mean Gaussian noise tops `false_peaks_per_s` times a second.

    `sigma` is the noise's standard deviation, `step_sigma` that of its
    sample-to-sample steps. Rice's formula: a stationary Gaussian sequence
    crosses the level u upwards nu0 exp(-u^2 / (2 sigma^2)) times a second,
    nu0 = fs arccos(rho) / (2 pi) its zero up-crossings, rho = 1 - step^2 /
    (2 sigma^2) its lag-one correlation. A noise peak that rises h above a
    trough and falls h again spans h, so it takes the noise above +h/2 or
    below -h/2: at most 2 nu(h/2) such peaks a second. Hence
    h = 2 sigma sqrt(2 ln(2 nu0 / rate)), a bound: white noise through the
    0.5-30 Hz band-pass tops it 3-4 times less often than asked.
    """
    if not sigma > 0:
        return 0.0
    rho = min(1.0, max(-1.0, 1.0 - step_sigma**2 / (2.0 * sigma**2)))
    nu0 = fs_hz * math.acos(rho) / (2.0 * math.pi)
    return 2.0 * sigma * math.sqrt(2.0 * math.log(max(2.0 * nu0 / false_peaks_per_s, math.e)))


@dataclass
class Segment:
    """Samples between two gaps (or chunk/update boundaries), after the front end."""

    t: np.ndarray
    x: np.ndarray  # raw force, N
    y: np.ndarray  # band-passed force, N
    force_n: np.ndarray  # static grip force (low-passed), N
    peaks: list[Peak]
    after_gap: bool  # the front end restarted at t[0] (first samples or after a gap)


class PulseFrontEnd:
    """Band-pass, static force, noise estimate and peaks for the pulse decoders.

    Parameters: `band_hz` (low, high) of the Butterworth band-pass (order
    `order` per edge, i.e. the thesis' 2nd-order design gives 4 poles),
    `static_corner_hz` for the grip force (base.StaticForce), and the peak
    (hysteresis) threshold: max(`threshold_n`, the height that the measured
    band-passed noise reaches `false_peaks_per_min` times a minute) - see
    `peak_threshold`. The noise is measured on the band-passed signal
    itself (about its running centre: white noise and the drift the band lets
    through alike)
    and on its sample-to-sample steps (how fast it wiggles), per block of
    `noise_block_s`, the median over `noise_history` blocks, leaving out
    blocks where the sensor sits on a rail and blocks where the signal
    reached the threshold (ridge pulses; see `NoiseEstimator`) unless that
    lasts `lasting_s`, longer than a slip across the skin, and blocks in the
    band-pass's start-up transient (3 time constants of its high-pass edge
    after a start or a gap: a trend at the start rings through it). Until
    the band-passed noise is known, the threshold comes from the
    sample-to-sample steps alone (white noise, as the band-pass shapes it);
    before any block, no peak is reported: a threshold without a noise
    measurement would be a guess.

    Gaps (a step longer than `gap_periods` sample periods, by default
    base.GAP_PERIODS like every decoder's input guard) restart the
    filters settled on the first sample after the gap and clear the peak
    detector's tail; the noise estimate keeps its history. Work is split at
    gaps and at noise-estimate block boundaries so the threshold in force
    for every sample does not depend on how the input was chunked.
    """

    def __init__(
        self,
        fs_hz: float,
        *,
        band_hz: tuple[float, float] = (0.5, 30.0),
        order: int = 1,
        threshold_n: float = 0.05,
        false_peaks_per_min: float = 1.0,
        static_corner_hz: float = 2.0,
        noise_block_s: float = 0.25,
        noise_history: int = 16,
        lasting_s: float = 30.0,
        gap_periods: float | None = None,
    ):
        from grasplink.decoding.base import GAP_PERIODS, StaticForce

        self.fs_hz = float(fs_hz)
        self._static_factory = lambda: StaticForce(self.fs_hz, static_corner_hz)
        self.sos = bandpass_sos(band_hz[0], band_hz[1], self.fs_hz, order)
        self.bandpass = SosFilter(self.sos)
        self.static = self._static_factory()
        self.peaks = PeakDetector()
        if not (math.isfinite(false_peaks_per_min) and false_peaks_per_min > 0):
            raise ConfigError(
                f"false_peaks_per_min must be a positive number, got {false_peaks_per_min}"
            )
        block = max(8, round(noise_block_s * self.fs_hz))
        limit = max(noise_history, round(lasting_s * self.fs_hz / block))
        self.noise = NoiseEstimator(
            block, noise_history, differences=False, running_centre=True, busy_limit=limit
        )
        self.steps = NoiseEstimator(block, noise_history, differences=True, busy_limit=limit)
        impulse = signal.sosfilt(self.sos, np.eye(1, 1 << 14).ravel())
        self._white_rho = float(impulse[1:] @ impulse[:-1] / (impulse @ impulse))
        slowest = float(np.max(np.abs(signal.sos2zpk(self.sos)[1])))  # pole nearest z = 1
        self._settle = round(3.0 / max(-math.log(slowest), 1e-9))  # 3 time constants, samples
        self._settled_in = self._settle
        self.threshold_n = float(threshold_n)
        self.false_peaks_per_s = float(false_peaks_per_min) / 60.0
        self.gap_s = (GAP_PERIODS if gap_periods is None else gap_periods) / self.fs_hz
        self._last_t: float | None = None
        self.gaps = 0

    @property
    def threshold(self) -> float:
        sigma, step = self.noise.sigma, self.steps.sigma
        if step is None:
            return math.inf  # the noise is not known yet
        step *= math.sqrt(2.0)
        if sigma is None:  # white noise through the band-pass: its steps tell its spread
            sigma = step / math.sqrt(2.0 * (1.0 - self._white_rho))
        return max(
            self.threshold_n, peak_threshold(sigma, step, self.fs_hz, self.false_peaks_per_s)
        )

    def restart(self) -> None:
        self.bandpass.reset()
        self.static = self._static_factory()
        self.peaks.reset()
        self.noise.reset(keep_history=True)
        self.steps.reset(keep_history=True)
        self._settled_in = self._settle

    def __call__(self, t: np.ndarray, x: np.ndarray) -> list[Segment]:
        """Run samples (finite, increasing) through; one Segment per piece between gaps."""
        if not len(t):
            return []
        previous = -np.inf if self._last_t is None else self._last_t
        steps = np.diff(np.concatenate([[previous], t]))
        cuts = np.nonzero(steps > self.gap_s)[0].tolist()  # includes 0 at the very start
        bounds = [*cuts, len(t)] if cuts and cuts[0] == 0 else [0, *cuts, len(t)]
        segments: list[Segment] = []
        for a, b in itertools.pairwise(bounds):
            if a == b:
                continue
            after_gap = a in cuts
            if after_gap:
                if self._last_t is not None:
                    self.gaps += 1
                self.restart()
            segments.append(self._run(t[a:b], x[a:b], after_gap))
        self._last_t = float(t[-1])
        return segments

    def _run(self, t: np.ndarray, x: np.ndarray, after_gap: bool) -> Segment:
        y = self.bandpass(x)
        force = self.static.filter(x)
        peaks: list[Peak] = []
        start = 0
        while start < len(t):
            stop = min(len(t), start + self.noise.room)
            threshold = self.threshold
            peaks += self.peaks(t[start:stop], y[start:stop], threshold)
            # a block where the band-passed signal reached the threshold holds signal:
            # the noise is measured around it, not on it
            busy = bool(np.max(np.abs(y[start:stop] - self.noise.centre)) >= threshold)
            settling = self._settled_in > 0
            self._settled_in = max(0, self._settled_in - (stop - start))
            self.noise(y[start:stop], x[start:stop], busy, settling)
            self.steps(y[start:stop], x[start:stop], busy)
            start = stop
        return Segment(t, x, y, force, peaks, after_gap)


class PeakLag:
    """Where the band-passed peak of a ridge pulse lies, in mm past the ridge.

    The pulse model of thesis ch. 5.3.1 peaks when the edge is half a ridge
    side past the ridge (rise time L / (2 v)); the band-pass shifts the peak
    by a speed-dependent amount. This table is computed once from the
    decoder's own filter on model pulses, so position estimates do not
    carry the filter's delay whatever the band or sample rate.
    """

    def __init__(
        self,
        sos: np.ndarray,
        fs_hz: float,
        ridge_side_mm: float = 2.5,
        speeds_mm_s: np.ndarray | None = None,
    ):
        speeds = np.geomspace(1.0, 1000.0, 31) if speeds_mm_s is None else speeds_mm_s
        lags = []
        for v in speeds:
            rise = min(max(ridge_side_mm / (2.0 * v), 0.002), 0.2)
            n = int(fs_hz * (8 * rise + 0.5)) + 8
            tau = np.arange(n) / fs_hz
            u = tau / rise
            y = signal.sosfilt(sos, u * np.exp(1.0 - u))
            k = int(np.argmax(y))
            if 0 < k < n - 1:
                denom = y[k - 1] - 2 * y[k] + y[k + 1]
                delta = 0.5 * (y[k - 1] - y[k + 1]) / denom if denom < 0 else 0.0
            else:
                delta = 0.0
            lags.append(v * (k + delta) / fs_hz)
        self._log_v = np.log(speeds)
        self._lag = np.asarray(lags)

    def __call__(self, speed_mm_s: float) -> float:
        return float(np.interp(math.log(max(abs(speed_mm_s), 1e-6)), self._log_v, self._lag))


def pulse_events(segments: list[Segment]) -> list[tuple[float, Peak | None]]:
    """Front-end output as time-ordered events: (time, None) = restart, (time, peak).

    A peak's event time is its confirmation (the sample where the signal
    dropped below it), so an update at time g sees exactly the peaks the
    samples up to g revealed, however the input was chunked.
    """
    events: list[tuple[float, Peak | None]] = []
    for seg in segments:
        if seg.after_gap:
            events.append((float(seg.t[0]), None))
        events += [(p.t_confirm, p) for p in seg.peaks]
    return events


class PeakActivity:
    """Slip flag from ridge pulses, with hysteresis.

    On at a second peak within `pair_s` of the previous one; off when no peak
    came for the hold time: `hold_factor` x the time the widest spacing takes
    at the decoded speed when a decoder supplies one, else `hold_factor` x the
    last interval x (widest / narrowest spacing) - a skin with one 33 mm gap
    among 3 mm ones must not drop the flag in the gap - within
    [`min_hold_s`, `max_hold_s`].
    """

    def __init__(
        self,
        spacings_mm: np.ndarray,
        *,
        pair_s: float = 1.5,
        hold_factor: float = 1.5,
        min_hold_s: float = 0.2,
        max_hold_s: float = 3.0,
    ):
        self.widest = float(np.max(spacings_mm))
        self.spread = float(np.max(spacings_mm) / np.min(spacings_mm))
        self.pair_s, self.hold_factor = float(pair_s), float(hold_factor)
        self.min_hold_s, self.max_hold_s = float(min_hold_s), float(max_hold_s)
        self.reset()

    def reset(self) -> None:
        self.last_peak: float | None = None
        self.interval: float | None = None
        self.on = False
        self.episode_start: float | None = None  # first peak of the current slip

    def peak(self, t: float) -> None:
        if self.last_peak is not None and not self.on and t - self.last_peak <= self.pair_s:
            self.on = True
            self.episode_start = self.last_peak
        if self.last_peak is not None:
            self.interval = t - self.last_peak
        self.last_peak = t

    def active(self, g: float, speed_mm_s: float | None = None) -> bool:
        if not self.on or self.last_peak is None:
            return False
        if speed_mm_s:
            expected = self.widest / abs(speed_mm_s)
        else:
            expected = (self.interval or self.pair_s) * self.spread
        hold = min(self.max_hold_s, max(self.min_hold_s, self.hold_factor * expected))
        if g - self.last_peak > hold:
            self.on = False
            self.episode_start = None
        return self.on


def interleave(
    events: list[tuple[float, Peak | None]],
    points: list[tuple[int, float]],
    apply: Callable[[tuple[float, Peak | None]], None],
) -> Iterator[tuple[int, float]]:
    """Apply events in time order, pausing at each update point: yields (count, t_update).

    Events at or before an update reach the decoder before it is asked for that
    estimate; the rest are applied when the generator is exhausted (consume it fully).
    """
    e = 0
    for count, g in points:
        while e < len(events) and events[e][0] <= g + 1e-12:
            apply(events[e])
            e += 1
        yield count, g
    for event in events[e:]:
        apply(event)

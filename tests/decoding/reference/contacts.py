"""REFERENCE (tests only): the numpy contact detector as it was at 0858d90, before its
per-block numeric path was compiled (`kernels.detector`), with later behaviour changes
ported (35f4b94: a chunk longer than a block is fed a block at a time; a80cd9a: the first
verdicts on a slip's rising level; issue 22: a block a ridge contact touched tells no
coloured noise, `_mark_busy`; issue 22: a kink with no rise after it on a pulse's falling
tail, `tail_kinks`, its pure test shared, timed back as `tail_onsets` times it; issue 22:
the coarse scales' noise at `weak_slip_share` while weak pulses are told, `_noise`). The compiled
detector is checked against it in the same process (tests/decoding/test_detector_kernels.py).

Streaming ridge-contact detector: finds the ONSET of every ridge pulse in the FSR signal.

Physics (thesis ch. 5.3.1, 5.4): when the object's leading edge reaches a
ridge the FSR force starts to rise fast (over the time the edge needs to
push the ridge over, ~1.25 mm of travel) and then relaxes. Whatever the exact
pulse shape, its onset is a *kink*: the slope of the force jumps up. The
kink is also what survives when pulses merge at high speed (a new pulse
starting on the decay of the previous one) and it is blind to the slow
trends of the signal (drift, the object covering more of the sensor).

Detector (all filters are FIR, run as `filters.SosFilter` - sample by sample
with carried state, so chunking cannot change a single bit):

* a bank of *hinge* filters, one per scale w (5, 10, 20, 40, 80 ms by
  default): h_w(n) = slope of x over [n, n + w] minus slope over [n - w, n]
  (least-squares slopes), i.e. the slope jump at n. A pure kink gives the
  same h at every scale while noise falls as w^-1.5, so the best scale is
  about half the rise: fast pulses show on the short scales, slow pulses
  (weak slope, long rise) on the long ones;
* each scale is normalised by its noise (per fixed block of 0.125 s: the
  finest scale's white noise times the scale's gain, or - if larger, for
  coloured noise - the scale's own median |h| over the last 10 s, with a
  floor and a margin while few blocks are known), so thresholds are in noise
  units and pulse amplitudes do not matter. What the node sends is
  quantised (12-bit ADC, ~0.024 N) and clipped at 0 N while nothing presses
  the sensor, and a plain median of such values sticks to a lattice point
  or to 0 - thresholds then fall to a fraction of the noise and noise
  becomes contacts (issue 11: the wrong slip direction through CAN,
  ~400 mm/s on the headline scene). So the medians are lattice medians
  (`filters.lattice_median`), the white noise is never taken below the
  ADC step's rounding noise (step / sqrt(12)), and blocks where the signal
  sits on a rail (`filters.on_rail`) do not count: they show no noise.
  Blocks with no such estimate before them wait for the first block that
  has one (bounded: after `noise_blocks` blocks they are dropped);
* a contact candidate is a local maximum of z_w = h_w / noise_w over +-w
  above `threshold`, after which the force rises (the end of a grip release
  is a kink too, but flat after); its time is refined coarse to fine (the
  finest scale that still sees it places it) and to a fraction of a sample
  by a parabola; a candidate within its own reach of an earlier contact is
  that contact again (long scales decide later);
* every contact is then watched: a *pulse* rises and falls back (by
  `drop_fraction` of its height, rising trend removed) within a few rise
  times; a grip step rises and stays level. The verdict (True, False, or
  None when the force kept rising) is reported later as a `PulseCheck`.

Events carry `emit_index`, the index of the sample whose arrival decided
them, so a caller can replay them exactly in step with its own updates.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cache
from typing import Any, NamedTuple

import numpy as np

from grasplink.decoding.contacts import sharp_flat_step
from grasplink.decoding.detector.arrival_tail import on_first_load
from grasplink.decoding.detector.tail_kinks import TailKinkSettings, tail_kink
from grasplink.decoding.detector.tail_onsets import tail_placed
from grasplink.decoding.filters import RAIL_SHARE, lattice_median, on_rail, resolution
from grasplink.decoding.kernels.layout import ROW_AFTER, ROW_HINGE, ROW_READY, ROW_Z
from tests.decoding.reference.filters import SosFilter

DEFAULT_SCALES_S = (0.005, 0.01, 0.02, 0.04, 0.08)
BUSY_MAX_S = 0.06  # ... in the hinge scales under this (s); wider ones count every block
BUSY_SNR = 3.0  # a pulse this many white-noise units high marks its blocks busy (`_noise`)
CLEAR_SNR = 10.0  # ... in the widest scale only while under this (a clear pulse's bends)
TAILS = TailKinkSettings()  # the kink bank's tail kinks (issue 22), as shipped
NOISE_FLOOR_N = 1e-3  # smallest white-noise level assumed, N per sample (an ideal, quiet FSR)
MEDIAN_TO_STD = 1.0 / 0.6745
STARTUP_MARGIN = 0.3  # noise inflation while the estimate rests on a single block
STEP_IDS = 1_000_000_000  # ids of the small steps found by the step probe (their own series)


class ContactEvent(NamedTuple):
    """A detected ridge contact (pulse onset)."""

    id: int
    t_s: float  # onset time, sub-sample
    index: int  # type: ignore[assignment]  # (shadows tuple.index) the sample nearest the onset
    emit_index: int  # global index of the sample that decided it
    z: float  # strength: slope jump in noise units
    jump_n_s: float  # slope jump, N/s
    scale_s: float  # the scale that found it
    sigma_s: float  # timing uncertainty (one sigma)


class PulseCheck(NamedTuple):
    """Later verdict on a contact: did the force fall back like a pulse?"""

    id: int
    emit_index: int
    pulse: bool | None  # True: rose and fell back; False: rose and stayed (a step); None: unclear
    # a step: the level's rising trend (the object covering more of the sensor) went on
    # after it (True: the object still moves), stopped (False), or no trend to tell (None)
    trend_on: bool | None = None
    sure: bool = False  # a step told at the sure hold (`sharp_flat_step`)


class _Series:
    """An array appended to in place and cut from the front by moving what is kept down.

    The detector extends a dozen arrays by a few samples every block; a
    concatenate copies the whole array each time, a slice write copies only
    the new samples. `view` is what is held (valid until the next append or
    cut); rows (`rows` > 0) share one index along the last axis. The storage
    grows (doubling) only when an append would not fit, and a cut keeps it:
    bounded by the longest stretch held.
    """

    __slots__ = ("data", "size")

    def __init__(self, capacity: int = 64, rows: int = 0):
        shape = (rows, max(1, capacity)) if rows else (max(1, capacity),)
        self.data: np.ndarray = np.empty(shape)
        self.size = 0

    def extend(self, count: int) -> np.ndarray:
        """`count` more entries (the caller fills them): their view."""
        start, end = self.size, self.size + count
        if end > self.data.shape[-1]:
            data = np.empty((*self.data.shape[:-1], max(end, 2 * self.data.shape[-1])))
            data[..., :start] = self.data[..., :start]
            self.data = data
        self.size = end
        return self.data[..., start:end]

    def append(self, values: np.ndarray) -> np.ndarray:
        """Write `values` after what is held; the new view of all."""
        self.extend(len(values))[...] = values
        return self.data[..., : self.size]

    def keep_last(self, keep: int) -> np.ndarray:
        """Drop all but the last `keep` entries; the new view of all."""
        self.data[..., :keep] = self.data[..., self.size - keep : self.size]
        self.size = keep
        return self.data[..., :keep]

    def view(self) -> np.ndarray:
        return self.data[..., : self.size]


@dataclass
class _Channel:
    width: int  # w, samples
    slope: SosFilter  # LS slope over the last w + 1 samples (FIR)
    after: np.ndarray = field(default_factory=lambda: np.zeros(0))  # slopes not yet paired
    next_n: int = 0  # next hinge centre to compute
    waiting: list = field(default_factory=list)  # (block, hinge, after) awaiting a noise
    noise_by_block: dict = field(default_factory=dict)
    # rows z, hinge (N/sample), slope after, sample that told the noise (known at), by centre
    # from z_start; z, zh, za, zready are views of their whole storage (refreshed when it
    # grows): the first rows.size entries are held
    rows: _Series = field(default_factory=lambda: _Series(256, rows=4))
    z: np.ndarray = field(default_factory=lambda: np.zeros(0))
    zh: np.ndarray = field(default_factory=lambda: np.zeros(0))
    za: np.ndarray = field(default_factory=lambda: np.zeros(0))
    zready: np.ndarray = field(default_factory=lambda: np.zeros(0))
    z_start: int = 0  # global centre index of z[0]
    next_test: int = 0  # next centre to test for a local maximum
    block_abs: np.ndarray = field(default_factory=lambda: np.zeros(0))  # |h| of the block ...
    abs_n: int = 0  # ... being filled, so far
    block_noise: dict = field(default_factory=dict)  # completed block -> robust noise
    done: int = 0  # blocks completed

    def refresh_views(self) -> None:
        """z, zh, za, zready as views of the rows' storage, after an append that grew it
        (or the first one); an append that fits keeps them."""
        data = self.rows.data  # (its rows: `kernels.layout.CHANNEL_ROWS`)
        if self.z.base is not data:
            self.z, self.zh, self.za = data[ROW_Z], data[ROW_HINGE], data[ROW_AFTER]
            self.zready = data[ROW_READY]


@dataclass
class _Watch:
    id: int
    index: int  # onset sample
    base: float  # level before the onset
    trend: float  # rising trend before the onset (N/sample, >= 0)
    noise: float  # level noise (N)
    fall: float = 0.0  # falling slope just before the onset (N/sample, >= 0): a pulse's tail
    peak: float = -math.inf
    early: float = -math.inf  # highest level in the first quarter of the watch
    history: np.ndarray = field(default_factory=lambda: np.zeros(0))  # running peak by sample
    levels: np.ndarray = field(default_factory=lambda: np.zeros(0))  # raw level (to the hold)
    detrended: np.ndarray = field(default_factory=lambda: np.zeros(0))  # ... trend taken out
    fell: bool = False  # a sharp rise that fell back like a pulse before the hold
    next_k: int = 0  # next level sample to examine
    top: float = 0.0  # told a step: the level it stepped to (trend out), watched for a fall
    fell_at: int = -1  # ... the sample where it fell back by drop_fraction (-1: not yet)
    slope: float = 0.0  # the level's slope before the onset (N/sample, either sign)
    room: float = 0.0  # how far a falling tail under the onset can still fall (N; 0: none)
    plain: np.ndarray = field(default_factory=lambda: np.zeros(0))  # level - base (to the hold)
    rise: int = 0  # a probe: the rise of its scale (samples)
    long: float = 0.0  # the slip's rising trend from the base of an earlier contact (N/sample)


@dataclass
class _StepScale:
    """One scale of the step probe: a difference of means over +-w samples."""

    w: int
    rise: int  # a step's rise is judged over this many samples (`_is_small_step`)
    fir: SosFilter
    d: np.ndarray  # difference of means by centre, from start (a view of `store`)
    start: int  # centre of d[0] (output m is centre m - w)
    next: int = 0  # next centre to test
    store: _Series = field(default_factory=lambda: _Series(256))


def _mean(x: np.ndarray) -> float:
    """np.mean's number (its sum over the count) without its wrappers."""
    return np.add.reduce(x) / len(x)


@cache
def _hinge_gain(width: int) -> float:
    """Noise of a hinge output per unit of white input noise (two LS slopes sharing a sample)."""
    s = width * (width + 1) * (width + 2) / 12.0  # sum of squared centred offsets
    return math.sqrt(2.0 / s + width * width / (2.0 * s * s))


def _slope_taps(width: int) -> np.ndarray:
    """FIR taps whose output at m is the LS slope of x[m - w .. m] (N/sample)."""
    k = np.arange(width + 1, dtype=np.float64) - width / 2.0
    kernel = k / float(np.sum(k * k))  # applied to x[n + 0 .. n + w]
    return kernel[::-1].copy()


class ContactDetector:
    """Finds ridge-contact onsets in a uniformly sampled FSR stream (see module doc)."""

    def __init__(
        self,
        fs_hz: float,
        *,
        scales_s: tuple[float, ...] = DEFAULT_SCALES_S,
        threshold: float = 4.5,
        refine_z: float = 3.0,
        merge_widths: float = 2.0,
        block_s: float = 0.125,
        noise_blocks: int = 8,
        history_s: float = 10.0,
        weak_slip_share: float = 0.9,
        weak_slip_s: float = 1.0,
        rise_fraction: float = 0.1,
        coarse_rise_fraction: float = 0.3,
        drop_fraction: float = 0.3,
        watch_s: float = 1.0,
        level_s: float = 0.01,
        trend_s: float = 0.1,
        decay_rises: float = 5.0,
        step_rise_s: float = 0.02,
        step_hold_s: float = 0.1,
        sure_hold_s: float = 0.05,
        sure_rise_s: float = 0.01,
        sure_snr: float = 20.0,
        sure_drop: float = 0.3,
        step_window_s: float = 0.02,
        long_step_window_s: float = 0.04,
        step_threshold: float = 6.0,
        revise_s: float = 0.35,
        long_trend_s: float = 0.6,
    ):
        self.fs_hz = float(fs_hz)
        widths = sorted({max(1, round(s * self.fs_hz)) for s in scales_s})
        self.noise_blocks = int(noise_blocks)
        self.history_blocks = max(self.noise_blocks, round(history_s / block_s))
        self.weak_slip_share = float(weak_slip_share)
        self.threshold = float(threshold)
        self.refine_z = float(refine_z)
        self.merge_widths = float(merge_widths)
        self.block = max(16, round(block_s * self.fs_hz))
        self.weak_slip_blocks = max(1, round(weak_slip_s * self.fs_hz / self.block))
        self.channels = [
            _Channel(w, SosFilter.fir(_slope_taps(w)), block_abs=np.empty(self.block))
            for w in widths
        ]
        self.rise_fraction = float(rise_fraction)
        self.coarse_rise_fraction = float(coarse_rise_fraction)
        self.drop_fraction = float(drop_fraction)
        self.watch = max(8, round(watch_s * self.fs_hz))
        self.decay_rises = float(decay_rises)
        self.min_rise = max(1, round(0.005 * self.fs_hz))
        # a sharp rise that stays: judged a step early (a stop, a grip change), see _advance
        self.step_rise = max(1, round(step_rise_s * self.fs_hz))
        self.step_hold = max(self.step_rise + 1, round(step_hold_s * self.fs_hz))
        # ... and a sharp, tall step that stays flat (`sharp_flat_step`) sooner still
        self.sure_rise = max(1, round(sure_rise_s * self.fs_hz))
        # only where that rise is resolved (2 samples: 200 Hz and up); at 100 Hz a ridge
        # pulse rises in a sample or two too (2 % of those judged at the hold passed)
        self.sure_hold = min(self.step_hold, round(sure_hold_s * self.fs_hz))
        self.sure_hold = self.sure_hold if self.sure_rise >= 2 else 0
        self.sure_snr = float(sure_snr)
        self.sure_drop = float(sure_drop)
        # small steps the kink bank misses: a difference of means over +-step_w samples
        self.step_w = max(2, round(step_window_s * self.fs_hz))
        self.small_rise = max(1, round(0.6 * step_window_s * self.fs_hz))
        w = self.step_w
        self.step_threshold = float(step_threshold)
        # and over a longer window too: a stop's step in heavy noise (10 dB of the ridge
        # pulses) is a few noise units of the short window's difference, more of the long's
        self._scales = [
            _StepScale(v, max(1, round(0.6 * v)), SosFilter.fir(k), np.zeros(0), -v)
            for v, k in (
                (v, np.concatenate([np.full(v, 1.0 / v), np.full(v, -1.0 / v)]))
                for v in sorted({w, max(w + 1, round(long_step_window_s * self.fs_hz))})
            )
        ]
        self._probes: list[tuple[_Watch, float, int]] = []  # step candidates judged (z, w)
        # probes judged steps: (emit, w, index, t, z, trend_on)
        self._confirmed: list[tuple[int, int, int, float, float, bool | None]] = []
        self._probe_onsets: deque[tuple[int, int, int]] = deque(maxlen=32)  # (index, emit, w)
        self._onsets: deque[tuple[int, int]] = deque(maxlen=32)  # contacts emitted: (index, emit)
        # the level before each contact's onset: (index, emit, level), see _tail_room
        self._bases: deque[tuple[int, int, float]] = deque(maxlen=32)
        self._next_step_id = STEP_IDS
        self.fall_n = max(2, round(0.02 * self.fs_hz))  # an earlier pulse's tail: its slope ...
        self.fall_credit = max(1, round(0.03 * self.fs_hz))  # ... followed this long at most
        half = max(0, round(level_s * self.fs_hz / 2.0))
        self.level_half = half
        self._level_filter = SosFilter.fir(np.full(2 * half + 1, 1.0 / (2 * half + 1)))
        self._n = 0  # samples received
        self._kept_from = -(10**9)  # block caches hold blocks from here on
        self._raw = np.empty(self.block)  # samples of the raw block being filled ...
        self._raw_n = 0  # ... so far
        self._raw_blocks = 0  # raw blocks completed
        self._censored: dict[int, bool] = {}  # block -> sat on a rail (its noise unseen)
        self._busy: dict[int, int] = {}  # block -> earliest emit of a contact touching it
        self._busy_wide: dict[int, int] = {}  # ... of a weak pulse (the widest scale's)
        self._floor: dict[int, float] = {}  # block -> quantisation noise floor (N per sample)
        self._white_by_block: dict[int, tuple[float, int]] = {}  # `_white` of final blocks
        keep = self.block + 4 * max(widths) + 2 * half + round(trend_s * self.fs_hz) + 8
        self._keep = keep
        # blocks of samples sitting on the sensor's upper rail (saturation), as times
        self.blind: deque[tuple[float, float]] = deque(maxlen=64)
        self._tx = _Series(4 * keep, rows=2)  # recent sample times and samples, ...
        self._t, self._x = self._tx.view()  # ... as views (same index)
        self._t_start = 0
        self._levels = _Series(4 * keep)
        self._level = self._levels.view()  # box-smoothed level, by centre index
        self._level_start = 0
        self._next_id = 0
        self._recent: deque[float] = deque(maxlen=16)  # times of the contacts emitted
        self._watches: list[_Watch] = []
        # steps told at the hold, watched on: a ridge pulse on a slow (hysteretic) skin may
        # stay up past the hold and fall back later - then the verdict is revised to a pulse
        self._stepped: list[_Watch] = []
        self.revise = max(self.step_hold + 1, round(revise_s * self.fs_hz))
        self.lag = 2 * max(widths)  # a contact is decided at most this many samples late
        self.trend_n = max(1, round(trend_s * self.fs_hz))
        self.long_trend_n = max(self.trend_n + 1, round(long_trend_s * self.fs_hz))
        self.slip_fall = 6.0  # noise units (`_fell_in_slip`)

    # ------------------------------------------------------------------ feeding
    def feed(self, t: np.ndarray, x: np.ndarray) -> tuple[list[ContactEvent], list[PulseCheck]]:
        """Take accepted samples; return contacts and pulse verdicts decided by them.

        Accepted: finite (`Decoder.process` drops the rest before they get here). The
        detector's buffers are written in place and its maxima assume finite z, so a NaN
        is refused here, by name, rather than spread through the history."""
        if not len(x):
            return [], []
        if not (np.isfinite(x).all() and np.isfinite(t).all()):
            raise ValueError(
                "ContactDetector.feed: samples must be finite (NaN or inf in t or x); "
                "drop them first, as Decoder.process does"
            )
        if len(x) <= self.block:
            return self._feed(t, x)
        # (35f4b94, a behaviour change after the numpy code: longer runs go in pieces that
        # end on block boundaries, so a recording decoded whole is told as it is live)
        events: list[ContactEvent] = []
        checks: list[PulseCheck] = []
        start = 0
        while start < len(x):
            end = min(len(x), start + self.block - (self._n + start) % self.block)
            ev, ck = self._feed(t[start:end], x[start:end])
            events += ev
            checks += ck
            start = end
        return sorted(events, key=lambda e: (e.emit_index, e.id)), checks

    def _feed(self, t: np.ndarray, x: np.ndarray) -> tuple[list[ContactEvent], list[PulseCheck]]:
        n0 = self._n
        self._n += len(x)
        new = self._tx.extend(len(x))
        new[0], new[1] = t, x
        self._t, self._x = self._tx.view()
        self._raw_stats(x)
        candidates: list[tuple[int, int, int, float, float, float]] = []
        for ci, ch in enumerate(self.channels):
            self._run_channel(ci, ch, x, n0, candidates)
        self._run_level(x)
        self._run_steps(x)
        events = self._merge(candidates)
        self._onsets.extend((ev.index, ev.emit_index) for ev in events)
        checks = self._check_pulses(events)
        steps, step_checks = self._step_events()
        self._trim()
        # block noises still needed: the last noise_blocks before the slowest channel's block
        oldest = (
            self.channels[-1].next_n // self.block  # the widest lags most
            - max(self.noise_blocks, self.history_blocks)
            - 2
        )
        if oldest > self._kept_from:  # a block fell out of the history: forget it
            self._kept_from = oldest
            caches: list[dict[int, Any]] = [
                self._censored, self._floor, self._busy, self._busy_wide,
            ]  # fmt: skip
            for cache in caches + [
                c for ch in self.channels for c in (ch.block_noise, ch.noise_by_block)
            ]:
                for b in list(filter(oldest.__gt__, cache)):  # b < oldest, at C speed
                    del cache[b]
            # white noises that read a block just forgotten: read again if asked (as then)
            white = self._white_by_block
            for b in list(filter((oldest + self.noise_blocks).__gt__, white)):
                del white[b]
        events = sorted(events + steps, key=lambda e: (e.emit_index, e.id))
        return events, checks + step_checks

    def _raw_stats(self, x: np.ndarray) -> None:
        """Per block of raw samples: on a rail (noise cut off)? quantisation floor?"""
        B, held = self.block, self._raw_n
        if held + len(x) < B:  # the block not full yet: only keep the samples
            self._raw[held : held + len(x)] = x
            self._raw_n += len(x)
            return
        raw = np.concatenate([self._raw[:held], x])
        full = len(raw) // B
        for k in range(full):
            block = raw[k * B : (k + 1) * B]
            b = self._raw_blocks + k
            self._censored[b] = on_rail(block)
            self._floor[b] = resolution(block) / math.sqrt(12.0)
            top = float(block.max())
            if self._censored[b] and top > 0.0 and np.count_nonzero(block == top) >= 0.5 * B:
                # saturated: no contact can show; times of the block's first and last sample
                i = b * B - self._t_start
                if i >= 0 and i + B <= len(self._t):
                    self.blind.append((float(self._t[i]), float(self._t[i + B - 1])))
        self._raw_blocks += full
        self._raw_n = len(raw) - full * B
        self._raw[: self._raw_n] = raw[full * B :]

    def _run_channel(self, ci: int, ch: _Channel, x: np.ndarray, n0: int, candidates: list) -> None:
        w = ch.width
        y = ch.slope(x)  # settled: as if the first sample had been held before (slopes 0)
        # y[m] is the slope over [m - w, m], i.e. "after" of centre n = m - w; `after`
        # holds the slopes of centres ch.next_n - w, ...; hinge(n) = after(n) - after(n - w).
        after = np.concatenate([ch.after, y]) if len(ch.after) else y
        count = len(after) - w
        if count <= 0:
            ch.after = after
            return
        start = ch.next_n
        ch.next_n += count
        block = start // self.block
        noise = None if ch.waiting else ch.noise_by_block.get(block)
        if noise is not None and (start + count - 1) // self.block == block:
            self._one_block(ch, after, count, noise, start)
        else:
            slope_after = after[w:]
            self._normalise(ch, start, slope_after - after[:count], slope_after)
        ch.after = after[count:]
        self._local_maxima(ci, ch, candidates)

    def _one_block(
        self, ch: _Channel, after: np.ndarray, count: int, noise: float, start: int
    ) -> None:
        """`_normalise` of centres start .. start + count - 1 when they lie in one block
        whose noise is known and none wait (the usual case: a CAN frame's few samples):
        the hinge written straight into the z rows, the same numbers."""
        w = ch.width
        new = ch.rows.extend(count)
        hinge = np.subtract(after[w:], after[:count], new[ROW_HINGE])
        np.divide(hinge, noise, new[ROW_Z])
        new[ROW_AFTER], new[ROW_READY] = after[w:], start + w
        ch.refresh_views()
        np.abs(hinge, out=ch.block_abs[ch.abs_n : ch.abs_n + count])
        ch.abs_n += count
        if (start + count) % self.block == 0:
            self._block_done(ch, start // self.block, start + count)

    def _normalise(
        self, ch: _Channel, start: int, hinge: np.ndarray, slope_after: np.ndarray
    ) -> None:
        """Noise per block of centres; z for every centre whose noise is known.

        Centres of a block use the noise of the blocks before it. Where none
        of those showed its noise (the first block, or a stretch on a rail)
        they wait for the first block that does - decided late, but judged
        against noise that was seen; after `noise_blocks` blocks of waiting
        the oldest are dropped undetected (bounded memory; a signal on a rail
        has no contacts to find).
        """
        B = self.block
        pos = 0
        n = start
        while pos < len(hinge):
            block = n // B
            end = min(len(hinge), pos + (block + 1) * B - n)
            seg_h, seg_a = hinge[pos:end], slope_after[pos:end]
            np.abs(seg_h, out=ch.block_abs[ch.abs_n : ch.abs_n + len(seg_h)])
            ch.abs_n += len(seg_h)
            noise = None if ch.waiting else self._noise(ch, block)
            if noise is None:
                ch.waiting.append((block, seg_h, seg_a))
            else:
                self._append_z(ch, seg_h, seg_a, noise, n + ch.width)
            n += end - pos
            pos = end
            if n % B == 0:
                self._block_done(ch, block, n)

    def _block_done(self, ch: _Channel, block: int, n: int) -> None:
        """Block complete (centres up to n - 1): its noise, and perhaps the waiting blocks'."""
        values = ch.block_abs[: ch.abs_n]
        ch.abs_n = 0
        ch.block_noise[block] = lattice_median(values, floor=0.0) * MEDIAN_TO_STD
        ch.done = block + 1
        self._release(ch, n - 1 + ch.width)

    def _release(self, ch: _Channel, ready: int) -> None:
        """z for the waiting blocks whose noise is now known (sample `ready` told it)."""
        while ch.waiting:
            block = ch.waiting[0][0]
            noise = self._noise(ch, block)
            if noise is None:
                if ch.done - block <= self.noise_blocks:
                    return
                noise = math.inf  # waited too long: nothing detected there
            while ch.waiting and ch.waiting[0][0] == block:
                _, seg_h, seg_a = ch.waiting.pop(0)
                self._append_z(ch, seg_h, seg_a, noise, ready)

    @staticmethod
    def _append_z(
        ch: _Channel, seg_h: np.ndarray, seg_a: np.ndarray, noise: float, ready: int
    ) -> None:
        new = ch.rows.extend(len(seg_h))
        np.divide(seg_h, noise, new[ROW_Z])
        new[ROW_HINGE], new[ROW_AFTER], new[ROW_READY] = seg_h, seg_a, ready
        ch.refresh_views()

    def _white(self, block: int) -> tuple[float, int] | None:
        """White input noise (N per sample) for centres of `block`, and how many blocks tell it.

        The median of the finest scale's noise over the last `noise_blocks`
        blocks that showed their noise (not on a rail), each at least its
        quantisation floor (ADC step / sqrt(12)). None if none did: then the
        first later block that does (the block itself, at the start) - or
        None while there is none yet.
        """
        fine = self.channels[0]
        gain = _hinge_gain(fine.width)
        noise, censored, floor = fine.block_noise, self._censored, self._floor

        def seen(b: int) -> float | None:
            if b not in noise or censored.get(b, True):
                return None
            return max(noise[b] / gain, floor.get(b, 0.0))

        told = self._white_by_block.get(block)
        if told is not None:
            return told
        values = []  # seen(b) of each block before, inlined (this runs a few times a block)
        for b in range(max(0, block - self.noise_blocks), block):
            if b in noise and not censored.get(b, True):
                v = max(noise[b] / gain, floor.get(b, 0.0))
                if v:
                    values.append(v)
        if values:
            values.sort()
            told = values[(len(values) - 1) // 2], len(values)
            if block <= fine.done:  # every block before it complete: final
                self._white_by_block[block] = told
            return told
        for b in range(block, fine.done):
            v = seen(b)
            if v is not None:
                return v, 1
        return None

    def _mark_busy(self, index: int, emit: int, height: float) -> None:
        """A contact at `index` told a pulse at `emit`, `height` N above its base (the
        running peak by the level sample that told it): when the pulse stands out of the
        white noise (`BUSY_SNR` units or more), the blocks it
        touches in the hinge (from half the decision lag before its onset to the lag
        after it) show the pulse, not the noise (`_noise`); in the widest scale too while
        it stands under `CLEAR_SNR` units (ported: heavy noise, issue 22 item 3)."""
        B = self.block
        white = self._white(index // B)
        if white is None:
            return
        unit = max(white[0], NOISE_FLOOR_N)
        if height < BUSY_SNR * unit:
            return
        marks = (self._busy, self._busy_wide) if height < CLEAR_SNR * unit else (self._busy,)
        for busy in marks:
            for b in range((index - self.lag // 2) // B, (index + self.lag) // B + 1):
                if busy.get(b, emit) >= emit:
                    busy[b] = emit

    def _noise(self, ch: _Channel, block: int) -> float | None:
        """Noise of the hinge for centres of `block` (None: not known yet).

        The larger of: the white noise seen by the finest scale (`_white`)
        times this scale's gain, and the median of this scale's own blocks
        over the last `history_s` (those not on a rail, and no ridge contact's:
        `_mark_busy`) - coloured noise that the white estimate misses. A slip
        over dense ridges keeps the long scales busy with its own pulses (on
        uniform4 their median |h| read 10-22 times the noise): counted as noise,
        they hid the pulses after short spacings (issue 22).
        """
        cached = ch.noise_by_block.get(block)
        if cached is not None:
            return cached
        white = self._white(block)
        if white is None:
            return None
        sigma, known = white
        noise = max(sigma, NOISE_FLOOR_N) * _hinge_gain(ch.width)
        if ch is not self.channels[0]:
            # blocks a ridge pulse touched show the pulse, not the noise (`_mark_busy`):
            # they do not count, as known before the block before this one (a feed spans
            # at most a block: whatever the chunking). The blocks since the last settled
            # one (every pulse near it told by then) count unless the pulses went on to it
            # (the widest: a weak pulse's only; a clear one's slow bends are its noise)
            told = (block - 1) * self.block
            busy = self._busy_wide if ch.width >= BUSY_MAX_S * self.fs_hz else self._busy
            settled = (told - self.lag - self.lag // 2 - self.step_hold) // self.block
            going = any(busy.get(b, told) < told for b in (settled - 2, settled - 1))
            end = min(block, settled) if going else block
            history = range(max(0, block - self.history_blocks), end)
            known_noise, censored = ch.block_noise, self._censored
            own = sorted(
                [
                    known_noise[b]
                    for b in history
                    if b in known_noise and not censored.get(b, True) and busy.get(b, told) >= told
                ]
            )
            if own:
                noise = max(noise, own[(len(own) - 1) // 2])
            # weak pulses told within weak_slip_s: a slip in heavy noise, a lower threshold
            weak = self._busy_wide
            reach = range(block - self.weak_slip_blocks, block + 1)
            if self.weak_slip_share < 1.0 and any(weak.get(b, told) < told for b in reach):
                noise *= self.weak_slip_share
        # few blocks yet: the estimate is itself noisy, be more careful
        noise *= 1.0 + STARTUP_MARGIN * max(0, self.noise_blocks - known) / self.noise_blocks
        ch.noise_by_block[block] = noise
        return noise

    def _local_maxima(self, ci: int, ch: _Channel, candidates: list) -> None:
        w = ch.width
        z = ch.z
        last = ch.z_start + ch.rows.size - 1  # last centre with z
        lo = max(ch.next_test, ch.z_start + w)
        hi = last - w  # test centres lo .. hi
        if hi < lo:
            return
        i0, i1 = lo - ch.z_start, hi - ch.z_start
        ch.next_test = hi + 1
        above = (z[i0 : i1 + 1] >= self.threshold).nonzero()[0]
        for h in above.tolist():  # a local maximum over +-w (ties: the first)
            i = i0 + h
            zc = z[i]
            if z[i - 1] >= zc or z[i + 1] > zc:  # a neighbour's higher: the window's too (z
                # is finite: the decoders take finite samples only)
                continue
            if zc <= z[i - w : i].max() or zc < z[i + 1 : i + w + 1].max():
                continue
            n = ch.z_start + i
            jump, rising = ch.zh[i], ch.za[i]
            # a contact makes the force rise; long scales must see a clear rise (the
            # slow bend at the end of a fast pulse's decay is no contact)
            needed = self.rise_fraction if w / self.fs_hz < 0.03 else self.coarse_rise_fraction
            # ... unless a ridge's kink on a pulse's falling tail (issue 22, `tail_kinks`)
            floor = TAILS.floor * jump
            tail = rising < needed * jump
            if tail and (rising < floor or not self._on_tail(n, w)):
                continue
            n_at, delta, placed = self._refine(ci, n)
            if tail:  # timed late by the tail's bend (`tail_onsets`), not on the first
                # load's pulse (`arrival_tail`)
                n_at, delta, placed = tail_placed(
                    n_at, delta, placed, w, keep_time=self._on_first_load(n_at)
                )
            if self._after_drop(n_at, w):
                continue
            # decided once z is known over +-w (late where the noise had to be waited for)
            emit = max(n + 2 * w, int(ch.zready[i - w : i + w + 1].max()))
            candidates.append((emit, w, n_at, delta, float(z[i]), float(jump), placed))

    def _on_first_load(self, n: int) -> bool:
        """A tail kink on the first load's pulse (`arrival_tail`)?"""

        def white(index: int) -> float | None:
            told = self._white(max(0, index) // self.block)
            return None if told is None else max(told[0], NOISE_FLOOR_N)

        return on_first_load(
            self._x, self._t_start, self._onsets, n, self.fs_hz, white, TAILS.arrival_empty_n
        )

    def _on_tail(self, n: int, w: int) -> bool:
        """A kink with no rise after it on a pulse's falling tail (`tail_kinks`)."""
        white = self._white(n // self.block)
        if white is None:
            return False
        sigma = max(white[0], NOISE_FLOOR_N)
        return tail_kink(self._x, n - self._t_start, w, sigma, self.fs_hz, TAILS)

    def _after_drop(self, n: int, w: int) -> bool:
        """Is the kink at sample n the bottom of a sharp fall (the level stepping down: a
        slip starting, the FSR model's friction term, or a grip released)? A fall within
        w + 2 samples before it, in one sample, of over 5 sigma of the noise's steps and
        over twice what the force then rises: a ridge pulse rises by far more than the
        fastest decay of the one before it falls in a sample."""
        i = n - self._t_start
        if i - w - 2 < 0 or i + w >= len(self._x):
            return False
        white = self._white(n // self.block)
        if white is None:
            return False
        x = self._x
        fall = float((x[i - w - 2 : i] - x[i - w - 1 : i + 1]).max())
        rise = float(_mean(x[i + 1 : i + w + 1]) - x[i])
        return fall > 5.0 * math.sqrt(2.0) * white[0] and fall > 2.0 * max(rise, 0.0)

    def _refine(self, ci: int, n: int) -> tuple[int, float, int]:
        """Coarse to fine: move the onset to the peak of each finer scale that sees it.

        Returns (sample, fraction of a sample, width of the scale that placed it).
        """
        reach = self.channels[ci].width
        for fi in range(ci, -1, -1):
            ch = self.channels[fi]
            i = n - ch.z_start
            if fi < ci:
                lo, hi = max(1, i - reach), min(ch.rows.size - 2, i + reach)
                if hi < lo:
                    break
                j = lo + int(np.argmax(ch.z[lo : hi + 1]))
                if ch.z[j] < self.refine_z or j in (lo, hi):
                    break
                i, n, reach = j, ch.z_start + j, ch.width
            zc, zl, zr = ch.z[i], ch.z[i - 1], ch.z[i + 1]
            denom = zl - 2.0 * zc + zr
            delta = 0.5 * (zl - zr) / denom if denom < 0 else 0.0
            best = (n, min(0.5, max(-0.5, delta)), ch.width)
        return best

    def _time(self, n: int, delta: float) -> float:
        i = n - self._t_start
        t = self._t
        if delta >= 0 and i + 1 < len(t):
            return float(t[i] + delta * (t[i + 1] - t[i]))
        if delta < 0 and i - 1 >= 0:
            return float(t[i] + delta * (t[i] - t[i - 1]))
        return float(t[i])

    def _merge(self, candidates: list) -> list[ContactEvent]:
        events = []
        candidates.sort(key=lambda c: (c[0], c[1], c[2]))
        for emit, w, n, delta, z, jump, placed in candidates:
            t = self._time(n, delta)
            # the same kink seen again (by a coarser scale, later): within its own reach
            reach = self.merge_widths * w / self.fs_hz
            if any(abs(t - t_old) <= reach for t_old in self._recent):
                continue
            self._recent.append(t)
            # timing: a quarter of the placing scale (the hinge peak is that wide), and
            # the sub-sample interpolation
            sigma = (0.25 * placed + 0.3) / self.fs_hz
            ev = ContactEvent(
                self._next_id, t, n, emit, z, jump * self.fs_hz, w / self.fs_hz, sigma
            )
            self._next_id += 1
            events.append(ev)
        return events

    # ------------------------------------------------------------------ small steps
    def _run_steps(self, x: np.ndarray) -> None:
        """Step candidates: local maxima (over +-step_w) of the difference of the means after
        and before, less the mean of the same difference 2 step_w earlier and later (a ramp
        - the object covering more of the sensor - is no step), above step_threshold noise
        units; each is watched like a contact and kept only if judged a step at the hold
        (`_step_events`)."""
        for sc in self._scales:
            self._run_scale(sc, x)

    def _run_scale(self, sc: _StepScale, x: np.ndarray) -> None:
        w = sc.w
        sc.d = sc.store.append(sc.fir(x))
        last = sc.start + len(sc.d) - 1  # last centre with a difference
        lo = max(sc.next, sc.start + 3 * w, 3 * w)
        hi = last - 3 * w
        if hi < lo:
            return
        sc.next = hi + 1
        d = sc.d
        i0, i1 = lo - sc.start - w, hi - sc.start + w  # adjusted over +-w
        ramp = d[i0 - 2 * w : i1 + 1 - 2 * w] + d[i0 + 2 * w : i1 + 1 + 2 * w]
        adj = d[i0 : i1 + 1] - 0.5 * ramp
        # local maxima over +-w (ties: the first): only rises above their neighbours tested
        n = len(adj) - 2 * w
        mid = adj[w : w + n]
        rising = (mid > 0.0) & (mid >= adj[w - 1 : w - 1 + n]) & (mid > adj[w + 1 : w + 1 + n])
        for j in (rising.nonzero()[0] + w).tolist():
            a = adj[j]
            if a < adj[j - w : j].max() or a <= adj[j + 1 : j + w + 1].max():
                continue
            c = i0 + j + sc.start
            white = self._white(c // self.block)
            if white is None:
                continue
            z = float(a) / (max(white[0], NOISE_FLOOR_N) * math.sqrt(3.0 / w))
            if z < self.step_threshold:
                continue
            watch = self._watch(-1, c + 1)
            if watch is not None:
                watch.rise = sc.rise
                self._probes.append((watch, z, w))

    def _step_events(self) -> tuple[list[ContactEvent], list[PulseCheck]]:
        """Probes judged steps, told once every contact near them would have been decided:
        a contact and its verdict - unless the kink bank found that onset itself."""
        still = []
        for watch, z, w in self._probes:
            done = self._advance(watch, small=True)
            if done is None and watch.next_k <= watch.index + self.step_hold:
                still.append((watch, z, w))
            elif (
                done is not None
                and done.pulse is False
                and done.emit_index < (watch.index + self.step_hold + self.level_half + 1)
            ):
                emit = max(done.emit_index, watch.index + self.lag + w)
                t = self._time(watch.index, 0.0)
                self._confirmed.append((emit, w, watch.index, t, z, done.trend_on))
        self._probes = still
        events, checks = [], []
        keep = []
        for emit, w, index, t, z, trend_on in sorted(self._confirmed):
            if emit >= self._n:
                keep.append((emit, w, index, t, z, trend_on))
                continue
            # the kink bank has it: a probe is timed mid-rise, up to a step window after
            # the onset the kink bank placed (a slow pulse rises for longer); or a probe
            # of the other scale told it first
            if any(-w - 2 <= index - n <= 2 * w + 2 for n, e in self._onsets if e <= emit) or any(
                abs(index - n) <= w + v + 2 for n, _, v in self._probe_onsets
            ):
                continue
            self._probe_onsets.append((index, emit, w))
            sid = self._next_step_id
            self._next_step_id += 1
            sigma = (0.25 * w + 0.3) / self.fs_hz
            events.append(ContactEvent(sid, t, index, emit, z, 0.0, w / self.fs_hz, sigma))
            checks.append(PulseCheck(sid, emit, False, trend_on))
        self._confirmed = keep
        return events, checks

    # ------------------------------------------------------------------ pulse checks
    def _run_level(self, x: np.ndarray) -> None:
        y = self._level_filter(x)
        # y[m] is the mean of x[m - 2h .. m]: the level centred on m - h.
        self._level = self._levels.append(y)

    def _level_at(self, k: int) -> float | None:
        i = k + self.level_half - self._level_start  # centre k is output m = k + h
        if 0 <= i < len(self._level):
            return float(self._level[i])
        return None

    def _watch(self, cid: int, index: int, emit: int | None = None) -> _Watch | None:
        """A watch on the level after an onset at sample `index`: its base, trends, noise
        (and, for a kink contact decided at `emit`, the falling tail under it)."""
        fine = self.channels[0]
        h = self.level_half
        before = index - 2 * h - 1  # last level centre not touched by the pulse
        base = self._level_at(before)
        if base is None:
            base = self._level_at(index)
        earlier = self._level_at(before - self.trend_n)
        trend = fall = 0.0
        if base is not None and earlier is not None:  # rising trend before the onset
            trend = max(0.0, (base - earlier) / self.trend_n)
        long = None
        if emit is not None and base is not None:
            long = self._long_trend(index, emit, base)
        recent = self._level_at(before - self.fall_n)
        floor = self._level_floor(before)
        if base is not None and recent is not None and floor is not None:
            # an earlier pulse's tail falling: its slope, and how far it can still fall
            fall = max(0.0, (recent - base) / self.fall_n)
            fall = min(fall, max(0.0, base - floor) / self.fall_credit)
        fine_noise = self._noise(fine, index // self.block)
        white = 0.0 if fine_noise is None else fine_noise / _hinge_gain(fine.width)
        noise = max(NOISE_FLOOR_N, white) / math.sqrt(2 * h + 1)
        watch = _Watch(
            cid, index, 0.0 if base is None else base, trend, noise, fall=fall, next_k=index
        )
        if emit is not None and base is not None:
            watch.slope = self._level_slope(before)
            watch.room = self._tail_room(index, emit, base)
            watch.long = 0.0 if long is None else long
            self._bases.append((index, emit, base))
        return watch

    def _level_slope(self, before: int) -> float:
        """Least-squares slope of the level over the fall_credit samples up to `before`
        (N/sample): the slope right before the onset (a tail's flattens as it relaxes)."""
        i1 = before + self.level_half - self._level_start + 1
        i0 = i1 - self.fall_credit - 1
        if i0 < 0 or i1 > len(self._level):
            return 0.0
        y = self._level[i0:i1]
        x = np.arange(len(y)) - (len(y) - 1) / 2.0
        return float(np.dot(x, y) / np.dot(x, x))

    def _long_trend(self, index: int, emit: int, base: float) -> float | None:
        """The slip's rising trend (N/sample, >= 0) from the base of the latest earlier contact
        between `trend_n` and `long_trend_n` samples before this one to this base (None:
        no such contact). While an object slips on, the level between
        ridge contacts is the rising trend (more of the object over the sensor) plus
        pulse tails, and under FSR hysteresis a falling tail reads flat: over the trend_s
        before an onset it may show no trend at all though the slip goes on (issue 22:
        the headline's ridge pulses told steps). From base to base the tails cancel and
        the trend shows. Only contacts decided by `emit` count (chunking cannot change it).
        """
        for n, e, level in reversed(self._bases):
            if e > emit or n > index - self.trend_n:
                continue
            if n < index - self.long_trend_n:
                return None
            return max(0.0, (base - level) / (index - n))
        return None

    def _tail_room(self, index: int, emit: int, base: float) -> float:
        """How far the level can still fall under a contact at `index`: down to where it
        was before the two contacts before it (their pulses' tails, the one riding on the
        other's, relax no lower). Only contacts decided by `emit` count (chunking cannot
        change it); 0 when there is none."""
        earlier = sorted((n, level) for n, e, level in self._bases if n < index - 2 and e <= emit)
        if not earlier:
            return 0.0
        return max(0.0, base - min(level for _, level in earlier[-2:]))

    def _check_pulses(self, events: list[ContactEvent]) -> list[PulseCheck]:
        checks: list[PulseCheck] = []
        for ev in events:
            watch = self._watch(ev.id, ev.index, ev.emit_index)
            if watch is not None:
                self._watches.append(watch)
        still = []
        for watch in self._watches:
            done = self._advance(watch)
            if done is None:
                still.append(watch)
            else:
                checks.append(done)
                if done.pulse is True and len(watch.history):
                    told = done.emit_index - self.level_half - watch.index
                    told = min(told, len(watch.history) - 1)
                    height = float(watch.history[told]) if told >= 0 else 0.0
                    self._mark_busy(watch.index, done.emit_index, height)
                if done.pulse is False and done.emit_index < watch.index + self.revise:
                    watch.top = float(watch.detrended.max()) if len(watch.detrended) else 0.0
                    watch.next_k = max(watch.next_k, done.emit_index - self.level_half + 1)
                    self._stepped.append(watch)
        self._watches = still
        kept = []
        for watch in self._stepped:
            revised = self._revise(watch)
            if revised is not None:
                checks.append(revised)
            elif self._revising(watch):
                kept.append(watch)
        self._stepped = kept
        return checks

    def _revise(self, watch: _Watch) -> PulseCheck | None:
        """A step told at the hold that falls back (trend and earlier tail out) by
        drop_fraction of the level it stepped to within `revise_s` of the onset, with
        another contact within that time, was a slow pulse: the verdict revised
        (pulse=True), told when both are known. A stop's step stays, and a stopped object
        makes no contacts."""
        h = self.level_half
        limit = watch.index + self.revise
        if watch.fell_at < 0:
            end = min(limit, self._level_start + len(self._level) - 1 - h)
            if end >= watch.next_k and watch.top > 0.0:
                i0 = watch.next_k + h - self._level_start
                level = self._level[i0 : i0 + end - watch.next_k + 1]
                k = np.arange(watch.next_k, end + 1)
                credit = self._tail_credit(watch, k)
                d = level - watch.base + credit - watch.trend * (k - watch.index + 2 * h + 1)
                watch.next_k = end + 1
                fell = (watch.top - d >= self.drop_fraction * watch.top).nonzero()[0]
                if len(fell):
                    watch.fell_at = int(k[fell[0]])
        if watch.fell_at >= 0:
            later = [e for n, e in self._onsets if watch.index + 2 < n <= limit]
            if later:
                watch.next_k = limit + self.lag + 1  # done
                return PulseCheck(watch.id, max(watch.fell_at + h, min(later)), True)
        return None

    def _revising(self, watch: _Watch) -> bool:
        """Still watched: the fall not yet looked for to the end, or a contact within the
        window not yet decided."""
        limit = watch.index + self.revise
        if watch.fell_at < 0:
            return watch.next_k <= limit
        return watch.next_k <= limit + self.lag and self._n <= limit + self.lag

    def _advance(self, watch: _Watch, small: bool = False) -> PulseCheck | None:
        """Examine the level from watch.next_k on; a verdict, or None while undecided.

        The rising trend of the `trend_s` before the onset (the object
        covering more of the sensor) is taken out, and an earlier pulse's tail
        falling under it for a while (`_tail_credit`). A pulse falls back by
        `drop_fraction` of its height within `decay_rises` times its rise time
        (to 90 % of its peak) after that (a grip step up and, later, down is no pulse); a step
        stays level for the whole watch. A *sharp* rise (to 80 % within `step_rise_s`)
        that has not fallen back by `drop_fraction` `step_hold_s` after the onset is a
        step already then: a ridge pulse that sharp is a fast one and has fallen back
        by then (its peak comes after ~1.25 mm of travel), while the end of a slip
        (the friction term of the FSR model, thesis ch. 4.3) or a grip change stays.
        A level that keeps rising (more of the object on the sensor) decides
        nothing.
        """
        h = self.level_half
        end = min(watch.index + self.watch, self._level_start + len(self._level) - 1 - h)
        if end >= watch.next_k:
            i0 = watch.next_k + h - self._level_start
            level = self._level[i0 : i0 + end - watch.next_k + 1]
            k = np.arange(watch.next_k, end + 1)
            since = k - watch.index
            # fallen back? an earlier pulse's tail under it taken out (`_tail_credit`)
            credit = watch.fall * np.minimum(since, self.fall_credit)
            raw = level - watch.base + credit
            d = raw - watch.trend * (since + (2 * h + 1))
            peak = np.maximum.accumulate(np.maximum(d - credit, watch.peak))
            history = np.concatenate([watch.history, peak])  # running peak since the onset
            watch.history = history
            hold = watch.index + self.step_hold
            if watch.next_k <= hold:
                keep = hold - watch.next_k + 1
                watch.plain = np.concatenate([watch.plain, (level - watch.base)[:keep]])
                watch.levels = np.concatenate([watch.levels, raw[:keep]])
                watch.detrended = np.concatenate([watch.detrended, d[:keep]])
            # rise time: onset to the first sample at 90 % of the peak so far (a noisy
            # plateau keeps nudging the peak, not this)
            rise = history.searchsorted(0.9 * peak)
            rise = np.maximum(rise, self.min_rise)
            ok = (
                (peak >= 4.0 * watch.noise)
                & (peak - d >= self.drop_fraction * peak)
                & (since <= (1.0 + self.decay_rises) * rise)
            )
            # a sharp rise is judged at the hold: a step, or (fallen back by then) a pulse
            if watch.next_k < hold:
                deferred = (k < hold) & (history.searchsorted(0.8 * peak) <= self.step_rise)
                watch.fell = watch.fell or bool((ok & deferred).any())
                hit = (ok & ~deferred).nonzero()[0]
            else:  # past the hold: nothing deferred
                hit = ok.nonzero()[0]
            sure = watch.index + self.sure_hold
            if (
                not small
                and self.sure_hold
                and watch.next_k <= sure <= end
                and not (len(hit) and k[hit[0]] <= sure)
                and not self._train_follows(watch, sure)
                and not self._clipped(watch.index, sure)
            ):
                head = slice(0, self.sure_hold + 1)
                if sharp_flat_step(
                    watch.detrended[head], watch.noise, self.sure_rise, self.sure_snr,
                    self.sure_drop,
                ):  # fmt: skip
                    watch.plain = watch.plain[head]
                    watch.levels = watch.levels[head]
                    watch.detrended = watch.detrended[head]
                    return PulseCheck(watch.id, sure + h, False, None, sure=True)
            if len(hit) and k[hit[0]] < hold:
                return PulseCheck(watch.id, int(k[hit[0]]) + h, True)
            if watch.next_k <= hold <= end and not self._clipped(watch.index, hold):
                if self._is_small_step(watch) if small else self._is_step(watch):
                    return PulseCheck(watch.id, hold + h, False, self._trend_on(watch))
                if watch.fell or (not small and self._fell_on_slip_trend(watch)):
                    return PulseCheck(watch.id, hold + h, True)
            if len(hit):
                return PulseCheck(watch.id, int(k[hit[0]]) + h, True)
            early = min(len(k), watch.index + self.watch // 4 - watch.next_k + 1)  # k rises
            if early > 0:
                watch.early = max(watch.early, float(peak[early - 1]))
            watch.peak = float(peak[-1])
            watch.next_k = end + 1
        if watch.next_k > watch.index + self.watch:
            flat = watch.peak <= 1.5 * watch.early
            return PulseCheck(watch.id, watch.index + self.watch + h, False if flat else None)
        return None

    def _level_floor(self, before: int) -> float | None:
        """The lowest level over the trend window up to `before` (under an earlier pulse)."""
        i1 = before + self.level_half - self._level_start + 1
        i0 = max(0, i1 - self.trend_n)
        if i1 <= i0:
            return None
        return float(self._level[i0:i1].min())

    def _tail_credit(self, watch: _Watch, k: np.ndarray) -> np.ndarray:
        """How far an earlier pulse's tail under the onset falls by k (>= 0): its slope
        just before the onset, followed for fall_credit and no further, and never below
        the level before that pulse (a tail flattens; a new ridge pulse replaces it -
        thesis ch. 5.3.1 - and still falls back)."""
        return watch.fall * np.minimum(k - watch.index, self.fall_credit)

    def _is_step(self, watch: _Watch) -> bool:
        """At step_hold after the onset: rose sharply (to 80 % of its top within
        step_rise) and has not fallen back by drop_fraction since - with the rising trend
        taken out (a grip step while the object slips on), or on the level itself when
        it is flat by then (a slip that stops ends the trend: the object no longer
        covers more of the sensor). A ridge pulse on a rising trend falls back from it,
        and the trend goes on."""

        def stays(levels: np.ndarray) -> bool:
            top = float(levels.max())
            if top < 6.0 * watch.noise:
                return False
            rise = int(np.argmax(levels >= 0.8 * top))
            if rise > self.step_rise:
                return False
            return float(levels[rise:].min()) >= (1.0 - self.drop_fraction) * top

        if self._tail_step(watch):
            return True
        if self._fell_in_slip(watch):
            return False
        return self._stayed_up(watch, stays) or self._rose_on(watch)

    def _rose_on(self, watch: _Watch) -> bool:
        """A sharp rise after which the level never fell back from its running top (by 3
        noise units and 5 % of the rise) by the hold: it rose on, not back - the stop of a
        slip while the grip rises (the reflex), which the tests above, with the trend
        taken out, see as a slow rise. A pulse falls back from its top. Only where the
        rise is resolved (step_rise of 4 samples or more: 200 Hz and up): at 100 Hz a
        ridge pulse's rise is a sample or two, and its fall is not told from noise."""
        level, r, noise = watch.plain, self.step_rise, watch.noise
        if r < 4 or len(level) < 4 * r + 2 or self._train_follows(watch):
            return False
        first = float(_mean(level[r : 2 * r + 1]))
        if first < 6.0 * noise or int(np.argmax(level >= 0.8 * first)) > r:
            return False
        after = level[r:]
        fell = float((np.maximum.accumulate(after) - after).max())
        if fell > 3.0 * noise + 0.05 * first:
            return False
        # a step, not a ramp's start: the jump is well above what the level rises after it
        # over as long (a slip's trend resuming after a plateau is a kink onto a ramp)
        rate = (float(_mean(level[-r:])) - first) / (len(level) - 2 * r)
        return first >= 2.5 * max(rate, 0.0) * (1.5 * r)

    def _fell_on_slip_trend(self, watch: _Watch) -> bool:
        """At the hold, not a step: did it fall back like a pulse from the slip's trend
        (`_long_trend`, when the trend_s before the onset hid it) - by drop_fraction of its
        top with that trend out, or by `slip_fall` noise units on the level itself?"""
        if watch.long <= watch.trend or not len(watch.levels):
            return False
        k = np.arange(len(watch.levels)) + 2 * self.level_half + 1
        detrended = watch.levels - watch.long * k
        top = float(detrended.max())
        if top >= 4.0 * watch.noise and top - float(detrended[-1]) >= self.drop_fraction * top:
            return True
        return self._fell_in_slip(watch)

    def _fell_in_slip(self, watch: _Watch) -> bool:
        """In a slip whose level rises (the base-to-base trend over the hold at least
        `slip_fall` noise units), has the level itself fallen from its top by `slip_fall`
        noise units by the hold? A ridge pulse on that trend: its fall is held up by the
        trend and the FSR's hysteresis (the 30 % drop may never show), while a stop leaves
        the level flat and a grip change raises it. A falling tail under the onset (the
        pulse before, relaxing on: `_tail_step`'s slope and room) is taken out first: a
        slip that stops on it, right where the next ridge was due, relaxes with it and
        is no pulse (issue 22: uniform4's stops, once its 4 mm contacts are found)."""
        if watch.long * self.step_hold < self.slip_fall * watch.noise:
            return False
        level = watch.plain
        if watch.slope < 0.0 and watch.room > 0.0:
            k = np.arange(len(level)) + 2 * self.level_half + 1  # samples since `before`
            level = level + np.minimum(-watch.slope * k, watch.room)
        end = float(_mean(level[-min(len(level), 2 * self.level_half + 1) :]))
        return float(level.max()) - end >= self.slip_fall * watch.noise

    def _tail_step(self, watch: _Watch) -> bool:
        """A sharp rise on the falling tail of the pulse before it that stays up over that
        tail relaxing on. A slip that stops leaves its last pulse relaxing (the ridge does
        not stop relaxing with the object), and the friction term's step (thesis ch. 4.3)
        may be small. The level itself must rise sharply, stop rising, fall no faster than
        the tail did before the onset (a ridge pulse replaces the tail, thesis ch. 5.3.1,
        and falls back faster: a pulse of its own) and not rise again by the hold (a
        stopped object covers no more of the sensor); with the tail's fall taken out - its
        slope before the onset, no lower than the level before the pulses under it - it
        stays up. Means over the hold, not extremes: the step may be a few noise units
        high."""
        if watch.slope >= 0.0 or watch.room <= 0.0 or len(watch.plain) < 4 * self.step_rise + 2:
            return False
        if self._train_follows(watch):
            return False
        level, r, noise = watch.plain, self.step_rise, watch.noise
        first = float(np.mean(level[r : 2 * r + 1]))
        if first < 6.0 * noise or int(np.argmax(level >= 0.8 * first)) > r:
            return False  # too small, or not sharp: a slow pulse
        if float(np.mean(level[2 * r : 4 * r + 1])) > 1.15 * first + 2.0 * noise:
            return False  # still rising: a slow pulse
        tail = level[len(level) // 2 :]
        x = np.arange(len(tail)) - (len(tail) - 1) / 2.0
        if float(np.dot(x, tail) / np.dot(x, x)) * len(tail) > 0.1 * first + 3.0 * noise:
            return False  # the level rising by the hold: the object still covers more of it
        after = level[r:]
        x = np.arange(len(after)) - (len(after) - 1) / 2.0
        norm = float(np.dot(x, x))
        if float(np.dot(x, after)) / norm < 1.25 * watch.slope - 6.0 * noise / math.sqrt(norm):
            return False  # falling faster than the tail: a pulse falling back
        k = np.arange(len(level)) + 2 * self.level_half + 1  # samples since `before`
        y = level + np.minimum(-watch.slope * k, watch.room)  # the tail relaxing on, out
        top = float(np.mean(y[r : 2 * r + 1]))
        if y[-1] - level[-1] < 0.25 * top:
            return False  # no tail worth the name: the level's own tests judge it
        keep = 1.0 - self.drop_fraction
        end = float(np.mean(y[-max(2, len(y) // 4) :]))
        low = float(np.min(y[r:]))
        return end >= keep * top and low >= (keep - 0.1) * top - 2.0 * noise

    def _stayed_up(self, watch: _Watch, stays: Callable[[np.ndarray], bool]) -> bool:
        """The step verdict both step tests share, given how each judges a level that
        `stays` up: no pulse train follows, and it stays up with the rising trend taken
        out, or on the level itself once that is flat by the hold."""
        if self._train_follows(watch):
            return False
        detrended = watch.detrended
        if watch.long > watch.trend:  # the slip's trend, hidden before the onset (`_long_trend`)
            k = np.arange(len(watch.levels)) + 2 * self.level_half + 1
            detrended = watch.levels - watch.long * k
        if stays(detrended):
            return True
        if watch.trend <= 0.0 or not stays(watch.levels):
            return False
        tail = watch.levels[len(watch.levels) // 2 :]  # flat by the hold?
        m = len(tail)
        x = np.arange(m) - (m - 1) / 2.0
        change = float(np.dot(x, tail) / np.dot(x, x)) * m
        top = float(watch.levels.max())
        # (falling by more than noise is no stopped level: a pulse on a rising trend
        # whose fall the hysteresis and the trend hold up - the tail step judges a
        # stop on a relaxing tail)
        return -(0.1 * top + 3.0 * watch.noise) <= change <= 0.2 * top + 3.0 * watch.noise

    def _train_follows(self, watch: _Watch, hold: int | None = None) -> bool:
        """Did more contacts come before the hold (or `hold`)? Pulses after short spacings
        start on the one before (thesis ch. 5.3.1): a train of them keeps the level up like
        a step, and a slip that stopped makes no more contacts. Only contacts decided by
        the verdict's sample count (chunking cannot change the verdict)."""
        hold = watch.index + self.step_hold if hold is None else hold
        told = hold + self.level_half
        return any(watch.index + 2 < n <= hold and e <= told for n, e in self._onsets)

    def _clipped(self, start: int, stop: int) -> bool:
        """Do samples start..stop pile up at their maximum (the sensor's upper rail)? A
        level clipped there stays whatever happens: no step to tell."""
        i0, i1 = start - self._t_start, stop - self._t_start + 1
        if i0 < 0 or i1 > len(self._x):
            return False
        x = self._x[i0:i1]
        return bool(on_rail(x)) and bool(np.count_nonzero(x == x.max()) >= RAIL_SHARE * len(x))

    def _trend_on(self, watch: _Watch) -> bool | None:
        """After a step: did the rising trend before it go on (True) or stop (False)? None
        when the trend is too weak to tell over half the hold (under 4 noise units)."""
        half = watch.levels[len(watch.levels) // 2 :]
        m = len(half)
        if watch.trend * m < 4.0 * watch.noise:
            return None
        x = np.arange(m) - (m - 1) / 2.0
        slope = float(np.dot(x, half) / np.dot(x, x))
        if slope >= 0.6 * watch.trend:
            return True
        if slope <= 0.3 * watch.trend:
            return False
        return None

    def _is_small_step(self, watch: _Watch) -> bool:
        """A probe (a small step the kink bank missed) at step_hold after the onset: rose
        sharply (no higher over the next 2 small_rise than over the small_rise after it)
        and has not fallen back by drop_fraction since (means, not extremes: a small step
        is a few noise units high) - with the rising trend
        taken out (a grip step while the object slips on), or on the level itself when
        it is flat by then (a slip that stops ends the trend: the object no longer
        covers more of the sensor). A ridge pulse on a rising trend falls back from it,
        and the trend goes on."""

        def stays(levels: np.ndarray) -> bool:
            n = watch.rise or self.small_rise
            first = float(_mean(levels[n : 2 * n + 1]))  # just after a sharp rise
            if first < 6.0 * watch.noise:
                return False
            later = float(_mean(levels[2 * n : 4 * n + 1]))
            if later > 1.15 * first + 2.0 * watch.noise:
                return False  # still rising: a slow pulse
            end = float(_mean(levels[-max(2, len(levels) // 4) :]))
            low = float(levels[n:].min())
            keep = 1.0 - self.drop_fraction
            if end > (2.0 - keep) * first + 2.0 * watch.noise:
                return False  # went on rising: a ramp
            return end >= keep * first and low >= (keep - 0.1) * first - 2.0 * watch.noise

        return self._stayed_up(watch, stays)

    # ------------------------------------------------------------------ memory
    def _trim(self) -> None:
        keep = self._keep
        if len(self._t) > 2 * keep:
            cut = len(self._t) - keep
            self._t, self._x = self._tx.keep_last(keep)
            self._t_start += cut
        if len(self._level) > 2 * keep:  # (under that it is under 2 lv_keep too)
            oldest_watch = min(
                [w.next_k for w in self._watches + self._stepped]
                + [w.next_k for w, _, _ in self._probes],
                default=None,
            )
            lv_keep = keep
            if oldest_watch is not None:
                lv_keep = max(lv_keep, self._level_start + len(self._level) - oldest_watch + 4)
            if len(self._level) > 2 * lv_keep:
                cut = len(self._level) - lv_keep
                self._level = self._levels.keep_last(lv_keep)
                self._level_start += cut
        for sc in self._scales:
            if len(sc.d) > 2 * keep:
                cut = len(sc.d) - keep
                sc.d = sc.store.keep_last(keep)
                sc.start += cut
        for ch in self.channels:
            if ch.rows.size > 2 * keep:
                cut = ch.rows.size - keep
                ch.rows.keep_last(keep)  # (in place: the views stay)
                ch.z_start += cut

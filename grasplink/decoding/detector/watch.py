"""The pulse watcher: the level after each contact, told a pulse or a step.

Every contact is watched: a *pulse* rises and falls back (by `drop_fraction` of its
height, rising trend removed) within a few rise times; a grip step rises and stays level.
The verdict (True, False, or None when the force kept rising) is reported later as a
`PulseCheck`. While the object slips on, the level rises and FSR hysteresis flattens a
pulse's fall, so the trend before an onset is also taken from base to base
(`_long_trend`) and a level that fell from its top in such a slip is a pulse
(`_fell_in_slip`); a sharp rise that rises on is a step (`_rose_on`). The probes' candidates
are watched here too (`advance`), and told contacts only on the verdict they need.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import numpy as np

from grasplink.decoding.detector import pulse_under
from grasplink.decoding.detector.events import ContactEvent, Ledger, PulseCheck
from grasplink.decoding.detector.noise_floor import NOISE_FLOOR_N, NoiseFloor, hinge_gain
from grasplink.decoding.detector.prior_trend import trend_past_pulse
from grasplink.decoding.detector.series import Samples, Series, mean
from grasplink.decoding.filters import SosFilter
from grasplink.decoding.kernels.detector import (
    ScanSettings,
    Watched,
    fir_run,
    watch_scan,
)
from grasplink.decoding.kernels.layout import HELD_DETRENDED, HELD_LEVELS, HELD_PLAIN, WATCH_ROWS


@dataclass(frozen=True)
class WatchSettings:
    """How a contact's level is watched and judged (durations in s)."""

    drop_fraction: float = 0.3  # a pulse falls back by this share of its height
    watch_s: float = 1.0  # watched this long at most
    level_s: float = 0.01  # the level: a moving mean this long
    trend_s: float = 0.1  # the rising trend before an onset, over this long
    decay_rises: float = 5.0  # a pulse falls back within this many rise times
    # a sharp rise (to 80 % within step_rise_s) that stays at step_hold_s: a step then
    step_rise_s: float = 0.02
    step_hold_s: float = 0.1
    # ... and a sharp, tall step that stays flat (`sharp_flat_step`) sooner still: the stop
    # of a slip told before the next ridge is due (issue 22 item 4); 0: off
    sure_hold_s: float = 0.05
    sure_rise_s: float = 0.01
    sure_snr: float = 20.0  # level-noise units (`Watch.noise`)
    sure_drop: float = 0.3  # share of its top it may fall back by then
    revise_s: float = 0.35  # a step told at the hold that falls back by then: a slow pulse
    long_trend_s: float = 0.6  # the slip's trend from an earlier contact's base this far back
    # a tail step's size and sharpness from the trough the tail fell to under its rise, not
    # from the level before the onset (`PulseWatcher._tail_step`); False: from that level
    tail_trough: bool = False
    # the trend before an onset with an earlier pulse in its window out (`prior_trend`);
    # False: the window's own change
    trend_past_pulse: bool = False
    # ... and the base-to-base trend too (its base sits on that pulse as well); False: off
    long_past_pulse: bool = False
    # a contact that falls back before the hold within `pulse_under.MAX_GAP_S` of an earlier
    # one: judged at the hold with that pulse's course out (`pulse_under`); False: off (the
    # outputs before it, bit for bit)
    pulse_under_step: bool = True


def step_hold_samples(fs_hz: float, settings: WatchSettings) -> int:
    """The hold (samples after an onset) at which a sharp rise that stays is a step."""
    step_rise = max(1, round(settings.step_rise_s * fs_hz))
    return max(step_rise + 1, round(settings.step_hold_s * fs_hz))


def level_span(fs_hz: float, settings: WatchSettings) -> int:
    """Samples of level before an onset a watch reads (the moving mean and the trend)."""
    return 2 * max(0, round(settings.level_s * fs_hz / 2.0)) + round(settings.trend_s * fs_hz)


@dataclass
class Watch:
    id: int
    index: int  # onset sample
    base: float  # level before the onset
    trend: float  # rising trend before the onset (N/sample, >= 0)
    noise: float  # level noise (N)
    fall: float = 0.0  # falling slope just before the onset (N/sample, >= 0): a pulse's tail
    peak: float = -math.inf
    early: float = -math.inf  # highest level in the first quarter of the watch
    # the running peak by sample since the onset: history[:hist_n] (room for the watch)
    history: np.ndarray = field(default_factory=lambda: np.zeros(0))
    hist_n: int = 0
    # to the hold: the level - base, with an earlier tail's fall out, with the trend out
    # too (`plain`, `levels`, `detrended`): held[:, :held_n] (room to the hold)
    held: np.ndarray = field(default_factory=lambda: np.zeros((len(WATCH_ROWS), 0)))
    held_n: int = 0
    fell: bool = False  # a sharp rise that fell back like a pulse before the hold
    next_k: int = 0  # next level sample to examine
    top: float = 0.0  # told a step: the level it stepped to (trend out), watched for a fall
    fell_at: int = -1  # ... the sample where it fell back by drop_fraction (-1: not yet)
    slope: float = 0.0  # the level's slope before the onset (N/sample, either sign)
    room: float = 0.0  # how far a falling tail under the onset can still fall (N; 0: none)
    rise: int = 0  # a probe: the rise of its scale (samples)
    long: float = 0.0  # the slip's rising trend from the base of an earlier contact (N/sample)
    under: bool = False  # fell back on an earlier pulse's course: judged at the hold (pulse_under)
    course: tuple[float, ...] | None = None  # ... that course (`PulseWatcher._under_course`)
    # what `watch_scan` reads of it that stays (a `kernels.detector.Watched` as a plain
    # tuple, built once by `PulseWatcher.start`: the fields it holds are never reassigned)
    scanned: tuple = ()

    @property
    def plain(self) -> np.ndarray:
        """level - base, to the hold."""
        return self.held[HELD_PLAIN, : self.held_n]

    @property
    def levels(self) -> np.ndarray:
        """The raw level (an earlier pulse's tail out, `_tail_credit`), to the hold."""
        return self.held[HELD_LEVELS, : self.held_n]

    @property
    def detrended(self) -> np.ndarray:
        """... and the rising trend taken out, to the hold."""
        return self.held[HELD_DETRENDED, : self.held_n]


def sharp_flat_step(
    detrended: np.ndarray, noise: float, rise: int, snr: float, drop: float
) -> bool:
    """A level (base and trend out, from the onset) that is a step beyond doubt: at least
    `snr` level-noise units high, at 80 % of its top within `rise` samples and never
    fallen by more than `drop` of the top (and 2 noise units) after that, nor at its
    end. The end of a slip (thesis ch. 4.3) and a grip change jump like this; a ridge
    pulse sharp enough to rise that fast is falling back by then, and one on a
    hysteretic skin rises slowly (the full plan's stop steps: 5-95 % rise 6-10 ms;
    ridge pulses told steps at the hold: 9-22 ms, falling 15-30 % within 40 ms)."""
    if not len(detrended):
        return False
    top = float(detrended.max())
    if top < snr * noise:
        return False
    up = int(np.argmax(detrended >= 0.8 * top))
    if up > rise:
        return False
    low = float(detrended[up:].min())
    return top - low <= drop * top + 2.0 * noise and float(detrended[-1]) >= (1.0 - drop) * top


class PulseWatcher:
    """Watches (`Watch`) on the level after each contact and probe candidate, and their
    verdicts (see the module doc)."""

    def __init__(
        self,
        fs_hz: float,
        settings: WatchSettings,
        noise: NoiseFloor,
        samples: Samples,
        ledger: Ledger,
        lag: int,
        capacity: int,
    ):
        self.fs_hz = fs_hz
        self.settings = settings
        self.noise, self.samples, self.ledger = noise, samples, ledger
        self.block = noise.block
        self.lag = lag  # the kink bank's decision lag (samples)
        self.drop_fraction = float(settings.drop_fraction)
        self.watch = max(8, round(settings.watch_s * fs_hz))
        self.decay_rises = float(settings.decay_rises)
        self.min_rise = max(1, round(0.005 * fs_hz))
        # a sharp rise that stays: judged a step early (a stop, a grip change), see advance
        self.step_rise = max(1, round(settings.step_rise_s * fs_hz))
        self.step_hold = step_hold_samples(fs_hz, settings)
        self.sure_rise = max(1, round(settings.sure_rise_s * fs_hz))
        # only where that rise is resolved (2 samples: 200 Hz and up); at 100 Hz a ridge
        # pulse rises in a sample or two too (2 % of those judged at the hold passed)
        self.sure_hold = min(self.step_hold, round(settings.sure_hold_s * fs_hz))
        if self.sure_rise < 2:
            self.sure_hold = 0
        self.sure_snr = float(settings.sure_snr)
        self.sure_drop = float(settings.sure_drop)
        # the level before each contact's onset: (index, emit, level), see _tail_room
        self._bases: deque[tuple[int, int, float]] = deque(maxlen=32)
        # ... and the trend its watch measured before it: (index, emit, trend), `prior_trend`
        self._trends: deque[tuple[int, int, float]] = deque(maxlen=32)
        self._longs: deque[tuple[int, int, float]] = deque(maxlen=32)  # ... its long trend
        self.fall_n = max(2, round(0.02 * fs_hz))  # an earlier pulse's tail: its slope ...
        self.fall_credit = max(1, round(0.03 * fs_hz))  # ... followed this long at most
        half = max(0, round(settings.level_s * fs_hz / 2.0))
        self.level_half = half
        self._level_filter = SosFilter.fir(np.full(2 * half + 1, 1.0 / (2 * half + 1)))
        self._level_fir: tuple[np.ndarray, np.ndarray] | None = None  # (taps, state): settle
        self._levels = Series(capacity)
        self._level = self._levels.view()  # box-smoothed level, by centre index
        self._level_start = 0
        self._watches: list[Watch] = []
        # steps told at the hold, watched on: a ridge pulse on a slow (hysteretic) skin may
        # stay up past the hold and fall back later - then the verdict is revised to a pulse
        self._stepped: list[Watch] = []
        self.revise = max(self.step_hold + 1, round(settings.revise_s * fs_hz))
        self.trend_n = max(1, round(settings.trend_s * fs_hz))
        self.long_trend_n = max(self.trend_n + 1, round(settings.long_trend_s * fs_hz))
        self.slip_fall = 6.0  # noise units (`_fell_in_slip`)
        self.under_gap = round(pulse_under.MAX_GAP_S * fs_hz)  # (`_under_residual`)
        self._scan_settings = tuple(
            ScanSettings(
                fall_credit=self.fall_credit, width=2 * half + 1, min_rise=self.min_rise,
                drop=self.drop_fraction, decay=1.0 + self.decay_rises, step_rise=self.step_rise,
            )
        )  # fmt: skip

    def settle(self, first: float) -> None:
        """The level filter's taps and state, settled on the first sample, for the kernel
        that runs it in place."""
        if self._level_filter.is_fir:  # (one tap, under 100 Hz: a plain gain, run as is)
            self._level_fir = self._level_filter.fir_state(first)

    def room(self, keep: int) -> int:
        """Samples to come before `trim(keep, ...)` would look at the level (an entry each;
        under 1 while a watch holds it longer)."""
        return 2 * keep - len(self._level)

    def trim(self, keep: int, others: Iterable[Watch]) -> None:
        """Keep the level back to `keep` samples, or to the oldest sample a watch (this
        watcher's, or `others`: the probes' candidates) still examines."""
        if len(self._level) > 2 * keep:  # (under that it is under 2 lv_keep too)
            oldest_watch = min(
                [w.next_k for w in self._watches + self._stepped] + [w.next_k for w in others],
                default=None,
            )
            lv_keep = keep
            if oldest_watch is not None:
                lv_keep = max(lv_keep, self._level_start + len(self._level) - oldest_watch + 4)
            if len(self._level) > 2 * lv_keep:
                cut = len(self._level) - lv_keep
                self._level = self._levels.keep_last(lv_keep)
                self._level_start += cut

    def run_level(self, x: np.ndarray) -> None:
        # y[m] is the mean of x[m - 2h .. m]: the level centred on m - h.
        new = self._levels.extend(len(x))
        if self._level_fir is None:
            new[...] = self._level_filter(x)
        else:
            fir_run(*self._level_fir, x, new)
        self._level = self._levels.view()

    def level_at(self, k: int) -> float | None:
        i = k + self.level_half - self._level_start  # centre k is output m = k + h
        if 0 <= i < len(self._level):
            return float(self._level[i])
        return None

    def start(self, cid: int, index: int, emit: int | None = None) -> Watch | None:
        """A watch on the level after an onset at sample `index`: its base, trends, noise
        (and, for a kink contact decided at `emit`, the falling tail under it)."""
        h = self.level_half
        before = index - 2 * h - 1  # last level centre not touched by the pulse
        base = self.level_at(before)
        if base is None:
            base = self.level_at(index)
        earlier = self.level_at(before - self.trend_n)
        trend = fall = 0.0
        if base is not None and earlier is not None:  # rising trend before the onset
            trend = max(0.0, (base - earlier) / self.trend_n)
        measured = trend
        if emit is not None and self.settings.trend_past_pulse:
            trend = trend_past_pulse(self._trends, index, emit, before - self.trend_n, trend)
        long = None
        if emit is not None and base is not None:
            long = self._long_trend(index, emit, base)
        long_measured = math.nan if long is None else long  # (none: min keeps the own)
        if long is not None and emit is not None and self.settings.long_past_pulse:
            long = trend_past_pulse(self._longs, index, emit, before - self.trend_n, long)
        recent = self.level_at(before - self.fall_n)
        floor = self._level_floor(before)
        if base is not None and recent is not None and floor is not None:
            # an earlier pulse's tail falling: its slope, and how far it can still fall
            fall = max(0.0, (recent - base) / self.fall_n)
            fall = min(fall, max(0.0, base - floor) / self.fall_credit)
        fine_noise = self.noise.of(0, index // self.block)
        white = 0.0 if fine_noise is None else fine_noise / hinge_gain(self.noise.widths[0])
        noise = max(NOISE_FLOOR_N, white) / math.sqrt(2 * h + 1)
        watch = Watch(
            cid,
            index,
            0.0 if base is None else base,
            trend,
            noise,
            fall=fall,
            next_k=index,
            history=np.empty(self.watch + 1),  # samples index .. index + watch
            held=np.empty((len(WATCH_ROWS), self.step_hold + 1)),  # ... to index + step_hold
        )
        watch.scanned = tuple(
            Watched(
                onset=watch.index, base=watch.base, fall=watch.fall, trend=watch.trend,
                noise=watch.noise, hold=watch.index + self.step_hold, history=watch.history,
                held=watch.held,
            )
        )  # fmt: skip
        if emit is not None and base is not None:
            watch.slope = self._level_slope(before)
            watch.room = self._tail_room(index, emit, base)
            watch.long = 0.0 if long is None else long
            self._bases.append((index, emit, base))
            self._trends.append((index, emit, measured))
            self._longs.append((index, emit, long_measured))
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

    def told_height(self, watch: Watch, emit: int) -> float:
        """A watch's height (running peak above its base) by the level sample whose verdict
        was told at `emit`, not by the last sample scanned (that one depends on how the
        samples came in)."""
        told = min(emit - self.level_half - watch.index, watch.hist_n - 1)
        return float(watch.history[told]) if told >= 0 else 0.0

    def check(self, events: list[ContactEvent]) -> list[PulseCheck]:
        if not (events or self._watches or self._stepped):
            return []  # nothing to start or watch (most blocks): what the loops below give
        checks: list[PulseCheck] = []
        for ev in events:
            watch = self.start(ev.id, ev.index, ev.emit_index)
            if watch is not None:
                self._watches.append(watch)
        still = []
        for watch in self._watches:
            done = self.advance(watch)
            if done is None:
                still.append(watch)
            else:
                if done.pulse is True and watch.hist_n:
                    height = self.told_height(watch, done.emit_index)
                    self.ledger.heights.append((done.emit_index, height))
                    self.noise.mark_busy(watch.index, done.emit_index, height)
                    white = self.noise.white(watch.index // self.block)
                    if white is not None:
                        snr = height / max(white[0], NOISE_FLOOR_N)
                        done = done._replace(height_snr=snr)
                checks.append(done)
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

    def _revise(self, watch: Watch) -> PulseCheck | None:
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
            later = [e for n, e in self.ledger.onsets if watch.index + 2 < n <= limit]
            if later:
                watch.next_k = limit + self.lag + 1  # done
                return PulseCheck(watch.id, max(watch.fell_at + h, min(later)), True)
        return None

    def _revising(self, watch: Watch) -> bool:
        """Still watched: the fall not yet looked for to the end, or a contact within the
        window not yet decided."""
        limit = watch.index + self.revise
        if watch.fell_at < 0:
            return watch.next_k <= limit
        return watch.next_k <= limit + self.lag and self.samples.n <= limit + self.lag

    def advance(self, watch: Watch, small: bool = False) -> PulseCheck | None:
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
            hold = watch.index + self.step_hold
            first = watch.hist_n  # the new samples' running peaks: history[first:]
            # (where the look starts: a `kernels.detector.ScanFrom`, as a plain tuple)
            at = (watch.next_k, watch.peak, first, watch.held_n)
            hit, fell = watch_scan(level, watch.scanned, at, self._scan_settings)
            watch.hist_n += len(level)
            if watch.next_k <= hold:
                watch.held_n += min(len(level), hold - watch.next_k + 1)
            watch.fell = watch.fell or fell
            if not small and self._sure_step(watch, end, hit):
                sure = watch.index + self.sure_hold
                watch.held_n = self.sure_hold + 1  # what the verdict saw (chunking)
                # (no trend_on: half the sure hold is too short to tell it)
                return PulseCheck(watch.id, sure + h, False, None, sure=True)
            if hit >= 0 and watch.next_k + hit < hold:
                if not (small or not self.settings.pulse_under_step) and (
                    watch.under or self._under_pulse(watch, watch.next_k + hit)
                ):
                    watch.under = True  # (judged at the hold)
                else:
                    return PulseCheck(watch.id, watch.next_k + hit + h, True)
            if watch.next_k <= hold <= end and not self.samples.clipped(watch.index, hold):
                if self._is_small_step(watch) if small else self._is_step(watch):
                    return PulseCheck(watch.id, hold + h, False, self._trend_on(watch))
                fell = watch.fell or (not small and self._fell_on_slip_trend(watch))
                under = watch.under or (fell and self.settings.pulse_under_step and not small)
                if under and self._under_step(watch):
                    return PulseCheck(watch.id, hold + h, False, None, under=True)
                if fell or watch.under:
                    return PulseCheck(watch.id, hold + h, True)
            if hit >= 0 and not (watch.under and end < hold):
                return PulseCheck(watch.id, watch.next_k + hit + h, True)
            early = min(len(level), watch.index + self.watch // 4 - watch.next_k + 1)
            if early > 0:
                watch.early = max(watch.early, float(watch.history[first + early - 1]))
            watch.peak = float(watch.history[watch.hist_n - 1])
            watch.next_k = end + 1
        if watch.next_k > watch.index + self.watch:
            flat = watch.peak <= 1.5 * watch.early
            return PulseCheck(watch.id, watch.index + self.watch + h, False if flat else None)
        return None

    def _sure_step(self, watch: Watch, end: int, hit: int) -> bool:
        """At `sure_hold` after the onset, in the level samples next_k .. end just
        examined (the first fall like a pulse at offset `hit`, -1: none): not fallen
        back before, no contact since, not clipped, and a sharp, flat, tall step
        (`sharp_flat_step`) - told a step then, not at the hold."""
        sure = watch.index + self.sure_hold
        if not self.sure_hold or not watch.next_k <= sure <= end:
            return False
        if hit >= 0 and watch.next_k + hit <= sure:
            return False
        if self._train_follows(watch, sure) or self.samples.clipped(watch.index, sure):
            return False
        detrended = watch.detrended[: self.sure_hold + 1]
        return sharp_flat_step(
            detrended, watch.noise, self.sure_rise, self.sure_snr, self.sure_drop
        )

    def _under_course(self, watch: Watch) -> tuple[float, ...]:
        """The course of the pulse of the latest earlier kink contact (decided by this
        one's decision, onset within `pulse_under.MAX_GAP_S`) fitted over the level from
        its onset to this one's base (`pulse_under.fit`), once per watch: (its onset,
        height, rise, the course's value at this base); () when there is none (no such
        contact, level or fit)."""
        if watch.course is not None:
            return watch.course
        watch.course = ()
        own = [e for n, e, _ in self._bases if n == watch.index]
        earlier = [
            (n, b) for n, e, b in self._bases if n < watch.index - 2 and own and e <= own[-1]
        ]
        if not earlier or watch.index - earlier[-1][0] > self.under_gap:
            return watch.course
        n, base = earlier[-1]
        h = self.level_half
        before = watch.index - 2 * h - 1
        i0, i1 = n - h + h - self._level_start, before + h - self._level_start + 1
        if i0 < 0 or i1 > len(self._level):
            return watch.course
        centres = np.arange(n - h, before + 1)
        course = pulse_under.fit(self._level[i0:i1] - base, centres - n, h, self.fs_hz)
        if course is not None:
            at = course.height * float(
                pulse_under.smoothed(np.array([before - n]), course.rise, h)[0]
            )
            watch.course = (float(n), course.height, course.rise, at)
        return watch.course

    def _under_residual(
        self, watch: Watch, upto: int, since: int | None = None
    ) -> np.ndarray | None:
        """The level from `since` (default: the onset) to sample `upto` less the base and
        the earlier pulse's course carried on from it (`_under_course`), as `plain`; None:
        no course, or no level."""
        course = self._under_course(watch)
        if not course:
            return None
        n, height, rise, at = course
        h = self.level_half
        since = watch.index if since is None else since
        i0, i1 = since + h - self._level_start, upto + h - self._level_start + 1
        if i0 < 0 or i1 > len(self._level) or i1 <= i0:
            return None
        k = np.arange(since, upto + 1)
        model = height * pulse_under.smoothed(k - n, rise, h) - at
        return self._level[i0:i1] - watch.base - model

    def _under_pulse(self, watch: Watch, upto: int) -> bool:
        """Fallen back like a pulse by `upto` (before the hold), but not with the earlier
        pulse's course out (`pulse_under`): a step on that pulse's rise may be - judged at
        the hold."""
        res = self._under_residual(watch, upto)
        if res is None or not len(res):
            return False
        top = float(res.max())
        return top >= 6.0 * watch.noise and float(res[-1]) > (1.0 - self.drop_fraction) * top

    def _under_step(self, watch: Watch) -> bool:
        """At the hold: with the earlier pulse's course out, a sharp rise that stays
        (`_is_step`'s test on the level) and no pulse train after it."""
        if self._train_follows(watch):
            return False
        res = self._under_residual(watch, watch.index + self.step_hold)
        if res is None or not len(res):
            return False
        top = float(res.max())
        if top < 6.0 * watch.noise:
            return False
        rise = int(np.argmax(res >= 0.8 * top))
        keep = (1.0 - self.drop_fraction) * top
        return rise <= self.step_rise and float(res[rise:].min()) >= keep

    def _level_floor(self, before: int) -> float | None:
        """The lowest level over the trend window up to `before` (under an earlier pulse)."""
        i1 = before + self.level_half - self._level_start + 1
        i0 = max(0, i1 - self.trend_n)
        if i1 <= i0:
            return None
        return float(self._level[i0:i1].min())

    def _tail_credit(self, watch: Watch, k: np.ndarray) -> np.ndarray:
        """How far an earlier pulse's tail under the onset falls by k (>= 0): its slope
        just before the onset, followed for fall_credit and no further, and never below
        the level before that pulse (a tail flattens; a new ridge pulse replaces it -
        thesis ch. 5.3.1 - and still falls back)."""
        return watch.fall * np.minimum(k - watch.index, self.fall_credit)

    def _is_step(self, watch: Watch) -> bool:
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

    def _rose_on(self, watch: Watch) -> bool:
        """A sharp rise after which the level never fell back from its running top (by 3
        noise units and 5 % of the rise) by the hold: it rose on, not back - the stop of a
        slip while the grip rises (the reflex), which the tests above, with the trend
        taken out, see as a slow rise. A pulse falls back from its top. Only where the
        rise is resolved (step_rise of 4 samples or more: 200 Hz and up): at 100 Hz a
        ridge pulse's rise is a sample or two, and its fall is not told from noise."""
        level, r, noise = watch.plain, self.step_rise, watch.noise
        if r < 4 or len(level) < 4 * r + 2 or self._train_follows(watch):
            return False
        first = float(mean(level[r : 2 * r + 1]))
        if first < 6.0 * noise or int(np.argmax(level >= 0.8 * first)) > r:
            return False
        after = level[r:]
        fell = float((np.maximum.accumulate(after) - after).max())
        if fell > 3.0 * noise + 0.05 * first:
            return False
        # a step, not a ramp's start: the jump is well above what the level rises after it
        # over as long (a slip's trend resuming after a plateau is a kink onto a ramp)
        rate = (float(mean(level[-r:])) - first) / (len(level) - 2 * r)
        return first >= 2.5 * max(rate, 0.0) * (1.5 * r)

    def _fell_on_slip_trend(self, watch: Watch) -> bool:
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

    def _fell_in_slip(self, watch: Watch) -> bool:
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
        end = float(mean(level[-min(len(level), 2 * self.level_half + 1) :]))
        return float(level.max()) - end >= self.slip_fall * watch.noise

    def _tail_step(self, watch: Watch) -> bool:
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
        # the tail goes on falling between the base and the onset (the base is the level
        # 2 level_half + 1 samples before it): the step rises from the trough it reached
        low = min(0.0, float(level[: r + 1].min())) if self.settings.tail_trough else 0.0
        if first - low < 6.0 * noise or int(np.argmax(level - low >= 0.8 * (first - low))) > r:
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

    def _stayed_up(self, watch: Watch, stays: Callable[[np.ndarray], bool]) -> bool:
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

    def _train_follows(self, watch: Watch, hold: int | None = None) -> bool:
        """Did more contacts come before the hold (or `hold`)? Pulses after short spacings
        start on the one before (thesis ch. 5.3.1): a train of them keeps the level up like
        a step, and a slip that stopped makes no more contacts. Only contacts decided by
        the verdict's sample count (chunking cannot change the verdict)."""
        hold = watch.index + self.step_hold if hold is None else hold
        told = hold + self.level_half
        return any(watch.index + 2 < n <= hold and e <= told for n, e in self.ledger.onsets)

    def _trend_on(self, watch: Watch) -> bool | None:
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

    def _is_small_step(self, watch: Watch) -> bool:
        """A probe (a small step the kink bank missed) at step_hold after the onset: rose
        sharply (no higher over the next 2 rises of its scale than over the rise after it)
        and has not fallen back by drop_fraction since (means, not extremes: a small step
        is a few noise units high) - with the rising trend
        taken out (a grip step while the object slips on), or on the level itself when
        it is flat by then (a slip that stops ends the trend: the object no longer
        covers more of the sensor). A ridge pulse on a rising trend falls back from it,
        and the trend goes on."""

        def stays(levels: np.ndarray) -> bool:
            n = watch.rise  # (a probe's: set from its scale)
            first = float(mean(levels[n : 2 * n + 1]))  # just after a sharp rise
            if first < 6.0 * watch.noise:
                return False
            later = float(mean(levels[2 * n : 4 * n + 1]))
            if later > 1.15 * first + 2.0 * watch.noise:
                return False  # still rising: a slow pulse
            end = float(mean(levels[-max(2, len(levels) // 4) :]))
            low = float(levels[n:].min())
            keep = 1.0 - self.drop_fraction
            if end > (2.0 - keep) * first + 2.0 * watch.noise:
                return False  # went on rising: a ramp
            return end >= keep * first and low >= (keep - 0.1) * first - 2.0 * watch.noise

        return self._stayed_up(watch, stays)

"""The step probe: small steps the kink bank misses (a stop's step in heavy noise).

A difference of the means over +-w samples after and before each centre, less the mean of
the same difference 2 w earlier and later (a ramp - the object covering more of the
sensor - is no step), at a short and a long window; local maxima above `threshold` white
noise units are watched like contacts (`PulseWatcher`) and told contacts (their own id
series, `STEP_IDS`) only when judged a step at the hold, and only where the kink bank
has no contact of its own. One kernel crossing steps every scale
(`kernels.detector.scales_fast`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from grasplink.decoding.detector.events import ContactEvent, Ledger, PulseCheck
from grasplink.decoding.detector.noise_floor import NOISE_FLOOR_N, NoiseFloor
from grasplink.decoding.detector.series import BankInt, BankRows, Found, Samples, Series
from grasplink.decoding.detector.watch import PulseWatcher, Watch
from grasplink.decoding.filters import SosFilter
from grasplink.decoding.kernels.common import PROBE_IDS
from grasplink.decoding.kernels.detector import scales_fast, step_scale
from grasplink.decoding.kernels.layout import S_NEXT, S_SIZE, S_START, S_W, SCALE_COLUMNS

STEP_IDS = PROBE_IDS  # ids of the small steps found by the step probe (their own series)


@dataclass(frozen=True)
class StepProbeSettings:
    """The step probe's windows (s) and threshold (white-noise units)."""

    window_s: float = 0.02
    # a stop's step in heavy noise (10 dB of the ridge pulses) is a few noise units of the
    # short window's difference, more of the long's
    long_window_s: float = 0.04
    threshold: float = 6.0


class _ScaleBank:
    """The step probe's scales side by side (a row per scale), for one kernel crossing
    (`kernels.detector.scales_fast`): their int state (`SCALE_COLUMNS`), the difference
    filters' taps and state, their stores, and the kernel's outputs."""

    def __init__(self, widths: list[int], block: int):
        S, wide = len(widths), max(widths)
        self.ints = np.zeros((S, len(SCALE_COLUMNS)), np.int64)
        self.ints[:, S_W] = widths
        self.ints[:, S_START] = [-w for w in widths]  # (output m is centre m - w)
        self.taps = np.zeros((S, 2 * wide))
        self.state = np.zeros((S, 2 * wide - 1))
        self.found = np.zeros((S, 2 * block), np.int64)
        self.found_adj = np.zeros((S, 2 * block))
        self.counts = np.zeros(S, np.int64)
        self.first = np.zeros(S, np.int64)
        self.stores: tuple[np.ndarray, ...] = ()  # the scales' `store.data`


@dataclass
class _StepScale:
    """One scale of the step probe: a difference of means over +-w samples."""

    w: int
    rise: int  # a step's rise is judged over this many samples (`PulseWatcher._is_small_step`)
    fir: SosFilter
    bank: _ScaleBank  # where its numbers live: row `index`
    index: int
    store: Series = field(init=False)  # differences of means by centre, from `start`
    start = BankInt(S_START)  # centre of d[0] (output m is centre m - w)
    next = BankInt(S_NEXT)  # next centre to test

    def __post_init__(self) -> None:
        self.store = BankRows(self.bank.ints, self.index, S_SIZE, 256)

    @property
    def d(self) -> np.ndarray:
        """The differences held (a view: valid until the next append or cut)."""
        return self.store.view()

    @property
    def taps(self) -> np.ndarray:
        """The difference filter's taps (from the first sample on, `StepProbe.settle`) ..."""
        return self.bank.taps[self.index, : 2 * self.w]

    @property
    def state(self) -> np.ndarray:
        """... and its carried state (in place)."""
        return self.bank.state[self.index, : 2 * self.w - 1]


class StepProbe:
    """The step probe's scales (see the module doc): samples in (`run`), the steps judged
    out (`events`)."""

    def __init__(
        self,
        fs_hz: float,
        settings: StepProbeSettings,
        watcher: PulseWatcher,
        noise: NoiseFloor,
        samples: Samples,
        ledger: Ledger,
        lag: int,
    ):
        self.fs_hz = fs_hz
        self.settings = settings
        self.noise, self.watcher, self.samples, self.ledger = noise, watcher, samples, ledger
        self.block = noise.block
        self.lag = lag  # the kink bank's decision lag (samples)
        w = max(2, round(settings.window_s * fs_hz))
        self.step_threshold = float(settings.threshold)
        self.widths = sorted({w, max(w + 1, round(settings.long_window_s * fs_hz))})
        self.bank = _ScaleBank(self.widths, self.block)
        self.scales = [
            _StepScale(
                v,
                max(1, round(0.6 * v)),
                SosFilter.fir(np.concatenate([np.full(v, 1.0 / v), np.full(v, -1.0 / v)])),
                self.bank,
                si,
            )
            for si, v in enumerate(self.widths)
        ]
        self.bank.stores = tuple(sc.store.data for sc in self.scales)
        self.found = Found(2 * self.block)  # `step_scale`'s found offsets and values
        self.probes: list[tuple[Watch, float, int]] = []  # step candidates judged (z, w)
        # probes judged steps: (emit, w, index, t, z, trend_on)
        self.confirmed: list[tuple[int, int, int, float, float, bool | None]] = []
        self.onsets: deque[tuple[int, int, int]] = deque(maxlen=32)  # told: (index, emit, w)
        self._next_id = STEP_IDS

    def settle(self, first: float) -> None:
        """The difference filters' taps and states, settled on the first sample (as if it
        had been held before: differences 0), for the kernels that run them in place."""
        for sc in self.scales:
            taps, state = sc.fir.fir_state(first)
            sc.taps[:], sc.state[:] = taps, state  # (the bank's rows: run in place from now)

    def room(self, keep: int) -> int:
        """Samples to come before `trim(keep)` would cut (a difference each per scale)."""
        return 2 * keep - max(self.bank.ints[:, S_SIZE].tolist(), default=0)

    def trim(self, keep: int) -> None:
        """Keep the last `keep` differences of each scale once twice that many are held."""
        if max(self.bank.ints[:, S_SIZE].tolist(), default=0) <= 2 * keep:
            return  # (every block: one read of the sizes, not a property each)
        for sc in self.scales:
            if sc.store.size > 2 * keep:
                cut = sc.store.size - keep
                sc.store.keep_last(keep)
                sc.start += cut

    def run(self, x: np.ndarray) -> None:
        """Step candidates: local maxima (over +-step_w) of the difference of the means after
        and before, less the mean of the same difference 2 step_w earlier and later (a ramp
        - the object covering more of the sensor - is no step), above step_threshold noise
        units; each is watched like a contact and kept only if judged a step at the hold
        (`_step_events`)."""
        bank = self.bank
        if not scales_fast(
            x, bank.ints, bank.taps, bank.state, bank.stores, bank.found, bank.found_adj,
            bank.counts, bank.first,
        ):  # fmt: skip
            return
        for si, told in enumerate(bank.counts.tolist()):
            sc = self.scales[si]
            if told < 0:
                self._run_scale(sc, x)
            elif told:
                found, adj = bank.found[si, :told], bank.found_adj[si, :told]
                self._probe(sc, int(bank.first[si]), found, adj)
        bank.stores = tuple(sc.store.data for sc in self.scales)  # (any grown)

    def _run_scale(self, sc: _StepScale, x: np.ndarray) -> None:
        """One scale on x, where `scales_fast` had no room (its store grows here)."""
        w = sc.w
        at = sc.store.size
        sc.store.extend(len(x))
        last = sc.start + sc.store.size - 1  # last centre with a difference
        lo = max(sc.next, sc.start + 3 * w, 3 * w)
        hi = last - 3 * w
        i0, i1 = lo - sc.start - w, hi - sc.start + w  # adjusted over +-w
        if hi >= lo:
            sc.next = hi + 1
        else:
            i0, i1 = 0, -1  # nothing to test yet
        # the difference filter, and the local maxima of the difference less the ramp
        found = self.found.room(i1 - i0 + 1)
        told = step_scale(
            x, sc.taps, sc.state, sc.store.data, at, i0, i1, w, found, self.found.values
        )
        if told:
            self._probe(sc, i0, found[:told], self.found.values[:told])

    def _probe(self, sc: _StepScale, i0: int, found: np.ndarray, adj: np.ndarray) -> None:
        """The maxima a scale found (offsets from i0 into its differences, and their adj
        values) strong enough, watched as step candidates."""
        w = sc.w
        for j, a in zip(found.tolist(), adj.tolist(), strict=True):
            c = i0 + j + sc.start
            white = self.noise.white(c // self.block)
            if white is None:
                continue
            z = a / (max(white[0], NOISE_FLOOR_N) * math.sqrt(3.0 / w))
            if z < self.step_threshold:
                continue
            watch = self.watcher.start(-1, c + 1)
            if watch is not None:
                watch.rise = sc.rise
                self.probes.append((watch, z, w))

    def events(self) -> tuple[list[ContactEvent], list[PulseCheck]]:
        """Probes judged steps, told once every contact near them would have been decided:
        a contact and its verdict - unless the kink bank found that onset itself."""
        if not (self.probes or self.confirmed):
            return [], []  # no probe out (most blocks): what the loops below give
        still = []
        for watch, z, w in self.probes:
            done = self.watcher.advance(watch, small=True)
            if done is None and watch.next_k <= watch.index + self.watcher.step_hold:
                still.append((watch, z, w))
            elif (
                done is not None
                and done.pulse is False
                and done.emit_index
                < (watch.index + self.watcher.step_hold + self.watcher.level_half + 1)
            ):
                emit = max(done.emit_index, watch.index + self.lag + w)
                t = self.samples.time(watch.index, 0.0)
                self.confirmed.append((emit, w, watch.index, t, z, done.trend_on))
        self.probes = still
        events, checks = [], []
        keep = []
        for emit, w, index, t, z, trend_on in sorted(self.confirmed):
            if emit >= self.samples.n:
                keep.append((emit, w, index, t, z, trend_on))
                continue
            # the kink bank has it: a probe is timed mid-rise, up to a step window after
            # the onset the kink bank placed (a slow pulse rises for longer); or a probe
            # of the other scale told it first
            if any(
                -w - 2 <= index - n <= 2 * w + 2 for n, e in self.ledger.onsets if e <= emit
            ) or any(abs(index - n) <= w + v + 2 for n, _, v in self.onsets):
                continue
            self.onsets.append((index, emit, w))
            sid = self._next_id  # (the step probe's own series: `STEP_IDS`)
            self._next_id += 1
            sigma = (0.25 * w + 0.3) / self.fs_hz
            events.append(ContactEvent(sid, t, index, emit, z, 0.0, w / self.fs_hz, sigma))
            checks.append(PulseCheck(sid, emit, False, trend_on))
        self.confirmed = keep
        return events, checks

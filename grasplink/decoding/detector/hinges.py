"""The hinge (kink) bank: the onsets of ridge pulses as jumps of the force's slope.

A bank of *hinge* filters, one per scale w (5, 10, 20, 40, 80 ms by default): h_w(n) =
slope of x over [n, n + w] minus slope over [n - w, n] (least-squares slopes), i.e. the
slope jump at n. A pure kink gives the same h at every scale while noise falls as w^-1.5,
so the best scale is about half the rise: fast pulses show on the short scales, slow
pulses (weak slope, long rise) on the long ones. Each scale is normalised by its noise
(`noise_floor`). A contact candidate is a local maximum of z_w = h_w / noise_w over +-w
above `threshold`, after which the force rises (the end of a grip release is a kink too,
but flat after) - or, with no rise, one on a pulse's falling tail (`tail_kinks`: a ridge
whose pulse starts on the previous one's tail; the kernels pass such candidates at the
lower `TailKinkSettings.floor` and `_candidates` judges them); its time is refined coarse
to fine (the finest scale that still sees it places it) and to a fraction of a sample by
a parabola; a candidate within its own reach of an earlier contact is that contact again
(long scales decide later).

The per-block numeric path (filters, hinges, normalising, local maxima) runs compiled,
one crossing for every channel (`kernels.detector.channels_fast`).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from grasplink.decoding.detector.arrival_tail import on_first_load
from grasplink.decoding.detector.events import ContactEvent, Ledger
from grasplink.decoding.detector.held_corners import held_corner
from grasplink.decoding.detector.noise_floor import MEDIAN_TO_STD, NOISE_FLOOR_N, NoiseFloor
from grasplink.decoding.detector.series import (
    BankInt,
    BankRows,
    Found,
    Samples,
    Series,
    mean,
)
from grasplink.decoding.detector.tail_kinks import TailKinkSettings, tail_kink
from grasplink.decoding.detector.tail_onsets import tail_placed
from grasplink.decoding.filters import SosFilter, lattice_median
from grasplink.decoding.kernels.detector import (
    BLOCK_DONE,
    NOT_TAKEN,
    TAKEN,
    Channels,
    ChannelSettings,
    ChannelsTold,
    channel_fast,
    channel_hinge,
    channels_fast,
    hinge_maxima,
    lattice_median_of,
)
from grasplink.decoding.kernels.layout import (
    CH_ABS_N,
    CH_HELD,
    CH_NEXT_N,
    CH_NEXT_TEST,
    CH_NOISE_BLOCK,
    CH_SIZE,
    CH_W,
    CH_WAIT_N,
    CH_Z_START,
    CHANNEL_COLUMNS,
    CHANNEL_ROWS,
    ROW_AFTER,
    ROW_HINGE,
    ROW_READY,
    ROW_Z,
    WAIT_AFTER,
    WAIT_HINGE,
    WAIT_ROWS,
)

DEFAULT_SCALES_S = (0.005, 0.01, 0.02, 0.04, 0.08)
_NONE_FOUND = np.empty(0, np.int64)  # `_maxima` with no centre to test
_NONE_FOUND.flags.writeable = False


@dataclass(frozen=True)
class HingeSettings:
    """The kink bank's scales and thresholds (z: noise units)."""

    scales_s: tuple[float, ...] = DEFAULT_SCALES_S
    threshold: float = 4.5  # a candidate's z
    refine_z: float = 3.0  # a finer scale places a candidate where its z is this or more
    merge_widths: float = 2.0  # a candidate this many of its widths from a contact is it
    # a contact makes the force rise after it, by this share of its hinge (`hinge_maxima`):
    # on the scales under 30 ms, and on the longer ones (the slow bend at the end of a fast
    # pulse's decay is no contact)
    rise_fraction: float = 0.1
    coarse_rise_fraction: float = 0.3
    # ... unless a kink on a pulse's falling tail (`tail_kinks`: a ridge after a short spacing)
    tails: TailKinkSettings = field(default_factory=TailKinkSettings)


def hinge_widths(fs_hz: float, settings: HingeSettings) -> list[int]:
    """The scales' widths in samples (distinct, finest first)."""
    return sorted({max(1, round(s * fs_hz)) for s in settings.scales_s})


def decision_lag(widths: list[int]) -> int:
    """A contact is decided at most this many samples late (its z known over +-w)."""
    return 2 * max(widths)


class _ChannelBank:
    """The hinge channels' numbers side by side (a row per channel), so that one kernel
    crossing steps them all (`kernels.detector.channels_fast`): their int state
    (`CHANNEL_COLUMNS`), the noise of the block they are in, the slope filters' taps and
    carried state, the slopes held, the block's |hinge|, the centres waiting for a noise
    (`wait`: room for `waits` of them), and the kernel's outputs; the kernel takes them
    in two bundles built here once (`numbers`, `told`). A `_Channel` reads and writes its
    own row through properties (no views are kept: a deep copy of the detector stays one
    piece)."""

    def __init__(self, widths: list[int], needed: list[float], block: int, waits: int):
        C, wide = len(widths), max(widths)
        self.ints = np.zeros((C, len(CHANNEL_COLUMNS)), np.int64)
        self.ints[:, CH_W] = widths
        self.ints[:, CH_NOISE_BLOCK] = -1
        self.noise = np.zeros(C)
        self.needed = np.array(needed, dtype=np.float64)
        self.taps = np.zeros((C, wide + 1))
        self.state = np.zeros((C, wide))
        self.after = np.zeros((C, wide))
        self.block_abs = np.zeros((C, block))
        self.wait = np.zeros((C, len(WAIT_ROWS), waits))
        self.found = np.zeros((C, 2 * block), np.int64)
        self.counts = np.zeros(C, np.int64)
        self.status = np.zeros(C, np.int64)
        self.taken = np.zeros(C, np.int64)
        self.rows: tuple[np.ndarray, ...] = ()  # the channels' rows storage (`BankRows.data`)
        # `channels_fast`'s bundles (plain tuples: `kernels.detector.Channels`, `ChannelsTold`)
        self.numbers = tuple(
            Channels(
                ints=self.ints, noise=self.noise, needed=self.needed, taps=self.taps,
                state=self.state, after=self.after, block_abs=self.block_abs, wait=self.wait,
            )
        )  # fmt: skip
        self.told = tuple(
            ChannelsTold(found=self.found, counts=self.counts, status=self.status, taken=self.taken)
        )


@dataclass
class _Channel:
    width: int  # w, samples
    slope: SosFilter  # LS slope over the last w + 1 samples (FIR)
    needed: float  # the rise after a candidate, per unit of its hinge (`hinge_maxima`)
    rise: float  # ... that the rise check asks (`needed` lower: tail kinks, `_candidates`)
    bank: _ChannelBank  # where its numbers live: row `index`
    index: int
    # rows z, hinge (N/sample), slope after, sample that told the noise (known at), by centre
    # from z_start; z, zh, za, zready are views of their whole storage (refreshed when it
    # grows): the first rows.size entries are held
    rows: Series = field(init=False)
    z: np.ndarray = field(default_factory=lambda: np.zeros(0))
    zh: np.ndarray = field(default_factory=lambda: np.zeros(0))
    za: np.ndarray = field(default_factory=lambda: np.zeros(0))
    zready: np.ndarray = field(default_factory=lambda: np.zeros(0))
    # slopes not yet paired: the first `held` of `after` (w entries, filled in place)
    held = BankInt(CH_HELD)
    next_n = BankInt(CH_NEXT_N)  # next hinge centre to compute
    abs_n = BankInt(CH_ABS_N)  # |h| of the block being filled (`block_abs`), so far
    next_test = BankInt(CH_NEXT_TEST)  # next centre to test for a local maximum
    z_start = BankInt(CH_Z_START)  # global centre index of z[0]
    # centres awaiting their block's noise: `waiting` of them after the last row, their
    # hinge and slope after in `wait` (once some wait, every later one does: `_release`)
    waiting = BankInt(CH_WAIT_N)

    def __post_init__(self) -> None:
        self.rows = BankRows(self.bank.ints, self.index, CH_SIZE, 256, rows=len(CHANNEL_ROWS))

    @property
    def taps(self) -> np.ndarray:
        """The slope filter's taps (set from the first sample on, `HingeBank.settle`)."""
        return self.bank.taps[self.index, : self.width + 1]

    @property
    def state(self) -> np.ndarray:
        """... and its carried state (in place)."""
        return self.bank.state[self.index, : self.width]

    @property
    def after(self) -> np.ndarray:
        return self.bank.after[self.index, : self.width]

    @property
    def block_abs(self) -> np.ndarray:
        return self.bank.block_abs[self.index]

    @property
    def wait(self) -> np.ndarray:
        """The waiting centres' rows (`WAIT_ROWS`; the first `waiting` entries held)."""
        return self.bank.wait[self.index]

    def refresh_views(self) -> None:
        """z, zh, za, zready as views of the rows' storage, after an append that grew it
        (or the first one); an append that fits keeps them."""
        data = self.rows.data
        if self.z.base is not data:
            self.z, self.zh, self.za = data[ROW_Z], data[ROW_HINGE], data[ROW_AFTER]
            self.zready = data[ROW_READY]


def slope_taps(width: int) -> np.ndarray:
    """FIR taps whose output at m is the LS slope of x[m - w .. m] (N/sample)."""
    k = np.arange(width + 1, dtype=np.float64) - width / 2.0
    kernel = k / float(np.sum(k * k))  # applied to x[n + 0 .. n + w]
    return kernel[::-1].copy()


class HingeBank:
    """The hinge channels, finest first (see the module doc): samples in, contact
    candidates out (`run`), merged into contacts (`merge`)."""

    def __init__(
        self,
        fs_hz: float,
        settings: HingeSettings,
        noise: NoiseFloor,
        samples: Samples,
        ledger: Ledger,
    ):
        self.fs_hz = fs_hz
        self.settings = settings
        self.noise, self.samples, self.ledger = noise, samples, ledger
        self.block = noise.block
        widths = hinge_widths(fs_hz, settings)
        self.threshold = float(settings.threshold)
        self.refine_z = float(settings.refine_z)
        self.merge_widths = float(settings.merge_widths)
        rise = [
            settings.rise_fraction if w / fs_hz < 0.03 else settings.coarse_rise_fraction
            for w in widths
        ]
        # the kernels pass the tail kinks' candidates too (`_candidates` judges them)
        self.tails = settings.tails
        floor = self.tails.floor if self.tails.residual_z > 0.0 else math.inf
        needed = [min(r, floor) for r in rise]
        # centres wait for a noise at most noise_blocks blocks past their own (`_release`):
        # room for those, the block being filled and one more
        waits = (noise.noise_blocks + 3) * self.block
        self.bank = _ChannelBank(widths, needed, self.block, waits)
        self.constants = tuple(ChannelSettings(block=self.block, threshold=self.threshold))
        self.channels = [
            _Channel(w, SosFilter.fir(slope_taps(w)), needed[ci], rise[ci], self.bank, ci)
            for ci, w in enumerate(widths)
        ]
        self.bank.rows = tuple(ch.rows.data for ch in self.channels)
        self.lag = decision_lag(widths)
        self.found = Found(2 * self.block)  # the kernels' found indices
        self._recent: deque[float] = deque(maxlen=16)  # times of the contacts emitted

    def settle(self, first: float) -> None:
        """The slope filters' taps and states, settled on the first sample (as if it had
        been held before: slopes 0), for the kernels that run them in place."""
        for ch in self.channels:
            taps, state = ch.slope.fir_state(first)
            ch.taps[:], ch.state[:] = taps, state  # (the bank's rows: run in place from now)

    def room(self, keep: int) -> int:
        """Samples to come before `trim(keep)` would cut: a channel gains at most a centre
        per sample, as a row or waiting for a noise (rows once `_release`d)."""
        held = self.bank.ints[:, CH_SIZE] + self.bank.ints[:, CH_WAIT_N]
        return 2 * keep - max(held.tolist(), default=0)

    def trim(self, keep: int) -> None:
        """Keep the last `keep` rows of each channel once twice that many are held."""
        if max(self.bank.ints[:, CH_SIZE].tolist(), default=0) <= 2 * keep:
            return  # (every block: one read of the sizes, not a property each)
        for ch in self.channels:
            if ch.rows.size > 2 * keep:
                cut = ch.rows.size - keep
                ch.rows.keep_last(keep)  # (in place: the views stay)
                ch.z_start += cut

    def run(self, x: np.ndarray, candidates: list) -> None:
        """Every hinge channel on x. Usually one kernel steps them all (`channels_fast`:
        a CAN frame's few centres in a block whose noise each channel knows; those past
        the block's end are left here); a channel it leaves (a new block, blocks waiting
        for a noise, no room) takes the Python path (`_run_channel`), and so do the
        centres past a block's end, after that block's noise. In channel order, as the
        channels one after the other: a channel reads only finer ones."""
        bank = self.bank
        if not channels_fast(x, bank.numbers, bank.rows, self.constants, bank.told):
            return
        said, taken = bank.status.tolist(), bank.taken.tolist()
        for ci, told in enumerate(bank.counts.tolist()):
            if said[ci] == TAKEN and not told:
                continue
            ch = self.channels[ci]
            if said[ci] == NOT_TAKEN:
                self._run_channel(ci, ch, x, candidates)
            else:
                if said[ci] == BLOCK_DONE:
                    n = ch.next_n
                    waited = ch.waiting
                    self._block_done(ch, (n - 1) // self.block, n)
                    if taken[ci] < len(x):  # the next block's first centres
                        self._run_channel(ci, ch, x[taken[ci] :], candidates)
                    elif waited:  # centres it released: tested now, as `_run_channel` would
                        found = self._maxima(ch)
                        if len(found):
                            self._candidates(ci, ch, found, candidates)
                if told:  # (after the rows of the rest: a candidate's timing reads them)
                    self._candidates(ci, ch, bank.found[ci, :told], candidates)
            self._arm(ci, ch)
        bank.rows = tuple(ch.rows.data for ch in self.channels)  # (any grown)

    def _arm(self, ci: int, ch: _Channel) -> None:
        """Tell the kernel the noise of the block the channel's next centres fall in, when
        known and none wait (else it leaves the channel to `_run_channel`)."""
        block = ch.next_n // self.block
        noise = None if ch.waiting else self.noise.known(ci, block)
        self.bank.ints[ci, CH_NOISE_BLOCK] = -1 if noise is None else block
        self.bank.noise[ci] = 0.0 if noise is None else noise

    def _run_channel(self, ci: int, ch: _Channel, x: np.ndarray, candidates: list) -> None:
        """The hinge of the centres x completes (y[m], the slope over [m - w, m], is the
        "after" of centre m - w; hinge(n) = after(n) - after(n - w)), normalised, and the
        contact candidates among them. Usually (the centres in one block whose noise is
        known, none waiting) one kernel does it all (`_one_block`); else the slopes come
        from a kernel and `_normalise` sorts them into blocks."""
        w, held, start = ch.width, ch.held, ch.next_n  # (each bank int read once)
        count = held + len(x) - w  # centres completed
        block = start // self.block
        noise = None
        if count > 0 and not ch.waiting and (start + count - 1) // self.block == block:
            noise = self.noise.known(ci, block)
            if noise is None:  # the block's first centres: its noise (as _normalise would)
                noise = self.noise.of(ch.index, block)
        if noise is not None:
            found = self._one_block(ch, x, count, noise, start)
        else:
            hinge, slope_after = channel_hinge(x, ch.taps, ch.state, ch.after, held)
            ch.held = min(w, held + len(x))
            if count <= 0:
                return
            ch.next_n = start + count
            self._normalise(ch, start, hinge, slope_after)
            found = self._maxima(ch)
        if len(found):
            self._candidates(ci, ch, found, candidates)

    def _one_block(
        self, ch: _Channel, x: np.ndarray, count: int, noise: float, start: int
    ) -> np.ndarray:
        """`_normalise` and `_maxima` of centres start .. start + count - 1 when they lie in
        one block whose noise is known and none wait (the usual case: a CAN frame's few
        samples), as one kernel writing the z rows in place: the same numbers."""
        w, rows = ch.width, ch.rows
        ch.next_n = start + count  # (start: the channel's next centre, as the caller read it)
        at = rows.size
        rows.extend(count)
        ch.refresh_views()
        lo, hi = self._test_range(ch)  # (after the extend: rows.size is at + count)
        found = self.found.room(hi - lo + 1)
        abs_n = ch.abs_n
        told = channel_fast(
            x,
            ch.taps,
            ch.state,
            ch.after,
            ch.held,
            rows.data,
            at,
            start + w,
            noise,
            ch.block_abs,
            abs_n,
            lo - ch.z_start,
            self.threshold,
            ch.needed,
            found,
        )
        ch.held = w
        ch.abs_n = abs_n + count
        if (start + count) % self.block == 0:
            self._block_done(ch, start // self.block, start + count)
        return found[:told]

    @staticmethod
    def _test_range(ch: _Channel) -> tuple[int, int]:
        """Centres lo .. hi to test for a local maximum (z known over +-w): the next ones
        from now on (hi < lo: none yet)."""
        z_start = ch.z_start
        lo = max(ch.next_test, z_start + ch.width)
        hi = z_start + ch.rows.size - 1 - ch.width
        if hi >= lo:
            ch.next_test = hi + 1
        return lo, hi

    def _maxima(self, ch: _Channel) -> np.ndarray:
        """Rows of the candidates among the centres not yet tested (`hinge_maxima`)."""
        lo, hi = self._test_range(ch)
        if hi < lo:  # none to test (no new rows: a channel waiting for a noise)
            return _NONE_FOUND
        z_start = ch.z_start
        i0, i1 = lo - z_start, hi - z_start
        found = self.found.room(i1 - i0 + 1)
        told = hinge_maxima(ch.rows.data, i0, i1, ch.width, self.threshold, ch.needed, found)
        return found[:told]

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
        block_abs, abs_n = ch.block_abs, ch.abs_n
        while pos < len(hinge):
            block = n // B
            end = min(len(hinge), pos + (block + 1) * B - n)
            seg_h, seg_a = hinge[pos:end], slope_after[pos:end]
            np.abs(seg_h, out=block_abs[abs_n : abs_n + len(seg_h)])
            abs_n += len(seg_h)
            ch.abs_n = abs_n
            noise = None if ch.waiting else self.noise.of(ch.index, block)
            if noise is None:
                self._wait(ch, seg_h, seg_a)
            else:
                self._append_z(ch, seg_h, seg_a, noise, n + ch.width)
            n += end - pos
            pos = end
            if n % B == 0:
                self._block_done(ch, block, n)
                abs_n = 0  # (`_block_done` starts the next block's)

    def _block_done(self, ch: _Channel, block: int, n: int) -> None:
        """Block complete (centres up to n - 1): its noise, and perhaps the waiting blocks'."""
        values = ch.block_abs[: ch.abs_n]
        ch.abs_n = 0
        median = lattice_median_of(values, 0.0)  # (compiled; NaN: numpy's rules, below)
        if median != median:
            median = lattice_median(values, floor=0.0)
        self.noise.tell(ch.index, block, median * MEDIAN_TO_STD)
        self._release(ch, n - 1 + ch.width)

    @staticmethod
    def _wait(ch: _Channel, seg_h: np.ndarray, seg_a: np.ndarray) -> None:
        """Centres (their hinge, slope after) after those waiting, to wait for a noise too
        (the kernel appends as `channel_wait`)."""
        at, wait = ch.waiting, ch.wait
        if at + len(seg_h) > wait.shape[1]:
            raise RuntimeError(
                f"hinge channel {ch.index}: {at + len(seg_h)} centres waiting for a noise, "
                f"room for {wait.shape[1]} (`_release` drops them sooner)"
            )
        wait[WAIT_HINGE, at : at + len(seg_h)] = seg_h
        wait[WAIT_AFTER, at : at + len(seg_a)] = seg_a
        ch.waiting = at + len(seg_h)

    def _release(self, ch: _Channel, ready: int) -> None:
        """z for the waiting blocks whose noise is now known (sample `ready` told it)."""
        B = self.block
        while ch.waiting:
            count = ch.waiting
            first = ch.z_start + ch.rows.size  # the first waiting centre: after every row
            block = first // B
            noise = self.noise.of(ch.index, block)
            if noise is None:
                if self.noise.done[ch.index] - block <= self.noise.noise_blocks:
                    return
                noise = math.inf  # waited too long: nothing detected there
            wait = ch.wait
            k = min(count, (block + 1) * B - first)  # the block's centres
            self._append_z(ch, wait[WAIT_HINGE, :k], wait[WAIT_AFTER, :k], noise, ready)
            wait[:, : count - k] = wait[:, k:count]  # (overlapping: numpy copies safely)
            ch.waiting = count - k

    @staticmethod
    def _append_z(
        ch: _Channel, seg_h: np.ndarray, seg_a: np.ndarray, noise: float, ready: int
    ) -> None:
        new = ch.rows.extend(len(seg_h))
        np.divide(seg_h, noise, new[ROW_Z])
        new[ROW_HINGE], new[ROW_AFTER], new[ROW_READY] = seg_h, seg_a, ready
        ch.refresh_views()

    def _candidates(self, ci: int, ch: _Channel, found: np.ndarray, candidates: list) -> None:
        """Local maxima of z (rows `found`, see `hinge_maxima`) as contact candidates: timed
        coarse to fine, unless the bottom of a sharp fall."""
        w = ch.width
        for i in found.tolist():
            n = ch.z_start + i
            tail = ch.za[i] < ch.rise * ch.zh[i]
            if tail and not self._on_tail(n, w):
                continue
            n_at, delta, placed = self._refine(ci, n)
            reach_w = self.merge_widths * w
            if tail:  # (timed late by the tail's bend: `tail_onsets`; not on the first
                # load's pulse: `arrival_tail`; not a held corner: `held_corners`)
                corner = self._held_corner(n, w, float(ch.za[i]))
                n_at, delta, placed = tail_placed(
                    n_at, delta, placed, w, keep_time=corner or self._on_first_load(n_at)
                )
                if corner:
                    reach_w = self.tails.corner_merge_widths * w
            if self._after_drop(n_at, w):
                continue
            # decided once z is known over +-w (late where the noise had to be waited for)
            emit = max(n + 2 * w, int(ch.zready[i - w : i + w + 1].max()))
            candidates.append(
                (emit, w, n_at, delta, float(ch.z[i]), float(ch.zh[i]), placed, reach_w)
            )

    def _held_corner(self, n: int, w: int, slope_after: float) -> bool:
        """Is the tail kink at sample n a held corner (`held_corners`)?"""
        flat_z = self.tails.corner_flat_z
        if not flat_z > 0.0:
            return False
        white = self.noise.white(n // self.block)
        if white is None:
            return False
        return held_corner(slope_after, w, max(white[0], NOISE_FLOOR_N), flat_z)

    def _on_tail(self, n: int, w: int) -> bool:
        """A candidate the rise check drops: a ridge's kink on a pulse's tail after all
        (`tail_kinks`)?"""
        white = self.noise.white(n // self.block)
        if white is None:
            return False
        sigma = max(white[0], NOISE_FLOOR_N)
        x = self.samples.x
        return tail_kink(x, n - self.samples.start, w, sigma, self.fs_hz, self.tails)

    def _on_first_load(self, n: int) -> bool:
        """Does the tail kink at sample n sit on the first load's pulse (`arrival_tail`)?"""
        empty_n = self.tails.arrival_empty_n
        if not empty_n > 0:
            return False

        x, white = self.samples.x, self.noise.white_at_sample
        return on_first_load(
            x, self.samples.start, self.ledger.onsets, n, self.fs_hz, white, empty_n
        )

    def _after_drop(self, n: int, w: int) -> bool:
        """Is the kink at sample n the bottom of a sharp fall (the level stepping down: a
        slip starting, the FSR model's friction term, or a grip released)? A fall within
        w + 2 samples before it, in one sample, of over 5 sigma of the noise's steps and
        over twice what the force then rises: a ridge pulse rises by far more than the
        fastest decay of the one before it falls in a sample."""
        i = n - self.samples.start
        if i - w - 2 < 0 or i + w >= len(self.samples.x):
            return False
        white = self.noise.white(n // self.block)
        if white is None:
            return False
        x = self.samples.x
        fall = float((x[i - w - 2 : i] - x[i - w - 1 : i + 1]).max())
        rise = float(mean(x[i + 1 : i + w + 1]) - x[i])
        return fall > 5.0 * math.sqrt(2.0) * white[0] and fall > 2.0 * max(rise, 0.0)

    def _refine(self, ci: int, n: int) -> tuple[int, float, float]:
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

    def merge(self, candidates: list) -> list[ContactEvent]:
        if not candidates:  # (most blocks)
            return []
        events = []
        candidates.sort(key=lambda c: (c[0], c[1], c[2]))
        for emit, w, n, delta, z, jump, placed, reach_w in candidates:
            t = self.samples.time(n, delta)
            # the same kink seen again (by a coarser scale, later): within its own reach
            # (merge_widths of its scale; a held corner's own, `held_corners`)
            reach = reach_w / self.fs_hz
            if any(abs(t - t_old) <= reach for t_old in self._recent):
                continue
            self._recent.append(t)
            # timing: a quarter of the placing scale (the hinge peak is that wide), and
            # the sub-sample interpolation
            sigma = (0.25 * placed + 0.3) / self.fs_hz
            ev = ContactEvent(
                self.ledger.take_id(), t, n, emit, z, jump * self.fs_hz, w / self.fs_hz, sigma
            )
            events.append(ev)
        return events

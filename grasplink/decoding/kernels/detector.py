"""Compiled kernels of the contact detector's per-block numeric path (`contacts.py`).

Why: every CAN frame (about 3 samples) runs five hinge channels, two step-probe scales
and the level filter; in numpy that is some dozens of calls on arrays of a few entries,
each costing more in overhead than in arithmetic. Here each channel (or scale, or the
level) is one crossing that filters with carried state, writes its rows in place and
returns only the few indices the Python state machines must look at.

Bit-identity with the numpy code they replace: the FIR loop is scipy's `lfilter`
(direct form II transposed, `a` = [1, 0, ...]) operation for operation, and the rest is
+ - * / abs and comparisons in numpy's order, so the detector's events do not change by
a bit (tests/decoding/test_detector_kernels.py, against the numpy code it replaced, run in
the same process: tests/decoding/reference/).

`channels_fast` and `watch_scan` take their arrays and constants in named bundles
(`Channels`, `ChannelSettings`, `ChannelsTold`; `Watched`, `ScanFrom`, `ScanSettings`) as
`kernels.posterior`'s do: the caller passes each as a plain tuple, built once where its
parts stay, and the kernel names it again on entry.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from grasplink.decoding.kernels import jit
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
    HELD_DETRENDED,
    HELD_LEVELS,
    HELD_PLAIN,
    ROW_AFTER,
    ROW_HINGE,
    ROW_READY,
    ROW_Z,
    S_NEXT,
    S_SIZE,
    S_START,
    S_W,
    WAIT_AFTER,
    WAIT_HINGE,
)

__all__ = [
    "all_finite",
    "channel_fast",
    "channel_hinge",
    "channels_fast",
    "fir_run",
    "hinge_maxima",
    "lattice_median_of",
    "scales_fast",
    "sos_run",
    "step_scale",
    "watch_scan",
]


@jit()
def all_finite(t: np.ndarray, x: np.ndarray) -> bool:
    """No NaN or inf in t or x (the detector refuses them by name): one crossing, not four
    numpy calls per frame."""
    return bool(np.isfinite(t).all() and np.isfinite(x).all())


@jit()
def fir_run(taps: np.ndarray, state: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
    """out[k] = the FIR `taps` applied to x[k] with `state` carried (updated in place).

    scipy's lfilter sample loop for b = taps, a = [1, 0, ...] (len(taps) >= 2): y = z0 + b0 x;
    z[n] = z[n + 1] + x b[n + 1] - y a[n + 1]; z[-1] = x b[-1] - y a[-1]. The `- y * 0.0` of
    the zero denominator taps is kept: it is what makes a zero state's sign the same.
    """
    last = len(taps) - 1
    for k in range(len(x)):
        xn = x[k]
        yn = state[0] + taps[0] * xn
        for n in range(last - 1):
            state[n] = state[n + 1] + xn * taps[n + 1] - yn * 0.0
        state[last - 1] = xn * taps[last] - yn * 0.0
        out[k] = yn


@jit()
def sos_run(sos: np.ndarray, state: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
    """out[k] = the second-order sections `sos` (a0 = 1) applied to x[k], `state` (sections,
    2) carried (updated in place): scipy's `sosfilt` sample loop (direct form II
    transposed), operation for operation - the same bits, without its per-call checks
    (a CAN frame brings 1-3 samples)."""
    for k in range(len(x)):
        value = x[k]
        for s in range(sos.shape[0]):
            y = sos[s, 0] * value + state[s, 0]
            state[s, 0] = sos[s, 1] * value - sos[s, 4] * y + state[s, 1]
            state[s, 1] = sos[s, 2] * value - sos[s, 5] * y
            value = y
        out[k] = value


@jit()
def _search(v: np.ndarray, value: float, right: bool) -> int:
    """np.searchsorted(v, value, side="right" if right else "left") of sorted v."""
    lo, hi = 0, len(v)
    while lo < hi:
        mid = (lo + hi) // 2
        if v[mid] < value or (right and v[mid] == value):
            lo = mid + 1
        else:
            hi = mid
    return lo


@jit()
def lattice_median_of(values: np.ndarray, floor: float) -> float:
    """`filters.lattice_median(values, floor)` of finite values, in one crossing: a hinge
    channel's block noise (`HingeBank._block_done`, a block's |hinge|: 50 values at 400
    Hz) took a sort, a median and two searches of numpy calls, each costing more than
    its arithmetic. The same operations in the same order (sorted values have one order
    whatever the sort; the median of one or two middle values, their sum over the
    count): the same bits. NaN for a NaN among them (the caller's numpy path then)."""
    v = np.sort(values)
    n = len(v)
    if n == 0:
        return 0.0
    if v[n - 1] != v[n - 1]:  # NaN (sorted last)
        return np.nan
    k0, k1 = (n - 1) // 2, n // 2
    m = v[k0] / 1.0 if k0 == k1 else (v[k0] + v[k1]) / 2.0
    first, last = abs(v[0]), abs(v[n - 1])
    tol = 1e-9 * (last if last > first else first)
    lo = _search(v, m - tol, False)
    hi = _search(v, m + tol, True)
    ties = hi - lo
    if ties <= 1 or (lo == 0 and hi == n):  # continuous data, or every value the same
        return m
    if lo > 0 and hi < n:
        below, above = m - v[lo - 1], v[hi] - m
        width = above if above < below else below
    else:
        width = m - v[lo - 1] if lo > 0 else v[hi] - m
    cell_lo, cell_hi = m - 0.5 * width, m + 0.5 * width
    if floor > cell_lo:
        cell_lo = floor
    return cell_lo + (0.5 * n - lo) / ties * (cell_hi - cell_lo)


@jit()
def rail_and_step(x: np.ndarray, share: float) -> tuple[int, float]:
    """`filters.on_rail(x)` (with RAIL_SHARE = `share`) and `filters.resolution(x)` of a
    raw block in one crossing (`NoiseFloor.raw_stats`, a block of 50 samples at 400 Hz:
    a sort, run counts, a diff and masks of numpy calls, each costing more than its
    arithmetic): (1 on a rail else 0, the smallest step). The same comparisons and
    subtractions: the same answer and bits. (-1, NaN) for a NaN among them (the caller's
    numpy path then)."""
    n = len(x)
    for i in range(n):
        if x[i] != x[i]:
            return -1, np.nan
    # resolution: the smallest |x[i + 1] - x[i]| above 1e-12 of the largest |x| (or of 1)
    top = 0.0
    for i in range(n):
        if abs(x[i]) > top:
            top = abs(x[i])
    tol = 1e-12 * (top if top > 1.0 else 1.0)
    step, stepped = 0.0, False
    for i in range(n - 1):
        d = abs(x[i + 1] - x[i])
        if d > tol and (not stepped or d < step):
            step, stepped = d, True
    if n < 2:
        return 0, step
    # on a rail: the run of the smallest (or largest) value at least `share` of them (and
    # 2) and twice any other value's run
    v = np.sort(x)
    runs = np.empty(n, np.int64)
    k, runs[0] = 0, 1
    for i in range(1, n):
        if v[i] != v[i - 1]:
            k += 1
            runs[k] = 0
        runs[k] += 1
    if k == 0:
        return 1, step  # constant: nothing of the noise shows
    need = share * n
    if need < 2.0:
        need = 2.0
    low, high = runs[0], runs[k]
    most_above, most_below = 0, 0  # the longest run but the first, but the last
    for j in range(1, k + 1):
        if runs[j] > most_above:
            most_above = runs[j]
    for j in range(k):
        if runs[j] > most_below:
            most_below = runs[j]
    if (low >= need and low >= 2 * most_above) or (high >= need and high >= 2 * most_below):
        return 1, step
    return 0, step


@jit()
def _slopes(
    x: np.ndarray, taps: np.ndarray, state: np.ndarray, after: np.ndarray, held: int
) -> np.ndarray:
    """The slopes not yet paired (after[:held]) followed by those of the new samples x;
    `after` keeps the last len(after) of them for the next call."""
    w = len(after)
    full = np.empty(held + len(x))
    full[:held] = after[:held]
    fir_run(taps, state, x, full[held:])
    keep = min(w, len(full))
    after[:keep] = full[len(full) - keep :]
    return full


@jit()
def channel_hinge(
    x: np.ndarray, taps: np.ndarray, state: np.ndarray, after: np.ndarray, held: int
) -> tuple[np.ndarray, np.ndarray]:
    """A hinge channel's slope filter on x: (hinge, slope after) of the centres now complete
    (none while fewer than w + 1 slopes are held), for the Python normalising path."""
    w = len(after)
    full = _slopes(x, taps, state, after, held)
    count = max(0, len(full) - w)
    slope_after = full[w : w + count].copy()
    return slope_after - full[:count], slope_after


@jit()
def _peak(z: np.ndarray, lo: int, hi: int) -> float:
    """z[lo:hi].max() as numpy has it (NaN if any is NaN); hi > lo."""
    top = z[lo]
    for i in range(lo + 1, hi):
        v = z[i]
        if v > top or math.isnan(v):
            top = v
            if math.isnan(v):
                break
    return top


@jit()
def hinge_maxima(
    rows: np.ndarray,
    i0: int,
    i1: int,
    w: int,
    threshold: float,
    needed: float,
    found: np.ndarray,
) -> int:
    """Rows (z, hinge, slope after, ...) i0 .. i1 that are contact candidates: z at least
    `threshold`, a local maximum over +-w (ties: the first) and the force rising after it
    by `needed` of the hinge. Their indices go to found[:count] (room for i1 - i0 + 1: the
    caller's), for the Python refinement; returns count (a count, not an array: no
    boxing on the usual call that finds none)."""
    z, jump, rising = rows[ROW_Z], rows[ROW_HINGE], rows[ROW_AFTER]
    count = 0
    for i in range(i0, i1 + 1):
        zc = z[i]
        if not zc >= threshold:
            continue
        if z[i - 1] >= zc or z[i + 1] > zc:  # a neighbour's higher: the window's too
            continue
        if zc <= _peak(z, i - w, i) or zc < _peak(z, i + 1, i + w + 1):
            continue
        if rising[i] < needed * jump[i]:
            continue
        found[count] = i
        count += 1
    return count


@jit()
def channel_fast(
    x: np.ndarray,
    taps: np.ndarray,
    state: np.ndarray,
    after: np.ndarray,
    held: int,
    rows: np.ndarray,
    at: int,
    ready: int,
    noise: float,
    block_abs: np.ndarray,
    abs_n: int,
    lo: int,
    threshold: float,
    needed: float,
    found: np.ndarray,
) -> int:
    """A hinge channel's usual step (its new centres in one block whose noise is known):
    the slope filter on x, hinge = slope after - slope before, z = hinge / noise, written
    into rows[:, at:] (z, hinge, slope after, `ready`) and |hinge| into block_abs[abs_n:];
    then the candidates (`hinge_maxima`, into `found`) among rows lo .. (last held - w)."""
    w = len(after)
    full = _slopes(x, taps, state, after, held)
    count = len(full) - w
    for i in range(count):
        slope_after = full[w + i]
        hinge = slope_after - full[i]
        rows[ROW_HINGE, at + i] = hinge
        rows[ROW_Z, at + i] = hinge / noise
        rows[ROW_AFTER, at + i] = slope_after
        rows[ROW_READY, at + i] = ready
        block_abs[abs_n + i] = abs(hinge)
    return hinge_maxima(rows, lo, at + count - 1 - w, w, threshold, needed, found)


@jit()
def channel_wait(
    x: np.ndarray,
    taps: np.ndarray,
    state: np.ndarray,
    after: np.ndarray,
    held: int,
    wait: np.ndarray,
    at: int,
    block_abs: np.ndarray,
    abs_n: int,
) -> int:
    """A hinge channel's step while its centres wait for a noise (no block before them has
    shown one yet: a signal on a rail, the first blocks): `channel_hinge` on x, the new
    centres' hinge and slope after appended to wait[:, at:] (`WAIT_ROWS`) and their
    |hinge| to block_abs[abs_n:], as `HingeBank._normalise` does; returns how many."""
    hinge, slope_after = channel_hinge(x, taps, state, after, held)
    for i in range(len(hinge)):
        wait[WAIT_HINGE, at + i] = hinge[i]
        wait[WAIT_AFTER, at + i] = slope_after[i]
        block_abs[abs_n + i] = abs(hinge[i])
    return len(hinge)


# what `channels_fast` says of each channel
TAKEN, NOT_TAKEN, BLOCK_DONE = 0, 1, 2


class Channels(NamedTuple):
    """The hinge channels' numbers, a row each (`detector.hinges._ChannelBank`): int state
    (`CHANNEL_COLUMNS`), the noise of the block each is in, the rise needed after a
    candidate, the slope filters' taps and carried state (a channel's first `width` + 1,
    `width` entries), the slopes held (`width`), the block's |hinge| and the centres
    waiting for a noise (`wait[c, :, :wait_n]`, `WAIT_ROWS`)."""

    ints: np.ndarray
    noise: np.ndarray
    needed: np.ndarray
    taps: np.ndarray
    state: np.ndarray
    after: np.ndarray
    block_abs: np.ndarray
    wait: np.ndarray


class ChannelSettings(NamedTuple):
    """The hinge bank's constants: block length (samples) and a candidate's z."""

    block: int
    threshold: float


class ChannelsTold(NamedTuple):
    """What `channels_fast` tells of each channel (a row each): its candidates' indices
    (`found[c, :counts[c]]`), its status and the samples taken."""

    found: np.ndarray
    counts: np.ndarray
    status: np.ndarray
    taken: np.ndarray


@jit()
def channels_fast(x: np.ndarray, bank: tuple, rows: tuple, settings: tuple, out: tuple) -> bool:
    """Every hinge channel's usual step (`channel_fast`) in one crossing: the new centres
    in the block of the channel's known noise, with room in its rows and for its
    candidates - or, while its centres wait for a noise, appended to those waiting
    (`channel_wait`: no candidates then). Per channel: status TAKEN (counts[c] candidates
    in found[c]), BLOCK_DONE (taken, and its block complete: the caller takes its noise;
    centres past the block's end are left to it: only x[:taken[c]] was taken) or
    NOT_TAKEN (nothing changed: the caller's Python path does it); the int state updated
    in `bank.ints`. `bank`, `settings`, `out`: a `Channels`, `ChannelSettings` and
    `ChannelsTold` as plain tuples (built once by the caller); `rows`: the channels' rows
    storage. Returns whether any channel needs the caller (not taken, a block done, a
    candidate): usually none does."""
    bank, settings, out = Channels(*bank), ChannelSettings(*settings), ChannelsTold(*out)
    ints, noise, needed, taps = bank.ints, bank.noise, bank.needed, bank.taps
    state, after, block_abs, wait = bank.state, bank.after, bank.block_abs, bank.wait
    block, threshold = settings.block, settings.threshold
    found, counts, status, taken = out.found, out.counts, out.status, out.taken
    attention = False
    for c in range(ints.shape[0]):
        w, held, start = ints[c, CH_W], ints[c, CH_HELD], ints[c, CH_NEXT_N]
        b = start // block
        count = held + len(x) - w
        m = len(x)
        if held == w and (start + count - 1) // block != b:  # to the block's end only
            m = (b + 1) * block - start
            count = m
        size, z_start = ints[c, CH_SIZE], ints[c, CH_Z_START]
        data = rows[c]
        counts[c] = 0
        taken[c] = 0
        waiting = ints[c, CH_WAIT_N]
        if waiting > 0:  # its centres wait for a noise: appended to those waiting
            if count <= 0 or (start + count - 1) // block != b or waiting + count > wait.shape[2]:
                status[c] = NOT_TAKEN
                attention = True
                continue
            channel_wait(
                x[:m], taps[c, : w + 1], state[c, :w], after[c, :w], held, wait[c], waiting,
                block_abs[c], ints[c, CH_ABS_N],
            )  # fmt: skip
            ints[c, CH_HELD] = min(w, held + m)
            ints[c, CH_ABS_N] += count
            ints[c, CH_NEXT_N] = start + count
            ints[c, CH_WAIT_N] = waiting + count
            taken[c] = m
            status[c] = BLOCK_DONE if (start + count) % block == 0 else TAKEN
            attention = attention or status[c] == BLOCK_DONE
            continue
        lo = max(ints[c, CH_NEXT_TEST], z_start + w)
        hi = z_start + size + count - 1 - w
        if (
            count <= 0
            or ints[c, CH_NOISE_BLOCK] != b
            or (start + count - 1) // block != b
            or size + count > data.shape[1]
            or hi - lo + 1 > found.shape[1]
        ):
            status[c] = NOT_TAKEN
            attention = True
            continue
        if hi >= lo:
            ints[c, CH_NEXT_TEST] = hi + 1
        told = channel_fast(
            x[:m],
            taps[c, : w + 1],
            state[c, :w],
            after[c, :w],
            held,
            data,
            size,
            start + w,
            noise[c],
            block_abs[c],
            ints[c, CH_ABS_N],
            lo - z_start,
            threshold,
            needed[c],
            found[c],
        )
        ints[c, CH_HELD] = w
        ints[c, CH_ABS_N] += count
        ints[c, CH_NEXT_N] = start + count
        ints[c, CH_SIZE] = size + count
        counts[c] = told
        taken[c] = m
        status[c] = BLOCK_DONE if (start + count) % block == 0 else TAKEN
        attention = attention or told > 0 or status[c] == BLOCK_DONE
    return attention


@jit()
def step_scale(
    x: np.ndarray,
    taps: np.ndarray,
    state: np.ndarray,
    d: np.ndarray,
    at: int,
    i0: int,
    i1: int,
    w: int,
    found: np.ndarray,
    found_adj: np.ndarray,
) -> int:
    """A step-probe scale: its difference filter on x into d[at:], then the local maxima
    (over +-w, ties: the first, above 0) of adj = d - (d 2w before + d 2w after) / 2 over
    d[i0 .. i1] (i1 < i0: none). The maxima's offsets from i0 go to found[:count], their
    adj to found_adj[:count] (room for i1 - i0 + 1: the caller's); returns count."""
    fir_run(taps, state, x, d[at : at + len(x)])
    n = max(0, i1 - i0 + 1)
    adj = np.empty(n)
    for j in range(n):
        i = i0 + j
        adj[j] = d[i] - 0.5 * (d[i - 2 * w] + d[i + 2 * w])
    count = 0
    for j in range(w, n - w):
        a = adj[j]
        if not (a > 0.0 and a >= adj[j - 1] and a > adj[j + 1]):
            continue
        if a < _peak(adj, j - w, j) or a <= _peak(adj, j + 1, j + w + 1):
            continue
        found[count] = j
        found_adj[count] = a
        count += 1
    return count


@jit()
def scales_fast(
    x: np.ndarray,
    ints: np.ndarray,
    taps: np.ndarray,
    state: np.ndarray,
    stores: tuple,
    found: np.ndarray,
    found_adj: np.ndarray,
    counts: np.ndarray,
    first: np.ndarray,
) -> bool:
    """Every step-probe scale (`step_scale`) on x in one crossing: its differences written
    after those held, the centres now testable tested. Per scale: counts[s] maxima, their
    offsets from first[s] in found[s] and their adj in found_adj[s]; -1: not taken (no
    room in its store or for its maxima: nothing changed, the caller's Python path does
    it). Rows of `taps` and `state` are the scales' (2 width and 2 width - 1 entries).
    Returns whether any scale needs the caller (not taken, or a maximum found)."""
    attention = False
    for s in range(ints.shape[0]):
        w, at, start = ints[s, S_W], ints[s, S_SIZE], ints[s, S_START]
        size = at + len(x)
        lo = max(ints[s, S_NEXT], start + 3 * w, 3 * w)
        hi = start + size - 1 - 3 * w
        i0, i1 = lo - start - w, hi - start + w  # adjusted over +-w
        if hi < lo:
            i0, i1 = 0, -1  # nothing to test yet
        d = stores[s]
        if size > len(d) or i1 - i0 + 1 > found.shape[1]:
            counts[s] = -1
            attention = True
            continue
        if hi >= lo:
            ints[s, S_NEXT] = hi + 1
        ints[s, S_SIZE] = size
        told = step_scale(
            x, taps[s, : 2 * w], state[s, : 2 * w - 1], d, at, i0, i1, w, found[s], found_adj[s]
        )
        counts[s] = told
        first[s] = i0
        attention = attention or told > 0
    return attention


@jit()
def _first_at_least(sorted_values: np.ndarray, count: int, value: float) -> int:
    """sorted_values[:count].searchsorted(value) (side left): binary search, as numpy's."""
    lo, hi = 0, count
    while lo < hi:
        mid = (lo + hi) // 2
        if sorted_values[mid] < value:
            lo = mid + 1
        else:
            hi = mid
    return lo


class Watched(NamedTuple):
    """What `watch_scan` reads of a pulse watch that stays for its life (`detector.watch.
    Watch`): its onset sample (`Watch.index`), base level, an earlier tail's fall and the
    rising trend (N/sample), the level noise (N), the hold (sample), and the rows it
    writes in place: the running peak by sample (`history`) and the level to the hold
    (`held`, rows `WATCH_ROWS`)."""

    onset: int
    base: float
    fall: float
    trend: float
    noise: float
    hold: int
    history: np.ndarray
    held: np.ndarray


class ScanFrom(NamedTuple):
    """Where a watch's look at new level samples starts: the first of them, the running
    peak before it, and the entries of history and held filled so far."""

    next_k: int
    peak: float
    hist_n: int
    held_n: int


class ScanSettings(NamedTuple):
    """The pulse watcher's constants `watch_scan` reads (`detector.watch.PulseWatcher`),
    in samples but for the drop (share of the peak) and the decay (rise times)."""

    fall_credit: int
    width: int
    min_rise: int
    drop: float
    decay: float
    step_rise: int


@jit()
def watch_scan(level: np.ndarray, watch: tuple, at: tuple, settings: tuple) -> tuple[int, bool]:
    """A pulse watch's look at the level samples k = next_k .. (level: their values):
    the numbers of `ContactDetector._advance`, which keeps the verdicts. `watch`, `at`,
    `settings`: a `Watched`, `ScanFrom` and `ScanSettings` as plain tuples.

    With since = k - index, credit = fall min(since, fall_credit) (an earlier tail's fall
    out), raw = level - base + credit and d = raw - trend (since + width) (the trend out):
    the running peak of d - credit (from `peak`) goes to history[hist_n:], and level - base,
    raw, d of the samples up to `hold` to held[:, held_n:]. A sample falls back like a
    pulse (ok) when its peak is at least 4 noise, d is `drop` of the peak below it, and
    since is at most `decay` times the rise (the first sample at 90 % of the peak, at
    least min_rise). Before the hold, a sharp rise (to 80 % within step_rise) is deferred:
    judged at the hold. Returns (the first sample ok and not deferred, as an offset from
    next_k, -1: none; whether one ok was deferred)."""
    watch, at, settings = Watched(*watch), ScanFrom(*at), ScanSettings(*settings)
    index, base, fall, trend = watch.onset, watch.base, watch.fall, watch.trend
    noise, hold, history, held = watch.noise, watch.hold, watch.history, watch.held
    next_k, peak, hist_n, held_n = at.next_k, at.peak, at.hist_n, at.held_n
    fall_credit, width, min_rise = settings.fall_credit, settings.width, settings.min_rise
    drop, decay, step_rise = settings.drop, settings.decay, settings.step_rise
    m = len(level)
    d = np.empty(m)
    for j in range(m):
        since = next_k + j - index
        credit = fall * min(since, fall_credit)
        plain = level[j] - base
        raw = plain + credit
        d[j] = raw - trend * (since + width)
        peak = max(d[j] - credit, peak)
        history[hist_n + j] = peak
        if next_k + j <= hold:
            held[HELD_PLAIN, held_n + j] = plain
            held[HELD_LEVELS, held_n + j] = raw
            held[HELD_DETRENDED, held_n + j] = d[j]
    count = hist_n + m
    floor = 4.0 * noise
    hit = -1
    fell = False
    for j in range(m):
        top = history[hist_n + j]
        rise = max(_first_at_least(history, count, 0.9 * top), min_rise)
        since = next_k + j - index
        ok = top >= floor and top - d[j] >= drop * top and since <= decay * rise
        if not ok:
            continue
        sharp = next_k + j < hold and _first_at_least(history, count, 0.8 * top) <= step_rise
        if sharp:  # deferred to the hold
            fell = True
            continue
        if hit < 0:
            hit = j
    return hit, fell

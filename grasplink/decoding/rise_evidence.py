"""Soft evidence of the ridges a track skips: the signal's rise where it predicts them.

A ridge the detector did not tell is not "no information" (issue 22, 10 dB SNR: the
detector finds 46 % of the crossings, and a missed one still shows as a sub-threshold
rise). Where a track that skipped ridges put them, the pulse probe's rise statistic z
(`detector.pulse_probe`: mean after less mean before over w, half the same difference
2 w either side taken out - a ramp is no rise -, in white-noise units) is an observation:
about N(h, 1) under "a ridge pulse here", h the pulse's size, N(0, 1) under "none". The
size is not known (the thesis's signal model draws each ridge's height at random and
starts each pulse on the previous one's tail: no height law is assumed here), so h is
taken log-uniform from `H_LOW` to `H_HIGH` times the median z of the contacts told
lately (`TOLD_KEPT`), and the log likelihood ratio is clipped to `CLIP` nats.

The tracker's fixed penalty for a skipped ridge is log(1 - DETECT_P(spacing)); this
module gives the score to use instead, never below it (`skip_score`): in a clean signal
a told pulse is 20-60 units of z and a flat place reads about 0, whose ratio lies far
below log(1 - 0.99), so nothing changes there, while at 10 dB a true track's missed
ridges (z 2.5 at their median) gain and an alias's (z 0) do not.
Measured by `benchmarks/snr10_soft_evidence.py` (full plan, 2 seeds: snr10 missed
crossings z 2.5 at their median against 0.0 at an alias's times, AUC 0.87).

z is read only from samples before the contact's decision (`ContactEvent.emit_index`),
so a contact weighs the same however the input was chunked and whenever it is replayed.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np

from grasplink.decoding.detector.pulse_probe import PULSE_RAMP, PULSE_SCALES_S
from grasplink.decoding.detector.step_shape import Recent
from grasplink.decoding.kernels.layout import F_STOP, F_V, I_DIRN, I_LAST, I_N, I_RIDGE, I_RUN
from grasplink.decoding.ridge_pulses import RISE_MM

OFFSET = 0.5  # the rise's centre after the onset, in rise times (the best measured)
# the pulse size's prior, times the told pulses' median z: from 0.3 (snr10 speed missing
# 54.2 % from 0.1, 53.3 % from 0.3, 54.7 % from 0.5: full plan, 2 seeds, one run) to 2
H_LOW, H_HIGH = 0.3, 2.0
CLIP = 3.0  # nats a skipped ridge may gain at most
# a rise this high (the pulse probe's threshold, white-noise units) would have been told:
# untold, it is some told contact's pulse or a bend of one - no evidence either way
TOLD_Z = 4.5
NEAR_TOLD = 2.0  # ... and so is one this many windows (at least 20 ms) from a told onset
TOLD_KEPT = 16  # told contacts whose z the median reads
H_DEFAULT = 5.0  # the median before any contact is told (a 10 dB pulse's)
_GRID = 32  # points of the size prior


def log_ratio(z: np.ndarray, median_h: float | np.ndarray, h_low: float = H_LOW) -> np.ndarray:
    """log p(z | a pulse of unknown size) / p(z | none), per z (unclipped): the size
    log-uniform over h_low..`H_HIGH` x median_h (one median, or one per z), z ~ N(h, 1)
    against N(0, 1). NaN where z is NaN; ValueError for a median that is not a positive
    number."""
    z = np.asarray(z, dtype=float)
    if not 0.0 < h_low < H_HIGH:
        raise ValueError(f"rise evidence: the size prior's low end {h_low!r} is not in (0, 2)")
    if np.ndim(median_h) == 0:
        h = _sizes(float(median_h), h_low)
    else:  # a grid per z (the same numbers as one call per median)
        medians = np.asarray(median_h, dtype=float).tolist()
        h = np.stack([_sizes(m, h_low) for m in medians]) if medians else np.zeros((0, _GRID))
    terms = z[..., None] * h - 0.5 * h * h
    top = np.max(terms, axis=-1, keepdims=True)
    return top[..., 0] + np.log(np.mean(np.exp(terms - top), axis=-1))


def sizes(median_h: float, h_low: float = H_LOW) -> np.ndarray:
    """The size prior's grid (z units) for a told median (read-only, shared)."""
    return _sizes(median_h, h_low)


@functools.lru_cache(maxsize=256)
def _sizes(median_h: float, h_low: float) -> np.ndarray:
    """The size prior's grid for a median (read-only: shared by every call)."""
    if not (math.isfinite(median_h) and median_h > 0.0):
        raise ValueError(f"rise evidence: the told pulses' median z {median_h!r} is not > 0")
    h = np.exp(np.linspace(math.log(h_low * median_h), math.log(H_HIGH * median_h), _GRID))
    h.flags.writeable = False
    return h


def skip_score(
    z: np.ndarray,
    median_h: float | np.ndarray,
    log_miss: np.ndarray,
    h_low: float = H_LOW,
) -> np.ndarray:
    """A skipped ridge's log score from its z: the ratio `log_ratio`, no less than the
    detector-based `log_miss` (log(1 - DETECT_P)), no more than `CLIP`; `log_miss` where
    z is unknown (NaN: the samples were not held) or `TOLD_Z` or more (the detector
    would have told such a rise: it is another contact's)."""
    log_miss = np.asarray(log_miss, dtype=float)
    ratio = log_ratio(z, median_h, h_low)
    score = np.minimum(CLIP, np.maximum(ratio, log_miss))
    return np.where(np.isfinite(ratio) & (np.nan_to_num(z) < TOLD_Z), score, log_miss)


class RiseEvidence:
    """z at predicted onsets from the tracker's recent samples (`step_shape.Recent`) and the
    detector's white noise (`white(block)` -> (N per sample, blocks) or None, blocks of
    `block` samples), and the median z of the contacts told lately."""

    def __init__(
        self,
        fs_hz: float,
        recent: Recent,
        white: Callable[[int], tuple[float, int] | None],
        block: int,
        floor_n: float,
    ):
        if not fs_hz > 0:
            raise ValueError(f"rise evidence: sample rate {fs_hz!r} Hz is not positive")
        self.fs_hz = float(fs_hz)
        self.recent = recent
        self.white = white
        self.block = int(block)
        self.floor_n = float(floor_n)
        self.widths = np.array(sorted({max(2, round(s * fs_hz)) for s in PULSE_SCALES_S}))
        self._told: dict[int, np.ndarray] = {}  # contact id -> its z per window (bounded)
        self.h_low = H_LOW  # the size prior's low end (x the median)
        self._heights: dict[int, float] = {}  # contact id -> told pulse height (noise units)
        # the medians read many times between contacts: kept until a contact changes them
        self._medians: dict[int, float] = {}
        self._height_median: float | None = None

    def width_for(self, speed_mm_s: np.ndarray) -> np.ndarray:
        """The probe window (samples) nearest each speed's rise time (`RISE_MM` of travel)."""
        rise = RISE_MM / np.maximum(np.asarray(speed_mm_s, dtype=float), 1.0) * self.fs_hz
        k = np.argmin(np.abs(np.log(self.widths[None, :] / rise[:, None])), axis=1)
        return self.widths[k]

    def z_at(self, onset: np.ndarray, width: np.ndarray, before: int) -> np.ndarray:
        """z for pulses with onsets at (fractional) global sample indices `onset`, read on
        windows `width` centred `OFFSET` of a window after them, from samples before the
        global index `before` only: NaN where they are not all held, or the noise is not
        known, or an input is not finite."""
        onset = np.asarray(onset, dtype=float)
        width = np.asarray(width, dtype=np.int64)
        out = np.full(onset.shape, np.nan)
        ok = np.isfinite(onset)
        if not ok.any():
            return out
        centre = np.zeros(onset.shape, np.int64)
        centre[ok] = np.rint(onset[ok] + OFFSET * width[ok]).astype(np.int64)
        lo, hi = centre - 3 * width, centre + 3 * width  # samples lo .. hi - 1 read
        ok &= hi <= before
        if not ok.any():
            return out
        start, end = int(lo[ok].min()), int(hi[ok].max())
        x = self.recent.held(start, end)
        if x is None:
            first = self.recent.start
            ok &= lo >= first
            if not ok.any():
                return out
            start = int(lo[ok].min())
            x = self.recent.held(start, end)
            if x is None:
                return out
        if not np.all(np.isfinite(x)):
            ok &= False  # a NaN sample: no evidence rather than a false one
            return out
        sums = np.concatenate([[0.0], np.cumsum(x)])
        for k in np.flatnonzero(ok):
            w, c = int(width[k]), int(centre[k]) - start
            white = self.white(int(centre[k]) // self.block)
            if white is None:
                continue
            d = [(sums[m + w] - 2.0 * sums[m] + sums[m - w]) / w for m in (c - 2 * w, c, c + 2 * w)]
            adj = d[1] - PULSE_RAMP * (d[0] + d[2])
            sigma = max(float(white[0]), self.floor_n)
            out[k] = adj / (sigma * math.sqrt(2.0 / w * (1.0 + 2.0 * PULSE_RAMP**2)))
        return out

    def z_each(self, onset: np.ndarray, width: np.ndarray, before: int) -> np.ndarray:
        """`z_at` of each onset on its own (its sums anchored at its own first sample, as
        a call with that onset alone reads it: the same z to the bit whatever else is
        read with it), vectorised per window width."""
        return self._z_each(onset, width, before, with_trend=False)[0]

    def z_and_trend_each(
        self, onset: np.ndarray, width: np.ndarray, before: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """(`z_each`, how the level went in the window just before each onset: the mean of
        its later half less the mean of its earlier half, in white-noise units of that
        difference - a falling pulse tail reads well under 0, a flat level about 0)."""
        return self._z_each(onset, width, before, with_trend=True)

    def _z_each(
        self, onset: np.ndarray, width: np.ndarray, before: int, with_trend: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """`z_each` and, `with_trend` (else left NaN), `z_and_trend_each`'s trend."""
        onset = np.asarray(onset, dtype=float)
        width = np.asarray(width, dtype=np.int64)
        out = np.full(onset.shape, np.nan)
        trend = np.full(onset.shape, np.nan)
        ok = np.isfinite(onset)
        centre = np.zeros(onset.shape, np.int64)
        centre[ok] = np.rint(onset[ok] + OFFSET * width[ok]).astype(np.int64)
        lo, hi = centre - 3 * width, centre + 3 * width  # samples lo .. hi - 1 read
        ok &= (hi <= before) & (lo >= self.recent.start)
        if not ok.any():
            return out, trend
        start, end = int(lo[ok].min()), int(hi[ok].max())
        x = self.recent.held(start, end)
        if x is None:  # (not all held: none of these is)
            return out, trend
        noise = {}  # the white noise per block: one lookup each
        for b in np.unique(centre[ok] // self.block).tolist():
            white = self.white(b)
            noise[b] = math.nan if white is None else max(float(white[0]), self.floor_n)
        for w in np.unique(width[ok]).tolist():
            k = np.flatnonzero(ok & (width == w))
            rows = x[(lo[k] - start)[:, None] + np.arange(6 * w)]
            sums = np.concatenate([np.zeros((len(k), 1)), np.cumsum(rows, axis=1)], axis=1)
            d0, d1, d2 = (
                (sums[:, m + w] - 2.0 * sums[:, m] + sums[:, m - w]) / w for m in (w, 3 * w, 5 * w)
            )
            adj = d1 - PULSE_RAMP * (d0 + d2)
            sigma = np.array([noise[b] for b in (centre[k] // self.block).tolist()], float)
            z = adj / (sigma * math.sqrt(2.0 / w * (1.0 + 2.0 * PULSE_RAMP**2)))
            finite = np.all(np.isfinite(rows), axis=1)
            out[k] = np.where(finite, z, np.nan)
            if not with_trend:
                continue
            # the window [onset - w, onset): its halves' means (the onset lies 2.5 w in)
            half = max(1, w // 2)
            o = (np.rint(onset[k]).astype(np.int64) - lo[k])[:, None]
            at = np.take_along_axis(sums, np.hstack([o - 2 * half, o - half, o]), axis=1)
            later_less_earlier = (at[:, 2] - 2.0 * at[:, 1] + at[:, 0]) / half
            trend[k] = np.where(
                finite, later_less_earlier / (sigma * math.sqrt(2.0 / half)), np.nan
            )
        return out, trend

    def tell(self, contact_id: int, onset: float, before: int) -> None:
        """Note a told contact's z on every window, for the size prior's median."""
        if contact_id in self._told:
            return
        z = self.z_at(np.full(len(self.widths), float(onset)), self.widths, before)
        if np.any(np.isfinite(z)):
            _put(self._told, contact_id, z)
            self._medians.clear()

    def note_height(self, contact_id: int, height_snr: float | None) -> None:
        """Note a told pulse's height above its base (white-noise units: `PulseCheck`)."""
        if height_snr is not None and math.isfinite(height_snr):
            _put(self._heights, contact_id, float(height_snr))
            self._height_median = None

    def blind(self, gate: float) -> bool:
        """The told pulses stand under `gate` noise units at their median: heavy noise, where
        the detector misses ridges a track can still read (none told: False)."""
        if not self._heights:
            return False
        if self._height_median is None:
            self._height_median = float(np.median(np.fromiter(self._heights.values(), float)))
        return self._height_median < gate

    def median_h(self, width: int) -> float:
        """The median z on `width` of the contacts told lately (`H_DEFAULT` before any; at
        least 1: a told pulse is a rise)."""
        known = self._medians.get(width)
        if known is not None:
            return known
        k = int(np.flatnonzero(self.widths == width)[0])
        told = [z[k] for z in self._told.values() if np.isfinite(z[k])]
        out = max(1.0, float(np.median(told))) if told else H_DEFAULT
        self._medians[width] = out
        return out


def _put(table: dict, key: int, value) -> None:
    table[key] = value
    while len(table) > TOLD_KEPT:
        del table[next(iter(table))]


def skip_adjustment(
    floats: np.ndarray,
    ints: np.ndarray,
    contact: tuple[int, float, int, int],
    earlier: dict[int, tuple[float, int]],
    pos_mm: np.ndarray,
    log_miss: np.ndarray,
    max_skip: int,
    evidence: RiseEvidence,
    gate: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The rows of a contact's children that took it for a ridge after skipping some, and
    what each gains (log) when its skipped ridges are scored by `skip_score` in place of
    `log_miss` (direction x ridge, travel order). `contact`: (id, time s, onset index,
    decision index); `earlier`: the held contacts' (time s, onset index) by id; `pos_mm`:
    the ridges' positions (direction x ridge, travel order). None unless the told pulses
    stand under `gate` noise units at their median (`RiseEvidence.blind`: in a clean
    signal the detector sees the ridges, and a slow pulse's rise reads as a ramp).

    A child's skipped ridges are not stored: the ridge it came from is the one (of the
    `max_skip` + 1 before its new one) whose distance to it best matches its speed times
    the time since its previous contact; the skipped ones are placed between the two
    contacts at a constant speed (times and sample indices interpolated)."""
    ev_id, t_s, index, emit = contact
    evidence.tell(ev_id, float(index), emit)
    if not evidence.blind(gate):
        return np.zeros(0, np.int64), np.zeros(0)
    rows = np.flatnonzero(
        (ints[:, I_LAST] == ev_id)
        & (ints[:, I_N] >= 2)
        & (ints[:, I_RUN] >= 2)
        & np.isnan(floats[:, F_STOP])
    )
    nowhere = (math.inf, -1)
    prev = [earlier.get(int(k), nowhere) for k in ints[rows, I_LAST - 1]]
    t_all = np.array([p[0] for p in prev], float)
    known = t_all < t_s
    rows = rows[known]
    if not len(rows):
        return rows, np.zeros(0)
    t_prev = t_all[known]
    i_prev = np.array([p[1] for p in prev], float)[known]
    way = (1 - ints[rows, I_DIRN]) // 2
    k_new = ints[rows, I_RIDGE]
    dt = t_s - t_prev
    travel = np.abs(floats[rows, F_V]) * dt
    skips = np.arange(max_skip + 1)
    k_par = k_new[:, None] - 1 - skips[None, :]
    valid = k_par >= 0
    gap = pos_mm[way[:, None], k_new[:, None]] - pos_mm[way[:, None], np.maximum(k_par, 0)]
    miss = np.where(valid, np.abs(gap - travel[:, None]), np.inf)
    skip = np.argmin(miss, axis=1)
    has = skip >= 1
    rows, way, k_new, skip = rows[has], way[has], k_new[has], skip[has]
    t_prev, i_prev, dt = t_prev[has], i_prev[has], dt[has]
    if not len(rows):
        return rows, np.zeros(0)
    # one entry per (child, skipped ridge)
    child = np.repeat(np.arange(len(rows)), skip)
    back = np.concatenate([np.arange(1, s + 1) for s in skip.tolist()])  # ridges before new
    k = k_new[child] - back
    w_ = way[child]
    p_par = pos_mm[w_, k_new[child] - 1 - skip[child]]
    p_new = pos_mm[w_, k_new[child]]
    share = (pos_mm[w_, k] - p_par) / (p_new - p_par)
    onset = i_prev[child] + share * (index - i_prev[child])
    speed = (p_new - p_par) / dt[child]
    width = evidence.width_for(speed)
    z = evidence.z_at(onset, width, emit)
    told = np.array([i for _, i in earlier.values()] + [index], float)
    reach = np.maximum(NEAR_TOLD * width, 0.02 * evidence.fs_hz)
    near = np.min(np.abs(onset[:, None] - told[None, :]), axis=1) <= reach
    z[near] = np.nan  # (a told contact's own rise)
    lm = log_miss[w_, k]
    gain = np.zeros(len(k))
    for w in np.unique(width).tolist():
        on = width == w
        gain[on] = skip_score(z[on], evidence.median_h(w), lm[on], evidence.h_low) - lm[on]
    return rows, np.bincount(child, weights=gain, minlength=len(rows))


def silence(
    open_sched: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    tables: dict[str, np.ndarray],
    bank: dict[str, np.ndarray],
    last: np.ndarray,
    held: int,
    g: float,
    log_miss: np.ndarray,
    log_stop: float,
    weight: float,
    scored: dict[tuple[int, int], float],
    evidence: RiseEvidence,
    ahead: int,
    memo: dict | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The silence schedule (due, adj, stopped, limit: `kernels.posterior.schedule`'s) with
    each due ridge of a slipping track scored by the signal's rise where the track puts it
    (`skip_score`, weighted by `weight` against log(1 - DETECT_P)) instead of its miss
    alone: a track whose due ridge shows a sub-threshold rise goes on, one whose due ridge
    lies on flat signal stops as before.

    `open_sched`: the schedule with no miss counted (`done` only at the coast end: every
    ridge ahead gets its time due); `tables`: the silence tables (rows by direction and
    ridge: `target`, `coast`); `bank`: the tracks' X, t, stop, run, dirn, ridge; `last`:
    the global sample index of each track's last contact (-1: not held, then the plain
    miss); `held`: samples held up to this global index; `scored`: (track, ridge ahead)
    -> its score once read (the bank's: a ridge is read once, the same at every later
    update). A ridge's time due waits for the samples its rise is read from. `memo`: the
    bank's own dict, where what does not change with g is kept between calls (`_plan`)."""
    due0, _, stopped0, limit0 = open_sched
    plan = None if memo is None else memo.get("plan")
    if plan is None or not np.array_equal(plan[0], last):
        plan = (last.copy(), *_plan(open_sched, tables, bank, last, log_miss, evidence))
        if memo is not None:
            memo["plan"] = plan
    _, active, due_a, k, coast, width, onset, lm = plan
    due, adj = due0.copy(), np.zeros(due0.shape)
    stopped, limit = stopped0.copy(), limit0.copy()
    if not len(active):
        return due, adj, stopped, limit
    S = due0.shape[1] - 1
    due[active, 1:] = due_a
    soft = lm.copy()
    # the due ridges read: per track, those ahead up to the coast end or one not yet due
    read = np.zeros(lm.shape, bool)
    span = min(S, ahead)
    if span > 0:
        open_ = ~coast[:, :span] & (due[active, 1 : span + 1] <= g)
        read[:, :span] = np.logical_and.accumulate(open_, axis=1) & (last[active] >= 0)[:, None]
    a_read, j_read = np.nonzero(read)
    if len(a_read):
        got = np.array(
            [
                scored.get((n, j), math.nan)
                for n, j in zip(active[a_read].tolist(), j_read.tolist(), strict=True)
            ]
        )
        new = np.flatnonzero(np.isnan(got))
        if len(new):  # read once: one z_at call for every ridge not read before
            a_new, j_new = a_read[new], j_read[new]
            z = evidence.z_each(onset[a_new, j_new], width[a_new], held)
            medians = {w: evidence.median_h(w) for w in np.unique(width[a_new]).tolist()}
            h = np.array([medians[w] for w in width[a_new].tolist()], float)
            fresh = skip_score(z, h, lm[a_new, j_new], evidence.h_low)
            got[new] = fresh
            for n, j, value, zk in zip(
                active[a_new].tolist(), j_new.tolist(), fresh.tolist(), z.tolist(), strict=True
            ):
                if math.isfinite(zk):  # (else read again at the next update)
                    scored[(n, j)] = value
        lm_read = lm[a_read, j_read]
        soft[a_read, j_read] = lm_read + weight * (got - lm_read)
    miss = np.cumsum(soft, axis=1)
    go_on = miss >= log_stop
    ended = np.logical_or.accumulate(~go_on | coast, axis=1)
    done = np.zeros(ended.shape, bool)
    done[:, 1:] = ended[:, :-1]
    adj[active, 1:] = np.where(done, 0.0, np.where(go_on, miss, log_stop))
    stopped[active, 1:] = ~(go_on | done)
    limit[active, 1:] = np.where(done, 0, k + go_on)
    due[active, 1:] = np.where(done, np.inf, due[active, 1:])
    return due, adj, stopped, limit


def _plan(
    open_sched: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    tables: dict[str, np.ndarray],
    bank: dict[str, np.ndarray],
    last: np.ndarray,
    log_miss: np.ndarray,
    evidence: RiseEvidence,
) -> tuple[np.ndarray, ...]:
    """What `silence` reads of a bank whatever the time: the slipping tracks with a
    speed, their due times (waiting for the samples each ridge's rise is read from), the
    ridges ahead, whether each is the coast end, the probe width, the predicted onsets
    (global sample index) and the misses' log(1 - DETECT_P)."""
    due0 = open_sched[0]
    X, t, stop, run = bank["X"], bank["t"], bank["stop"], bank["run"]
    dirn, ridge = bank["dirn"], bank["ridge"]
    R = log_miss.shape[1] - 1
    S = due0.shape[1] - 1
    fs = evidence.fs_hz
    active = np.flatnonzero(np.isnan(stop) & (run >= 2))
    di = (1 - dirn[active]) // 2
    row = di * (R + 1) + np.minimum(ridge[active], R)
    k = np.minimum(ridge[active][:, None] + 1 + np.arange(S), R)
    coast = tables["coast"][row]
    v = np.maximum(X[active, 1], 1.0)
    tau = (tables["target"][row] - X[active, 0][:, None]) / v[:, None]
    width = evidence.width_for(v)
    onset = last[active][:, None] + tau * fs
    ready_s = t[active][:, None] + (tau * fs + (OFFSET + 3.0) * width[:, None] + 1) / fs
    when = np.where(last[active][:, None] >= 0, ready_s, -np.inf)
    due_a = np.maximum.accumulate(np.maximum(due0[active, 1:], when), axis=1)
    lm = log_miss[di[:, None], k]
    return active, due_a, k, coast, width, onset, lm

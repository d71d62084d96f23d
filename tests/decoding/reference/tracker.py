"""REFERENCE (tests only): the tracker's numpy branching, pruning and posterior as they were
at 0858d90, before each became a compiled kernel (`kernels.branch`, `kernels.prune`,
`kernels.posterior`); the kernels are checked against them call by call, in the same process
(tests/decoding/test_branch_kernel.py, test_prune_kernel.py, test_posterior_kernel.py).

The methods are those of `TrackerDecoder` at 0858d90, unchanged but for three things:
`NumpyTracker` reads the decoder it wraps (its constants, tables, tracks, null score,
detector) and never writes it (`_branch` keeps its own null score); `_prune` returns the rows
it keeps (the kernel's answer) instead of the bank; `_schedule` caches nothing on the bank
(and ends with the runtime's coast bound past the last ridge, `_coast_bounded`).

Every elementary operation whose bits may differ between numpy and the compiled kernels, or
between two CPUs, goes through `ops` (`Ops`): exp, log and erf (numpy's SIMD loops on one
CPU, libm on another, numba's libm calls in the kernels: each within a few ulps of the true
value, not equal), and the small matrix products of the Kalman prediction (numpy's matmul
calls BLAS, whose kernel - fused multiply-adds or not, its order of terms - depends on the
CPU; einsum's order is numpy's). `Ops.perturbed` moves each of their results by up to a
stated bound, so a test can measure how far those differences can carry through the rest of
the arithmetic (+ - * / sqrt and comparisons, which IEEE 754 rounds the same everywhere).
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
from scipy.special import erf

from grasplink.decoding import coast_bound
from grasplink.decoding.contacts import STEP_IDS, ContactEvent
from grasplink.decoding.kernels.layout import (
    CHANGING,
    F_A,
    F_BEFORE,
    F_COLS,
    F_D,
    F_M,
    F_S,
    F_SCORE,
    F_SIG,
    F_STOP,
    F_T,
    F_V,
    F_WIDTH,
    I_COLS,
    I_DIRN,
    I_FIRST,
    I_MODEL,
    I_N,
    I_RIDGE,
    I_RUN,
    I_WIDTH,
    P00,
    P01,
    P10,
    P11,
    P12,
    P13,
    P21,
    P22,
    P31,
    P33,
    STEADY,
)
from grasplink.decoding.tracker import (
    RING,
    V_MAX_MM_S,
    V_MIN_MM_S,
    TrackerDecoder,
    _Bank,
    _One,
)

# process noise of the Kalman prediction as one scatter per model: flat (4 x 4) index of each
# entry, and the powers of dt (columns of [1, dt, dt^2, dt^3]) and divisor of its term, in
# the order _kalman adds them (x * 1.0 and x / 1.0 are exact: the same bits as without)
_QV_AT, _QV_POW = np.array([0, 1, 4, 5]), np.array([3, 2, 2, 1])
_QV_DIV = np.array([3.0, 2.0, 2.0, 1.0])
_QJ_AT = np.array([0, 1, 4, 2, 8, 5, 6, 9, 10])
_QJ_POW1, _QJ_POW2 = np.array([3, 2, 2, 3, 3, 3, 2, 2, 1]), np.array([2, 2, 2, 0, 0, 0, 0, 0, 0])
_QJ_DIV = np.array([20.0, 8.0, 8.0, 6.0, 6.0, 3.0, 2.0, 2.0, 1.0])
_VAR_AT = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))  # covariance entries a sigma needs
# the columns of a bank's two matrices: the kernels' and the runtime's (`kernels.layout`),
# named as the numpy code of 0858d90 named them
_P, _X, _S, _V, _A, _D = F_COLS["P"], slice(F_S, F_D + 1), F_S, F_V, F_A, F_D
_M, _SCORE, _SIG, _STOP, _T, _BEFORE = F_M, F_SCORE, F_SIG, F_STOP, F_T, F_BEFORE
_DIRN, _FIRST, _IDS = I_DIRN, I_FIRST, I_COLS["ids"]
_MODEL, _N, _RIDGE, _RUN = I_MODEL, I_N, I_RIDGE, I_RUN
_F_WIDTH, _I_WIDTH = F_WIDTH, I_WIDTH
_P00, _P01, _P10, _P11, _P12, _P13, _P21, _P22, _P31, _P33 = (
    P00,
    P01,
    P10,
    P11,
    P12,
    P13,
    P21,
    P22,
    P31,
    P33,
)
# `_prune`'s dedup key, the int columns' part: the last three contact ids, ridge, direction
# and model weighted (mod 2^64, as the chained int64 multiply-adds wrap)
_KEY_M = 1000003
_KEY_WEIGHTS = np.zeros(_I_WIDTH, np.int64)
_KEY_WEIGHTS[[_IDS.stop - 1, _IDS.stop - 2, _IDS.stop - 3]] = [_KEY_M**3, _KEY_M**2, _KEY_M]
_KEY_WEIGHTS[[_RIDGE, _DIRN, _MODEL]] = [16, 4, 4]
EPS = float(np.finfo(float).eps)


class Ops:
    """The operations whose rounding is not fixed by IEEE 754 (see the module doc): plain,
    or - inside `perturbed` - each result moved by a random share (sign and size, per
    element) of a bound: `ulps` ulps of the value for exp, log and erf; for a matrix
    product A B, `terms` x eps x (|A| |B|), the rounding bound of a `terms`-term dot
    product in any order, fused or not. `rnd` marks an intermediate of the Kalman update
    computed from such results: once its inputs differ, its own rounding may fall the
    other way (1 ulp; there the update cancels: P - K P0 is small beside its terms).
    `magnify` scales every move, so that first-order effects stand out above the
    rounding of the outputs (their excursion divided by `magnify`)."""

    def __init__(self) -> None:
        self._rng: np.random.Generator | None = None
        self.ulps = 0.0
        self.terms = 0
        self.magnify = 1.0
        self.marks: list = []  # the decisions `_posterior` took (`mark`), in order

    def mark(self, decision):
        """Note a decision (a comparison of computed numbers: it can flip when they move)."""
        self.marks.append(
            np.array(decision, dtype=object)
            if decision is None or isinstance(decision, tuple)
            else np.asarray(decision).copy()
        )
        return decision

    @contextmanager
    def perturbed(
        self, rng: np.random.Generator, ulps: float, terms: int, magnify: float = 1.0
    ) -> Iterator[None]:
        self._rng, self.ulps, self.terms, self.magnify = rng, ulps, terms, magnify
        try:
            yield
        finally:
            self._rng = None

    def _nudge(self, value, scale):
        if self._rng is None:
            return value
        share = self._rng.uniform(-1.0, 1.0, np.shape(value)) * self.magnify
        with np.errstate(invalid="ignore"):  # (an infinity or NaN stays as it is)
            moved = value + share * scale
        return np.where(np.isfinite(value) & np.isfinite(scale), moved, value)

    def _fn(self, value):
        return self._nudge(value, self.ulps * EPS * np.abs(value))

    def rnd(self, value):
        return self._nudge(value, EPS * np.abs(value))

    def exp(self, x):
        return self._fn(np.exp(x))

    def log(self, x):
        return self._fn(np.log(x))

    def erf(self, x):
        return self._fn(erf(x))

    def mexp(self, x: float) -> float:
        return float(self._fn(math.exp(x)))

    def mlog(self, x: float) -> float:
        return float(self._fn(math.log(x)))

    def matmul(self, a, b):
        return self._nudge(a @ b, self.terms * EPS * (np.abs(a) @ np.abs(b)))

    def einsum(self, spec, a, b):
        return self._nudge(
            np.einsum(spec, a, b), self.terms * EPS * np.einsum(spec, np.abs(a), np.abs(b))
        )


ops = Ops()


def _nz(mask: np.ndarray) -> np.ndarray:
    return mask.nonzero()[0]


def _full(n: int, value: float) -> np.ndarray:
    out: np.ndarray = np.empty(n)
    out.fill(value)
    return out


def _clip(x: np.ndarray, low: float | np.ndarray, high: float | np.ndarray) -> np.ndarray:
    """np.clip's numbers; ties (+0 against -0) as np.clip breaks them."""
    if isinstance(low, np.ndarray):
        return np.minimum(np.maximum(x, low), high)
    return np.minimum(high, np.maximum(low, x))


def _concat(banks: list[_Bank]) -> _Bank:
    banks = [b for b in banks if len(b)]
    if not banks:
        return _Bank.empty()
    if len(banks) == 1:
        return banks[0]
    return _Bank(np.concatenate([b._f for b in banks]), np.concatenate([b._i for b in banks]))


def _with_score(B: _Bank, score: np.ndarray) -> _Bank:
    floats = B._f.copy()
    floats[:, _SCORE] = score
    return _Bank(floats, B._i)


def _with_contact(ints: np.ndarray, ev_id: int, ridge: np.ndarray, run) -> np.ndarray:
    """The int columns of tracks `ints` that assign contact ev_id to `ridge`: one more
    contact, `run`, and ev_id the last of their ids (a new matrix)."""
    out = ints.copy()
    out[:, _IDS.start : _IDS.stop - 1] = ints[:, _IDS.start + 1 : _IDS.stop]
    out[:, _IDS.stop - 1] = ev_id
    out[:, _N] += 1
    out[:, _RIDGE] = ridge
    out[:, _RUN] = run
    return out


def branch(dec: TrackerDecoder, ev: ContactEvent) -> tuple[_Bank, float]:
    """The numpy `_branch` of dec's tracks for contact ev: (children pool, null score after)."""
    ref = NumpyTracker(dec)
    with np.errstate(invalid="ignore", divide="ignore"):  # NaN and inf edge cases
        pool = ref._branch(ev)
    return pool, ref._null


def prune_choice(dec: TrackerDecoder, B: _Bank, recent, held) -> np.ndarray:
    """The rows of pool B the numpy `_prune` keeps, best first."""
    recent, held = np.asarray(recent, np.int64), np.asarray(held, np.int64)
    return NumpyTracker(dec)._prune(B, recent, held)


def posterior(dec: TrackerDecoder, g: float) -> tuple[tuple, list]:
    """The numpy `_posterior` of dec's tracks at g, and the decisions it took on the way
    (`Ops.mark`: schedule steps, what bounds the refresh, the choice, whether it reports,
    which tracks the agreement counts)."""
    ops.marks = []
    return NumpyTracker(dec)._posterior(g), ops.marks


class NumpyTracker:
    """The numpy methods over a live decoder's state (read through, never written)."""

    def __init__(self, dec: TrackerDecoder):
        self._dec = dec

    def __getattr__(self, name: str):
        return getattr(self._dec, name)

    def _branch(self, ev: ContactEvent) -> _Bank:
        """Every track's children for contact ev (updates the null score), unpruned; a step
        told at the sure hold is seldom a ridge the slip went on from (LOG_SURE_STEP_RIDGE)."""
        pool = self._children(ev)
        if ev.id not in self._sure or not len(pool):
            return pool
        floats, ints = pool._f.copy(), pool._i.copy()
        ridge = (ints[:, _IDS.stop - 1] == ev.id) & (ints[:, _N] >= 2) & np.isnan(floats[:, _STOP])
        floats[ridge, _SCORE] += self.LOG_SURE_STEP_RIDGE
        return _Bank(floats, ints)

    def _children(self, ev: ContactEvent) -> _Bank:
        """`_branch` before the sure-step weighting."""
        tc = ev.t_s
        B = self._retire(self._tracks, tc)
        step = ev.id in self._steps
        # a stop ends the rising trend of the level (the object no longer covers more of
        # the sensor): a step after which it went on is seldom one
        stop_rate = self.STOP_STEP_PER_S * (0.1 if self._steps.get(ev.id) else 1.0)
        probe = ev.id >= STEP_IDS
        if probe:  # a small step the kink bank missed: often a weak ridge pulse
            stop_rate *= self.PROBE_STOP
        best_before = max(self._null, float(B.score.max()) if len(B) else -math.inf)
        rate = self._clutter_rate(B, tc)
        children = []
        if len(B):
            moving = np.isnan(B.stop)
            if step:  # a grip change (slipping or not) or, slipping, a stop here
                children.append(_with_score(B, B.score + math.log(self.GRIP_STEP_PER_S)))
                stopping = B.take(_nz(moving & (B.n >= 2)))
                children.append(self._stopped_at(stopping, tc, math.log(stop_rate)))
            else:
                children.append(_with_score(B, B.score + ops.log(rate)))
            if probe:
                # a small step the kink bank missed: pulses after short spacings start on
                # the one before (thesis ch. 5.3.1) and pile up like a step - so perhaps a
                # ridge it could not time (mid-rise, loosely), or a stop, or a grip change
                loose = ev._replace(sigma_s=max(ev.sigma_s, self.PROBE_SIGMA_S))
                assigned = [
                    _with_score(c, c.score + self.LOG_PROBE_RIDGE) for c in self._assign(B, loose)
                ]
            else:
                assigned = self._assign(B, ev)
            children += assigned
            if step and assigned:  # a stop right at a ridge (the step is that ridge's contact)
                ridden = _concat(assigned)  # all at once: the numbers are per track
                at = ridden.take(_nz(ridden.n >= 2))
                children.append(self._stopped_at(at, tc, self.LOG_STOP_AT_RIDGE))
        self._null += self.LOG_CLUTTER_IDLE if not step else math.log(self.GRIP_STEP_PER_S)
        if probe:
            return _concat(children)
        # a new track starting at this contact: a slip starting (the earlier story ends
        # here) or, while one slips, reversing (the other edge leads, anywhere)
        base = _full(2, best_before + self.LOG_NEW_TRACK)
        if len(B):
            slipping = np.isnan(B.stop) & (B.n >= 2)
            for di, d in enumerate((1, -1)):
                way = slipping & (B.dirn == -d)
                if way.any():
                    reverse = float(B.score[way].max()) + self.LOG_REVERSE + math.log(2.0)
                    base[di] = max(base[di], reverse)
                same = slipping & (B.dirn == d)  # going on its way from an unplaced ridge
                if same.any() and math.isfinite(self.LOG_REBIRTH):
                    again = float(B.score[same].max()) + self.LOG_REBIRTH + math.log(2.0)
                    base[di] = max(base[di], again)
        children.append(self._births(ev, base + self._log_strength(ev.z)))
        return _concat(children)

    def _retire(self, B: _Bank, tc: float) -> _Bank:
        """B without the tracks whose last contact is longer before tc than the slowest
        slip takes to cross the skin (`_stale_s`): tc is no part of their slip, and one
        restarting there would carry minutes-old contacts (their count and pulse verdicts)
        into a new slip - held still for an hour, noise contacts minutes apart were chained
        into slips that way."""
        if not len(B):
            return B
        stale = tc - B.t > self._stale_s
        return B.take(_nz(~stale)) if stale.any() else B

    def _clutter_rate(self, B: _Bank, tc: float) -> np.ndarray:
        """Spurious contacts per s at tc under each track: detector false alarms, and while
        slipping the tipping front edge's, within TIP_MM of travel after a ridge contact."""
        rate = _full(len(B), self.CLUTTER_PER_S)
        moving = np.isnan(B.stop)
        dt = tc - B.t
        v = B.X[:, 1]
        di = (1 - B.dirn) // 2
        gap = self._gap[di, np.minimum(B.ridge, self.count - 1)]
        room = np.minimum(self.TIP_MM, gap - 2.0)
        tipping = moving & (gap >= self.TIP_GAP_MM)
        fast = tipping & (B.run >= 2) & (v * dt <= room)
        rate[fast] += self.P_TIP * v[fast] / room[fast]
        slow = tipping & (B.run == 1) & (dt <= self.TIP_S)
        rate[slow] += self.P_TIP / self.TIP_S
        return rate

    def _births(self, ev: ContactEvent, base: np.ndarray) -> _Bank:
        """One-contact tracks at every ridge, both ways; `base`: log prior per direction."""
        floats, ints = self._birth._f.copy(), self._birth._i.copy()
        ints[:, _FIRST] = ints[:, _IDS.stop - 1] = ev.id
        floats[:, _SCORE] = (base[:, None] + self._log_prior).ravel()
        floats[:, _SIG] = ev.sigma_s
        floats[:, _T] = ev.t_s
        return _Bank(floats, ints)

    def _stopped_at(self, B: _Bank, tc: float, log_prior: float | None = None) -> _Bank:
        """Copies of slipping tracks B that stopped at tc (a step), where they were then.

        `log_prior`: of the stop (by default STOP_STEP_PER_S, a density in time)."""
        if not len(B):
            return B
        s = self._travel(B, tc)
        limit = self._pos[(1 - B.dirn) // 2, np.minimum(B.ridge + 1, self.count)]
        prior = math.log(self.STOP_STEP_PER_S) if log_prior is None else log_prior
        floats = B._f.copy()
        floats[:, _S] = np.minimum(s, limit - 0.1)
        floats[:, _A] = 0.0  # the speed kept: when its next ridge was due
        floats[:, _STOP] = tc
        floats[:, _SCORE] = B.score + prior
        return _Bank(floats, B._i)

    def _assign(self, B: _Bank, ev: ContactEvent) -> list[_Bank]:
        """Children of B that assign contact ev to one of the next ridges (each branch type
        as one batch over tracks and ridges)."""
        dt = ev.t_s - B.t
        R = self.count
        di = (1 - B.dirn) // 2
        moving = np.isnan(B.stop)
        ok = dt > 0
        # every (skip, track) at once, skip-major: the order of one skip after the other
        k = B.ridge[:, None] + 1 + np.arange(self.MAX_SKIP + 1)
        valid = (ok[:, None] & (k < R)).T
        skip_arr, row = valid.nonzero()
        if not len(row):
            return []
        prior = self._skip_prior[di.take(row), B.ridge.take(row), skip_arr]
        run, mov = B.run[row], moving[row]
        out = []
        fresh = _nz(mov & (run == 1))  # one-contact or restarted tracks
        sel = _nz(mov & (run >= 2))  # slipping tracks with a speed
        # the Kalman filter; far off, the speed starts again from the last two contacts -
        # in one pass with the tracks whose speed comes from this contact and the last
        kalman, far, far_prior = _Bank.empty(), sel[:0], prior[:0]
        if len(sel):
            kalman, far, far_prior = self._kalman(B.take(row[sel]), ev, skip_arr[sel], prior[sel])
        again = np.concatenate([fresh, sel.take(far)])
        started, restarted = self._start_speed(
            B.take(row.take(again)),
            ev,
            skip_arr.take(again),
            np.concatenate([prior.take(fresh), far_prior]),
            len(fresh),
        )
        if len(fresh):
            out.append(started)
        if len(sel):
            out += [kalman, restarted]  # (joined with the other children, in this order)
            # or the slip stopped unseen and went on: a restart at the next ridge
            first = sel[skip_arr[sel] == 0]
            if len(first):
                at = B.take(row[first])
                di_at = (1 - at.dirn) // 2
                dist = self._pos[di_at, at.ridge + 1] - self._pos[di_at, at.ridge]
                reach = self._log_reach(dist, ev.t_s - at.t, self.RESTART_REACH)
                out.append(
                    self._restart(at, ev, at.ridge + 1, prior[first] + self.LOG_RESTART + reach)
                )
        # a stopped track restarting here
        sel = _nz(~mov)
        if len(sel):
            at = B.take(row[sel])
            log_rate = math.log(self.RESTART_PER_S)
            k = at.ridge + 1 + skip_arr[sel]
            dist = self._pos[(1 - at.dirn) // 2, k] - at.X[:, 0]
            reach = self._log_reach(dist, ev.t_s - at.stop, self.STOPPED_REACH)
            out.append(self._restart(at, ev, k, prior[sel] + log_rate + reach))
        return out

    def _log_reach(self, dist: np.ndarray, dt: np.ndarray, weight: float) -> np.ndarray:
        """weight x log P(speed >= dist / dt) under the speed prior, 0 where nothing is left
        to cover (`kernels.branch._log_reach`)."""
        if not weight > 0.0:
            return np.zeros(len(dist))
        far = dist > 0.0
        safe = np.where(far, dist, 1.0)
        z = ops.log(safe / (np.maximum(dt, 1e-9) * self.SPEED_PRIOR_MM_S)) * self._erf_scale
        reach = weight * ops.log(np.maximum(0.5 * (1.0 - ops.erf(z)), 1e-12))
        return np.where(far, reach, 0.0)

    def _restart(self, B: _Bank, ev: ContactEvent, k: np.ndarray, log_prior: np.ndarray) -> _Bank:
        """B restarted (speed unknown) with ev at ridge k."""
        di = (1 - B.dirn) // 2
        floats = np.zeros((len(B), _F_WIDTH))  # P, v and a: 0
        floats[:, _S] = self._pos[di, k]
        floats[:, _D] = B.X[:, 3]
        floats[:, _P33] = np.maximum(B.P[:, 3, 3], 0.0)
        floats[:, _M] = 1.0
        floats[:, _SCORE] = B.score + log_prior
        floats[:, _SIG] = ev.sigma_s
        floats[:, _STOP] = np.nan
        floats[:, _T] = ev.t_s
        # the speed it had (a restarted parent's own, 0, keeps the one before: added after
        # 0858d90, `restart_confirm`)
        floats[:, _BEFORE] = np.where(B.X[:, 1] > 0, B.X[:, 1], B.before)
        return _Bank(floats, _with_contact(B._i, ev.id, k, 1))

    def _start_speed(
        self,
        B: _Bank,
        ev: ContactEvent,
        skip: np.ndarray,
        log_prior: np.ndarray,
        fresh: int,
    ) -> tuple[_Bank, _Bank]:
        """Tracks at ridge k whose speed comes from their last contact and this one: the
        first `fresh` (one contact, or restarted) each in both motion models (with their
        priors); the rest (far off their Kalman prediction) in their own model, within
        MAX_SPEED_JUMP of their speed. Both kinds in one pass (the numbers are per track),
        returned apart."""
        tc = ev.t_s
        dt, k, target, decay, lag = self._toward_ridge(B, tc, skip)
        d = B.X[:, 3]
        v = (target - B.X[:, 0] + lag * d) / dt
        good = (v >= V_MIN_MM_S) & (v <= V_MAX_MM_S)
        v_ref = np.maximum(B.X[fresh:, 1], V_MIN_MM_S)
        v_far = v[fresh:]
        good[fresh:] &= (v_far * self.MAX_SPEED_JUMP >= v_ref) & (
            v_far <= self.MAX_SPEED_JUMP * v_ref
        )
        if not good.all():
            sel = _nz(good)
            fresh = int(np.count_nonzero(good[:fresh]))
            B, dt, k, target, decay, lag, d, v = (
                B.take(sel),
                dt[sel],
                k[sel],
                target[sel],
                decay[sel],
                lag[sel],
                d[sel],
                v[sel],
            )
            log_prior = log_prior[sel]
        N = len(B)
        if not N:
            return B, B
        r = self._meas_var(v, ev.sigma_s)
        r_before = self._meas_var(v, B.sig)

        def covariance(dip_prior_mm: float) -> np.ndarray:
            """The covariance, flat (N, 16)."""
            var_d = np.where(B.P[:, 3, 3] > 0, B.P[:, 3, 3], dip_prior_mm**2)
            P = np.zeros((N, 16))
            P[:, _P00] = r
            P[:, _P01] = P[:, _P10] = r / dt
            P[:, _P11] = (r + r_before + lag * lag * var_d) / (dt * dt)
            P[:, _P11] += (self.SPEED_INIT_REL * v) ** 2
            P[:, _P13] = P[:, _P31] = lag * var_d / dt
            P[:, _P33] = var_d
            return P

        P = covariance(self.DIP_PRIOR_MM)
        score = B.score + log_prior + self._log_speed_prior(v) - ops.log(dt)
        # changing: the mean speed over the interval is the speed half an interval ago
        sa = self.ACC_PER_S * v
        if self.DIP_PRIOR_CHANGING_MM == self.DIP_PRIOR_MM:  # the same numbers: built once
            Pc = P.copy()
        else:
            Pc = covariance(self.DIP_PRIOR_CHANGING_MM)
        half = dt / 2.0
        Pc[:, _P11] += (half * sa) ** 2
        Pc[:, _P12] = Pc[:, _P21] = half * sa * sa
        Pc[:, _P22] = sa * sa
        # the children's columns, built in place: the steady model's covariance first
        floats = np.empty((N, _F_WIDTH))
        floats[:, _P] = P
        floats[:, _S] = target
        floats[:, _V] = v
        floats[:, _A] = 0.0
        floats[:, _D] = d
        floats[:, _M] = 1.0 + B.m * decay
        floats[:, _SCORE] = score
        floats[:, _SIG] = ev.sigma_s
        floats[:, _STOP] = B.stop
        floats[:, _T] = tc
        floats[:, _BEFORE] = B.before
        ints = _with_contact(B._i, ev.id, k, 2)
        started = restarted = _Bank.empty()
        if fresh:  # each in both models: steady, then changing
            both_f = np.concatenate((floats[:fresh], floats[:fresh]))
            both_i = np.concatenate((ints[:fresh], ints[:fresh]))
            both_f[:fresh, _SCORE] = score[:fresh] + math.log(1.0 - math.exp(self.LOG_CHANGING))
            both_f[fresh:, _SCORE] = score[:fresh] + self.LOG_CHANGING
            both_f[fresh:, _P] = Pc[:fresh]
            both_i[:fresh, _MODEL] = STEADY
            both_i[fresh:, _MODEL] = CHANGING
            started = _Bank(both_f, both_i)
        if fresh < N:  # in their own model
            own_f = floats[fresh:]
            chg = _nz(ints[fresh:, _MODEL] == CHANGING)
            own_f[chg, _P] = Pc[fresh:].take(chg, 0)
            restarted = _Bank(own_f, ints[fresh:])
        return started, restarted

    def _toward_ridge(
        self, B: _Bank, tc: float, skip: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per track, for a contact at tc on the ridge after the next `skip`: time since
        its last contact, that ridge (index, position along the track's direction), how
        far the last ridge's speed dip has recovered, and the travel the dip lags by."""
        dt = tc - B.t
        di = (1 - B.dirn) // 2
        k = B.ridge + 1 + skip
        decay = ops.exp(-dt / self.DIP_RECOVERY_S)
        return dt, k, self._pos[di, k], decay, B.m * (1.0 - decay) + skip

    def _kalman(
        self, B: _Bank, ev: ContactEvent, skip: np.ndarray, log_prior: np.ndarray
    ) -> tuple[_Bank, np.ndarray, np.ndarray]:
        """Predict B to the contact and update with ridge k (robust: far off, the speed
        starts again from the last two contacts): the updated tracks, and those far off
        (indices into B, log prior with their likelihood) for `_start_speed`."""
        tc = ev.t_s
        N = len(B)
        dt, k, target, decay, lag = self._toward_ridge(B, tc, skip)
        X, P = B.X, B.P
        v = np.maximum(X[:, 1], V_MIN_MM_S)
        F = np.zeros((N, 4, 4))
        F[:, 0, 0] = F[:, 1, 1] = F[:, 2, 2] = F[:, 3, 3] = 1.0
        F[:, 0, 1] = F[:, 1, 2] = dt
        F[:, 0, 2] = 0.5 * dt * dt
        F[:, 0, 3] = -lag
        Xp = ops.einsum("nij,nj->ni", F, X)
        Pp = ops.matmul(ops.matmul(F, P), F.transpose(0, 2, 1))
        # process noise: the speed's random walk; the jerk of the changing model
        # (qv dt^3 / 3 at (0, 0), qv dt^2 / 2 at (0, 1) and (1, 0), qv dt at (1, 1); then
        # the jerk's terms: see _QJ_*), each entry's terms added in this order
        qv = self.SPEED_WALK**2 * v**3 / self.SPEED_WALK_MM
        dt2, dt3 = dt * dt, dt * dt * dt
        powers = np.empty((N, 4))
        powers[:, 0] = 1.0
        powers[:, 1] = dt
        powers[:, 2] = dt2
        powers[:, 3] = dt3
        flat = Pp.reshape(N, 16)
        flat[:, _QV_AT] += qv[:, None] * powers[:, _QV_POW] / _QV_DIV
        chg = B.model == CHANGING
        if chg.any():
            qj = np.where(chg, (self.JERK_PER_S2 * v) ** 2, 0.0)
            flat[:, _QJ_AT] += qj[:, None] * powers[:, _QJ_POW1] * powers[:, _QJ_POW2] / _QJ_DIV
        Pp = ops.rnd(flat.reshape(N, 4, 4))
        var = ops.rnd(Pp[:, 0, 0] + self._meas_var(v, ev.sigma_s) + skip * self.SIGMA_POS_MM**2)
        resid = ops.rnd(target - Xp[:, 0])
        inlier = (
            (1.0 - self.ROBUST_FLOOR)
            * v
            * ops.exp(-0.5 * resid * resid / var)
            / np.sqrt(2 * np.pi * var)
        )
        outlier = self.ROBUST_FLOOR * v / (4.0 * np.maximum(target - X[:, 0], 1.0))
        like = ops.log(inlier + outlier)
        K = ops.rnd(Pp[:, :, 0] / var[:, None])
        Xn = ops.rnd(Xp + ops.rnd(K * resid[:, None]))
        Xn[:, 3] = _clip(Xn[:, 3], 0.0, self.DIP_MAX_MM)
        Pn = ops.rnd(Pp - ops.rnd(K[:, :, None] * Pp[:, None, 0, :]))
        Pn = ops.rnd(0.5 * (Pn + Pn.transpose(0, 2, 1)))
        good = (inlier >= outlier) & (Xn[:, 1] >= V_MIN_MM_S) & (Xn[:, 1] <= V_MAX_MM_S)
        out = _Bank.empty()
        sel = _nz(good)
        if len(sel):
            floats = np.empty((len(sel), _F_WIDTH))
            floats[:, _P] = Pn.reshape(N, 16).take(sel, 0)
            floats[:, _X] = Xn.take(sel, 0)
            floats[:, _M] = 1.0 + B.m.take(sel) * decay.take(sel)
            floats[:, _SCORE] = B.score.take(sel) + log_prior.take(sel) + like.take(sel)
            floats[:, _SIG] = ev.sigma_s
            floats[:, _STOP] = B.stop.take(sel)
            floats[:, _T] = tc
            floats[:, _BEFORE] = B.before.take(sel)
            ints = B._i.take(sel, 0)
            out = _Bank(floats, _with_contact(ints, ev.id, k.take(sel), ints[:, _RUN] + 1))
        # far off: the speed changed; it starts again from the last two contacts
        far = _nz(inlier < outlier)
        return out, far, log_prior[far] + like[far]

    def _meas_var(self, v, sigma_t):
        """Variance of a ridge contact as a position measurement at speed v."""
        return self.SIGMA_POS_MM**2 + (v * sigma_t) ** 2

    def _log_speed_prior(self, v: np.ndarray) -> np.ndarray:
        """Log density of ln(v): log-normal around the usual slip speeds."""
        z = ops.log(v / self.SPEED_PRIOR_MM_S) / self.SPEED_PRIOR_LOG_SIGMA
        return -0.5 * z * z - math.log(self.SPEED_PRIOR_LOG_SIGMA * math.sqrt(2.0 * math.pi))

    def _prune(self, B: _Bank, recent: np.ndarray, held: np.ndarray) -> np.ndarray:
        """Best first, one per (direction, ridge, model, state, last three contacts); bounded.

        Tracks with two or more contacts: the best max_hypotheses, plus the best
        PER_START of every contact a track starts at while that contact is in the
        bounded history (`held`), so that a slip whose true start came after a
        spurious contact is not crowded out by the tracks that took the spurious
        one for its start (an older start competes on score alone: memory stays
        bounded however long the stream). One-contact tracks (a slip starting at
        one of the `recent` contacts) are all kept.
        """
        if not len(B):
            return B
        # decided on the fields it needs in score order; the bank is taken once, at the end
        score = B.score
        order = (-score).argsort(kind="stable")
        ints = B._i.take(order, 0)  # the int columns in score order
        # the key ((id[-1] M + id[-2]) M + id[-3]) M + state, state = 16 ridge + 8 (dirn > 0)
        # + 4 model + 2 slipping + (run == 1), wrapping as int64 does: as one int matmul
        # (the same sum mod 2^64, less the constant 4 of 8 (dirn > 0) = 4 dirn + 4)
        key = ints @ _KEY_WEIGHTS + np.isnan(B.stop.take(order)) * 2 + (ints[:, _RUN] == 1)
        # the first of each key (np.unique's return_index: a stable sort, each run's head)
        perm = key.argsort(kind="mergesort")
        aux = key.take(perm)
        head = np.empty(len(aux), bool)
        head[0] = True
        np.not_equal(aux[1:], aux[:-1], out=head[1:])
        keep = np.zeros(len(B), bool)
        keep[perm[head]] = True
        score = score.take(order)
        keep &= score >= score[0] - self.NEGLIGIBLE - 20.0
        # one-contact tracks: only those starting at a recent contact
        single = ints[:, _N] == 1
        last = ints[:, _IDS.stop - 1]
        recent_start = np.zeros(len(B), bool)
        for r in recent.tolist():
            recent_start |= last == r
        keep &= ~single | recent_start
        idx = _nz(keep & ~single)
        # the best max_hypotheses, and the best PER_START of each start contact held
        rank = np.arange(len(idx))
        ok = rank < self.max_hypotheses
        if len(idx) and len(held):
            # rank within each start contact: a stable sort by start, counted from each
            # run's head
            firsts = ints[:, _FIRST].take(idx)
            by_start = firsts.argsort(kind="stable")
            starts = firsts.take(by_start)
            head = np.empty(len(starts), bool)
            head[0] = True
            np.not_equal(starts[1:], starts[:-1], out=head[1:])
            group_rank = rank - np.maximum.accumulate(np.where(head, rank, 0))
            held_sorted = held.copy()
            held_sorted.sort()
            at = np.minimum(held_sorted.searchsorted(starts), len(held_sorted) - 1)
            quota = (group_rank < self.PER_START) & (held_sorted.take(at) == starts)
            ok[by_start[quota]] = True
        keep[idx[~ok]] = False
        chosen = order.take(_nz(keep))
        return chosen

    def _travel(self, B: _Bank, g: float, past_last: bool = False) -> np.ndarray:
        """Travel of slipping tracks B extrapolated to g: speed changing at the track's
        acceleration (bounded to 0.25-4x; `past_last`: as carried on past the last ridge),
        less the ridge dip still recovering."""
        tau = np.maximum(0.0, g - B.t)
        v, a, d = B.X[:, 1], B.X[:, 2], B.X[:, 3]
        if past_last:
            a = self._acceleration(a, B.P[:, 2, 2], B.ridge)
        v_end = _clip(v + a * tau, 0.25 * v, 4.0 * v)
        decay = ops.exp(-tau / self.DIP_RECOVERY_S)
        return B.X[:, 0] + 0.5 * (v + v_end) * tau - d * B.m * (1.0 - decay)

    def _acceleration(self, a, p22, ridge):
        """The acceleration tracks at `ridge` carry on with (variance p22): past the last
        ridge no contact can confirm a braking, so only as much of it as the contacts
        before made certain, LAST_BRAKE_Z sigma gentler (added after 0858d90)."""
        gentler = np.minimum(0.0, a + self.LAST_BRAKE_Z * np.sqrt(np.maximum(p22, 0.0)))
        return np.where((ridge == self.count - 1) & (a < 0), gentler, a)

    def _schedule(self, B: _Bank):
        """Silence of slipping tracks with a speed: per track and ridge ahead (time due,
        score adjustment from then, stopped from then, next ridge not reached from then).
        All but the times due come from tables (`_silence_tables`); the times are
        computed for the active tracks only (the others keep the tables' values)."""
        T, R = self._silence_tables, self.count
        active = np.isnan(B.stop) & (B.run >= 2)
        di = (1 - B.dirn) // 2
        row = di * (R + 1) + np.minimum(B.ridge, R)
        at = row + active * (2 * (R + 1))
        due = T["due"].take(at, axis=0)
        adj = T["adj"].take(at, axis=0)
        stopped = T["stopped"].take(at, axis=0)
        limit = T["limit"].take(at, axis=0)
        act = _nz(active)
        if len(act):
            # every ridge ahead at once (tracks, SCHEDULE): elementwise the same numbers as
            # one ridge after the other, in a third of the numpy calls
            ra = row[act]
            X, P = B.X[act], B.P[act]
            s0, v, d = X[:, 0], np.maximum(X[:, 1], V_MIN_MM_S), X[:, 3]
            a = self._acceleration(X[:, 2], P[:, 2, 2], B.ridge[act])
            p00, p01, p11, p02, p12, p22 = (P[:, i, j, None] for i, j in _VAR_AT)
            coast = self._coast_end(di[act], v)[:, None]
            target = np.where(T["coast"][ra], coast, T["target"][ra])
            s0, a, v = s0[:, None], a[:, None], v[:, None]
            dist = np.maximum(target - s0, 1e-3)
            a_p = np.maximum(a, -self.ACC_FLOOR * v * v / dist)
            vv, a2 = v * v, 2.0 * a_p  # (the same numbers in every pass below)
            root = np.sqrt(np.maximum(vv + a2 * dist, 1e-9))
            tau = 2.0 * dist / (v + root)
            dm = (d * B.m[act])[:, None]
            for _ in range(2):  # the part of the dip recovered by then
                eff = dist + dm * (1.0 - ops.exp(-tau / self.DIP_RECOVERY_S))
                root = np.sqrt(np.maximum(vv + a2 * eff, 1e-9))
                tau = 2.0 * eff / (v + root)
            v_k = np.maximum(v + a_p * tau, 0.2 * v)
            tt = tau * tau  # tau**2 too: numpy squares exactly so
            var = p00 + 2 * tau * p01 + tt * p11 + tt * (p02 + tau * p12 + 0.25 * tau * tau * p22)
            span = np.minimum(np.sqrt(np.maximum(var, 0.0)) / v_k, self.SPAN_MAX_REL * tau)
            latency = _clip(self.DETECT_MM / v_k, self._min_latency, self._max_latency)
            latency = np.maximum(latency, self._latency_floor(B)[act, None])
            t_due = B.t[act, None] + tau + 3.0 * span + self.LATE_REL * tau + latency
            due[act, 1:] = np.where(T["done"][ra], np.inf, t_due)
        return self._coast_bounded(B, (due, adj, stopped, limit))

    def _coast_bounded(self, B: _Bank, sched: tuple) -> tuple:
        """The schedule with each slipping track stopped COAST_INTERVALS intervals past the
        last ridge (added after 0858d90: `decoding.coast_bound`, numpy in the runtime too,
        applied after the schedule kernel there; 0: as it is)."""
        if not self.COAST_INTERVALS or not len(B):
            return sched
        tracks = {"s": B.X[:, 0], "t": B.t, "v": B.X[:, 1], "stop": B.stop, "run": B.run}
        tracks |= {"dirn": B.dirn, "ridge": B.ridge}
        return coast_bound.bound(
            sched, tracks, self._pos, self._last_gaps, self.count, self.COAST_INTERVALS
        )

    def _coast_end(self, di, v):
        """How far a slip at speed v goes past the last ridge before silence alone says it
        stopped: past the skin no ridge tells, only the level (a stop's step, thesis ch. 4.3)
        - so at least the longest spacing, and COAST_S at that speed."""
        return self._pos[di, self.count - 1] + np.maximum(self._coast, self.COAST_S * v)

    def _x1(self, h: _One, s: float) -> float:
        return s if h.dirn > 0 else self.length - s

    def _where(self, h: _One, g: float, stopped: bool, limit: int) -> tuple[float, float, float]:
        """(travel of the edge from the first ridge met, speed, sigma) of one track at g."""
        di = (1 - h.dirn) // 2
        pos = self._pos[di]
        if h.stop == h.stop:  # stopped at a step: where it was then
            r = h.ridge
            gap = float(pos[min(r + 1, self.count)] - pos[r])
            held = max(math.sqrt(max(h.p00, 0.0)), 0.1 * gap)
            if stopped:
                return h.s, 0.0, held
            # not yet told stopped (its next ridge not yet due): moving on as before it
            ahead = float(pos[min(r + 1, self.count)])
            return min(h.s + h.v * max(0.0, g - h.stop), ahead), h.v, held
        tau = max(0.0, g - h.t)
        v = h.v
        a = float(self._acceleration(h.a, h.p22, h.ridge))
        v_end = min(max(v + a * tau, 0.25 * v), 4.0 * v)
        decay = ops.mexp(-tau / self.DIP_RECOVERY_S)
        s = h.s + 0.5 * (v + v_end) * tau - h.d * h.m * (1.0 - decay)
        speed = max(0.0, v_end - h.d * h.m * decay / self.DIP_RECOVERY_S)
        var = (
            h.p00
            + 2 * tau * h.p01
            + tau * tau * h.p11
            + tau * tau * (h.p02 + tau * h.p12 + 0.25 * tau * tau * h.p22)
        )
        sigma = math.sqrt(max(var, 0.0))
        end = float(pos[limit]) if limit < self.count else float(self._coast_end(di, v))
        s = min(s, end)
        if stopped:  # somewhere before the ridge it never reached: as likely anywhere
            start = float(pos[min(limit, self.count) - 1])
            sigma = max(sigma, (end - start) / math.sqrt(12.0))
            speed = 0.0
        if h.ridge == self.count - 1:
            sigma += 0.2 * max(0.0, s - float(pos[self.count - 1]))
        return s, speed, sigma

    def _stop_seen(self, B: _Bank, i: int) -> float:
        """When track i's stop at a step is told: the time of the next ridge due after the
        step at the speed it had (the one after the next when the step lies within 3 sigma
        of the next: it may be that ridge's contact), plus the detector's latency there,
        times STEP_STOP_WAIT."""
        v, s = float(B.X[i, 1]), float(B.X[i, 0])
        tau = float(B.stop[i] - B.t[i])
        P = B.P[i]
        sigma = math.sqrt(max(P[0, 0] + 2 * tau * P[0, 1] + tau * tau * P[1, 1], 0.0))
        pos = self._pos[(1 - B.dirn[i]) // 2]
        k = min(int(B.ridge[i]) + 1, self.count)
        if pos[k] - s <= 3.0 * sigma:
            k = min(k + 1, self.count)
        if k >= self.count:  # past the last ridge no contact is due: told at once
            return float(B.stop[i])
        latency = min(self._max_latency, max(self._min_latency, self.DETECT_MM / v))
        return float(B.stop[i]) + self.STEP_STOP_WAIT * (max(float(pos[k]) - s, 0.0) / v + latency)

    def _x(self, B: _Bank, s: np.ndarray) -> np.ndarray:
        return np.where(B.dirn > 0, s, self.length - s)

    def _posterior(self, g: float):
        """(valid until, chosen (index, stopped, limit) or None, P(slip), agreement,
        direction log odds) at g.

        Agreement: the share of the posterior that puts the edge within AGREE_MM of
        the chosen track's position (and, slipping, its speed within AGREE_SPEED).
        Direction log odds: the posterior mass of the slipping tracks, and the tracks just
        started (a slip starting or reversing), moving the chosen track's way over that
        moving the other way.
        """
        B = self._tracks
        until = g + self.REFRESH_S
        score = B.score
        best = float(score.max())
        live = score >= best - self.NEGLIGIBLE
        # silence
        due, adj_t, stop_t, limit_t = self._schedule(B)
        blind = self._blind(B.t, g)  # time on the rail since each track's contact: unseen
        # (None: none - the same numbers as subtracting and adding zeros)
        seen = g if blind is None else g - blind[:, None]
        j = np.add.reduce(due <= seen, axis=1) - 1  # (a bool sum without its wrapper)
        ops.mark(j)
        rows = np.arange(len(B))
        adj = adj_t[rows, j]
        running = np.isnan(B.stop)
        # braked to rest: even braking BRAKE_Z sigma gentler, the track's own motion brought
        # it below the slowest slip by now
        a_hi = self._acceleration(
            B.X[:, 2] + self.BRAKE_Z * np.sqrt(np.maximum(B.P[:, 2, 2], 0.0)), B.P[:, 2, 2], B.ridge
        )
        braking = running & (B.run >= 2) & (a_hi < 0)
        t_rest = np.full(len(B), np.inf)
        rest = np.maximum(V_MIN_MM_S, self.REST_SHARE * B.X[braking, 1])
        t_rest[braking] = B.t[braking] + (rest - B.X[braking, 1]) / a_hi[braking]
        braked = ops.mark(t_rest <= g)
        soon = t_rest[ops.mark(live & ~braked & (t_rest < np.inf))]
        if len(soon):
            until = min(until, float(soon.min()))
        # a stop at a step is told once the next ridge, had the slip gone on, would have
        # been decided (`TrackerDecoder.STEP_STOP_WAIT`): before that it is slipping on
        pending = np.zeros(len(B), bool)
        if self.STEP_STOP_WAIT > 0:
            for i in _nz(~running & (B.X[:, 1] > 0)):
                t_seen = self._stop_seen(B, int(i))
                if g < t_seen:
                    pending[i] = True
                    if live[i]:
                        until = min(until, t_seen)
        stopped = (stop_t[rows, j] | ~running | braked) & ~pending
        limit = limit_t[rows, j]
        upcoming = due[rows, np.minimum(j + 1, due.shape[1] - 1)]
        if blind is not None:
            upcoming = upcoming + blind
        upcoming = np.where(j + 1 < due.shape[1], upcoming, np.inf)
        nxt = upcoming[ops.mark(live & (upcoming > g))]
        if len(nxt):
            until = min(until, float(nxt.min()))
        waiting = running & (B.run == 1)
        w = _nz(waiting & live)
        if len(w):
            adj[w] = self._log_waiting(B, w, g, None if blind is None else blind[w])
        evident, bonus = self._evidence(B)
        total = np.where(live, score + adj + bonus, -np.inf)
        top = max(self._null, float(total.max()))
        weight = ops.exp(total - top)
        mass = ops.mexp(self._null - top) + float(weight.sum())
        slipping = evident & ~stopped
        p_slip = float(weight[slipping].sum()) / mass
        chosen = None
        if p_slip >= 0.5 and slipping.any():
            # the first best of the slipping tracks (one of them has weight)
            i = int(np.where(slipping, total, -np.inf).argmax())
            chosen = (i, False, int(limit[i]))
        else:
            cand = evident & stopped
            if cand.any():
                i = int(_nz(cand)[np.argmax(total[cand])])
                if total[i] >= self._null:
                    chosen = (i, True, int(limit[i]))
        ops.mark(chosen)
        if chosen is None:
            return (until, None, p_slip, 0.0, -math.inf)
        i, is_stopped, lim = chosen
        one = _One(B, i)
        odds = math.inf
        if not is_stopped:
            # the direction: the posterior mass of moving each way - slipping tracks, and
            # tracks just started at a contact (a slip starting or reversing)
            moving = (slipping | (waiting & live)) & np.isfinite(total)
            way = B.dirn == B.dirn[i]
            this = float(weight[moving & way].sum())
            other = float(weight[moving & ~way].sum())
            odds = ops.mlog(this / other) if other > 0 else math.inf
            if (
                one.run == 1
                or one.n < self.DIRECTION_CONTACTS
                or ops.mark(odds < self.LOG_REPORT_ODDS)
            ):
                return (until, (one, is_stopped, lim), p_slip, 0.0, odds)  # no estimate
        # agreement
        x_ref = self._x1(one, self._where(one, g, is_stopped, lim)[0])
        use = live & evident & (stopped == is_stopped) & (weight >= 1e-4 * mass)
        if not is_stopped:
            use &= (B.dirn == B.dirn[i]) & (
                np.abs(B.X[:, 1] - B.X[i, 1]) <= self.AGREE_SPEED * B.X[i, 1]
            )
        idx = _nz(ops.mark(use))
        agree = 0.0
        if len(idx):
            Bu = B.take(idx)
            s = self._travel(Bu, g, past_last=True)
            # held where the ridge not reached is, or where they stopped
            di = (1 - Bu.dirn) // 2
            ahead = np.minimum(limit[idx], self.count)
            end = np.where(
                ahead < self.count, self._pos[di, ahead], self._coast_end(di, Bu.X[:, 1])
            )
            s = np.where(np.isnan(Bu.stop), np.minimum(s, end), Bu.X[:, 0])
            xs = self._x(Bu, s)
            agree = float(weight[idx][ops.mark(np.abs(xs - x_ref) <= self.AGREE_MM)].sum()) / mass
        return (until, (one, is_stopped, lim), p_slip, agree, odds)

    def _blind(self, t: np.ndarray, g: float) -> np.ndarray | None:
        """Seconds of [t, g] the sensor sat on its upper rail (no contact can show there);
        None when it sat there for none of them."""
        out = None
        for r0, r1 in self.detector.blind:
            if r1 <= float(t.min(initial=g)) or r0 >= g:
                continue
            if out is None:
                out = np.zeros(len(t))
            out += np.clip(np.minimum(g, r1) - np.maximum(t, r0), 0.0, None)
        return out

    def _evidence(self, B: _Bank) -> tuple[np.ndarray, np.ndarray]:
        """Is it a slip (a contact fell back like a pulse, or many contacts and no step)?
        And the score bonus of the pulse verdicts on its recent contacts. (A slot never
        written holds id -1 and no verdict: an unused id, -1, reads no verdict there.)"""
        weight, bonus, evident, hold = self._evidence_tables
        ids = B.ids
        slot = ids % RING + np.where(ids >= STEP_IDS, RING, 0)  # (`kernels.common.ring_slot`)
        verdicts = np.where(self._ring_id.take(slot) == ids, self._ring.take(slot), 0)
        packed = np.add.reduce(weight.take(verdicts), axis=1)
        # speed unknown (restarted) and its last contact's verdict holds it: no slip yet
        held = (B.run == 1) & hold[0].take(verdicts[:, -1])
        # ... and a restart's first speed while neither of its two contacts is told a pulse
        # (`restart_confirm`, added after 0858d90)
        second = (B.run == 2) & (B.n > B.run)
        # unless that speed agrees with the one before the restart (`agrees`)
        rel = self.RESTART_AGREE_REL
        agree = (rel > 0) & (B.before > 0) & (np.abs(B.X[:, 1] - B.before) <= rel * B.before)
        second &= ~agree
        held |= second & hold[1].take(verdicts[:, -1]) & hold[1].take(verdicts[:, -2])
        return evident[np.minimum(B.n, 4) + 5 * held, packed], bonus.take(packed)

    def _log_waiting(
        self, B: _Bank, w: np.ndarray, g: float, blind: np.ndarray | None
    ) -> np.ndarray:
        """Log P(no contact detected yet) for tracks w whose speed is unknown (one contact,
        or restarted), g - t after their contact (less the time on the rail): every ridge
        ahead not yet reached under the speed prior, or reached and missed."""
        elapsed = g - B.t[w]
        if blind is not None:
            elapsed = elapsed - blind
        elapsed = elapsed - self._max_latency
        pos = elapsed > 0
        if not pos.any():
            return np.zeros(len(w))
        ahead_log, ahead_finite, ahead_before = self._waiting_tables
        row = (1 - B.dirn[w]) // 2 * self.count + np.minimum(B.ridge[w], self.count - 1)
        logd = ahead_log.take(row, axis=0)  # (N, R + 1): the ridges ahead, the coast end
        shift = ops.log(np.maximum(elapsed, 1e-9) * self.SPEED_PRIOR_MM_S)
        nr = 0.5 * (1.0 + ops.erf((logd - shift[:, None]) * self._erf_scale))
        # P(reached ridge j but not j+1) weighted by P(all missed up to j)
        cdf = np.zeros((len(w), nr.shape[1] + 1))
        cdf[:, 1:] = np.where(ahead_finite.take(row, axis=0), nr, 1.0)
        step = cdf[:, 1:] - cdf[:, :-1]
        total = np.add.reduce(ahead_before.take(row, axis=0) * step, axis=1)  # past the coast
        return np.where(pos, ops.log(np.maximum(total, 1e-12)), 0.0)  # end: stopped

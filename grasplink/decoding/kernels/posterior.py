"""The tracker's posterior as compiled kernels: each track's silence schedule, and what
the posterior over the tracks says at a time g (`TrackerDecoder._posterior` reads it).

The formulas and their order are the numpy code's (see the tracker's docstrings for
what they mean); sums keep numpy's pairwise order. exp, log and erf come from LLVM's
libm, not numpy's SIMD loops or scipy: the same numbers to an ulp or so.

Constants come in one float vector, `K`, indexed by the names below (the decoder
packs it once with `constants`). The arrays come in named bundles: the tracks' fields
(`Tracks`), the silence tables (`Silence` to make a schedule, `Schedule` made), the pulse
verdicts (`Verdicts`), the tables of a track waiting for its speed (`Waiting`) and the
skin (`Skin`); `where` takes one track's numbers (`One`) and what silence says of it
(`Bound`). A caller builds each by name and passes it as a plain tuple (`tuple(bundle)`;
a bundle of plain numbers made per call is written in its order instead: making the
NamedTuple by name costs some microseconds in Python); the kernel names it again on
entry (`Tracks(*tracks)`). numba types a plain tuple's arrays in C and a NamedTuple's in
Python on every call: 1.7 against 8.3 us a call for a bundle of three arrays, and the
posterior takes 25.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from grasplink.decoding.kernels import jit
from grasplink.decoding.kernels.common import pack, ring_slot, travel

NAMES = (
    "negligible",
    "refresh_s",
    "v_min_mm_s",
    "acc_floor",
    "dip_recovery_s",
    "detect_mm",
    "late_rel",
    "min_latency_s",
    "max_latency_s",
    "coast_mm",
    "coast_s",
    "length_mm",
    "agree_mm",
    "agree_speed",
    "direction_contacts",
    "log_report_odds",
    "speed_prior_mm_s",
    "erf_scale",
    "bound_share",
    "span_max_rel",
    "brake_z",
    "step_stop_wait",
    "last_brake_z",
    "rest_share",
    "silence_brake",
    "restart_agree_rel",
)
(
    NEGLIGIBLE,
    REFRESH_S,
    V_MIN,
    ACC_FLOOR,
    DIP_S,
    DETECT_MM,
    LATE_REL,
    MIN_LATENCY,
    MAX_LATENCY,
    COAST_MM,
    COAST_S,
    LENGTH_MM,
    AGREE_MM,
    AGREE_SPEED,
    DIRECTION_CONTACTS,
    LOG_REPORT_ODDS,
    SPEED_PRIOR,
    ERF_SCALE,
    BOUND_SHARE,
    SPAN_MAX_REL,
    BRAKE_Z,
    STEP_STOP_WAIT,
    LAST_BRAKE_Z,
    REST_SHARE,
    SILENCE_BRAKE,
    RESTART_AGREE_REL,
) = range(len(NAMES))


class Tracks(NamedTuple):
    """The tracks' fields (a bank's views: `tracker._Bank`)."""

    score: np.ndarray
    X: np.ndarray  # (s, v, a, d) per track
    P: np.ndarray  # covariance (4 x 4) per track
    m: np.ndarray
    t: np.ndarray
    stop: np.ndarray
    dirn: np.ndarray
    ridge: np.ndarray
    run: np.ndarray
    n: np.ndarray
    ids: np.ndarray
    before: np.ndarray  # the speed before its last restart (0: none)


class Silence(NamedTuple):
    """The silence tables by (direction, ridge) row and ridge ahead (`TrackerDecoder.
    _silence_tables`): time due, score adjustment, stopped, next ridge not reached (the
    first two rows per direction for idle tracks, then for active ones), and for the
    active tracks' times due: done, coasting past the last ridge, the target travel."""

    due: np.ndarray
    adj: np.ndarray
    stopped: np.ndarray
    limit: np.ndarray
    done: np.ndarray
    coast: np.ndarray
    target: np.ndarray


class Schedule(NamedTuple):
    """Per track and ridge ahead (`schedule`'s): time due, score adjustment, stopped,
    next ridge not reached."""

    due: np.ndarray
    adj: np.ndarray
    stopped: np.ndarray
    limit: np.ndarray


class Verdicts(NamedTuple):
    """The pulse verdicts on recent contacts: the ring and the ids it holds, and what a
    track's count of them says (`_evidence`)."""

    ring: np.ndarray
    ring_id: np.ndarray
    weight: np.ndarray
    bonus: np.ndarray
    evident: np.ndarray
    hold: np.ndarray


class Waiting(NamedTuple):
    """A track waiting for its speed: per (direction, ridge) row and ridge ahead, the log
    of the distance, whether finite, and P(all before it missed) (`_log_waiting`)."""

    log: np.ndarray
    finite: np.ndarray
    before: np.ndarray


class One(NamedTuple):
    """One track's numbers (`tracker._One`, `where`): travel s, speed v, acceleration a, dip
    d, dip memory m, time t of its last contact, stop (NaN: slipping), the covariance
    entries `where` reads, direction and the ridge of its last contact."""

    s: float
    v: float
    a: float
    d: float
    m: float
    t: float
    stop: float
    p00: float
    p01: float
    p11: float
    p02: float
    p12: float
    p22: float
    dirn: int
    ridge: int


class Bound(NamedTuple):
    """What silence says of a track (`where`): no contact told in the `silent` s after
    its contact, so by then it travelled less than `reach` mm (inf: no bound)."""

    reach: float
    silent: float


class Skin(NamedTuple):
    """The skin and the decoder: ridge positions (2, R + 1) and the constants `K`."""

    pos: np.ndarray
    K: np.ndarray


def constants(**values: float) -> np.ndarray:
    """The constants vector `K` from its named values (every name in NAMES, no other)."""
    return pack(NAMES, values, "posterior")


@jit()
def pairwise_sum(x: np.ndarray) -> float:
    """Sum in numpy's pairwise order (np.add.reduce on a contiguous float64 vector)."""
    n = len(x)
    if n < 8:
        total = -0.0
        for i in range(n):
            total += x[i]
        return total
    if n <= 128:
        r = x[:8].copy()
        i = 8
        while i < n - n % 8:
            for k in range(8):
                r[k] += x[i + k]
            i += 8
        total = (r[0] + r[1] + (r[2] + r[3])) + (r[4] + r[5] + (r[6] + r[7]))
        while i < n:
            total += x[i]
            i += 1
        return total
    half = n // 2
    half -= half % 8
    return pairwise_sum(x[:half]) + pairwise_sum(x[half:])


@jit()
def acceleration(a: float, p22: float, ridge: int, R: int, K: np.ndarray) -> float:
    """The acceleration a track at `ridge` carries on with (variance p22): past the last
    ridge (R - 1) no contact can confirm a braking, so only as much of it as the contacts
    before made certain, LAST_BRAKE_Z sigma gentler (`TrackerDecoder.LAST_BRAKE_Z`)."""
    if ridge == R - 1 and a < 0:
        return min(0.0, a + K[LAST_BRAKE_Z] * math.sqrt(max(p22, 0.0)))
    return a


@jit()
def coast_end(pos: np.ndarray, di: int, v: float, K: np.ndarray) -> float:
    """How far a slip at speed v goes past the last ridge before silence alone says it
    stopped (`TrackerDecoder._coast_end`)."""
    return pos[di, pos.shape[1] - 2] + np.maximum(K[COAST_MM], K[COAST_S] * v)


@jit()
def schedule(
    tracks: tuple, tables: tuple, skin: tuple, floor: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per track and ridge ahead: time due, score adjustment, stopped, next ridge not
    reached, from then on (`TrackerDecoder._schedule`): the tables' rows, and for the
    slipping tracks with a speed the times due computed. `floor`: each track's least
    latency (`TrackerDecoder._latency_floor`). `tracks`, `tables`, `skin`: a `Tracks`,
    `Silence` and `Skin` as plain tuples; returns a `Schedule`'s (a plain tuple)."""
    tracks, tables, skin = Tracks(*tracks), Silence(*tables), Skin(*skin)
    X, P, m, t, stop = tracks.X, tracks.P, tracks.m, tracks.t, tracks.stop
    dirn, ridge, run = tracks.dirn, tracks.ridge, tracks.run
    due_t, adj_t, stopped_t, limit_t = tables.due, tables.adj, tables.stopped, tables.limit
    done_t, coast_t, target_t = tables.done, tables.coast, tables.target
    pos, K = skin.pos, skin.K
    N = len(t)
    R = pos.shape[1] - 1
    S = done_t.shape[1]
    J = due_t.shape[1]
    due = np.empty((N, J))
    adj = np.empty((N, J))
    stopped = np.empty((N, J), np.bool_)
    limit = np.empty((N, J), np.int64)
    for n in range(N):
        active = np.isnan(stop[n]) and run[n] >= 2
        di = (1 - dirn[n]) // 2
        row = di * (R + 1) + min(ridge[n], R)
        at = row + (2 * (R + 1) if active else 0)
        due[n] = due_t[at]
        adj[n] = adj_t[at]
        stopped[n] = stopped_t[at]
        limit[n] = limit_t[at]
        if not active:
            continue
        s0, v, d = X[n, 0], np.maximum(X[n, 1], K[V_MIN]), X[n, 3]
        a = acceleration(X[n, 2], P[n, 2, 2], ridge[n], R, K)
        p00, p01, p11 = P[n, 0, 0], P[n, 0, 1], P[n, 1, 1]
        p02, p12, p22 = P[n, 0, 2], P[n, 1, 2], P[n, 2, 2]
        coast = coast_end(pos, di, v, K)
        dm = d * m[n]
        vv = v * v
        for j in range(S):
            target = coast if coast_t[row, j] else target_t[row, j]
            dist = np.maximum(target - s0, 1e-3)
            a_p = np.maximum(a, -K[ACC_FLOOR] * v * v / dist)
            a2 = 2.0 * a_p
            root = math.sqrt(np.maximum(vv + a2 * dist, 1e-9))
            tau = 2.0 * dist / (v + root)
            for _ in range(2):  # the part of the dip recovered by then
                eff = dist + dm * (1.0 - math.exp(-tau / K[DIP_S]))
                root = math.sqrt(np.maximum(vv + a2 * eff, 1e-9))
                tau = 2.0 * eff / (v + root)
            v_k = np.maximum(v + a_p * tau, 0.2 * v)
            tt = tau * tau
            var = p00 + 2 * tau * p01 + tt * p11 + tt * (p02 + tau * p12 + 0.25 * tau * tau * p22)
            span = min(math.sqrt(np.maximum(var, 0.0)) / v_k, K[SPAN_MAX_REL] * tau)
            latency = np.minimum(K[MAX_LATENCY], np.maximum(K[MIN_LATENCY], K[DETECT_MM] / v_k))
            latency = max(latency, floor[n])
            t_due = t[n] + tau + 3.0 * span + K[LATE_REL] * tau + latency
            due[n, j + 1] = np.inf if done_t[row, j] else t_due
    return due, adj, stopped, limit


@jit()
def stop_seen(
    s: float,
    v: float,
    stop: float,
    sigma: float,
    dirn: int,
    ridge: int,
    pos: np.ndarray,
    K: np.ndarray,
) -> float:
    """When a track's stop at a step (at `stop`, travel s, speed v before it, s's sigma
    then) is told: the time of the next ridge due after the step at that speed - the one
    after the next when the step lies within 3 sigma of the next (it may be that ridge's
    contact) -, plus the detector's latency there, times STEP_STOP_WAIT
    (`TrackerDecoder.STEP_STOP_WAIT`); at once when no ridge is ahead."""
    R = pos.shape[1] - 1
    di = (1 - dirn) // 2
    k = min(ridge + 1, R)
    if pos[di, k] - s <= 3.0 * sigma:
        k = min(k + 1, R)
    if k >= R:  # past the last ridge no contact is due: told at once
        return stop
    latency = min(K[MAX_LATENCY], max(K[MIN_LATENCY], K[DETECT_MM] / v))
    return stop + K[STEP_STOP_WAIT] * (max(pos[di, k] - s, 0.0) / v + latency)


@jit()
def where(
    one: tuple, g: float, stopped: bool, limit: int, bound: tuple, skin: tuple
) -> tuple[float, float, float]:
    """(travel of the edge from the first ridge met, speed, sigma) of one track at g
    (`TrackerDecoder._where`). Silence bounds it: no contact told in the `bound.silent` s
    after the track's contact, so by then it travelled less than `bound.reach` mm (inf:
    no bound) - its acceleration is capped to keep it there (`TrackerDecoder.
    SILENCE_REACH`). `one`, `bound`, `skin`: a `One`, `Bound` and `Skin` as plain tuples."""
    one, bound, skin = One(*one), Bound(*bound), Skin(*skin)
    s, v, a, d, m, t, stop = one.s, one.v, one.a, one.d, one.m, one.t, one.stop
    p00, p01, p11, p02, p12, p22 = one.p00, one.p01, one.p11, one.p02, one.p12, one.p22
    dirn, ridge = one.dirn, one.ridge
    reach, silent = bound.reach, bound.silent
    pos, K = skin.pos, skin.K
    R = pos.shape[1] - 1
    di = (1 - dirn) // 2
    if stop == stop:  # stopped at a step: where it was then
        gap = pos[di, min(ridge + 1, R)] - pos[di, ridge]
        held = max(math.sqrt(max(p00, 0.0)), 0.1 * gap)
        if stopped:
            return s, 0.0, held
        # not yet told stopped (its next ridge not yet due): moving on as before it
        return min(s + v * max(0.0, g - stop), pos[di, min(ridge + 1, R)]), v, held
    tau = max(0.0, g - t)
    a = acceleration(a, p22, ridge, R, K)
    mean = np.inf  # the mean speed silence allows since t
    if silent > 0 and reach < np.inf:
        # from v at t on with a constant acceleration, travel (less the dip lost by then)
        # stays below reach until t + silent; below v only as `SILENCE_BRAKE` allows
        lost = d * m * (1.0 - math.exp(-silent / K[DIP_S]))
        mean = (reach + lost) / silent
        a_max = 2.0 * (mean - v) / silent
        if K[SILENCE_BRAKE] < 2:
            a_max = max(a_max, min(a, 0.0))
        a = min(a, a_max)
    v_end = min(max(v + a * tau, 0.25 * v), 4.0 * v)
    # the speed shown: at most that mean, unless below v (SILENCE_BRAKE 0) or v / 4 (1)
    v_end = min(v_end, max(mean, (1.0 if K[SILENCE_BRAKE] < 1 else 0.25) * v))
    decay = math.exp(-tau / K[DIP_S])
    x = s + 0.5 * (v + v_end) * tau - d * m * (1.0 - decay)
    speed = max(0.0, v_end - d * m * decay / K[DIP_S])
    var = (
        p00
        + 2 * tau * p01
        + tau * tau * p11
        + tau * tau * (p02 + tau * p12 + 0.25 * tau * tau * p22)
    )
    sigma = math.sqrt(max(var, 0.0))
    end = pos[di, limit] if limit < R else coast_end(pos, di, v, K)
    x = min(x, end)
    if stopped:  # somewhere before the ridge it never reached: as likely anywhere
        start = pos[di, min(limit, R) - 1]
        sigma = max(sigma, (end - start) / math.sqrt(12.0))
        speed = 0.0
    if ridge == R - 1:
        sigma += 0.2 * max(0.0, x - pos[di, R - 1])
    return x, speed, sigma


@jit()
def _log_waiting(
    elapsed: float,
    row: int,
    ahead_log: np.ndarray,
    ahead_finite: np.ndarray,
    ahead_before: np.ndarray,
    K: np.ndarray,
) -> float:
    """Log P(no contact detected yet) for a track whose speed is unknown, `elapsed`
    after its contact less the detector's latency (`TrackerDecoder._log_waiting`)."""
    if not elapsed > 0:
        return 0.0
    shift = math.log(np.maximum(elapsed, 1e-9) * K[SPEED_PRIOR])
    C = ahead_log.shape[1]
    step = np.empty(C)
    before = 0.0
    for c in range(C):
        nr = 0.5 * (1.0 + math.erf((ahead_log[row, c] - shift) * K[ERF_SCALE]))
        now = nr if ahead_finite[row, c] else 1.0
        step[c] = ahead_before[row, c] * (now - before)
        before = now
    return math.log(np.maximum(pairwise_sum(step), 1e-12))


def log_waiting(elapsed_s: float, row: int, waiting: tuple, K: np.ndarray) -> float:
    """Log P(no ridge contact told yet) for a track of row `row` (direction x ridge) whose
    speed is unknown, `elapsed_s` after its contact less the detector's latency, from the
    waiting tables `waiting` (a `Waiting`: the tracker's `_waiting`) and constants `K`.

    The posterior weighs its waiting tracks with this (`_log_waiting`, inside the kernel);
    a rule that asks the same question outside it (`decoding.arrival_flag`) calls this
    rather than the kernel's private helper, so both read one definition, bit for bit."""
    log, finite, before = waiting
    return float(_log_waiting(elapsed_s, row, log, finite, before, K))


@jit()
def agrees(speed_mm_s: float, before_mm_s: float, agree_rel: float) -> bool:
    """Does a restarted track's first speed agree with the one it had before it stopped:
    within `agree_rel` of it (`restart_confirm`: a slip going on after a stick resumes
    about its speed; two kinks at rest give any). False when none is known (0) or off."""
    if not (agree_rel > 0 and before_mm_s > 0):
        return False
    return abs(speed_mm_s - before_mm_s) <= agree_rel * before_mm_s


@jit()
def _evidence(
    ids: np.ndarray,
    n: np.ndarray,
    run: np.ndarray,
    ring: np.ndarray,
    ring_id: np.ndarray,
    weight_t: np.ndarray,
    bonus_t: np.ndarray,
    evident_t: np.ndarray,
    hold_t: np.ndarray,
    speed: np.ndarray,
    before: np.ndarray,
    agree_rel: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Per track: is it evidently a slip, and its score bonus, from the pulse verdicts on
    its recent contacts (`TrackerDecoder._evidence_tables`): a contact's verdict counts
    where the ring of verdicts still holds that contact's id. A track whose speed is
    unknown (run 1) reads rows 5-9 (not evident) when its last contact's verdict holds it
    (`hold_t[0]`: a restart on a contact told a step is no slip yet); a restarted track's
    first speed (run 2, with contacts before the restart: n > run) too while both its
    restart contact and the one after it are held by `hold_t[1]` (`restart_confirm`: two
    kinks at rest are no restart until one is told a pulse or a third contact comes) - unless
    that speed (`speed`, X's v) is within `agree_rel` of the one the track had before it
    restarted (`before`; `agrees`)."""
    N, R, last_c = ids.shape[0], len(ring), ids.shape[1] - 1
    evident = np.empty(N, np.bool_)
    bonus = np.empty(N)
    for i in range(N):
        packed = 0
        for c in range(ids.shape[1]):
            slot = ring_slot(ids[i, c], R)
            if ring_id[slot] == ids[i, c]:
                packed += weight_t[ring[slot]]
        last = ids[i, last_c]
        slot = ring_slot(last, R)
        verdict = ring[slot] if ring_id[slot] == last else 0
        held = run[i] == 1 and hold_t[0, verdict]
        if run[i] == 2 and n[i] > run[i] and hold_t[1, verdict]:
            first = ids[i, last_c - 1]
            slot = ring_slot(first, R)
            held = hold_t[1, ring[slot] if ring_id[slot] == first else 0]
            held = held and not agrees(speed[i], before[i], agree_rel)
        evident[i] = evident_t[min(n[i], 4) + 5 * held, packed]
        bonus[i] = bonus_t[packed]
    return evident, bonus


@jit()
def posterior(
    g: float,
    null: float,
    tracks: tuple,
    sched: tuple,
    blind: np.ndarray,
    has_blind: bool,
    verdicts: tuple,
    waiting_t: tuple,
    skin: tuple,
) -> tuple[float, int, bool, int, float, float, float, int, float, float, float]:
    """(valid until, chosen track or -1, stopped, its limit, P(slip), agreement, direction
    log odds, then the speed whichever way (`_magnitude`): its track or -1, the share
    agreeing on it, the range of speeds) at g: `TrackerDecoder._posterior`. `tracks.ids`:
    each track's recent contacts, whose pulse verdicts (`verdicts`: see `_evidence`) tell
    a slip; `blind` (if `has_blind`) the time each track's contact has
    spent on the sensor's rail since. The bundles (a `Tracks`, `Schedule`, `Verdicts`,
    `Waiting`, `Skin`) come as plain tuples."""
    tracks, sched, verdicts = Tracks(*tracks), Schedule(*sched), Verdicts(*verdicts)
    waiting_t, skin = Waiting(*waiting_t), Skin(*skin)
    score, X, P, m, t, stop = tracks.score, tracks.X, tracks.P, tracks.m, tracks.t, tracks.stop
    dirn, ridge, run, n, ids = tracks.dirn, tracks.ridge, tracks.run, tracks.n, tracks.ids
    due, adj_t, stop_t, limit_t = sched.due, sched.adj, sched.stopped, sched.limit
    ring, ring_id = verdicts.ring, verdicts.ring_id
    evidence_t = (verdicts.weight, verdicts.bonus, verdicts.evident, verdicts.hold)
    ahead_log, ahead_finite, ahead_before = waiting_t.log, waiting_t.finite, waiting_t.before
    pos, K = skin.pos, skin.K
    N = len(score)
    R = pos.shape[1] - 1
    J = due.shape[1]
    until = g + K[REFRESH_S]
    evident, bonus = _evidence(
        ids, n, run, ring, ring_id, *evidence_t, X[:, 1], tracks.before, K[RESTART_AGREE_REL]
    )
    best = -np.inf
    for i in range(N):
        best = max(best, score[i])
    total = np.empty(N)
    stopped = np.empty(N, np.bool_)
    limit = np.empty(N, np.int64)
    live = np.empty(N, np.bool_)
    waiting = np.empty(N, np.bool_)
    for i in range(N):
        live[i] = score[i] >= best - K[NEGLIGIBLE]
        seen = g - blind[i] if has_blind else g
        j = -1
        for c in range(J):
            if due[i, c] <= seen:
                j += 1
        adj = adj_t[i, j]
        running = np.isnan(stop[i])
        # braked to rest: even braking BRAKE_Z sigma gentler than its estimate, the track's
        # own motion brought it below the slowest slip by now (`TrackerDecoder.BRAKE_Z`)
        braked = False
        if running and run[i] >= 2:
            a_hi = acceleration(
                X[i, 2] + K[BRAKE_Z] * math.sqrt(max(P[i, 2, 2], 0.0)), P[i, 2, 2], ridge[i], R, K
            )
            if a_hi < 0:
                rest = max(K[V_MIN], K[REST_SHARE] * X[i, 1])
                t_rest = t[i] + (rest - X[i, 1]) / a_hi
                if t_rest <= g:
                    braked = True
                elif live[i]:
                    until = min(until, t_rest)
        # a stop at a step is told once the next ridge, had the slip gone on, would have
        # been decided (`TrackerDecoder.STEP_STOP_WAIT`): before that it is slipping on
        pending = False
        if K[STEP_STOP_WAIT] > 0 and not running and X[i, 1] > 0:
            tau = stop[i] - t[i]
            var = P[i, 0, 0] + 2 * tau * P[i, 0, 1] + tau * tau * P[i, 1, 1]
            sigma = math.sqrt(max(var, 0.0))
            t_seen = stop_seen(X[i, 0], X[i, 1], stop[i], sigma, dirn[i], ridge[i], pos, K)
            if g < t_seen:
                pending = True
                if live[i]:
                    until = min(until, t_seen)
        stopped[i] = (stop_t[i, j] or not running or braked) and not pending
        limit[i] = limit_t[i, j]
        if j + 1 < J:
            upcoming = due[i, j + 1] + blind[i] if has_blind else due[i, j + 1]
            if live[i] and upcoming > g:
                until = min(until, upcoming)
        waiting[i] = running and run[i] == 1
        if waiting[i] and live[i]:
            elapsed = g - t[i]
            if has_blind:
                elapsed = elapsed - blind[i]
            row = (1 - dirn[i]) // 2 * R + min(ridge[i], R - 1)
            adj = _log_waiting(
                elapsed - K[MAX_LATENCY], row, ahead_log, ahead_finite, ahead_before, K
            )
        total[i] = score[i] + adj + bonus[i] if live[i] else -np.inf
    top = null
    for i in range(N):
        top = max(top, total[i])
    weight = np.exp(total - top)
    mass = math.exp(null - top) + pairwise_sum(weight)
    slipping = evident & ~stopped
    p_slip = pairwise_sum(weight[slipping]) / mass
    chosen, is_stopped = -1, False
    if p_slip >= 0.5 and slipping.any():
        best_total = -np.inf  # the first best of the slipping tracks
        for i in range(N):
            if slipping[i] and (chosen < 0 or total[i] > best_total):
                chosen, best_total = i, total[i]
    else:
        best_total = -np.inf
        cand = -1
        for i in range(N):
            if evident[i] and stopped[i] and (cand < 0 or total[i] > best_total):
                cand, best_total = i, total[i]
        if cand >= 0 and total[cand] >= null:
            chosen, is_stopped = cand, True
    if chosen < 0:
        return until, -1, False, 0, p_slip, 0.0, -np.inf, -1, 0.0, np.nan, np.nan
    lim = limit[chosen]
    fast, share, low, high = -1, 0.0, np.nan, np.nan
    odds = np.inf
    if not is_stopped:
        fast, share, low, high = _magnitude(slipping, run, total, weight, X, K)
        # the direction: the posterior mass moving each way - slipping tracks, and tracks
        # just started at a contact (a slip starting or reversing)
        moving = (slipping | (waiting & live)) & np.isfinite(total)
        way = dirn == dirn[chosen]
        this = pairwise_sum(weight[moving & way])
        other = pairwise_sum(weight[moving & ~way])
        odds = math.log(this / other) if other > 0 else np.inf
        if run[chosen] == 1 or n[chosen] < K[DIRECTION_CONTACTS] or odds < K[LOG_REPORT_ODDS]:
            return until, chosen, is_stopped, lim, p_slip, 0.0, odds, fast, share, low, high
    c = chosen
    one = (
        X[c, 0], X[c, 1], X[c, 2], X[c, 3], m[c], t[c], stop[c],
        P[c, 0, 0], P[c, 0, 1], P[c, 1, 1], P[c, 0, 2], P[c, 1, 2], P[c, 2, 2],
        dirn[c], ridge[c],
    )  # fmt: skip
    x_ref = where(one, g, is_stopped, lim, (np.inf, 0.0), (pos, K))[0]  # (plain tuples)
    if dirn[c] < 0:
        x_ref = K[LENGTH_MM] - x_ref
    # agreement: the share of the posterior within AGREE_MM (and AGREE_SPEED) of the chosen
    use = live & evident & (stopped == is_stopped) & (weight >= 1e-4 * mass)
    if not is_stopped:
        v_i = X[chosen, 1]
        use &= (dirn == dirn[chosen]) & (np.abs(X[:, 1] - v_i) <= K[AGREE_SPEED] * v_i)
    idx = np.nonzero(use)[0]
    agreeing = np.zeros(len(idx))
    count = 0
    for u in idx:
        if np.isnan(stop[u]):
            a_u = acceleration(X[u, 2], P[u, 2, 2], ridge[u], R, K)
            s = travel(X[u, 0], X[u, 1], a_u, X[u, 3], m[u], t[u], g, K[DIP_S])
            di = (1 - dirn[u]) // 2
            ahead = min(limit[u], R)
            end = pos[di, ahead] if ahead < R else coast_end(pos, di, X[u, 1], K)
            s = np.minimum(s, end)
        else:
            s = X[u, 0]
        x = s if dirn[u] > 0 else K[LENGTH_MM] - s
        if np.abs(x - x_ref) <= K[AGREE_MM]:
            agreeing[count] = weight[u]
            count += 1
    agree = pairwise_sum(agreeing[:count]) / mass
    return until, chosen, is_stopped, lim, p_slip, agree, odds, fast, share, low, high


@jit()
def _magnitude(
    slipping: np.ndarray,
    run: np.ndarray,
    total: np.ndarray,
    weight: np.ndarray,
    X: np.ndarray,
    K: np.ndarray,
) -> tuple[int, float, float, float]:
    """The slip's speed whichever way it goes (issue 22: the belt and the reflex need no
    direction): the best slipping track with a measured speed (-1 if none), the share of
    the slipping mass whose speed is within AGREE_SPEED of its speed (either way), and the
    range of speeds the slipping tracks holding at least BOUND_SHARE of it still allow."""
    fast, best = -1, -np.inf
    for i in range(len(total)):
        if slipping[i] and run[i] >= 2 and total[i] > best:
            fast, best = i, total[i]
    if fast < 0:
        return -1, 0.0, np.nan, np.nan
    v_ref = abs(X[fast, 1])
    moving = np.zeros(len(total))
    close = np.zeros(len(total))
    for i in range(len(total)):
        if slipping[i]:
            moving[i] = weight[i]
            if run[i] >= 2 and abs(abs(X[i, 1]) - v_ref) <= K[AGREE_SPEED] * v_ref:
                close[i] = weight[i]
    mass = pairwise_sum(moving)
    share = pairwise_sum(close) / mass
    low, high = v_ref, v_ref  # the track the speed would come from bounds it too
    for i in range(len(total)):
        if slipping[i] and run[i] >= 2 and weight[i] >= K[BOUND_SHARE] * mass:
            low = min(low, abs(X[i, 1]))
            high = max(high, abs(X[i, 1]))
    return fast, share, low, high

"""The tracker's branching of its hypotheses at a contact, compiled (`branch`).

Why one kernel: at every contact each track branches into its children (the contact
spurious, assigned to one of the next ridges - Kalman update, speed started afresh or
restarted -, a stop at a step, a new track at every ridge). As numpy code that was a few
hundred calls on arrays of tens of rows, about half a contact's CPU; here it is one call
that writes the children pool row by row, in the order the numpy code built it (the
pruning keeps the first of equal scores, so the order is part of the result).

The bank's layout (its float and int columns) is `layout`'s, as the tracker's and the
numpy reference's in the tests (numba freezes its ints into the code). The decoder's
constants come in one float array (`pack_constants`, names in `CONSTANTS`), its tables
(ridge positions, spacings, priors, the one-contact track template) as arrays. `branch`
takes them in named bundles (`Bank`: the tracks, `Contact`, `Model`: the constants and
tables), each a plain tuple named again on entry, as `kernels.posterior`'s.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from grasplink.decoding.kernels import jit
from grasplink.decoding.kernels.common import maximum as _maximum
from grasplink.decoding.kernels.common import minimum as _minimum
from grasplink.decoding.kernels.common import pack, travel
from grasplink.decoding.kernels.layout import (
    CHANGING,
    F_A,
    F_BEFORE,
    F_D,
    F_M,
    F_S,
    F_SCORE,
    F_SIG,
    F_STOP,
    F_T,
    F_V,
    F_WIDTH,
    I_DIRN,
    I_FIRST,
    I_IDS,
    I_LAST,
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

__all__ = ["CONSTANTS", "branch", "pack_constants"]

# the bank's columns and the covariance entries the kernels write (`layout`)
# the decoder's constants, in the order `pack_constants` packs them
CONSTANTS = (
    "stale_s", "clutter_per_s", "p_tip", "tip_mm", "tip_gap_mm", "tip_s", "tip_slow_per_s",
    "log_grip", "log_probe_ridge", "log_stop_at_ridge", "log_clutter_idle", "log_new_track",
    "log_reverse", "log_2", "dip_recovery_s", "log_restart", "log_restart_rate", "v_min_mm_s",
    "v_max_mm_s", "max_speed_jump", "pos_var_mm2", "speed_init_rel", "dip_var_mm2",
    "dip_var_changing_mm2", "acc_per_s", "log_changing", "log_steady", "speed_prior_mm_s",
    "speed_prior_log_sigma", "log_speed_norm", "speed_walk2", "speed_walk_mm", "jerk_per_s2",
    "robust_floor", "dip_max_mm", "log_rebirth", "restart_reach", "stopped_reach", "erf_scale",
)  # fmt: skip
(
    STALE_S, CLUTTER_PER_S, P_TIP, TIP_MM, TIP_GAP_MM, TIP_S, TIP_SLOW_PER_S,
    LOG_GRIP, LOG_PROBE_RIDGE, LOG_STOP_AT_RIDGE, LOG_CLUTTER_IDLE, LOG_NEW_TRACK,
    LOG_REVERSE, LOG_2, DIP_RECOVERY_S, LOG_RESTART, LOG_RESTART_RATE, V_MIN_MM_S,
    V_MAX_MM_S, MAX_SPEED_JUMP, POS_VAR_MM2, SPEED_INIT_REL, DIP_VAR_MM2,
    DIP_VAR_CHANGING_MM2, ACC_PER_S, LOG_CHANGING, LOG_STEADY, SPEED_PRIOR_MM_S,
    SPEED_PRIOR_LOG_SIGMA, LOG_SPEED_NORM, SPEED_WALK2, SPEED_WALK_MM, JERK_PER_S2,
    ROBUST_FLOOR, DIP_MAX_MM, LOG_REBIRTH, RESTART_REACH, STOPPED_REACH, ERF_SCALE,
) = range(len(CONSTANTS))  # fmt: skip


def pack_constants(values: dict[str, float]) -> np.ndarray:
    """The constants `branch` takes, by name (every one of CONSTANTS), as one array."""
    return pack(CONSTANTS, values, "branch")


# ------------------------------------------------------------------ numpy's scalar rules
@jit()
def _nan_max(x: np.ndarray, rows: np.ndarray) -> float:
    """x[rows].max() as numpy takes it: NaN if any is NaN."""
    best = -np.inf
    for r in rows:
        if x[r] != x[r]:
            return x[r]
        if x[r] > best:
            best = x[r]
    return best


@intrinsic
def _fma(typingctx, a, b, c):
    """a * b + c rounded once (LLVM's fma): what numpy's BLAS matmul does per term."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, signature, args):
        double = ir.DoubleType()
        fn = builder.module.declare_intrinsic(
            "llvm.fma", [double], ir.FunctionType(double, [double, double, double])
        )
        return builder.call(fn, args)

    return sig, codegen


@jit()
def _matmul_fma(A: np.ndarray, B: np.ndarray, C: np.ndarray, b_transposed: bool) -> None:
    """C = A @ B (4 x 4; B.T given when b_transposed) as numpy's matmul (OpenBLAS) sums
    it: from 0, one fused multiply-add per term in order - the same bits, where plain sums
    differ by ulps."""
    for a in range(4):
        for b in range(4):
            acc = 0.0
            for k in range(4):
                term = B[b, k] if b_transposed else B[k, b]
                acc = _fma(A[a, k], term, acc)  # type: ignore[call-arg]
            C[a, b] = acc


# ------------------------------------------------------------------ row writers
@jit()
def _with_contact(
    src_i: np.ndarray, r: int, out_i: np.ndarray, j: int, ev_id: int, ridge: int, run: int
) -> None:
    """out_i[j]: track src_i[r] having taken contact ev_id at `ridge`: one more contact,
    `run`, and ev_id the last of its ids."""
    out_i[j, :] = src_i[r, :]
    for c in range(I_IDS, I_LAST):
        out_i[j, c] = src_i[r, c + 1]
    out_i[j, I_LAST] = ev_id
    out_i[j, I_N] = src_i[r, I_N] + 1
    out_i[j, I_RIDGE] = ridge
    out_i[j, I_RUN] = run


@jit()
def _travel(f: np.ndarray, r: int, tc: float, dip_recovery_s: float) -> float:
    """Travel of slipping track f[r] extrapolated to tc."""
    return travel(
        f[r, F_S], f[r, F_V], f[r, F_A], f[r, F_D], f[r, F_M], f[r, F_T], tc, dip_recovery_s
    )


@jit()
def _stopped_at(
    src_f: np.ndarray,
    src_i: np.ndarray,
    r: int,
    out_f: np.ndarray,
    out_i: np.ndarray,
    j: int,
    tc: float,
    log_prior: float,
    c: np.ndarray,
    pos: np.ndarray,
) -> None:
    """out[j]: slipping track src[r] stopped at tc (a step), where it was then (short of
    its next ridge), keeping the speed it had: when its next ridge was due (the stop
    reported no sooner: `kernels.posterior`)."""
    R = pos.shape[1] - 1
    s = _travel(src_f, r, tc, c[DIP_RECOVERY_S])
    di = (1 - src_i[r, I_DIRN]) // 2
    limit = pos[di, min(src_i[r, I_RIDGE] + 1, R)]
    out_f[j, :] = src_f[r, :]
    out_f[j, F_S] = _minimum(s, limit - 0.1)
    out_f[j, F_A] = 0.0
    out_f[j, F_STOP] = tc
    out_f[j, F_SCORE] = src_f[r, F_SCORE] + log_prior
    out_i[j, :] = src_i[r, :]


@jit()
def _clutter_rate(f: np.ndarray, i: np.ndarray, r: int, tc: float, c: np.ndarray, gap) -> float:
    """Spurious contacts per s at tc under track r: detector false alarms, and while
    slipping the tipping front edge's, within TIP_MM of travel after a ridge contact."""
    rate = c[CLUTTER_PER_S]
    dt = tc - f[r, F_T]
    v = f[r, F_V]
    R = gap.shape[1]
    g = gap[(1 - i[r, I_DIRN]) // 2, min(i[r, I_RIDGE], R - 1)]
    room = _minimum(c[TIP_MM], g - 2.0)
    tipping = f[r, F_STOP] != f[r, F_STOP] and g >= c[TIP_GAP_MM]
    run = i[r, I_RUN]
    if tipping and run >= 2 and v * dt <= room:
        rate += c[P_TIP] * v / room
    elif tipping and run == 1 and dt <= c[TIP_S]:
        rate += c[TIP_SLOW_PER_S]
    return rate


@jit()
def _restart(
    f: np.ndarray,
    i: np.ndarray,
    r: int,
    out_f: np.ndarray,
    out_i: np.ndarray,
    j: int,
    k: int,
    log_prior: float,
    contact: tuple[float, int, float],
    pos: np.ndarray,
) -> None:
    """out[j]: track r restarted (speed unknown) with the contact at ridge k."""
    tc, ev_id, sigma_s = contact
    di = (1 - i[r, I_DIRN]) // 2
    out_f[j, :] = 0.0  # P, v and a: 0
    out_f[j, F_S] = pos[di, k]
    out_f[j, F_D] = f[r, F_D]
    out_f[j, P33] = _maximum(f[r, P33], 0.0)
    out_f[j, F_M] = 1.0
    out_f[j, F_SCORE] = f[r, F_SCORE] + log_prior
    out_f[j, F_SIG] = sigma_s
    out_f[j, F_STOP] = np.nan
    out_f[j, F_T] = tc
    # the speed it had (a restarted parent's own, 0, keeps the one before that)
    out_f[j, F_BEFORE] = f[r, F_V] if f[r, F_V] > 0 else f[r, F_BEFORE]
    _with_contact(i, r, out_i, j, ev_id, k, 1)


@jit()
def _log_reach(dist_mm: float, dt_s: float, weight: float, c: np.ndarray) -> float:
    """weight x log P(a restarted slip covers dist_mm within dt_s): its speed, unknown,
    drawn from the speed prior (log-normal) must be at least dist_mm / dt_s - a slip that
    stopped and went on reaches the next ridge later than one that did not, never sooner
    (`TrackerDecoder.RESTART_REACH`); 0 when weight is 0 or nothing is left to cover."""
    if not weight > 0.0 or not dist_mm > 0.0:
        return 0.0
    z = math.log(dist_mm / (_maximum(dt_s, 1e-9) * c[SPEED_PRIOR_MM_S])) * c[ERF_SCALE]
    return weight * math.log(_maximum(0.5 * (1.0 - math.erf(z)), 1e-12))


@jit()
def _toward_ridge(
    f: np.ndarray, i: np.ndarray, r: int, skip: int, tc: float, c: np.ndarray, pos: np.ndarray
) -> tuple[float, int, float, float, float]:
    """For track r and a contact at tc on the ridge after the next `skip`: time since its
    last contact, that ridge (index, position along the track's direction), how far the
    last ridge's speed dip has recovered, and the travel the dip lags by."""
    dt = tc - f[r, F_T]
    k = i[r, I_RIDGE] + 1 + skip
    decay = np.exp(-dt / c[DIP_RECOVERY_S])
    lag = f[r, F_M] * (1.0 - decay) + skip
    return dt, k, pos[(1 - i[r, I_DIRN]) // 2, k], decay, lag


@jit()
def _started_speed(
    f: np.ndarray,
    i: np.ndarray,
    r: int,
    skip: int,
    far: bool,
    c: np.ndarray,
    pos: np.ndarray,
    tc: float,
) -> tuple[bool, float, int, float, float, float, float]:
    """Track r's speed from its last contact and this one at ridge k: whether it is one
    (within the speed range; far off its Kalman prediction, also within MAX_SPEED_JUMP of
    its speed), and (dt, k, target, decay, lag, v)."""
    dt, k, target, decay, lag = _toward_ridge(f, i, r, skip, tc, c, pos)
    v = (target - f[r, F_S] + lag * f[r, F_D]) / dt
    good = v >= c[V_MIN_MM_S] and v <= c[V_MAX_MM_S]
    if far:
        v_ref = _maximum(f[r, F_V], c[V_MIN_MM_S])
        jump = c[MAX_SPEED_JUMP]
        good = good and v * jump >= v_ref and v <= jump * v_ref
    return good, dt, k, target, decay, lag, v


@jit()
def _start_speed(
    f: np.ndarray,
    i: np.ndarray,
    r: int,
    skip: int,
    log_prior: float,
    far: bool,
    changing: bool,
    out_f: np.ndarray,
    out_i: np.ndarray,
    j: int,
    contact: tuple[float, int, float],
    c: np.ndarray,
    pos: np.ndarray,
) -> bool:
    """out[j]: track r at ridge k with its speed from its last contact and this one, the
    covariance of the `changing` model or the steady one (the model column as it was);
    False (nothing written) when that speed is out of range (`_started_speed`)."""
    tc, ev_id, sigma_s = contact
    good, dt, k, target, decay, lag, v = _started_speed(f, i, r, skip, far, c, pos, tc)
    if not good:
        return False
    d = f[r, F_D]
    vs = v * sigma_s
    r_now = c[POS_VAR_MM2] + vs * vs
    vs = v * f[r, F_SIG]
    r_before = c[POS_VAR_MM2] + vs * vs
    p33 = f[r, P33]
    var_d = p33 if p33 > 0 else c[DIP_VAR_CHANGING_MM2] if changing else c[DIP_VAR_MM2]
    out_f[j, :16] = 0.0
    out_f[j, P00] = r_now
    out_f[j, P01] = out_f[j, P10] = r_now / dt
    rel = c[SPEED_INIT_REL] * v
    out_f[j, P11] = (r_now + r_before + lag * lag * var_d) / (dt * dt) + rel * rel
    out_f[j, P13] = out_f[j, P31] = lag * var_d / dt
    out_f[j, P33] = var_d
    if changing:  # the mean speed over the interval is the speed half an interval ago
        sa = c[ACC_PER_S] * v
        half_sa = dt / 2.0 * sa
        out_f[j, P11] += half_sa * half_sa
        out_f[j, P12] = out_f[j, P21] = half_sa * sa
        out_f[j, P22] = sa * sa
    z = np.log(v / c[SPEED_PRIOR_MM_S]) / c[SPEED_PRIOR_LOG_SIGMA]
    log_speed_prior = -0.5 * z * z - c[LOG_SPEED_NORM]
    out_f[j, F_S] = target
    out_f[j, F_V] = v
    out_f[j, F_A] = 0.0
    out_f[j, F_D] = d
    out_f[j, F_M] = 1.0 + f[r, F_M] * decay
    out_f[j, F_SCORE] = f[r, F_SCORE] + log_prior + log_speed_prior - np.log(dt)
    out_f[j, F_SIG] = sigma_s
    out_f[j, F_STOP] = f[r, F_STOP]
    out_f[j, F_T] = tc
    out_f[j, F_BEFORE] = f[r, F_BEFORE]
    _with_contact(i, r, out_i, j, ev_id, k, 2)
    return True


@jit()
def _process_noise(
    Pp: np.ndarray, v: float, dt: float, jerk: bool, changing: bool, c: np.ndarray
) -> None:
    """Add the prediction's process noise to Pp (4 x 4): the speed's random walk, then
    (`jerk`: its batch held a changing-model track) the jerk of the changing model, 0 for
    a steady track; each entry's terms in the numpy code's order."""
    qv = c[SPEED_WALK2] * v**3.0 / c[SPEED_WALK_MM]
    dt2, dt3 = dt * dt, dt * dt * dt
    Pp[0, 0] += qv * dt3 / 3.0
    Pp[0, 1] += qv * dt2 / 2.0
    Pp[1, 0] += qv * dt2 / 2.0
    Pp[1, 1] += qv * dt / 1.0
    if not jerk:
        return
    jv = c[JERK_PER_S2] * v
    qj = jv * jv if changing else 0.0
    Pp[0, 0] += qj * dt3 * dt2 / 20.0
    Pp[0, 1] += qj * dt2 * dt2 / 8.0
    Pp[1, 0] += qj * dt2 * dt2 / 8.0
    Pp[0, 2] += qj * dt3 * 1.0 / 6.0
    Pp[2, 0] += qj * dt3 * 1.0 / 6.0
    Pp[1, 1] += qj * dt3 * 1.0 / 3.0
    Pp[1, 2] += qj * dt2 * 1.0 / 2.0
    Pp[2, 1] += qj * dt2 * 1.0 / 2.0
    Pp[2, 2] += qj * dt * 1.0 / 1.0


@jit()
def _kalman(
    f: np.ndarray,
    i: np.ndarray,
    r: int,
    skip: int,
    log_prior: float,
    any_changing: bool,
    out_f: np.ndarray,
    out_i: np.ndarray,
    j: int,
    contact: tuple[float, int, float],
    c: np.ndarray,
    pos: np.ndarray,
    work: np.ndarray,
    vectors: np.ndarray,
) -> tuple[bool, bool, float]:
    """Predict track r to the contact and update it with ridge k (robust: far off, the
    speed starts again from the last two contacts). Writes out[j] when the update is
    kept; returns (kept, far off, log prior with the contact's likelihood). `work` (4, 4,
    4) and `vectors` (2, 4): the caller's scratch, written over (no allocation per
    assignment: there are a hundred or more at a contact)."""
    tc, ev_id, sigma_s = contact
    dt, k, target, decay, lag = _toward_ridge(f, i, r, skip, tc, c, pos)
    v = _maximum(f[r, F_V], c[V_MIN_MM_S])
    F, P, FP, Pp = work[0], work[1], work[2], work[3]
    F[:, :] = 0.0
    for a in range(4):
        F[a, a] = 1.0
    F[0, 1] = F[1, 2] = dt
    F[0, 2] = 0.5 * dt * dt
    F[0, 3] = -lag
    X = f[r, F_S : F_D + 1]
    for a in range(4):
        P[a, :] = f[r, 4 * a : 4 * a + 4]
    Xp, Xn = vectors[0], vectors[1]
    for a in range(4):  # (einsum's order: even terms, odd terms, then their sum)
        Xp[a] = (F[a, 0] * X[0] + F[a, 2] * X[2]) + (F[a, 1] * X[1] + F[a, 3] * X[3])
    _matmul_fma(F, P, FP, False)
    _matmul_fma(FP, F, Pp, True)  # (F P) F.T
    _process_noise(Pp, v, dt, any_changing, i[r, I_MODEL] == CHANGING, c)
    vs = v * sigma_s
    var = Pp[0, 0] + (c[POS_VAR_MM2] + vs * vs) + skip * c[POS_VAR_MM2]
    resid = target - Xp[0]
    floor = c[ROBUST_FLOOR]
    inlier = (1.0 - floor) * v * np.exp(-0.5 * resid * resid / var) / np.sqrt(2 * np.pi * var)
    outlier = floor * v / (4.0 * _maximum(target - X[0], 1.0))
    like = np.log(inlier + outlier)
    far = inlier < outlier
    for a in range(4):
        Xn[a] = Xp[a] + Pp[a, 0] / var * resid
    Xn[3] = _minimum(c[DIP_MAX_MM], _maximum(0.0, Xn[3]))
    kept = inlier >= outlier and Xn[1] >= c[V_MIN_MM_S] and Xn[1] <= c[V_MAX_MM_S]
    if not kept:
        return False, far, log_prior + like
    for a in range(4):
        for b in range(4):
            pab = Pp[a, b] - Pp[a, 0] / var * Pp[0, b]
            pba = Pp[b, a] - Pp[b, 0] / var * Pp[0, a]
            out_f[j, 4 * a + b] = 0.5 * (pab + pba)
    out_f[j, F_S : F_D + 1] = Xn
    out_f[j, F_M] = 1.0 + f[r, F_M] * decay
    out_f[j, F_SCORE] = f[r, F_SCORE] + log_prior + like
    out_f[j, F_SIG] = sigma_s
    out_f[j, F_STOP] = f[r, F_STOP]
    out_f[j, F_T] = tc
    out_f[j, F_BEFORE] = f[r, F_BEFORE]
    _with_contact(i, r, out_i, j, ev_id, k, i[r, I_RUN] + 1)
    return True, far, log_prior + like


@jit()
def _assign_rows(
    f: np.ndarray, i: np.ndarray, tc: float, skip_prior: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every (skip, track) whose contact at tc may be the ridge after the next `skip`
    (later than the track's last contact, a ridge that exists), skip-major (one skip after
    the other): the track, the skip and its log prior."""
    N, R, S = len(f), skip_prior.shape[1], skip_prior.shape[2]
    track = np.empty(N * S, np.int64)
    skips = np.empty(N * S, np.int64)
    prior = np.empty(N * S)
    n = 0
    for skip in range(S):
        for r in range(N):
            ridge = i[r, I_RIDGE]
            if tc - f[r, F_T] > 0 and ridge + 1 + skip < R:
                track[n], skips[n] = r, skip
                prior[n] = skip_prior[(1 - i[r, I_DIRN]) // 2, ridge, skip]
                n += 1
    return track[:n], skips[:n], prior[:n]


@jit()
def _started(
    f: np.ndarray,
    i: np.ndarray,
    rows: tuple[np.ndarray, np.ndarray, np.ndarray],
    out_f: np.ndarray,
    out_i: np.ndarray,
    j: int,
    contact: tuple[float, int, float],
    c: np.ndarray,
    pos: np.ndarray,
) -> int:
    """Children of the one-contact or restarted tracks (`rows` of `_assign_rows`): their
    speed from the last contact and this one, each in both motion models (steady ones
    first, with the models' priors). Returns the next free row."""
    track, skips, prior = rows
    first = j
    for q in range(len(track)):
        r = track[q]
        if f[r, F_STOP] != f[r, F_STOP] and i[r, I_RUN] == 1:
            j += int(
                _start_speed(
                    f, i, r, skips[q], prior[q], False, False, out_f, out_i, j, contact, c, pos
                )
            )
    steady = j - first
    for q in range(len(track)):
        r = track[q]
        if f[r, F_STOP] != f[r, F_STOP] and i[r, I_RUN] == 1:
            j += int(
                _start_speed(
                    f, i, r, skips[q], prior[q], False, True, out_f, out_i, j, contact, c, pos
                )
            )
    for q in range(first, first + steady):
        out_f[q, F_SCORE] += c[LOG_STEADY]
        out_i[q, I_MODEL] = STEADY
    for q in range(first + steady, j):
        out_f[q, F_SCORE] += c[LOG_CHANGING]
        out_i[q, I_MODEL] = CHANGING
    return j


@jit()
def _assign(
    f: np.ndarray,
    i: np.ndarray,
    out_f: np.ndarray,
    out_i: np.ndarray,
    j: int,
    contact: tuple[float, int, float],
    c: np.ndarray,
    pos: np.ndarray,
    skip_prior: np.ndarray,
) -> int:
    """Children of tracks (f, i) that assign the contact to one of the next ridges, each
    branch kind after the other (the numpy code's batches): speeds started, Kalman
    updates, speeds started again far off the prediction, restarts of slipping tracks
    (stopped unseen), restarts of stopped ones. Returns the next free row."""
    rows = _assign_rows(f, i, contact[0], skip_prior)
    track, skips, prior = rows
    j = _started(f, i, rows, out_f, out_i, j, contact, c, pos)
    slipping = np.zeros(len(track), np.bool_)
    any_changing = False
    for q in range(len(track)):
        r = track[q]
        slipping[q] = f[r, F_STOP] != f[r, F_STOP] and i[r, I_RUN] >= 2
        any_changing |= slipping[q] and i[r, I_MODEL] == CHANGING
    far = np.zeros(len(track), np.bool_)
    far_prior = np.empty(len(track))
    work, vectors = np.empty((4, 4, 4)), np.empty((2, 4))
    for q in range(len(track)):
        if not slipping[q]:
            continue
        kept, far_off, log_like = _kalman(
            f, i, track[q], skips[q], prior[q], any_changing, out_f, out_i, j, contact, c, pos,
            work, vectors,
        )  # fmt: skip
        far[q], far_prior[q] = far_off, log_like
        j += int(kept)
    for q in range(len(track)):  # far off: the speed starts again from the last two contacts
        if not far[q]:
            continue
        r = track[q]
        changing = i[r, I_MODEL] == CHANGING
        j += int(
            _start_speed(
                f, i, r, skips[q], far_prior[q], True, changing, out_f, out_i, j, contact, c, pos
            )
        )
    for q in range(len(track)):  # stopped unseen, went on: a restart
        if not slipping[q] or skips[q] != 0:
            continue
        r = track[q]
        k = i[r, I_RIDGE] + 1
        di = (1 - i[r, I_DIRN]) // 2
        reach = _log_reach(
            pos[di, k] - pos[di, i[r, I_RIDGE]], contact[0] - f[r, F_T], c[RESTART_REACH], c
        )
        _restart(f, i, r, out_f, out_i, j, k, prior[q] + c[LOG_RESTART] + reach, contact, pos)
        j += 1
    for q in range(len(track)):  # a stopped track restarting here
        r = track[q]
        if f[r, F_STOP] == f[r, F_STOP]:
            k = i[r, I_RIDGE] + 1 + skips[q]
            di = (1 - i[r, I_DIRN]) // 2
            reach = _log_reach(
                pos[di, k] - f[r, F_S], contact[0] - f[r, F_STOP], c[STOPPED_REACH], c
            )
            log_prior = prior[q] + c[LOG_RESTART_RATE] + reach
            _restart(f, i, r, out_f, out_i, j, k, log_prior, contact, pos)
            j += 1
    return j


@jit()
def _births(
    f: np.ndarray,
    i: np.ndarray,
    out_f: np.ndarray,
    out_i: np.ndarray,
    j: int,
    best_before: float,
    log_strength: float,
    contact: tuple[float, int, float],
    c: np.ndarray,
    log_prior: np.ndarray,
    birth_f: np.ndarray,
    birth_i: np.ndarray,
) -> int:
    """One-contact tracks at every ridge, both ways (a slip starting: the earlier story
    ends here; or, while one slips, reversing: the other edge leads, anywhere). Returns
    the next free row."""
    tc, ev_id, sigma_s = contact
    R = log_prior.shape[1]
    for di in range(2):
        base = best_before + c[LOG_NEW_TRACK]
        way = np.zeros(len(f), np.bool_)
        for r in range(len(f)):
            slipping = f[r, F_STOP] != f[r, F_STOP] and i[r, I_N] >= 2
            way[r] = slipping and i[r, I_DIRN] == 2 * di - 1  # moving the other way
        if way.any():
            reverse = _nan_max(f[:, F_SCORE], np.nonzero(way)[0]) + c[LOG_REVERSE] + c[LOG_2]
            base = reverse if reverse > base else base
        if c[LOG_REBIRTH] > -np.inf:  # going on its way from a ridge its tracks do not place
            same = np.zeros(len(f), np.bool_)
            for r in range(len(f)):
                slipping = f[r, F_STOP] != f[r, F_STOP] and i[r, I_N] >= 2
                same[r] = slipping and i[r, I_DIRN] == 1 - 2 * di
            if same.any():
                again = _nan_max(f[:, F_SCORE], np.nonzero(same)[0]) + c[LOG_REBIRTH] + c[LOG_2]
                base = again if again > base else base
        base += log_strength
        for ridge in range(R):
            q = di * R + ridge
            out_f[j, :] = birth_f[q, :]
            out_i[j, :] = birth_i[q, :]
            out_i[j, I_FIRST] = out_i[j, I_LAST] = ev_id
            out_f[j, F_SCORE] = base + log_prior[di, ridge]
            out_f[j, F_SIG] = sigma_s
            out_f[j, F_T] = tc
            j += 1
    return j


@jit()
def _kept(floats: np.ndarray, ints: np.ndarray, tc: float, stale_s: float):
    """The tracks whose last contact is at most stale_s before tc (the others retire:
    the contact is no part of their slip)."""
    keep = np.nonzero(~(tc - floats[:, F_T] > stale_s))[0]
    return floats[keep], ints[keep]


@jit()
def _spurious(
    f: np.ndarray,
    i: np.ndarray,
    out_f: np.ndarray,
    out_i: np.ndarray,
    j: int,
    tc: float,
    step: bool,
    log_stop: float,
    c: np.ndarray,
    pos: np.ndarray,
    gap: np.ndarray,
) -> int:
    """Children that do not take the contact as a ridge: a step is a grip change, or
    (slipping) a stop here with prior log_stop; else the contact is clutter (at the
    clutter rate under each track). Returns the next free row."""
    for r in range(len(f)):
        out_f[j + r, :] = f[r, :]
        out_i[j + r, :] = i[r, :]
        if step:
            out_f[j + r, F_SCORE] = f[r, F_SCORE] + c[LOG_GRIP]
        else:
            out_f[j + r, F_SCORE] = f[r, F_SCORE] + np.log(_clutter_rate(f, i, r, tc, c, gap))
    j += len(f)
    if step:
        for r in range(len(f)):
            if f[r, F_STOP] != f[r, F_STOP] and i[r, I_N] >= 2:
                _stopped_at(f, i, r, out_f, out_i, j, tc, log_stop, c, pos)
                j += 1
    return j


class Bank(NamedTuple):
    """The tracks: the bank's float and int matrices (a row per track, `layout`)."""

    floats: np.ndarray
    ints: np.ndarray


class Contact(NamedTuple):
    """The contact the tracks branch on, and what the decoder made of it: its time (s),
    id and timing sigma (s); its timing sigma as a ridge (a step probe's: loosened); its
    ridge / false-alarm log odds (births; unused for a probe); the prior of a stop at a
    step (log); whether it is a step; whether a probe (a small step the kink bank missed:
    no births, its ridge children less likely)."""

    t_s: float
    id: int
    sigma_s: float
    sigma_assign_s: float
    log_strength: float
    log_stop: float
    step: bool
    probe: bool


class Model(NamedTuple):
    """What the branching reads besides the tracks, built once by the decoder: its
    constants (`pack_constants`), ridge positions (2, R + 1), spacings after each ridge
    (2, R), a new track's log prior (2, R), `_assign`'s log prior (2, R, skips), the
    one-contact tracks' float and int rows (2 R)."""

    c: np.ndarray
    pos: np.ndarray
    gap: np.ndarray
    log_prior: np.ndarray
    skip_prior: np.ndarray
    birth_f: np.ndarray
    birth_i: np.ndarray


@jit()
def branch(
    tracks: tuple, contact: tuple, null: float, model: tuple
) -> tuple[np.ndarray, np.ndarray, float]:
    """Every track's children for a contact, unpruned, in the numpy code's order, and the
    new null score ("no slip": every contact clutter). `tracks`, `contact`, `model`: a
    `Bank`, `Contact` and `Model` as plain tuples."""
    tracks, contact, model = Bank(*tracks), Contact(*contact), Model(*model)
    floats, ints = tracks.floats, tracks.ints
    tc, ev_id, sigma_s = contact.t_s, contact.id, contact.sigma_s
    sigma_assign_s, log_strength = contact.sigma_assign_s, contact.log_strength
    log_stop, step, probe = contact.log_stop, contact.step, contact.probe
    c, pos, gap, log_prior = model.c, model.pos, model.gap, model.log_prior
    skip_prior, birth_f, birth_i = model.skip_prior, model.birth_f, model.birth_i
    f, i = _kept(floats, ints, tc, c[STALE_S])
    N, R, S = len(f), gap.shape[1], skip_prior.shape[2]
    cap = 2 * N + 4 * N * S + 2 * R
    out_f = np.empty((cap, F_WIDTH))
    out_i = np.empty((cap, I_WIDTH), np.int64)
    best_before = null
    if N:
        top = _nan_max(f[:, F_SCORE], np.arange(N))
        best_before = top if top > null else null
    j = 0
    if N:
        j = _spurious(f, i, out_f, out_i, j, tc, step, log_stop, c, pos, gap)
        first = j
        j = _assign(f, i, out_f, out_i, j, (tc, ev_id, sigma_assign_s), c, pos, skip_prior)
        if probe:  # a ridge it could not time (mid-rise, loosely), sometimes
            out_f[first:j, F_SCORE] += c[LOG_PROBE_RIDGE]
        if step:  # a stop right at a ridge (the step is that ridge's contact)
            for q in range(first, j):
                if out_i[q, I_N] >= 2:
                    _stopped_at(out_f, out_i, q, out_f, out_i, j, tc, c[LOG_STOP_AT_RIDGE], c, pos)
                    j += 1
    null += c[LOG_GRIP] if step else c[LOG_CLUTTER_IDLE]
    if not probe:
        j = _births(
            f,
            i,
            out_f,
            out_i,
            j,
            best_before,
            log_strength,
            (tc, ev_id, sigma_s),
            c,
            log_prior,
            birth_f,
            birth_i,
        )
    return out_f[:j].copy(), out_i[:j].copy(), null

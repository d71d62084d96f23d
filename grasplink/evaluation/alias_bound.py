"""The 10 dB bound without the ridge identities: how often *any* causal decoder could name
the speed from the oracle's told contacts when it must also work out which ridge each
contact was (issue 22, the snr10 figure; `detection_bound` is the bound that knows them).

Why: two or three told contacts with missed ridges between them fit several (direction,
ridge assignment, speed) hypotheses - the aliases. The s27 bound credits a speed whenever
two contacts are told, as if the ridges were known; a real decoder also has to rule the
aliases out. Here a hypothesis is a direction and an assignment of the told contacts, in
time order, to ridges of the layout in travel order (ridges may be skipped: missed), the
edge having entered at the skin's end. It must fit the contact times:

- each interval's speed, with every contact time known to +-`tol_s`, inside the decoder's
  window [`v_min_mm_s`, `v_max_mm_s`];
- consecutive intervals' speed ranges within `rel` of each other plus `dv_dx_per_s` times
  the distance the two intervals span (a speed that changes smoothly with the travel: the
  snr10 set's 21->98 mm/s ramp changes by 0.86 mm/s per mm, so the true assignment always
  fits; an allowance per second instead would let a slow slide's long intervals fit
  almost any ratio - 100 mm/s^2 over 0.4 s is 40 mm/s). Only
  consecutive intervals are checked (a chain): a relaxation, so more aliases survive than
  a full kinematic fit would leave - the bound errs towards missing.

Two rules say when the speed is determined (its current speed: the last interval's):

- *unanimous*: every fitting hypothesis, any number of ridges skipped, gives a speed within
  `agree` of each other (max <= (1 + agree) min);
- *likelihood*: a hypothesis weighs prod P(detect) over its told ridges times prod P(miss)
  over the ridges it skips - before the first told one (the edge entered at the end),
  between told ones, and after the last one those its speed says were crossed and decided
  by now - with P(detect) = Phi(SNR - level) from the oracle's SNR at that physical ridge
  (its statistic is N(SNR, 1)); the prior over direction and assignment is uniform. The
  speed is determined when the hypotheses within `agree` of the MAP hypothesis's speed hold
  `mass` of the posterior (the tracker's 9:1).

The chain is a dynamic programme over the last two told ridges (a pair state), exact for
both rules and vectorised over the layout's ridges (<= 22: uniform4). With `Heights` each
told contact's measured pulse height weighs too (`height_evidence`: its density if it was
that ridge, the unknown scale shared by the run and summed over its prior), so the
likelihood rule reads times, detection chances and heights; with their rise times too
(`Heights.rise_s`), each told contact's rise weighs the speed its interval allows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import ndtr

from grasplink.evaluation import height_evidence as he


@dataclass(frozen=True)
class AliasSettings:
    """What a hypothesis must fit and what determines a speed (see the module docstring)."""

    tol_s: float = 0.005  # a contact time's error (a few ms at 10 dB; the oracle's are exact)
    rel: float = 0.1  # consecutive interval speeds' slack beyond the acceleration
    dv_dx_per_s: float = 1.0  # the largest speed change per mm travelled (snr10 set: 0.86)
    v_min_mm_s: float = 2.0  # the tracker's window (tracker.V_MIN_MM_S / V_MAX_MM_S)
    v_max_mm_s: float = 400.0
    agree: float = 0.1  # speeds within 10 % are "the same"
    mass: float = 0.9  # the posterior share that names a speed (9:1)


@dataclass(frozen=True)
class Chain:
    """The hypotheses fitting a set of told contacts, by the pair of ridges (travel order
    indices of one direction) the last two were assigned: `fits` whether any does, `weight`
    their summed likelihood (before the ridges after the last), `speed_mm_s` the last
    interval's speed."""

    fits: np.ndarray  # (n, n) bool, [a, b] with a < b
    weight: np.ndarray  # (n, n) float
    speed_mm_s: np.ndarray  # (n, n) float, nan where a >= b


def p_detect(snr: np.ndarray, level: float) -> np.ndarray:
    """The chance the oracle's statistic, N(SNR, 1), reaches `level`."""
    return np.asarray(ndtr(np.asarray(snr, float) - level))


def _skips(p_miss: np.ndarray) -> np.ndarray:
    """[a, b]: the product of P(miss) over the ridges strictly between a and b (a < b);
    [n, b] (the last row): over the ridges before b (the edge entered at ridge 0)."""
    n = len(p_miss)
    out = np.ones((n + 1, n))
    for b in range(n):
        for a in range(b):
            out[a, b] = float(np.prod(p_miss[a + 1 : b]))
        out[n, b] = float(np.prod(p_miss[:b]))
    return out


def _ranges(pos_mm: np.ndarray, dt_s: float, s: AliasSettings):
    """An interval's speed per ridge pair: nominal, low and high (the times +-tol_s), and
    whether the pair can hold it (a < b, the range meets the decoder's window)."""
    dist = pos_mm[None, :] - pos_mm[:, None]
    ahead = dist > 0
    with np.errstate(divide="ignore", invalid="ignore"):
        nominal = np.where(ahead, dist / dt_s, np.nan)
        low = np.where(ahead, dist / (dt_s + 2 * s.tol_s), np.nan)
        short = dt_s - 2 * s.tol_s
        high = np.where(ahead, dist / short if short > 0 else np.inf, np.nan)
    ok = ahead & (high >= s.v_min_mm_s) & (low <= s.v_max_mm_s)
    return nominal, low, high, ok


def chain(
    pos_mm: np.ndarray,
    times_s: np.ndarray,
    p_det: np.ndarray,
    settings: AliasSettings,
    entry: bool = True,
    evidence: np.ndarray | None = None,
    prior: np.ndarray | None = None,
    rise: np.ndarray | None = None,
) -> Chain:
    """The hypotheses of one direction for told contacts at `times_s` (>= 2, time order),
    the ridges at `pos_mm` (travel order, from the entry end) with detection chances
    `p_det`. `entry`: the ridges before the first told one were crossed and missed (False:
    the earlier contacts are forgotten, nothing known before the first). `evidence`
    [g, j, k] (`height_evidence.evidence`): a further factor for told contact j at ridge k
    under a shared parameter's value g, whose `prior` weights sum the weights over g.
    `rise` [2, j]: told contact j's measured rise time and its sigma (s), weighed by the
    speed range its interval allows (`height_evidence.rise_density`)."""
    n = len(pos_mm)
    p_miss = 1.0 - p_det
    skip = _skips(p_miss)
    before = skip[n] if entry else np.ones(n)
    nominal, low, high, ok = _ranges(pos_mm, float(times_s[1] - times_s[0]), settings)
    fits = ok.copy()
    if evidence is not None or rise is not None:
        if evidence is None:
            evidence = np.ones((1, len(times_s), n))
        return _chain_evidence(pos_mm, times_s, p_det, settings, before, evidence, prior, rise)
    weight = np.where(ok, (before * p_det)[:, None] * skip[:n] * p_det[None, :], 0.0)
    for j in range(1, len(times_s) - 1):
        nom2, low2, high2, ok2 = _ranges(pos_mm, float(times_s[j + 1] - times_s[j]), settings)
        # [a, b, c]: (a, b) then (b, c) within the allowance over the distance a..c
        slack = settings.dv_dx_per_s * (pos_mm[None, None, :] - pos_mm[:, None, None])
        top = (high * (1 + settings.rel))[:, :, None] + slack
        bottom = (low / (1 + settings.rel))[:, :, None] - slack
        meet = (low2[None, :, :] <= top) & (high2[None, :, :] >= bottom)
        step = meet & fits[:, :, None] & ok2[None, :, :]
        new_fits = step.any(axis=0)
        new_weight = np.einsum("ab,abc->bc", weight, step.astype(float))
        new_weight *= skip[:n] * p_det[None, :]
        fits, weight, nominal, low, high = new_fits, new_weight, nom2, low2, high2
    return Chain(fits, weight, nominal)


def _meet(
    low: np.ndarray, high: np.ndarray, low2: np.ndarray, high2: np.ndarray, pos_mm, s
) -> np.ndarray:
    """[a, b, c]: (a, b) then (b, c) within the allowance over the distance a..c."""
    slack = s.dv_dx_per_s * (pos_mm[None, None, :] - pos_mm[:, None, None])
    top = (high * (1 + s.rel))[:, :, None] + slack
    bottom = (low / (1 + s.rel))[:, :, None] - slack
    return (low2[None, :, :] <= top) & (high2[None, :, :] >= bottom)


def _rise(
    rise: np.ndarray,
    j: int,
    low: np.ndarray,
    high: np.ndarray,
    dist: np.ndarray,
    s: AliasSettings,
) -> np.ndarray:
    """[a, b]: the density of told contact j's rise if the interval it ends or starts is
    the pair (a, b): its speed range widened by the allowance (the speed at the contact
    may differ from the interval's mean by as much as consecutive intervals may)."""
    with np.errstate(invalid="ignore"):
        v_low = low / (1 + s.rel) - s.dv_dx_per_s * dist
        v_high = high * (1 + s.rel) + s.dv_dx_per_s * dist
    return np.asarray(he.rise_density(rise[0, j], rise[1, j], v_low, v_high))


def _chain_evidence(
    pos_mm: np.ndarray,
    times_s: np.ndarray,
    p_det: np.ndarray,
    settings: AliasSettings,
    before: np.ndarray,
    evidence: np.ndarray,
    prior: np.ndarray | None,
    rise: np.ndarray | None = None,
) -> Chain:
    """`chain` with a per-contact factor under each value g of a shared parameter: the
    programme carries a weight per g (the paths' factors multiply within one g), summed
    with `prior` at the end. Kept apart so that `chain` without evidence stays as it was,
    to the bit."""
    n = len(pos_mm)
    skip = _skips(1.0 - p_det)
    g_count = evidence.shape[0]
    w_prior = np.full(g_count, 1.0 / g_count) if prior is None else np.asarray(prior, float)
    told = p_det[None, None, :] * evidence  # [g, j, k]
    nominal, low, high, ok = _ranges(pos_mm, float(times_s[1] - times_s[0]), settings)
    fits = ok.copy()
    first = (before[None, :] * told[:, 0, :])[:, :, None]
    weight = np.where(ok[None], first * skip[None, :n] * told[:, 1, None, :], 0.0)
    dist = pos_mm[None, :] - pos_mm[:, None]
    if rise is not None:  # both contacts of the first interval read its speed
        weight *= (
            _rise(rise, 0, low, high, dist, settings) * _rise(rise, 1, low, high, dist, settings)
        )[None]
    for j in range(1, len(times_s) - 1):
        nom2, low2, high2, ok2 = _ranges(pos_mm, float(times_s[j + 1] - times_s[j]), settings)
        step = _meet(low, high, low2, high2, pos_mm, settings) & fits[:, :, None] & ok2[None]
        fits = step.any(axis=0)
        weight = np.einsum("gab,abc->gbc", weight, step.astype(float))
        weight *= skip[None, :n] * told[:, j + 1, None, :]
        if rise is not None:
            weight *= _rise(rise, j + 1, low2, high2, dist, settings)[None]
        nominal, low, high = nom2, low2, high2
    return Chain(fits, np.tensordot(w_prior, weight, axes=1), nominal)


def after_miss(
    pos_mm: np.ndarray,
    p_det: np.ndarray,
    lag_s: np.ndarray,
    speed_mm_s: np.ndarray,
    t_last_s: float,
    t_now_s: float,
) -> np.ndarray:
    """[a, b]: the product of P(miss) over the ridges after b that the pair's speed says
    the edge crossed, and a detector could have decided (`lag_s` after), by `t_now_s`."""
    n = len(pos_mm)
    dist = pos_mm[None, :] - pos_mm[:, None]  # [b, q]
    with np.errstate(divide="ignore", invalid="ignore"):
        due = t_last_s + dist[None, :, :] / speed_mm_s[:, :, None] + lag_s[None, None, :]
    passed = (dist[None, :, :] > 0) & (due <= t_now_s)
    log_miss = np.log(np.maximum(1.0 - p_det, 1e-300))
    return np.exp(np.where(passed, log_miss[None, None, :], 0.0).sum(axis=2)).reshape(n, n)


def determined(
    speeds: np.ndarray, fits: np.ndarray, weights: np.ndarray, settings: AliasSettings
) -> tuple[bool, bool, float]:
    """Over final pair states (flattened, both directions): (unanimous, likelihood, the MAP
    speed - nan if no hypothesis fits)."""
    v = speeds[fits]
    if not len(v):
        return False, False, float("nan")
    unanimous = bool(v.max() <= (1 + settings.agree) * v.min())
    w = weights[fits]
    total = float(w.sum())
    if total <= 0:
        return unanimous, False, float("nan")
    v_map = float(v[int(np.argmax(w))])
    near = np.abs(v / v_map - 1) <= settings.agree
    return unanimous, bool(w[near].sum() >= settings.mass * total), v_map


@dataclass(frozen=True)
class Layout:
    """A case's skin as the hypotheses see it: per direction (+1 the layout's order, -1
    reversed) the ridge positions from the entry end, and per physical ridge the oracle's
    detection chance and decision lag."""

    spacings_mm: tuple[float, ...]
    p_det: np.ndarray  # per physical ridge (layout order)
    lag_s: np.ndarray  # per physical ridge: onset to decided

    def travel(self, direction: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Positions, detection chances and lags in travel order."""
        sp = np.asarray(self.spacings_mm, float)
        if direction > 0:
            return np.concatenate([[0.0], np.cumsum(sp)]), self.p_det, self.lag_s
        return np.concatenate([[0.0], np.cumsum(sp[::-1])]), self.p_det[::-1], self.lag_s[::-1]


Hypotheses = list[tuple[np.ndarray, np.ndarray, np.ndarray, Chain]]  # per direction


@dataclass(frozen=True)
class Heights:
    """Per true contact of a run (time order) its measured height and that's noise sigma
    (`height_evidence.measure`), and what a hypothesis predicts for it."""

    h_n: np.ndarray
    sigma_n: np.ndarray
    model: he.HeightModel | None  # None: the heights not weighed
    rise_s: np.ndarray | None = None  # measured rise times and sigmas: weighed when given
    rise_sigma_s: np.ndarray | None = None


def hypotheses(
    layout: Layout,
    times_s: np.ndarray,
    settings: AliasSettings,
    entry: bool = True,
    heights: Heights | None = None,
    told: np.ndarray | None = None,
) -> Hypotheses:
    """Both directions' chains (direction +1 first) for told contacts at `times_s`: with
    `heights`, each told contact's height weighs too (`told`: which of the run's contacts
    these are)."""
    out: Hypotheses = []
    for direction in (1, -1):
        pos, p_det, lag = layout.travel(direction)
        if heights is None:
            c = chain(pos, times_s, p_det, settings, entry)
        else:
            ev, prior, rise = None, None, None
            if heights.model is not None:
                h, sigma = heights.h_n[told], heights.sigma_n[told]
                ev = he.evidence(h, sigma, pos, heights.model)
                prior = heights.model.prior
            if heights.rise_s is not None and heights.rise_sigma_s is not None:
                rise = np.stack([heights.rise_s[told], heights.rise_sigma_s[told]])
            c = chain(pos, times_s, p_det, settings, entry, ev, prior, rise)
        out.append((pos, p_det, lag, c))
    return out


def judge(
    hyps: Hypotheses, t_last_s: float, t_now_s: float, settings: AliasSettings
) -> tuple[bool, bool, float, int]:
    """At `t_now_s`, the ridges passed since the last contact (at `t_last_s`) charged:
    `determined`'s (unanimous, likelihood, MAP speed) and the MAP pair state's index in
    the flattened (direction, a, b) states (-1: none weighs)."""
    speeds, fits, weights = [], [], []
    for pos, p_det, lag, c in hyps:
        after = after_miss(pos, p_det, lag, c.speed_mm_s, t_last_s, t_now_s)
        speeds.append(c.speed_mm_s.ravel())
        fits.append(c.fits.ravel())
        weights.append((c.weight * after).ravel())
    v, f, w = np.concatenate(speeds), np.concatenate(fits), np.concatenate(weights)
    u, lk, v_map = determined(v, f, w, settings)
    fitting = np.flatnonzero(f)
    best = int(fitting[np.argmax(w[fitting])]) if len(fitting) and w[fitting].sum() > 0 else -1
    return u, lk, v_map, best


def assess(
    layout: Layout,
    times_s: np.ndarray,
    t_now_s: float,
    settings: AliasSettings,
    entry: bool = True,
) -> tuple[bool, bool, float]:
    """At `t_now_s`, from told contacts at `times_s` (decided by then): both directions'
    hypotheses, the ridges passed since the last contact charged (likelihood).
    Returns `determined`'s (unanimous, likelihood, MAP speed)."""
    if len(times_s) < 2:
        return False, False, float("nan")
    hyps = hypotheses(layout, times_s, settings, entry)
    return judge(hyps, float(times_s[-1]), t_now_s, settings)[:3]


def true_fits(
    layout: Layout,
    direction: int,
    ridges: np.ndarray,
    times_s: np.ndarray,
    settings: AliasSettings,
) -> bool:
    """Whether the true assignment (travel-order `ridges` of the told contacts) fits - the
    allowances' check: it must, or the bound excludes the truth."""
    pos = layout.travel(direction)[0]
    ones = np.ones(len(pos))
    sub = np.zeros(len(pos), bool)
    sub[ridges] = True
    # the chain restricted to the true ridges: every other ridge undetectable
    c = chain(pos, times_s, np.where(sub, ones, 0.0), settings, entry=False)
    return bool(c.fits[ridges[-2], ridges[-1]] and c.weight[ridges[-2], ridges[-1]] > 0)


@dataclass(frozen=True)
class RunBound:
    """Per scored update of one run: whether the speed is determined now (`*_now`), held
    from an earlier update of the run (`*_held`), determined now with the last two told
    contacts among the run's last three true ones (`*_fresh`: the memory of older contacts
    resolves the aliases), or from those fresh contacts alone (`*_alone`: nothing older
    remembered); where the likelihood rule names a speed the true assignment's speed is
    more than `agree` away from (`wrong`: the posterior on an alias); and, where two told
    contacts are decided (`assessed`), whether the MAP pair state is the true one."""

    unanimous_now: np.ndarray
    likelihood_now: np.ndarray
    unanimous_held: np.ndarray
    likelihood_held: np.ndarray
    unanimous_fresh: np.ndarray
    likelihood_fresh: np.ndarray
    unanimous_alone: np.ndarray
    likelihood_alone: np.ndarray
    wrong: np.ndarray
    assessed: np.ndarray  # two told contacts decided: the hypotheses weighed
    map_true: np.ndarray  # the MAP pair state is the true one (direction, last two ridges)
    map_speed: np.ndarray  # the MAP pair state's speed is within `agree` of the true one
    truth_fits: bool  # the true assignment fits at every told set


def run_bound(
    layout: Layout,
    direction: int,
    contact_s: np.ndarray,
    told: np.ndarray,
    decided_s: np.ndarray,
    t_upd_s: np.ndarray,
    settings: AliasSettings,
    heights: Heights | None = None,
) -> RunBound:
    """One run (the edge crossing every ridge once in travel order, contact j at travel
    ridge j): the bounds at each of its scored updates `t_upd_s` (time order); with
    `heights` (per true contact) the told contacts' heights weigh too. The hypotheses of a
    set of told contacts are built once (they change only when a contact is decided)."""
    m = len(t_upd_s)
    out = {k: np.zeros(m, bool) for k in RunBound.__dataclass_fields__ if k != "truth_fits"}
    pos, _, _ = layout.travel(direction)
    n = len(pos)
    upto = np.searchsorted(contact_s, t_upd_s, side="right")
    held_u = held_l = False
    truth_ok = True
    checked: set[tuple[int, ...]] = set()
    cache: dict[tuple[bool, tuple[int, ...]], Hypotheses] = {}

    def judged(subset: np.ndarray, t: float, entry: bool) -> tuple[bool, bool, float, int]:
        key = (entry, tuple(int(k) for k in subset))
        if key not in cache:
            cache[key] = hypotheses(layout, contact_s[subset], settings, entry, heights, subset)
        return judge(cache[key], float(contact_s[subset[-1]]), t, settings)

    for i, t in enumerate(t_upd_s):
        known = np.flatnonzero(told & (decided_s <= t) & (np.arange(len(contact_s)) < upto[i]))
        if len(known) >= 2:
            key = tuple(int(k) for k in known)
            if key not in checked:
                checked.add(key)
                truth_ok &= true_fits(layout, direction, known, contact_s[known], settings)
            u, lk, v_map, best = judged(known, float(t), True)
            out["unanimous_now"][i], out["likelihood_now"][i] = u, lk
            a, b = known[-2], known[-1]
            out["assessed"][i] = True
            out["map_true"][i] = best == (0 if direction > 0 else 1) * n * n + a * n + b
            v_true = (pos[b] - pos[a]) / (contact_s[b] - contact_s[a])
            near = abs(v_map / v_true - 1) <= settings.agree
            out["map_speed"][i] = near
            out["wrong"][i] = lk and not near
            fresh = a >= upto[i] - 3
            out["unanimous_fresh"][i] = u and fresh
            out["likelihood_fresh"][i] = lk and fresh
            recent = known[known >= upto[i] - 3]
            if len(recent) >= 2:
                ua, la, _, _ = judged(recent, float(t), False)
                out["unanimous_alone"][i], out["likelihood_alone"][i] = ua, la
            held_u |= u
            held_l |= lk
        out["unanimous_held"][i], out["likelihood_held"][i] = held_u, held_l
    return RunBound(**out, truth_fits=truth_ok)

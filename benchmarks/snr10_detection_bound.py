"""The information bound at 10 dB SNR (issue 22): the least speed missing any detector
could give on slip_reporting's snr10 cases (`evaluation/detection_bound.py`).

1. The oracle: each true ridge pulse's matched filter (its shape and onset known, a
   linear background unknown) at its true onset, on the recorded signal (`raw`: the other
   pulses' tails left in, as a detector sees them) and on the signal less the other
   pulses (`clean`: the ideal, N(SNR, 1)); and the same filter at random times of the
   slide 2 rise times and 20 ms or more from any onset (the pulses' own bends as noise).
2. The threshold: a scanning detector (the bank of every snr10 pulse's template of that
   layout, at every sample) on the held-noise cases (10 dB, no slip): the level none of
   them crosses (`strict`), and the level at which it tells as many contacts per held
   minute as today's detector does there (`today`: held objects stay at 0 false slips).
   Inside a track's gate (+-GATE_S around a predicted onset, one template) the chance a
   held signal crosses a level is far lower: the level for GATE_FA.
3. The bound: slipping updates from each run's 3rd contact (slip_reporting's scored set,
   checked against `slip_reporting.score`) with no two told contacts decided by then -
   among all of the run's (`any 2`) or among its last 3 true contacts (`last 3`: a speed
   from fresh contacts, as a tracker gives it) - per layout and per speed; told = the
   oracle's statistic at or above the threshold, or (gated) at or above the gate's level
   once two contacts of the run are told (a track predicts the rest). Beside it today's
   detector's found share (+-20 ms), the same bound on the contacts it finds (a perfect
   tracker behind today's detector), and, with `--decoder`, the default decoder's missing.
4. With `--aliases`: the same bound without the ridge identities (`evaluation/alias_bound.py`)
   on the clean told contacts at the level "today", per allowance of `ALIAS_SETTINGS`.

Every snr10 case is sampled at 400 Hz (`nonstationary.make_signal`): no rate to split by.

5. With `--heights` (and `--aliases`): the told contacts' pulse heights weigh too
   (`evaluation/height_evidence.py`: the oracle's least-squares height on the clean signal,
   the model's f(spacing before) times a scale a marginalised or known) and, apart and
   together, the told pulses' rise times (the oracle's least-squares rise: evidence on the
   speed itself), times only beside them, and how often the MAP ridge assignment is the
   true one.

Run: `.venv/bin/python benchmarks/snr10_detection_bound.py [--seeds N] [--decoder] [--aliases]
[--heights] [--workers 2]`.
"""

from __future__ import annotations

import argparse
import zlib
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from grasplink.decoding.base import SlipEstimate
from grasplink.decoding.registry import DEFAULT_DECODER
from grasplink.evaluation import alias_bound as ab
from grasplink.evaluation import contact_truth as ct
from grasplink.evaluation import detection_bound as db
from grasplink.evaluation import height_evidence as he
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

GATE_S = 0.015  # a track's prediction of the next onset, +- (10 dB: a few ms of timing)
GATE_FA = 0.05  # a gate's false-alarm chance on a held signal the gated level allows
NULL_PER_CASE = 40  # random slide times per case
LEVELS = np.round(np.arange(2.0, 7.01, 0.25), 2)  # thresholds tabulated (noise units)
SEED = 22
UPDATE_S = 0.01  # the tracker's update period (one estimate per 10 ms)


def _white(layout_mm) -> float:
    return ns.pulse_height_n(layout_mm) / 10 ** (ns.SNR_DB / 20)


def _scored(truth, t_upd: np.ndarray) -> np.ndarray:
    """slip_reporting's from-3rd scored updates (moving, from the run's 3rd contact, the
    edge not past the last ridge ahead)."""
    v = np.interp(t_upd, truth.t_s, truth.speed_mm_s)
    moving = np.abs(v) >= sr.V_MOVING_MM_S
    edge = np.interp(t_upd, truth.t_s, truth.position_mm)
    skin_mm = sr.ridges_mm(truth.layout_mm)
    contacts = np.sort(np.asarray(truth.contact_times_s, dtype=float))
    out = np.zeros(len(t_upd), bool)
    for start, end, sign in ns.motion(truth).runs:
        mine = contacts[(contacts >= start) & (contacts < end)]
        inside = (t_upd >= start) & (t_upd < end)
        beyond = (edge >= skin_mm[-1]) if sign > 0 else (edge <= skin_mm[0])
        if len(mine) >= 3:
            out |= inside & (t_upd >= mine[2]) & ~beyond
    return out & moving


def snr10_job(case: sr.Case, decoder: bool) -> dict:
    """One snr10 case: per contact SNR, raw and clean statistics, decision time, run and
    found-now; slide nulls; templates; scored updates."""
    rec = case.make()
    truth, fs = rec.truth, rec.fs_hz
    if len(rec.t_s) != len(truth.t_s):
        raise ValueError(f"{case}: samples dropped, the oracle needs the full signal")
    white = _white(truth.layout_mm)
    train = ct.pulse_train(truth, case.seed)
    x = np.asarray(rec.force_n, dtype=float)
    rest = x - train.pulses_n  # everything but the pulses: grip, level, drift, noise
    tmpls = [db.template(train, i, fs) for i in range(len(train.times_s))]
    onsets = np.ceil(train.times_s * fs).astype(int)
    snr = np.array([t.norm_n / white for t in tmpls])
    raw = np.array([db.statistic(x, a, t, white) for a, t in zip(onsets, tmpls, strict=True)])
    clean = (
        np.array([db.statistic(rest, a, t, white) for a, t in zip(onsets, tmpls, strict=True)])
        + snr
    )
    decided = (onsets + np.array([t.after for t in tmpls])) / fs
    heights = np.array(  # the oracle's least-squares heights (N) and sigmas, clean
        [
            he.measure(rest, a, t.offsets, alpha, rise, fs, white, t0)
            for a, t, alpha, rise, t0 in zip(
                onsets, tmpls, train.alpha_n, train.rise_s, train.times_s, strict=True
            )
        ]
    ).reshape(-1, 2)
    rise_rel = np.array(  # the rise time's Cramer-Rao bound, relative (left out of the bound)
        [
            he.rise_sigma(a, t.offsets, alpha, rise, fs, white, t0)
            for a, t, alpha, rise, t0 in zip(
                onsets, tmpls, train.alpha_n, train.rise_s, train.times_s, strict=True
            )
        ]
    )
    found = np.asarray(ct.by_contact(truth, rec.t_s, rec.force_n, fs).found, dtype=bool)
    # slide nulls: random onsets away from every true one, the nearest pulse's template
    rng = np.random.default_rng([SEED, case.seed, zlib.crc32(case.layout.encode())])
    sliding = np.flatnonzero(np.asarray(truth.slipping) > 0)
    null_raw, null_clean = [], []
    if len(sliding) and len(tmpls):
        margin = np.maximum(2 * train.rise_s, 0.02)
        for _ in range(NULL_PER_CASE * 4):
            at = int(rng.choice(sliding))
            t = at / fs
            if np.any(np.abs(train.times_s - t) < margin):
                continue
            j = int(np.argmin(np.abs(train.times_s - t)))
            a, b = db.statistic(x, at, tmpls[j], white), db.statistic(rest, at, tmpls[j], white)
            if np.isfinite(a):
                null_raw.append(a)
                null_clean.append(b)
            if len(null_raw) >= NULL_PER_CASE:
                break
    runs = np.full(len(train.times_s), -1)
    for r, (start, end, _sign) in enumerate(ns.motion(truth).runs):
        runs[(train.times_s >= start) & (train.times_s < end)] = r
    t_upd = rec.t_s[:: round(UPDATE_S * fs)]  # the decoder's update times
    scored = _scored(truth, t_upd)
    blank = [SlipEstimate(float(t), False, None, None, None, 0.0) for t in t_upd]
    if sr.score(blank, truth).moving_from3 != int(scored.sum()):
        raise AssertionError(f"{case}: the scored set is not slip_reporting's")
    out = {
        "layout": case.layout,
        "variant": case.variant,
        "snr": snr,
        "raw": raw,
        "clean": clean,
        "decided": decided,
        "alpha": train.alpha_n,
        "height": heights[:, 0],
        "height_sigma": heights[:, 1],
        "rise_rel": rise_rel,
        "rise": train.rise_s,
        "rise_hat": np.array(
            [
                he.measure_rise(rest, a, t.offsets, alpha, rise, fs, t0, RISE_GRID_S)
                for a, t, alpha, rise, t0 in zip(
                    onsets, tmpls, train.alpha_n, train.rise_s, train.times_s, strict=True
                )
            ]
        ),
        "times": train.times_s,
        "runs": runs,
        "found": found,
        "null_raw": np.array(null_raw),
        "null_clean": np.array(null_clean),
        **_slide_false(rec, train, tmpls, white, sliding),
        "templates": tmpls,
        "t_upd": t_upd[scored],
        "upd_run": _update_runs(truth, t_upd[scored]),
        "spacings": tuple(truth.layout_mm),
        "reverse": bool(case.reverse),
    }
    if decoder:
        dec = sr.build_decoder(DEFAULT_DECODER, truth.layout_mm, fs, {})
        estimates, _ = ns.feed(dec, rec.t_s, rec.force_n, sr.CHUNK)
        score = sr.score(estimates, truth)
        if score.moving_from3 != int(scored.sum()):
            raise AssertionError(
                f"{case}: decoder's updates {score.moving_from3} scored, not {int(scored.sum())}"
            )
        out["decoder_missing"] = score.missing_from3
        t_est = np.array([e.t_s for e in estimates])
        if len(t_est) != len(t_upd) or not np.allclose(t_est, t_upd):
            raise AssertionError(f"{case}: the decoder's updates are not every {UPDATE_S} s")
        out["decoder_state"] = np.array([_state(e) for e in estimates])[scored]
    return out


def _slide_false(rec, train, tmpls, white: float, sliding: np.ndarray) -> dict:
    """False contacts while the object slides: the scan of the case's own templates on the
    signal less its pulses (the clean filter's background: the level moving with the
    object, the drift) per level, and today's detector's contacts 20 ms or more from any
    crossing; and the slide's length."""
    fs = rec.fs_hz
    bank = [t for t in tmpls if t.norm_n > 0]
    if not len(sliding) or not bank:
        return {"slide_s": 0.0, "slide_counts": np.zeros(len(LEVELS)), "slide_today": 0}
    stat = db.scan(np.asarray(rec.force_n) - train.pulses_n, bank, white)
    outside = np.ones(len(stat), bool)
    outside[sliding[0] : sliding[-1] + 1] = False
    stat[outside] = -np.inf
    told = ct.detect(rec.t_s, rec.force_n, fs)
    times = np.array([e.t_s for e in told.contacts])
    t0, t1 = rec.t_s[sliding[0]], rec.t_s[sliding[-1]]
    during = (times >= t0) & (times <= t1) if len(times) else np.zeros(0, bool)
    near = ct.near_truth(times, train.times_s) if len(times) else np.zeros(0, bool)
    return {
        "slide_s": float(t1 - t0),
        "slide_counts": np.array([db.events(stat, float(lv), fs) for lv in LEVELS]),
        "slide_today": int(np.sum(during & ~near)),
    }


STATES = ("speed", "range", "flag only", "no slip")


def _state(e: SlipEstimate) -> int:
    """An update's answer (`STATES`): a speed, a range of speeds with the flag up, the
    flag alone, or no slip."""
    if e.speed_mm_s is not None and e.speed_mm_s > 0:
        return 0
    if e.slip and e.speed_low_mm_s is not None:
        return 1
    return 2 if e.slip else 3


def _update_runs(truth, t_upd: np.ndarray) -> np.ndarray:
    out = np.full(len(t_upd), -1)
    for r, (start, end, _sign) in enumerate(ns.motion(truth).runs):
        out[(t_upd >= start) & (t_upd < end)] = r
    return out


def held_job(case: sr.Case, bank: list[db.Template], gates: int) -> dict:
    """One held-noise case: the scan's events per level, and gated false alarms."""
    rec = case.make()
    white = _white(rec.truth.layout_mm)
    x = np.asarray(rec.force_n, dtype=float)
    stat = db.scan(x, bank, white)
    fs = rec.fs_hz
    settle = int(0.5 * fs)  # the first half second: the filters fill
    stat[:settle] = -np.inf
    counts = [db.events(stat, float(level), fs) for level in LEVELS]
    rng = np.random.default_rng([SEED, case.seed, zlib.crc32(case.layout.encode()), 1])
    half = round(GATE_S * fs)
    gate_max = []
    for _ in range(gates):
        tmpl = bank[int(rng.integers(len(bank)))]
        centre = int(rng.integers(settle + half, len(x) - half - int(tmpl.offsets[-1]) - 1))
        gate_max.append(
            max(db.statistic(x, c, tmpl, white) for c in range(centre - half, centre + half + 1))
        )
    told = ct.detect(rec.t_s, rec.force_n, fs)
    return {
        "layout": case.layout,
        "steady": case.numbers[0] == "steady",
        "minutes": (len(x) - settle) / fs / 60.0,
        "max": float(np.max(stat)),
        "counts": counts,
        "gate_max": np.array(gate_max),
        "today": len(told.contacts),
    }


def told_mask(row: dict, level: float, gate_level: float | None, key: str) -> np.ndarray:
    """Which contacts the oracle tells: at or above `level`; with a gate, at or above
    `gate_level` once two earlier contacts of its run are told."""
    stat = row[key]
    told = stat >= level
    if gate_level is None:
        return told
    out = told.copy()
    for r in np.unique(row["runs"]):
        mine = np.flatnonzero(row["runs"] == r)
        n = 0
        for j in mine:
            out[j] = stat[j] >= (gate_level if n >= 2 else level)
            n += int(out[j])
    return out


def missing(row: dict, told: np.ndarray, last: int | None) -> int:
    """Scored updates of one case with no speed possible."""
    return int((~_possible(row, told, last)).sum())


def _possible(row: dict, told: np.ndarray, last: int | None) -> np.ndarray:
    """Per scored update of one case: a speed possible from the told contacts."""
    possible = np.zeros(len(row["t_upd"]), bool)
    for r in np.unique(row["upd_run"]):
        upd = row["upd_run"] == r
        mine = row["runs"] == r
        possible[upd] = db.speed_possible(
            row["t_upd"][upd], row["times"][mine], told[mine], row["decided"][mine], last
        )
    return possible


def level_for(held: list[dict], rate_per_min: float) -> float:
    """The lowest tabulated level whose scan tells at most `rate_per_min` contacts per held
    minute over the held-noise cases."""
    minutes = sum(h["minutes"] for h in held)
    counts = np.sum([h["counts"] for h in held], axis=0)
    ok = np.flatnonzero(counts / minutes <= rate_per_min)
    return float(LEVELS[ok[0]]) if len(ok) else float("inf")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="seeds of the full plan (1-3)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--decoder", action="store_true", help="the default decoder beside it")
    parser.add_argument("--gates", type=int, default=400, help="gates per held case")
    parser.add_argument(
        "--aliases",
        action="store_true",
        help="the bound without the ridge identities (evaluation/alias_bound.py) beside it",
    )
    parser.add_argument(
        "--heights",
        action="store_true",
        help="with --aliases: the told contacts' pulse heights weigh too (height_evidence.py)",
    )
    args = parser.parse_args(argv)
    if args.heights and not args.aliases:
        parser.error("--heights needs --aliases")
    if not 1 <= args.seeds <= sr.FULL.seeds:
        parser.error(f"--seeds must be 1-{sr.FULL.seeds}, got {args.seeds}")
    every = sr.cases(sr.FULL)
    snr_cases = [c for c in every if c.kind == "snr10"]
    held_cases = [c for c in every if c.kind == "held-noise"]
    if args.seeds < sr.FULL.seeds:  # the first N seeds of each layout's cases
        per = defaultdict(list)
        for c in snr_cases:
            per[(c.layout, c.variant, c.reverse)].append(c)
        snr_cases = [c for group in per.values() for c in group[: args.seeds]]
        per = defaultdict(list)
        for c in held_cases:
            per[(c.layout, c.variant)].append(c)
        held_cases = [c for group in per.values() for c in group[: args.seeds]]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(snr10_job, snr_cases, [args.decoder] * len(snr_cases)))
        banks: dict[str, list[db.Template]] = defaultdict(list)
        for row in rows:
            banks[row["layout"]] += [t for t in row["templates"] if t.norm_n > 0]
        held = list(
            pool.map(
                held_job,
                held_cases,
                [banks[c.layout] for c in held_cases],
                [args.gates] * len(held_cases),
            )
        )
        if args.aliases:  # on the oracle's told contacts at the level "today"
            level = _level_today(held)
            widen = (_height_widen(rows), _rise_widen(rows, level)) if args.heights else None
            per = list(pool.map(alias_job, rows, [level] * len(rows), [widen] * len(rows)))
            for row, bounds in zip(rows, per, strict=True):
                row["aliases"] = bounds
    report(rows, held, args)
    if args.aliases:
        alias_report(rows, args)
    if args.heights:
        height_report(rows, args)
    return 0


ALIAS_SETTINGS = {  # the allowances tabulated: name -> what a hypothesis must fit
    "smooth": ab.AliasSettings(),  # every snr10 case's true assignment fits
    "25 %": ab.AliasSettings(rel=0.25, dv_dx_per_s=0.0),  # consecutive speeds +-25 %
    "smooth, 10 ms": ab.AliasSettings(tol_s=0.010),
    # the most favourable: near-constant speed and the set's speeds (21-118 mm/s) known
    "25 %, 15-150 mm/s": ab.AliasSettings(
        rel=0.25, dv_dx_per_s=0.0, v_min_mm_s=15.0, v_max_mm_s=150.0
    ),
}


def _level_today(every_held: list[dict]) -> float:
    """The level "today" of `report`: the scan tells as many contacts per held minute (grip
    steady) as today's detector."""
    held = [h for h in every_held if h["steady"]]
    minutes = sum(h["minutes"] for h in held)
    return level_for(held, sum(h["today"] for h in held) / minutes)


SCALE_GRID = he.log_grid(0.25, 4.0, 49)  # the unknown scale a's range (N): log-uniform
RISE_GRID_S = he.log_grid(0.002, 0.25, 400)  # the rise times the oracle's fit tries
_KNOWN = he.HeightModel(np.array([he.SIM_SCALE_N]))
HEIGHT_SETTINGS: dict[str, tuple[str, he.HeightModel | None, bool]] = {
    # name -> (the allowance of ALIAS_SETTINGS, the heights' model, the rise weighed)
    "smooth + heights": ("smooth", he.HeightModel(SCALE_GRID), False),
    "smooth + heights, a known": ("smooth", _KNOWN, False),
    "25 %, 15-150 mm/s + heights": ("25 %, 15-150 mm/s", he.HeightModel(SCALE_GRID), False),
    "25 %, 15-150 mm/s + heights, a known": ("25 %, 15-150 mm/s", _KNOWN, False),
    "smooth + rise": ("smooth", None, True),
    "smooth + heights + rise": ("smooth", he.HeightModel(SCALE_GRID), True),
    "25 %, 15-150 mm/s + heights + rise, a known": ("25 %, 15-150 mm/s", _KNOWN, True),
}


def _rise_widen(rows: list[dict], level: float) -> float:
    """The measured rise times' errors in their Cramer-Rao sigmas over the told snr10
    contacts: their standard deviation (the factor the rise likelihood widens by)."""
    z = np.concatenate(
        [
            ((r["rise_hat"] - r["rise"]) / (r["rise_rel"] * r["rise"]))[r["clean"] >= level]
            for r in rows
        ]
    )
    return float(np.std(z[np.isfinite(z)]))


def _height_widen(rows: list[dict]) -> float:
    """The measured heights' errors in their white-noise sigmas, over every snr10 contact:
    their standard deviation (the clean signal's drift and moving level add to the white
    noise) - the factor the likelihood widens each sigma by."""
    z = np.concatenate([(r["height"] - r["alpha"]) / r["height_sigma"] for r in rows])
    z = z[np.isfinite(z)]
    return float(np.std(z))


def alias_job(row: dict, level: float, widen: tuple[float, float] | None = None) -> dict:
    """One snr10 case's alias bounds (`ab.run_bound`) per allowance of `ALIAS_SETTINGS`, on
    the oracle's clean told contacts at `level`: summed over its scored updates; with
    `widen` (the heights' and the rise times' sigma factors) also per variant of
    `HEIGHT_SETTINGS`."""
    told = row["clean"] >= level
    n = len(row["spacings"]) + 1
    if len(row["times"]) != n or np.any(row["runs"] != 0):
        raise AssertionError("an snr10 case is one run crossing every ridge once")
    by_ridge = slice(None, None, -1) if row["reverse"] else slice(None)  # physical order
    layout = ab.Layout(
        row["spacings"],
        ab.p_detect(row["snr"], level)[by_ridge],
        (row["decided"] - row["times"])[by_ridge],
    )
    out: dict = {"level": level}

    def bound(settings: ab.AliasSettings, heights: ab.Heights | None = None) -> dict:
        """One variant's counts on this case."""
        b = ab.run_bound(
            layout,
            -1 if row["reverse"] else 1,
            row["times"],
            told,
            row["decided"],
            row["t_upd"],
            settings,
            heights,
        )
        return {k: int(np.sum(getattr(b, k))) for k in ALIAS_COLUMNS} | {"truth_fits": b.truth_fits}

    for name, settings in ALIAS_SETTINGS.items():
        out[name] = bound(settings)
    if widen is None:
        return out
    for name, (allowance, model, with_rise) in HEIGHT_SETTINGS.items():
        rise_sigma = row["rise_rel"] * row["rise"] * widen[1]
        heights = ab.Heights(
            row["height"],
            row["height_sigma"] * widen[0],
            model,
            row["rise_hat"] if with_rise else None,
            rise_sigma if with_rise else None,
        )
        out[name] = bound(ALIAS_SETTINGS[allowance], heights)
    return out


ALIAS_COLUMNS = (
    "unanimous_held",
    "likelihood_held",
    "unanimous_fresh",
    "likelihood_fresh",
    "unanimous_alone",
    "likelihood_alone",
    "likelihood_now",
    "wrong",
    "assessed",
    "map_true",
    "map_speed",
)


def _by_set(rows: list[dict]) -> tuple[dict[str, list[dict]], list[str]]:
    """The rows by layout, by speed set ("speed ...") and all together, and the order the
    tables print them in (layouts, then speed sets, then "all")."""
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[r["layout"]].append(r)
        groups[f"speed {r['variant']}"].append(r)
        groups["all"].append(r)
    return groups, sorted(groups, key=lambda k: (k == "all", k.startswith("speed"), k))


def alias_report(rows: list[dict], args) -> None:
    """The alias bounds per layout and speed set beside the s27 bound (any 2 / last 3,
    ridges known) and the decoder: speed missing = scored updates not determined."""
    level = rows[0]["aliases"]["level"]
    groups, order = _by_set(rows)
    for name in ALIAS_SETTINGS:
        s = ALIAS_SETTINGS[name]
        excluded = sum(not r["aliases"][name]["truth_fits"] for r in rows)
        print(
            f"Aliases, allowance {name!r} (times +-{s.tol_s * 1e3:g} ms, consecutive speeds"
            f" +-{s.rel:.0%} + {s.dv_dx_per_s:g} mm/s per mm, {s.v_min_mm_s:g}-"
            f"{s.v_max_mm_s:g} mm/s; agree {s.agree:.0%}, mass {s.mass:.0%}), clean told at"
            f" {level:.2f}; the true assignment excluded in {excluded} of {len(rows)} cases."
            " Speed missing % (held: determined once in the run; fresh: now, the last two"
            " told among the last 3 true; alone: from those alone):"
        )
        header = (
            "| set | scored updates | s27 ridges known: any 2 / last 3 |"
            " unanimous: held / fresh / alone | likelihood: held / fresh / alone |"
            " likelihood on an alias (of scored) |" + (" decoder |" if args.decoder else "")
        )
        print(header)
        print("|---" * (header.count("|") - 1) + "|")
        for key in order:
            rs = groups[key]
            scored = sum(len(r["t_upd"]) for r in rs)
            told = [r["clean"] >= level for r in rs]
            any2 = sum(missing(r, m, None) for r, m in zip(rs, told, strict=True))
            last3 = sum(missing(r, m, 3) for r, m in zip(rs, told, strict=True))

            def pct(col: str, rs=rs, scored=scored, name=name) -> str:
                got = sum(r["aliases"][name][col] for r in rs)
                return f"{(scored - got) / scored:.1%}"

            cells = [
                key,
                str(scored),
                f"{any2 / scored:.1%} / {last3 / scored:.1%}",
                " / ".join(
                    pct(c) for c in ("unanimous_held", "unanimous_fresh", "unanimous_alone")
                ),
                " / ".join(
                    pct(c) for c in ("likelihood_held", "likelihood_fresh", "likelihood_alone")
                ),
                f"{sum(r['aliases'][name]['wrong'] for r in rs) / scored:.1%}",
            ]
            if args.decoder:
                cells.append(f"{sum(r['decoder_missing'] for r in rs) / scored:.1%}")
            print("| " + " | ".join(cells) + " |")


def height_report(rows: list[dict], args) -> None:
    """Times only beside times + heights (`HEIGHT_SETTINGS`), likelihood rule, per layout
    and speed set: speed missing % held / fresh, the share of scored updates on an
    alias's speed, and how often the MAP pair state is the true one."""
    widen = _height_widen(rows)
    ratio = np.concatenate([r["alpha"] / he.shape_factor(_before(r)) for r in rows])
    told = np.concatenate([r["clean"] >= r["aliases"]["level"] for r in rows])
    rel = np.concatenate([r["height_sigma"] / r["alpha"] for r in rows]) * widen
    print(
        f"Heights: alpha / f(spacing before) in the truth {ratio.min():.3f}-{ratio.max():.3f}"
        f" (the per-contact draw; the scale a = 1 N shared); measured heights' errors"
        f" {widen:.2f} white-noise sigmas (std over {np.isfinite(rel).sum()} contacts: the"
        f" likelihood's sigma widened by it); sigma / alpha median {np.nanmedian(rel):.2f}"
        f" (told {np.nanmedian(rel[told]):.2f}); a marginalised log-uniform over"
        f" {SCALE_GRID[0]:g}-{SCALE_GRID[-1]:g} N ({len(SCALE_GRID)} points) or known."
    )
    rise = np.concatenate([r["rise_rel"] for r in rows])
    jitter = 0.1 / 3**0.5  # rise_jitter [0.9, 1.1]: its standard deviation
    speed_rel = np.sqrt(rise**2 + jitter**2)
    variants: dict[str, list[np.ndarray]] = defaultdict(list)
    for r in rows:
        variants[r["variant"]].append(r["rise_rel"][r["clean"] >= r["aliases"]["level"]])
    print(
        "Left out: the rise time (1.25 mm / speed, +-10 % jitter) at its Cramer-Rao bound"
        " (height, rise, linear background unknown; onset known) tells the speed to"
        f" {np.nanmedian(speed_rel):.0%} (median; told {np.nanmedian(speed_rel[told]):.0%},"
        f" within 10 % for {np.mean(speed_rel[told] <= 0.1):.0%} of the told contacts);"
        " the rise alone, told, by speed set (median): "
        + ", ".join(f"{v} {np.nanmedian(np.concatenate(x)):.0%}" for v, x in variants.items())
    )
    level = rows[0]["aliases"]["level"]
    rz = np.concatenate([((r["rise_hat"] - r["rise"]) / r["rise"]) for r in rows])
    print(
        f"The oracle's least-squares rise (the onset known): error / rise over the told"
        f" contacts median {np.nanmedian(np.abs(rz[told])):.0%} (|.|), errors"
        f" {_rise_widen(rows, level):.2f} Cramer-Rao sigmas (std: the rise likelihood's"
        " sigma widened by it)"
    )
    pairs = [("smooth", "smooth + heights"), ("smooth", "smooth + heights, a known")]
    pairs += [
        ("25 %, 15-150 mm/s", "25 %, 15-150 mm/s + heights"),
        ("25 %, 15-150 mm/s", "25 %, 15-150 mm/s + heights, a known"),
    ]
    groups, order = _by_set(rows)
    header = (
        "| set | scored updates | ridges known: any 2 / last 3 |"
        + "".join(f" {a} / {b}: held / fresh |" for a, b in pairs[::2])
        + " smooth + heights, a known |"
        + " 25 %, 15-150 + heights, a known |"
        + " smooth + rise | smooth + heights + rise |"
        + " 25 %, 15-150 + heights + rise, a known |"
        + " on an alias: smooth / + heights / + heights + rise |"
        + (" decoder |" if args.decoder else "")
    )
    print("Speed missing %, likelihood rule: times only beside times + heights")
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    for key in order:
        rs = groups[key]
        scored = sum(len(r["t_upd"]) for r in rs)
        masks = [r["clean"] >= r["aliases"]["level"] for r in rs]
        any2 = sum(missing(r, m, None) for r, m in zip(rs, masks, strict=True))
        last3 = sum(missing(r, m, 3) for r, m in zip(rs, masks, strict=True))

        def miss(name: str, rs=rs, scored=scored) -> str:
            held = sum(r["aliases"][name]["likelihood_held"] for r in rs)
            fresh = sum(r["aliases"][name]["likelihood_fresh"] for r in rs)
            return f"{(scored - held) / scored:.1%} / {(scored - fresh) / scored:.1%}"

        def share(name: str, col: str, rs=rs, scored=scored) -> str:
            return f"{sum(r['aliases'][name][col] for r in rs) / scored:.1%}"

        cells = [key, str(scored), f"{any2 / scored:.1%} / {last3 / scored:.1%}"]
        cells += [f"{miss(a)} -> {miss(b)}" for a, b in pairs[::2]]
        cells += [miss(pairs[1][1]), miss(pairs[3][1])]
        cells += [
            miss("smooth + rise"),
            miss("smooth + heights + rise"),
            miss("25 %, 15-150 mm/s + heights + rise, a known"),
        ]
        cells.append(
            " / ".join(
                share(n, "wrong") for n in ("smooth", "smooth + heights", "smooth + heights + rise")
            )
        )
        if args.decoder:
            cells.append(f"{sum(r['decoder_missing'] for r in rs) / scored:.1%}")
        print("| " + " | ".join(cells) + " |")
    assessed = sum(r["aliases"]["smooth"]["assessed"] for r in rows)
    names = ["smooth", "25 %, 15-150 mm/s", *HEIGHT_SETTINGS]
    print(
        f"The MAP pair state (direction, last two told ridges) is the true one, of the"
        f" {assessed} scored updates with two told contacts decided: "
        + ", ".join(
            f"{n} {sum(r['aliases'][n]['map_true'] for r in rows) / assessed:.1%}" for n in names
        )
    )
    print(
        "  its speed within 10 % of the true one: "
        + ", ".join(
            f"{n} {sum(r['aliases'][n]['map_speed'] for r in rows) / assessed:.1%}" for n in names
        )
    )
    scored_all = sum(len(r["t_upd"]) for r in rows)
    print(
        "  the likelihood names an alias's speed (of the scored updates): "
        + ", ".join(
            f"{n} {sum(r['aliases'][n]['wrong'] for r in rows) / scored_all:.1%}" for n in names
        )
    )
    excluded = {n: sum(not r["aliases"][n]["truth_fits"] for r in rows) for n in names}
    print(f"The true assignment excluded (cases): {excluded}")


def _before(row: dict) -> np.ndarray:
    """Per true contact (time order) the spacing crossed before its ridge (mm)."""
    sp = np.asarray(row["spacings"], float)
    travel = sp[::-1] if row["reverse"] else sp
    return np.concatenate([[he.LEAD_IN_MM], travel])


def report(rows: list[dict], every_held: list[dict], args) -> None:
    held = [h for h in every_held if h["steady"]]  # the noise alone: grip ramps apart
    ramps = [h for h in every_held if not h["steady"]]
    minutes = sum(h["minutes"] for h in held)
    today = sum(h["today"] for h in held) / minutes
    strict = max(h["max"] for h in held)
    level_today = level_for(held, today)
    gate_max = np.concatenate([h["gate_max"] for h in held])
    gate_level = float(np.quantile(gate_max, 1 - GATE_FA))
    n_contacts = sum(len(r["snr"]) for r in rows)
    print(
        f"snr10 cases {len(rows)} ({n_contacts} ridge contacts), held-noise cases"
        f" {len(every_held)} ({minutes:.1f} held min with the grip steady), {args.seeds}"
        " seed(s), full plan"
    )
    print("Thresholds (white-noise units of the matched filter), held-noise, grip steady:")
    print(f"  scan: largest output {strict:.2f} (strict: none crosses it)")
    print(
        f"  today's detector tells {today:.2f} contacts per held minute; the scan tells as"
        f" many from {level_today:.2f} (today)"
    )
    print(
        f"  a gate of +-{GATE_S * 1e3:.0f} ms (one template): {GATE_FA:.0%} of held gates"
        f" cross {gate_level:.2f}"
    )
    per_level = np.sum([h["counts"] for h in held], axis=0) / minutes
    print(
        "  scan contacts per held minute by level: "
        + ", ".join(
            f"{lv:g}: {c:.2f}" for lv, c in zip(LEVELS, per_level, strict=True) if 3 <= lv <= 6
        )
    )
    if ramps:
        r_min = sum(h["minutes"] for h in ramps)
        print(
            f"  grip ramps 4-6 N ({r_min:.1f} min): largest scan output"
            f" {max(h['max'] for h in ramps):.2f} (the ramps' knees: a shape, not noise - a"
            f" detector tells them apart from a pulse), today's detector"
            f" {sum(h['today'] for h in ramps) / r_min:.2f} contacts per min"
        )
    null_raw = np.concatenate([r["null_raw"] for r in rows])
    null_clean = np.concatenate([r["null_clean"] for r in rows])
    q = [0.5, 0.9, 0.99]
    print(
        f"Filter at {len(null_raw)} random slide times (no onset near): raw quantiles"
        f" {', '.join(f'{v:.2f}' for v in np.quantile(null_raw, q))} (50/90/99 %),"
        f" std {np.std(null_raw):.2f}; clean std {np.std(null_clean):.2f} (N(0,1): 1.00)"
    )
    for name, lv in (("strict", strict), ("today", level_today)):
        print(
            f"  at {name} ({lv:.2f}) the filter crosses at {np.mean(null_raw >= lv):.1%} (raw)"
            f" / {np.mean(null_clean >= lv):.1%} (clean) of those slide times"
        )
    slide_s = sum(r["slide_s"] for r in rows)
    slide_today = sum(r["slide_today"] for r in rows) / slide_s
    slide_rate = np.sum([r["slide_counts"] for r in rows], axis=0) / slide_s
    ok = np.flatnonzero(slide_rate <= slide_today)
    level_slide = float(LEVELS[ok[0]]) if len(ok) else float("inf")
    print(
        f"While sliding ({slide_s:.0f} s): today's detector tells {slide_today:.2f} contacts"
        f" per s 20 ms or more from any crossing; the clean scan (each case's own templates)"
        f" tells as many from {level_slide:.2f} (slide); per s by level: "
        + ", ".join(
            f"{lv:g}: {c:.2f}" for lv, c in zip(LEVELS, slide_rate, strict=True) if 3 <= lv <= 7
        )
    )
    levels = {"strict": strict, "today": level_today}
    header = (
        "| set | contacts | scored updates | SNR median | found today |"
        " told: clean strict / today |"
        " raw today | gated (clean) |"
        " missing any 2: clean strict / today / raw today / gated |"
        " missing last 3: clean strict / today / raw today / gated |"
        " missing with today's found: any 2 / last 3 |"
        + (" decoder missing |" if args.decoder else "")
    )
    print(
        f"Oracle by set (levels: strict {strict:.2f}, today {level_today:.2f}, gated"
        f" {gate_level:.2f} after two told); missing = scored updates from the 3rd contact"
        " with no two told contacts"
    )
    print(header)
    print("|---" * (header.count("|") - 1) + "|")
    groups, order = _by_set(rows)
    for key in order:
        rs = groups[key]
        snr = np.concatenate([r["snr"] for r in rs])
        found = np.concatenate([r["found"] for r in rs])
        variants = [
            ("clean", levels["strict"], None),
            ("clean", levels["today"], None),
            ("raw", levels["today"], None),
            ("clean", levels["today"], gate_level),
        ]
        told_share, miss_any, miss_last = [], [], []
        scored = sum(len(r["t_upd"]) for r in rs)
        for k, lv, gl in variants:
            masks = [told_mask(r, lv, gl, k) for r in rs]
            told_share.append(np.mean(np.concatenate(masks)))
            miss_any.append(sum(missing(r, m, None) for r, m in zip(rs, masks, strict=True)))
            miss_last.append(sum(missing(r, m, 3) for r, m in zip(rs, masks, strict=True)))
        now_any = sum(missing(r, r["found"], None) for r in rs)
        now_last = sum(missing(r, r["found"], 3) for r in rs)
        cells = [
            key,
            str(len(snr)),
            str(scored),
            f"{np.median(snr):.1f}",
            f"{found.mean():.0%}",
            f"{told_share[0]:.0%} / {told_share[1]:.0%}",
            f"{told_share[2]:.0%}",
            f"{told_share[3]:.0%}",
            " / ".join(f"{m / scored:.1%}" for m in miss_any),
            " / ".join(f"{m / scored:.1%}" for m in miss_last),
            f"{now_any / scored:.1%} / {now_last / scored:.1%}",
        ]
        if args.decoder:
            cells.append(f"{sum(r['decoder_missing'] for r in rs) / scored:.1%}")
        print("| " + " | ".join(cells) + " |")
    if args.decoder:
        print(
            "The decoder's answers where a tracker knowing the ridges would give a speed from"
            " today's found contacts (any 2) and where it could not (share of the scored"
            " updates; " + " / ".join(STATES) + "):"
        )
        for key in order:
            rs = groups[key]
            scored = sum(len(r["t_upd"]) for r in rs)
            cells = [key]
            for able in (True, False):
                counts = np.zeros(len(STATES))
                for r in rs:
                    ok = _possible(r, r["found"], None) == able
                    counts += np.bincount(r["decoder_state"][ok], minlength=len(STATES))
                cells.append(" / ".join(f"{c / scored:.1%}" for c in counts))
            print("| " + " | ".join(cells) + " |")
    total = sum(len(r["t_upd"]) for r in rows)
    for label, last in (("any 2", None), ("last 3", 3)):
        cells = []
        for lv in LEVELS:
            if 3.0 <= lv <= 6.0:
                miss = sum(missing(r, told_mask(r, float(lv), None, "clean"), last) for r in rows)
                cells.append(f"{lv:g}: {miss / total:.1%}")
        print(f"Missing ({label}, clean, no gate) by level, all cases: " + ", ".join(cells))


if __name__ == "__main__":
    raise SystemExit(main())

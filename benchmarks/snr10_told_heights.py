"""Do the told contacts' own heights follow the spacing before their ridge? (issue 22)

Session 30's bound (`evaluation.height_evidence`) weighed an oracle's least-squares height
of each told pulse against 1 - exp(-spacing before / 10 mm). The decoder has cheaper
heights: the contact's slope jump (`ContactEvent.z`, noise units, and `jump_n_s`) at once,
and the pulse's height above its base (`PulseCheck.height_snr`) when it is told a pulse,
later. On slip_reporting's snr10 cases (full plan, `--seeds`), per found true crossing
(the nearest contact within `contact_truth.MATCH_S`): each measure over its case's median
against the spacing factor f; printed: Spearman rank correlation, the AUC of the measure
for f >= 0.9 against f < 0.6, the median per f band, and how late the height comes
(verdict's emit index less the contact's decision, ms).

Run: `.venv/bin/python benchmarks/snr10_told_heights.py [--seeds N] [--kinds snr10]`.
"""

from __future__ import annotations

import argparse

import numpy as np
import plan_cases

from grasplink.decoding.detector.pulse_probe import PULSE_RAMP, PULSE_SCALES_S
from grasplink.decoding.ridge_pulses import RISE_MM
from grasplink.decoding.rise_evidence import OFFSET
from grasplink.evaluation import contact_truth as ct
from grasplink.evaluation import slip_reporting as sr
from grasplink.evaluation.height_evidence import shape_factor
from grasplink.simulators.effects.skin import LEAD_IN_MM

WIDTHS = np.array([round(w * 400) for w in PULSE_SCALES_S], float)  # (the plan's 400 Hz)


def job(case: sr.Case) -> list[tuple[float, float, float, float, float, float]]:
    """(f, z, jump N/s, height_snr, speed mm/s, verdict delay ms) per found crossing,
    heights over the case's median."""
    rec = case.make()
    told = ct.detect(rec.t_s, rec.force_n, rec.fs_hz)
    truth = rec.truth
    crossings = np.asarray(truth.contact_times_s, float)
    before = [LEAD_IN_MM if s is None else s for s in ct.spacings_before_mm(truth)]
    speeds = ct.speeds_at_mm_s(truth)
    times = np.array([e.t_s for e in told.contacts])
    x = np.asarray(rec.force_n, float)
    rows = []
    for c, s, v in zip(crossings, before, speeds, strict=True):
        if not len(times):
            break
        j = int(np.argmin(np.abs(times - c)))
        if abs(times[j] - c) > ct.MATCH_S:
            continue
        ev = told.contacts[j]
        check = told.first_verdict.get(ev.id)
        h = np.nan if check is None or check.height_snr is None else check.height_snr
        delay = np.nan if check is None else 1e3 * (check.emit_index - ev.emit_index) / rec.fs_hz
        rise = RISE_MM / max(float(v), 1.0) * rec.fs_hz
        w = int(WIDTHS[np.argmin(np.abs(np.log(WIDTHS / rise)))])
        c0 = round(ev.index + OFFSET * w)
        probe = np.nan
        if c0 - 3 * w >= 0 and c0 + 3 * w <= len(x):
            cs = np.concatenate([[0.0], np.cumsum(x[c0 - 3 * w : c0 + 3 * w])])
            d = [(cs[m + w] - 2 * cs[m] + cs[m - w]) / w for m in (w, 3 * w, 5 * w)]
            probe = d[1] - PULSE_RAMP * (d[0] + d[2])
        held = float(c0 + 3 * w <= ev.emit_index)
        # the pulse's own shape at the true rise, a line under it, least squares
        n_r = max(2, round(rise))
        k = np.arange(ev.index - 2 * n_r, ev.index + 2 * n_r)
        fit = np.nan
        if k[0] >= 0 and k[-1] < len(x):
            u = np.maximum(k - ev.index, 0) / rise
            g = u * np.exp(1 - u)
            basis = np.stack([np.ones(len(k)), k - ev.index, g], axis=1)
            fit = float(np.linalg.lstsq(basis, x[k], rcond=None)[0][2])
        rows.append(
            (float(shape_factor(s)), ev.z, ev.jump_n_s, h, float(v), delay, probe, held, fit)
        )
    if not rows:
        return []
    a = np.array(rows)
    for col in (1, 2, 3, 6, 8):
        med = np.nanmedian(a[:, col])
        if np.isfinite(med) and med > 0:
            a[:, col] /= med
    return [tuple(r) for r in a.tolist()]


def auc(pos: np.ndarray, neg: np.ndarray) -> float:
    pos, neg = pos[np.isfinite(pos)], neg[np.isfinite(neg)]
    if not len(pos) or not len(neg):
        return float("nan")
    return float(np.mean(pos[:, None] > neg[None, :]) + 0.5 * np.mean(pos[:, None] == neg[None, :]))


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    ok = np.isfinite(x) & np.isfinite(y)
    rx = np.argsort(np.argsort(x[ok]))
    ry = np.argsort(np.argsort(y[ok]))
    return float(np.corrcoef(rx, ry)[0, 1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--kinds", default="snr10")
    args = parser.parse_args(argv)
    todo = plan_cases.full_plan_cases(parser, args.kinds, args.seeds)
    rows = [r for case in todo for r in job(case)]
    if not rows:
        parser.error(f"no told contact found a true crossing in {args.kinds}")
    a = np.array(rows)
    f = a[:, 0]
    print(f"{len(a)} found crossings ({args.kinds}, full plan, {args.seeds} seed(s))")
    print("| measure | Spearman vs f | AUC f>=0.9 vs f<0.6 | median f<0.6 | 0.6-0.9 | >=0.9 |")
    print("|---|---:|---:|---:|---:|---:|")
    bands = (f < 0.6, (f >= 0.6) & (f < 0.9), f >= 0.9)
    for name, col in (
        ("z (slope jump)", 1),
        ("jump N/s", 2),
        ("height_snr", 3),
        ("probe z, true rise", 6),
        ("shape fit, true rise", 8),
    ):
        m = a[:, col]
        meds = " | ".join(f"{np.nanmedian(m[b]):.2f}" if b.any() else "-" for b in bands)
        print(f"| {name} | {spearman(m, f):.2f} | {auc(m[f >= 0.9], m[f < 0.6]):.2f} | {meds} |")
    print(f"crossings per band: {[int(b.sum()) for b in bands]}")
    d = a[:, 5]
    print(
        f"height verdict after the decision: median {np.nanmedian(d):.0f} ms, p90 "
        f"{np.nanpercentile(d, 90):.0f} ms; height known for {np.mean(np.isfinite(a[:, 3])):.0%}"
    )
    print(f"probe window held by the decision: {np.mean(a[:, 7]):.0%}")
    for name, col in (("probe z", 6), ("shape fit", 8)):
        ok = np.isfinite(a[:, col]) & (a[:, col] > 0)
        lx, ly = np.log(f[ok]), np.log(a[ok, col])
        slope, icpt = np.polyfit(lx, ly, 1)
        resid = ly - (slope * lx + icpt)
        print(
            f"log {name} on log f: slope {slope:.2f}, residual sd {np.std(resid):.2f} "
            f"({np.mean(~ok):.0%} not positive)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

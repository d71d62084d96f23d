"""The rise-scale model the tracker weighs a contact's scale by, fitted (issue 22).

A ridge pulse rises while the edge pushes the ridge over: about a millimetre of travel
whatever the speed, so a true contact's rise lasts about travel / speed. The kink bank
tells it at one of its scales (`HingeSettings.scales_s`, distinct in samples at the rate:
at 100 Hz the 5 ms scale is the 10 ms one). `grasplink.decoding.rise_travel` models that:
ln scale ~ Normal(mu + slope x ln speed, sigma) (slope -1: the same travel at every
speed), each scale the bin of ln scale between the geometric means of its neighbours,
the finest taking every shorter rise, plus a share found at any scale alike. A false
contact's scale has nothing to do with the speed: a measured share per scale.

For slip_reporting's cases (`--seeds N`: the full plan's first N) this script matches
each contact the shipped detector tells (3 samples at a time; the step probe's excluded:
the tracker does not weigh them) to the truth's ridge crossings
(`contact_truth.near_truth`), fits (mu, slope, sigma, any-scale share) by maximum
likelihood over the true ones while the object moves, counts the false ones' scales
while it moves, and prints the constants to ship (`rise_travel.MU_LN_S`, `SLOPE`,
`SIGMA_LN`, `ANY_SCALE`, `FALSE_SHARE`) and the true contacts per scale and speed band,
observed beside modelled.

Run: `.venv/bin/python benchmarks/contact_scale_model.py --seeds 2` (about 2 minutes).
"""

from __future__ import annotations

import argparse
import itertools
import json
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from grasplink.decoding import rise_travel
from grasplink.decoding.contacts import STEP_IDS
from grasplink.decoding.detector.hinges import DEFAULT_SCALES_S
from grasplink.evaluation import slip_reporting as sr
from grasplink.evaluation.contact_truth import detect, near_truth

MOVING_MM_S = 3.0  # slower than this the edge is at rest (or braking to it at a run's end)
SPEED_BANDS_MM_S = (3.0, 10.0, 20.0, 40.0, 80.0, 1e9)


def job(case: sr.Case) -> list[tuple[str, float, bool, float, float]]:
    """Per kink-bank contact told: (kind, fs_hz, true?, scale_s, |speed| at it)."""
    rec = case.make()
    truth = rec.truth
    told = detect(rec.t_s, rec.force_n, rec.fs_hz)
    kinks = [e for e in told.contacts if e.id < STEP_IDS]
    near = near_truth(np.array([e.t_s for e in kinks]), truth.contact_times_s)
    out = []
    for event, is_near in zip(kinks, near.tolist(), strict=True):
        speed = abs(float(np.interp(event.t_s, truth.t_s, truth.speed_mm_s)))
        out.append((case.kind, rec.fs_hz, bool(is_near), event.scale_s, speed))
    return out


def scale_index(scale_s: float) -> int:
    """The contact's scale among `DEFAULT_SCALES_S` (nearest in log)."""
    return int(np.argmin(np.abs(np.log(np.array(DEFAULT_SCALES_S) / scale_s))))


def fit(rows: list[tuple[str, float, bool, float, float]]) -> tuple[float, float, float, float]:
    """(mu, slope, sigma, any-scale share) maximising the true moving contacts' likelihood."""
    true = [r for r in rows if r[2] and r[4] >= MOVING_MM_S]
    fs = np.array([r[1] for r in true])
    scale = np.array([r[3] for r in true])
    speed = np.array([r[4] for r in true])

    def cost(params: np.ndarray) -> float:
        mu, slope, sigma = float(params[0]), float(params[1]), float(np.exp(params[2]))
        share = float(1.0 / (1.0 + np.exp(-params[3])))
        like = rise_travel.true_probability(scale, speed, 0.0, fs, mu, slope, sigma, share)
        return -float(np.sum(np.log(np.maximum(like, 1e-12))))

    start = np.array([np.log(0.5), -1.0, np.log(0.7), -4.0])  # 0.5 mm of travel, 2 %
    best = minimize(cost, start, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-3})
    x = best.x
    return float(x[0]), float(x[1]), float(np.exp(x[2])), float(1.0 / (1.0 + np.exp(-x[3])))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--kinds", default=",".join(sr.KINDS))
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rows", type=Path, help="read (or write, if absent) the contacts")
    args = parser.parse_args(argv)
    kinds = args.kinds.split(",")
    unknown = sorted(set(kinds) - set(sr.KINDS))
    if unknown:
        parser.error(f"unknown kinds {unknown}; known: {', '.join(sr.KINDS)}")
    if args.rows and args.rows.exists():
        rows = [tuple(r) for r in json.loads(args.rows.read_text())]
    else:
        todo = [c for c in sr.cases(replace(sr.FULL, seeds=args.seeds)) if c.kind in kinds]
        rows = []
        with ProcessPoolExecutor(args.workers) as pool:
            for got in pool.map(job, todo, chunksize=4):
                rows += got
        if args.rows:
            args.rows.write_text(json.dumps(rows))
    mu, slope, sigma, any_share = fit(rows)  # type: ignore[arg-type]
    print(f"{len(rows)} contacts; true contacts' ln scale_s ~ Normal(mu + slope ln speed, sigma):")
    print(f"  MU_LN_S = {mu:.3f}, SLOPE = {slope:.3f}, SIGMA_LN = {sigma:.3f}")
    print(f"  ANY_SCALE = {any_share:.4f} (the share found at any scale alike)")
    for v in (10.0, 30.0, 100.0):
        print(f"  at {v:g} mm/s: median scale {np.exp(mu + slope * np.log(v)) * 1e3:.1f} ms")
    moving = [r for r in rows if r[4] >= MOVING_MM_S]
    false = np.bincount(
        [scale_index(r[3]) for r in moving if not r[2]], minlength=len(DEFAULT_SCALES_S)
    )
    false_share = false / max(1, false.sum())
    print("false moving contacts by scale:", " ".join(f"{s:.4f}" for s in false_share))
    print("\ntrue contacts by scale and speed band: observed / modelled")
    print("| speed mm/s | " + " | ".join(f"{s * 1e3:g} ms" for s in DEFAULT_SCALES_S) + " |")
    print("|---|" + "---:|" * len(DEFAULT_SCALES_S))
    for lo, hi in itertools.pairwise(SPEED_BANDS_MM_S):
        band = [r for r in moving if r[2] and lo <= r[4] < hi]
        seen = np.bincount([scale_index(r[3]) for r in band], minlength=len(DEFAULT_SCALES_S))
        model = np.zeros(len(DEFAULT_SCALES_S))
        for r in band:
            for s in rise_travel.bank_scales(r[1])[0]:
                k = scale_index(s)
                model[k] += rise_travel.true_probability(
                    np.array([s]),
                    np.array([r[4]]),
                    0.0,
                    np.array([r[1]]),
                    mu,
                    slope,
                    sigma,
                    any_share,
                )[0]
        cells = " | ".join(f"{a} / {b:.0f}" for a, b in zip(seen, model, strict=True))
        print(f"| {lo:g}-{hi:g} | {cells} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""How long a contact's rise lasts, read as edge travel: a ridge's or not (issue 22).

The kink bank tells each contact with the scale (s) of the hinge channel that found it.
A ridge pulse rises while the edge pushes the ridge over (about a millimetre of travel,
whatever the speed), so scale x speed should cluster for true ridge contacts, while a
contact on something else (the level starting to rise as the object covers more of the
sensor, a grip change, noise) need not. If it does, a track's speed predicts the scale
its next contact is found at, and a contact whose scale is far from that is likelier
clutter: a likelihood the tracker does not use yet.

For slip_reporting's cases (`--kinds`, `--seeds N`: the full plan's first N), every
contact the shipped detector tells (3 samples at a time) is matched to the truth's ridge
crossings (`contact_truth.near_truth`); the table gives, per kind, the travel
(scale_s x the truth's |speed| at the contact) of true contacts and of false ones while
the object moves, as quantiles, and the false contacts told at rest.

Run: `.venv/bin/python benchmarks/contact_scales.py --kinds constant,loop,stop --seeds 1`.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from grasplink.evaluation import slip_reporting as sr
from grasplink.evaluation.contact_truth import detect, near_truth

MOVING_MM_S = 3.0  # slower than this the edge is at rest (or braking to it at a run's end)
QUANTILES = (0.1, 0.5, 0.9)


def job(case: sr.Case) -> tuple[str, list[tuple[bool, float, float, float]]]:
    """(kind, per contact told: true?, scale_s, |speed| at it, travel mm)."""
    rec = case.make()
    truth = rec.truth
    told = detect(rec.t_s, rec.force_n, rec.fs_hz)
    near = near_truth(np.array([e.t_s for e in told.contacts]), truth.contact_times_s)
    out = []
    for event, is_near in zip(told.contacts, near.tolist(), strict=True):
        speed = abs(float(np.interp(event.t_s, truth.t_s, truth.speed_mm_s)))
        out.append((is_near, event.scale_s, speed, event.scale_s * speed))
    return case.kind, out


def quantiles(values: list[float]) -> str:
    if not values:
        return "-"
    return " / ".join(f"{q:.2f}" for q in np.quantile(values, QUANTILES))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kinds", default="constant,loop,stop,stick-slip,snr10")
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    kinds = args.kinds.split(",")
    unknown = sorted(set(kinds) - set(sr.KINDS))
    if unknown:
        parser.error(f"unknown kinds {unknown}; known: {', '.join(sr.KINDS)}")
    todo = [c for c in sr.cases(replace(sr.FULL, seeds=args.seeds)) if c.kind in kinds]
    rows: dict[str, list] = defaultdict(list)
    with ProcessPoolExecutor(args.workers) as pool:
        for kind, contacts in pool.map(job, todo, chunksize=4):
            rows[kind] += contacts
    print(f"{len(todo)} cases; travel = scale_s x |speed| (mm), quantiles {QUANTILES}")
    print("| kind | true | travel true | false moving | travel false | false at rest |")
    print("|---|---:|---:|---:|---:|---:|")
    every: list = []
    for kind in [*kinds, "all"]:
        got = every if kind == "all" else rows[kind]
        if kind != "all":
            every += got
        true = [c[3] for c in got if c[0] and c[2] >= MOVING_MM_S]
        false = [c[3] for c in got if not c[0] and c[2] >= MOVING_MM_S]
        at_rest = sum(1 for c in got if not c[0] and c[2] < MOVING_MM_S)
        print(
            f"| {kind} | {len(true)} | {quantiles(true)} | {len(false)} | {quantiles(false)}"
            f" | {at_rest} |"
        )
    print("\nby scale (all kinds, moving): true / false contacts, travel median true / false")
    scales = sorted({c[1] for c in every})
    for scale in scales:
        true = [c[3] for c in every if c[0] and c[1] == scale and c[2] >= MOVING_MM_S]
        false = [c[3] for c in every if not c[0] and c[1] == scale and c[2] >= MOVING_MM_S]
        med_t = f"{np.median(true):.2f}" if true else "-"
        med_f = f"{np.median(false):.2f}" if false else "-"
        print(f"  {scale * 1e3:6.1f} ms: {len(true):5d} / {len(false):4d}   {med_t} / {med_f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

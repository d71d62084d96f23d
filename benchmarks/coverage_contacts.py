"""Contacts where the slip's rising level resumes (issue 22): the headline's first speed.

    .venv/bin/python benchmarks/coverage_contacts.py [--kinds loop,constant] [--every N]

While an object slides onto the skin, the level rises as it covers more of the sensor
(the loop kind's objects start 8 mm before it). After a ridge pulse its tail relaxes
against that rise and the FSR's play holds the level flat, until the rise takes over
again: a kink whose slope jump is no more than the rise's own slope. The headline loop's
contact at 1.496 s is one (80 ms scale, 1.6 N/s, the level rising 1.7 N/s from the
contact before), and it splits the true 1.199 -> 1.680 s interval 19 : 12, alpha0.1's
first spacings: three ridges at 65 mm/s. This script tells, on slip_reporting's full plan
cases of each kind (every Nth case), the kink-bank contacts after a run's first one,
true (within `contact_truth.MATCH_S` of a ridge crossing) or false while the object moves,
by their slope jump over the level's rise from the contact before (the mean of the
LEVEL_S ahead of each onset, base to base): the share at or under each ratio.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np

from grasplink.decoding.contacts import STEP_IDS
from grasplink.evaluation import slip_reporting as sr
from grasplink.evaluation.contact_truth import detect, near_truth

LEVEL_S = 0.02  # the level ahead of an onset: the mean of the samples this long before it
RATIOS = (0.5, 1.0, 1.5, 2.0, 3.0)


def ratios(case: sr.Case) -> dict[str, list[float]]:
    """Per class (true, false moving), each contact's slope jump over the level's rise."""
    rec = case.make()
    told = detect(rec.t_s, rec.force_n, rec.fs_hz)
    kinks = sorted((e for e in told.contacts if e.id < STEP_IDS), key=lambda e: e.t_s)
    out: dict[str, list[float]] = defaultdict(list)
    if len(kinks) < 2:
        return out
    near = near_truth(np.array([e.t_s for e in kinks]), sr.ridge_crossings_s(rec.truth))
    n = max(1, round(LEVEL_S * rec.fs_hz))
    x = rec.force_n
    for before, ev, true in zip(kinks, kinks[1:], near[1:], strict=False):
        span = ev.t_s - before.t_s
        if span <= LEVEL_S:
            continue
        level = float(np.mean(x[max(0, ev.index - n) : ev.index]))
        earlier = float(np.mean(x[max(0, before.index - n) : before.index]))
        rise = (level - earlier) / span
        moving = abs(float(np.interp(ev.t_s, rec.truth.t_s, rec.truth.speed_mm_s))) > 0
        if true or moving:
            out["true" if true else "false, moving"].append(
                ev.jump_n_s / rise if rise > 0 else float("inf")
            )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", default="loop,constant")
    parser.add_argument("--every", type=int, default=1, help="every Nth case of a kind")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    print(f"slope jump over the level's rise since the contact before (every {args.every}th case)")
    print(f"{'kind':10} {'contacts':18} {'n':>5}  " + "  ".join(f"<={r:<4g}" for r in RATIOS))
    for kind in args.kinds.split(","):
        cases = [c for c in sr.cases(sr.FULL) if c.kind == kind][:: args.every]
        pooled: dict[str, list[float]] = defaultdict(list)
        with ProcessPoolExecutor(args.workers) as pool:
            for found in pool.map(ratios, cases):
                for key, values in found.items():
                    pooled[key] += values
        for key in ("true", "false, moving"):
            a = np.array(pooled[key])
            shares = "  ".join(f"{np.mean(a <= r) * 100:5.1f}%" for r in RATIOS) if len(a) else ""
            print(f"{kind:10} {key:18} {len(a):5d}  {shares}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The full plan's cases where the arrival flag (`decoding.arrival_flag`) moved a stop's
clearing or a flag at rest: each such case, its stops' delays and its at-rest flags with
the flag and without (`--try` the other setting, default ARRIVAL_FLAG_P=0).

Why: `tune_tracker_kinds.py` tells a kind's stops cleared and flagged at rest moved; this
names the cases to trace (`plan_cases`-like, one line each).

Run: `.venv/bin/python benchmarks/arrival_flag_cases.py --kinds stick-slip,rates-drops
--seeds 2`.
"""

from __future__ import annotations

import argparse
import math
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import tune_tracker

from grasplink.evaluation import slip_reporting as sr


def _stops(score: sr.CaseScore) -> list[str]:
    return [
        f"{st.start_s:.2f}:{'inf' if math.isinf(st.delay_s) else f'{st.delay_s:.2f}'}"
        for st in score.stops
        if st.judged
    ]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", required=True, help="comma-separated kinds")
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--try", dest="other", default="ARRIVAL_FLAG_P=0", type=tune_tracker.parse)
    args = parser.parse_args(argv)
    chosen = args.kinds.split(",")
    unknown = set(chosen) - set(sr.KINDS)
    if unknown:
        parser.error(f"unknown kinds {sorted(unknown)}; known: {', '.join(sr.KINDS)}")
    plan = replace(sr.FULL, seeds=args.seeds)
    plan = replace(plan, variants={k: v for k, v in plan.variants.items() if k in chosen})
    todo = sr.cases(plan)
    configs = {"this": tune_tracker.config({}), "other": tune_tracker.config(args.other)}
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(tune_tracker.job, todo, [configs] * len(todo), chunksize=2))
    print(f"{len(todo)} cases; this (defaults) against {args.other}")
    for case, scores in zip(todo, results, strict=True):
        a, b = scores["this"], scores["other"]
        if _stops(a) == _stops(b) and a.rest_flagged == b.rest_flagged:
            continue
        print(
            f"{case.kind:12s} {case.variant:24s} {case.layout:10s} "
            f"{'r' if case.reverse else 'f'} seed {case.seed}: stops {_stops(a)} vs "
            f"{_stops(b)}; flagged at rest {a.rest_flagged} vs {b.rest_flagged}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())

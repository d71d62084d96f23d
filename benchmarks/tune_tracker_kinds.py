"""Tracker settings side by side, kind by kind: `tune_tracker`'s run, one line per kind.

`tune_tracker.py` pools the moving kinds; a change aimed at one kind (decelerating
slips, stops) needs that kind's own line, beside what it costs the others, from the
same run. `--kinds a,b` runs only those kinds; `--seeds N` the plan's first N seeds.

Run: `.venv/bin/python benchmarks/tune_tracker_kinds.py --full --try NAME=VALUE`.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plan_cases
import tune_tracker

from grasplink.evaluation import slip_reporting as sr

COLUMNS = (
    ("missing_from3_pct", "miss%"),
    ("speed_err_median_pct", "med%"),
    ("speed_err_p90_pct", "p90%"),
    ("first_good_by_third_pct", "by3rd%"),
    ("wrong_direction_pct", "wdir%"),
    ("stops_cleared_pct", "stops%"),
    ("speed_after_observable_pct", "aobs%"),
    ("flagged_at_rest_pct", "frest%"),
    ("speed_at_rest_pct", "vrest%"),
    ("dropped_from2_pct", "drop%"),
    ("chatter_per_min", "chat/m"),
    ("cpu_us_per_sample", "us"),
)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--try", dest="tries", action="append", default=[], type=tune_tracker.parse)
    parser.add_argument("--full", action="store_true", help="the full plan's cases")
    parser.add_argument("--kinds", default="", help="comma-separated kinds (default: all)")
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument(
        "--first-seed", type=int, default=0, help="0-2: tuned; 3 and up: held out (validate)"
    )
    args = parser.parse_args(argv)
    plan = replace(sr.FULL if args.full else sr.QUICK, seeds=args.seeds, first_seed=args.first_seed)
    if args.kinds:
        chosen = args.kinds.split(",")
        unknown = set(chosen) - set(sr.KINDS)
        if unknown:
            parser.error(f"unknown kinds {sorted(unknown)}; known: {', '.join(sr.KINDS)}")
        plan = replace(plan, variants={k: v for k, v in plan.variants.items() if k in chosen})
    todo = plan_cases.plan_cases_or_exit(parser, plan)
    tunings = [{}, *args.tries]
    configs = {str(k): tune_tracker.config(t) for k, t in enumerate(tunings)}
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(tune_tracker.job, todo, [configs] * len(todo), chunksize=2))
    print(f"{len(todo)} cases ({plan.name} plan, {args.seeds} seed(s))")
    print("kind / setting".ljust(36) + "".join(f"{label:>8s}" for _, label in COLUMNS))
    groups = [((k,), k) for k in sr.KINDS] + [(sr.MOVING, "MOVING"), (sr.HELD, "HELD")]
    for kinds, title in groups:
        for k, tuning in enumerate(tunings):
            scores = [r[str(k)] for r in results if r[str(k)].kind in kinds]
            if not scores:
                continue
            fig = sr.summarise(scores)
            name = ",".join(f"{a}={b}" for a, b in tuning.items()) or "shipped"
            cells = "".join(
                f"{fig[key]:8.1f}" if fig.get(key) is not None else f"{'-':>8s}"
                for key, _ in COLUMNS
            )
            print(f"{(title + ' ' + name)[:36]:36s}{cells}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Which cases give a speed after a stop's report was due, per setting, in one run.

`slip_reporting.score` counts, per stop, the updates later than its observable moment
plus `CLEAR_WITHIN_S` (the stop's report due) and before its end, and those of them
carrying a speed above 0 (*speed after due*: target 0). This lists every case of the
chosen kinds where any setting gives such a speed: the count under the shipped settings
and under each `--try`, so a change aimed at those cases shows what it clears and what it
brings, case by case, beside the pooled share.

`--kinds` (default: every moving kind), `--seeds N` (the full plan's first N, default 3),
`--try NAME=VALUE[,...]` (repeatable) as in `tune_tracker_kinds.py`, `--cases SEED,...`
only those cases (a setting that only withholds speeds, `TrackerDecoder.OVERDUE_SPEED`,
brings none to a case the shipped settings keep clear, so the cases these list say all
of it; the pooled share is then of those cases' updates).

Run: `.venv/bin/python benchmarks/after_due_cases.py --seeds 3 --try NAME=VALUE`.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plan_cases
import tune_tracker

from grasplink.evaluation import slip_reporting as sr


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", default=",".join(sr.MOVING), help="comma-separated kinds")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--try", dest="tries", action="append", default=[], type=tune_tracker.parse)
    parser.add_argument("--cases", default=None, help="only these case seeds (comma-separated)")
    args = parser.parse_args(argv)
    todo = plan_cases.full_plan_cases(parser, args.kinds, args.seeds, args.cases)
    tunings = [{}, *args.tries]
    names = [",".join(f"{a}={b}" for a, b in t.items()) or "shipped" for t in tunings]
    configs = {str(k): tune_tracker.config(t) for k, t in enumerate(tunings)}
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(tune_tracker.job, todo, [configs] * len(todo), chunksize=2))
    print(f"{len(todo)} cases (full plan, {args.seeds} seed(s)); after-due speed updates")
    print("settings: " + " | ".join(f"[{k}] {name}" for k, name in enumerate(names)))
    rows = []
    for case, scores in zip(todo, results, strict=True):
        counts = [scores[str(k)].after_observable_speed for k in range(len(tunings))]
        if any(counts):
            rows.append((case, [" ".join(f"[{k}] {n:3d}" for k, n in enumerate(counts))]))
    plan_cases.print_case_lines(rows)
    for k, name in enumerate(names):
        speed = sum(r[str(k)].after_observable_speed for r in results)
        total = sum(r[str(k)].after_observable for r in results)
        share = 100.0 * speed / total if total else float("nan")
        print(f"[{k}] {name}: {speed} of {total} updates after due carry a speed ({share:.2f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

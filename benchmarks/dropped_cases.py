"""Which cases drop the slip flag while the object slides, per setting, in one run.

`slip_reporting.score` counts an update as *slip dropped* when the truth moves, from its
run's 2nd ridge contact on, and the flag is down (`CaseScore.dropped_from2`). This lists
every case of the chosen kinds whose count differs between the shipped settings and any
`--try`, with the counts side by side, so a rule that holds the flag (e.g.
`TrackerDecoder.RESTART_CONFIRM_TWO`) shows which cases it costs and which it gives back;
then the pooled counts. Why a case drops: `dropped_causes.py`.

`--kinds` (default: every moving kind), `--seeds N` (the full plan's first N, default 1),
`--try NAME=VALUE[,...]` (repeatable) as in `tune_tracker_kinds.py`, `--cases SEED,...`.

Run: `.venv/bin/python benchmarks/dropped_cases.py --kinds stick-slip,rates-drops --try NAME=VALUE`.
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
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--try", dest="tries", action="append", default=[], type=tune_tracker.parse)
    parser.add_argument("--cases", default=None, help="only these case seeds (comma-separated)")
    args = parser.parse_args(argv)
    todo = plan_cases.full_plan_cases(parser, args.kinds, args.seeds, args.cases)
    tunings = [{}, *args.tries]
    names = [",".join(f"{a}={b}" for a, b in t.items()) or "shipped" for t in tunings]
    configs = {str(k): tune_tracker.config(t) for k, t in enumerate(tunings)}
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(tune_tracker.job, todo, [configs] * len(todo), chunksize=2))
    print(f"{len(todo)} cases (full plan, {args.seeds} seed(s)); slip dropped updates")
    print("settings: " + " | ".join(f"[{k}] {name}" for k, name in enumerate(names)))
    rows = []
    for case, scores in zip(todo, results, strict=True):
        counts = [scores[str(k)].dropped_from2 for k in range(len(tunings))]
        if len(set(counts)) > 1:
            rows.append((case, [" ".join(f"[{k}] {n:3d}" for k, n in enumerate(counts))]))
    plan_cases.print_case_lines(rows)
    for k, name in enumerate(names):
        dropped = sum(r[str(k)].dropped_from2 for r in results)
        moving = sum(r[str(k)].moving_from2 for r in results)
        share = 100.0 * dropped / moving if moving else float("nan")
        print(f"[{k}] {name}: {dropped} of {moving} moving updates dropped ({share:.2f} %)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

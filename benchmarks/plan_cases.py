"""The slip-reporting full plan's cases of some kinds: what the per-case diagnostic scripts
(stop_causes.py, dropped_causes.py, rest_speed_causes.py, ...) run and print."""

from __future__ import annotations

import argparse
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import tune_tracker

from grasplink.decoding.registry import DEFAULT_DECODER
from grasplink.evaluation import slip_reporting as sr


def add_plan_arguments(
    parser: argparse.ArgumentParser, kinds: str, seeds: int, cases: bool = False
) -> None:
    """`--kinds` (default `kinds`), `--seeds` (default `seeds`), `--try` (a tuning, as in
    `tune_tracker_kinds.py`: `args.tuning`) and, with `cases`, `--cases`: the options every
    per-case diagnostic takes, read back by `full_plan_cases`."""
    parser.add_argument("--kinds", default=kinds, help="comma-separated kinds")
    parser.add_argument("--seeds", type=int, default=seeds, help="the full plan's first N")
    parser.add_argument(
        "--first-seed",
        type=int,
        default=0,
        help="from this seed index on (0-2: tuned; 3 and up: held out, `held_out_seeds.py`)",
    )
    parser.add_argument("--try", dest="tuning", default={}, type=tune_tracker.parse)
    if cases:
        parser.add_argument("--cases", default=None, help="only these case seeds (comma-separated)")


def kinds_of(
    parser: argparse.ArgumentParser, kinds_text: str, allowed: Sequence[str] = sr.KINDS
) -> list[str]:
    """The comma-separated kinds; one not `allowed` (default: every kind the plan knows)
    is a usage error naming it."""
    kinds = kinds_text.split(",")
    unknown = sorted(set(kinds) - set(allowed))
    if unknown:
        parser.error(f"unknown kinds {unknown}; known: {', '.join(allowed)}")
    return kinds


def plan_cases_or_exit(parser: argparse.ArgumentParser, plan: sr.Plan) -> list[sr.Case]:
    """`plan`'s cases (`slip_reporting.cases`), or a usage error naming the seeds it
    asks that a variant does not hold (`--seeds`, `--first-seed`), before any work."""
    try:
        return sr.cases(plan)
    except ValueError as exc:
        parser.error(str(exc))


def full_plan_cases(
    parser: argparse.ArgumentParser,
    kinds_text: str,
    seeds: int,
    only: str | None = None,
    allowed: Sequence[str] = sr.KINDS,
    first_seed: int = 0,
) -> list[sr.Case]:
    """The full plan's cases of these kinds (`kinds_of`) with `seeds` seeds from
    `first_seed` on (0-2 the tuned ones, 3 and up held out; a usage error outside the
    seeds a variant holds); `only`: the comma-separated case seeds to keep (None: all)."""
    kinds = kinds_of(parser, kinds_text, allowed)
    plan = replace(sr.FULL, seeds=seeds, first_seed=first_seed)
    todo = [c for c in plan_cases_or_exit(parser, plan) if c.kind in kinds]
    if only:
        todo = [c for c in todo if str(c.seed) in only.split(",")]
    return todo


def pct_cell(part: float, whole: float) -> str:
    """part of whole in percent with one decimal, for a table whose header carries the %;
    "-" where there is no whole."""
    return f"{100.0 * part / whole:.1f}" if whole else "-"


def run_title(
    todo: Sequence[sr.Case], seeds: int, kinds: Sequence[str], workers: int, seconds: float
) -> str:
    """The line a full-plan benchmark prints above its tables: what ran, how long, with
    which decoder."""
    return (
        f"{len(todo)} cases (full plan, {seeds} seed(s), kinds {', '.join(kinds)}) in"
        f" {seconds:.0f} s on {workers} worker(s); decoder {DEFAULT_DECODER}"
    )


def print_case_lines(results: Iterable[tuple[sr.Case, Sequence[str]]]) -> None:
    """Each case's lines, after the case (kind, layout, variant, way, seed)."""
    for case, lines in results:
        for line in lines:
            way = "r" if case.reverse else "f"
            print(f"{case.kind:11s} {case.layout:9s} {case.variant:26s} {way} {case.seed:6d}", line)


def compare_settings(
    doc: str,
    default_seeds: int,
    what: str,
    part: Callable[[sr.CaseScore], int],
    whole: Callable[[sr.CaseScore], int],
    phrase: str,
    shown: Callable[[list[int]], bool],
    argv: list[str] | None = None,
) -> None:
    """The shipped settings and each `--try` on the chosen cases (`--kinds`, default every
    moving kind; `--seeds`; `--cases`), in one run on 2 workers: prints `what` ran, each
    case whose settings' `part` counts (of its score) are `shown`, and per setting `part`
    pooled "of" `whole` with the share, e.g. "12 of 40 `phrase` (30.00 %)"."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--kinds", default=",".join(sr.MOVING), help="comma-separated kinds")
    parser.add_argument("--seeds", type=int, default=default_seeds)
    parser.add_argument("--first-seed", type=int, default=0, help="3 and up: held out")
    parser.add_argument("--try", dest="tries", action="append", default=[], type=tune_tracker.parse)
    parser.add_argument("--cases", default=None, help="only these case seeds (comma-separated)")
    args = parser.parse_args(argv)
    todo = full_plan_cases(parser, args.kinds, args.seeds, args.cases, first_seed=args.first_seed)
    tunings = [{}, *args.tries]
    names = [",".join(f"{a}={b}" for a, b in t.items()) or "shipped" for t in tunings]
    configs = {str(k): tune_tracker.config(t) for k, t in enumerate(tunings)}
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(tune_tracker.job, todo, [configs] * len(todo), chunksize=2))
    print(f"{len(todo)} cases (full plan, {args.seeds} seed(s)); {what}")
    print("settings: " + " | ".join(f"[{k}] {name}" for k, name in enumerate(names)))
    rows = []
    for case, scores in zip(todo, results, strict=True):
        each = [part(scores[str(k)]) for k in range(len(tunings))]
        if shown(each):
            rows.append((case, [" ".join(f"[{k}] {n:3d}" for k, n in enumerate(each))]))
    print_case_lines(rows)
    for k, name in enumerate(names):
        counted = sum(part(r[str(k)]) for r in results)
        total = sum(whole(r[str(k)]) for r in results)
        share = 100.0 * counted / total if total else float("nan")
        print(f"[{k}] {name}: {counted} of {total} {phrase} ({share:.2f} %)")

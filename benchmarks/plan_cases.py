"""The slip-reporting full plan's cases of some kinds: what the per-case diagnostic scripts
(stop_causes.py, dropped_causes.py, rest_speed_causes.py, ...) run and print."""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Sequence
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


def full_plan_cases(
    parser: argparse.ArgumentParser,
    kinds_text: str,
    seeds: int,
    only: str | None = None,
    allowed: Sequence[str] = sr.KINDS,
) -> list[sr.Case]:
    """The full plan's cases of these kinds (`kinds_of`) with its first `seeds` seeds (a
    usage error outside 1 to the plan's); `only`: the comma-separated case seeds to keep
    (None: all)."""
    if not 1 <= seeds <= sr.FULL.seeds:
        parser.error(f"--seeds must be 1-{sr.FULL.seeds}, got {seeds}")
    kinds = kinds_of(parser, kinds_text, allowed)
    todo = [c for c in sr.cases(replace(sr.FULL, seeds=seeds)) if c.kind in kinds]
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

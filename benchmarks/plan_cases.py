"""The slip-reporting full plan's cases of some kinds: what the per-case diagnostic scripts
(stop_causes.py, dropped_causes.py, rest_speed_causes.py, ...) run and print."""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Sequence
from dataclasses import replace

from grasplink.evaluation import slip_reporting as sr


def kinds_of(parser: argparse.ArgumentParser, kinds_text: str) -> list[str]:
    """The comma-separated kinds; one the plan does not know is a usage error naming it."""
    kinds = kinds_text.split(",")
    unknown = sorted(set(kinds) - set(sr.KINDS))
    if unknown:
        parser.error(f"unknown kinds {unknown}; known: {', '.join(sr.KINDS)}")
    return kinds


def full_plan_cases(
    parser: argparse.ArgumentParser, kinds_text: str, seeds: int, only: str | None = None
) -> list[sr.Case]:
    """The full plan's cases of these kinds with its first `seeds` seeds; `only`: the
    comma-separated case seeds to keep (None: all)."""
    kinds = kinds_of(parser, kinds_text)
    todo = [c for c in sr.cases(replace(sr.FULL, seeds=seeds)) if c.kind in kinds]
    if only:
        todo = [c for c in todo if str(c.seed) in only.split(",")]
    return todo


def print_case_lines(results: Iterable[tuple[sr.Case, Sequence[str]]]) -> None:
    """Each case's lines, after the case (kind, layout, variant, way, seed)."""
    for case, lines in results:
        for line in lines:
            way = "r" if case.reverse else "f"
            print(f"{case.kind:11s} {case.layout:9s} {case.variant:26s} {way} {case.seed:6d}", line)

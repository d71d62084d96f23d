"""The case-by-case cause scripts (benchmarks/) decode a case as the benchmark does.

Their tables explain the benchmark's figures, so a loop case must be decoded with the
grip commands its gateway would have sent (`slip_reporting.tell_grip_commands`): told,
164101 drops the flag in 69 of its 91 scored updates, untold in 32.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from grasplink.evaluation import slip_reporting as sr

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
LOOP_SEED = 164101  # alpha0.9 at 20 mm/s: the commands change its dropped count


@pytest.fixture
def dropped_causes(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import dropped_causes

    return dropped_causes


def _loop_case() -> sr.Case:
    (case,) = [c for c in sr.cases(replace(sr.FULL, seeds=1)) if c.seed == LOOP_SEED]
    assert case.kind == "loop"
    return case


def test_dropped_causes_counts_a_loop_case_as_the_benchmark_scores_it(dropped_causes):
    case = _loop_case()
    scores = sr.case_job(case, "tracker", {"told": {}, "untold": {"grip_commands": False}}, False)[
        "scores"
    ]
    assert scores["told"].dropped_from2 != scores["untold"].dropped_from2  # the case matters
    _, dropped, _, scored = dropped_causes.job(case, {})
    assert (len(dropped), scored) == (scores["told"].dropped_from2, scores["told"].moving_from2)

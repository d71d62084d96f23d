"""The case-by-case cause scripts (benchmarks/) decode a case as the benchmark does.

Their tables explain the benchmark's figures, so a loop case must be decoded with the
grip commands its gateway would have sent (`slip_reporting.tell_grip_commands`): told,
164101 drops the flag in 69 of its 91 scored updates, untold in 32. Each script reaches
into the tracker's internals (a subclass noting why at every update), which a change to
the tracker can break without a figure moving (s31: `dropped_causes` raised a TypeError
for a session): each runs here on one case and counts what the benchmark counts.
"""

from __future__ import annotations

import importlib
import math
from pathlib import Path

import pytest

from grasplink.evaluation import slip_reporting as sr
from tests.decoding.plan_cases import plan_case

BENCHMARKS = Path(__file__).resolve().parents[2] / "benchmarks"
LOOP_SEED = 164101  # alpha0.9 at 20 mm/s: the commands change its dropped count


@pytest.fixture
def scripts(monkeypatch):
    """Import a benchmark script by name."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    return importlib.import_module


@pytest.fixture
def dropped_causes(scripts):
    return scripts("dropped_causes")


def _loop_case() -> sr.Case:
    return plan_case("loop", LOOP_SEED)


def _score(case: sr.Case) -> sr.CaseScore:
    return sr.case_job(case, "tracker", {"shipped": {}}, False)["scores"]["shipped"]


def test_dropped_causes_counts_a_loop_case_as_the_benchmark_scores_it(dropped_causes):
    case = _loop_case()
    scores = sr.case_job(case, "tracker", {"told": {}, "untold": {"grip_commands": False}}, False)[
        "scores"
    ]
    assert scores["told"].dropped_from2 != scores["untold"].dropped_from2  # the case matters
    _, dropped, _, scored = dropped_causes.job(case, {})
    assert (len(dropped), scored) == (scores["told"].dropped_from2, scores["told"].moving_from2)


def test_missing_speed_causes_names_a_cause_for_every_update_without_a_speed(scripts):
    case = plan_case("snr10", 110001)  # 37 of 84 updates from the 3rd contact without a speed
    scored = _score(case)
    _, rows = scripts("missing_speed_causes").job(case, {})
    from3 = [cause for third, cause, _ in rows if third]
    assert len(from3) == scored.moving_from3
    assert sum(1 for cause in from3 if cause) == scored.missing_from3 > 0


def test_rest_speed_causes_names_the_track_of_every_speed_at_rest(scripts):
    case = plan_case("snr10", 112000)  # 19 updates at rest carry a speed
    scored = _score(case)
    _, rows = scripts("rest_speed_causes").job(case, {})
    assert len(rows) == scored.rest_speed > 0
    assert all(where != "?" for _, where, _ in rows)  # each speed's track was found


def test_stop_causes_judges_the_stops_the_benchmark_judges(scripts):
    case = plan_case("stop", 92000)
    scored = _score(case)
    _, rows = scripts("stop_causes").job(case, {})
    judged = [s for s in scored.stops if s.judged and s.observable_s is not None]
    assert [delay for delay, *_ in rows] == [s.delay_s for s in judged] and rows
    assert all((cause != "") == (delay > sr.CLEAR_WITHIN_S) for delay, cause, *_ in rows)


def test_two_contact_hypotheses_shares_are_a_posterior_between_the_3rd_and_4th(scripts):
    case = plan_case("constant", 55001)  # 100 such updates, a speed given in 37
    rows = scripts("two_contact_hypotheses").job(case, {})
    assert 0 < sum(given for _, _, given, _, _ in rows) < len(rows)
    for _, v_true, _, mine, ideal in rows:
        assert v_true >= sr.V_MOVING_MM_S
        assert sum(mine.values()) <= 1.0 + 1e-9
        assert math.isclose(sum(ideal.values()), 1.0)

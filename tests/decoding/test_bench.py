"""The default decoder comes from the benchmark, and the benchmark's scoring is sound."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from grasplink.decoding.registry import DEFAULT_DECODER, make_decoder
from grasplink.evaluation import scoring as ev
from grasplink.evaluation.decoding_bench import BUDGET_UNDER_MMSE, COST_BUDGET_US, recommend
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators.synth import slip_recording

RESULTS = Path(__file__).resolve().parents[2] / "docs" / "benchmarks" / "decoding.json"


def test_registry_default_is_the_benchmarks_recommendation():
    results = json.loads(RESULTS.read_text())
    assert not results["quick"], "docs hold a quick run; run `grasplink bench decode`"
    assert results["recommended_default"] == DEFAULT_DECODER


def _entry(p90: float, pos: float, cost: float) -> dict:
    return {"target": {"speed_p90_pct": p90, "position_p90_mm": pos, "cpu_us_per_sample": cost}}


def test_recommendation_is_the_most_accurate_decoder_within_the_cost_budget():
    decoders = {
        "cheap": _entry(9.0, 3.0, 5.0),
        "best": _entry(1.0, 0.5, COST_BUDGET_US - 1),
        "expensive": _entry(0.1, 0.1, COST_BUDGET_US * 10),
    }
    assert recommend(decoders) == "best"


def test_recommendation_judges_cost_against_the_mmse_of_the_same_run():
    """A loaded host slows every decoder alike: the pick must not move with it. With the
    faithful MMSE in the run, the budget is a share of its cost, not 50 µs."""

    def run(slowdown: float) -> dict:
        mmse = _entry(200.0, 40.0, 125.0 * slowdown) | {"decoder": "mmse"}
        return {
            "cheap": _entry(9.0, 3.0, 5.0 * slowdown),
            "best": _entry(1.0, 0.5, 40.0 * slowdown),
            "expensive": _entry(0.1, 0.1, 100.0 * slowdown),
            "mmse (window 5 s)": mmse,
        }

    for slowdown in (0.5, 1.0, 2.5):
        assert recommend(run(slowdown)) == "best", slowdown
    over = run(1.0)
    over["best"]["target"]["cpu_us_per_sample"] = 125.0 / BUDGET_UNDER_MMSE * 1.01
    assert recommend(over) == "cheap"


def test_scoring_counts_missing_estimates_and_the_physical_limit():
    rec = slip_recording(LAYOUTS_MM["alpha0.1"], 40.0, noise_scale=0.0, seed=3)
    score = ev.score(lambda: make_decoder("ratio", rec.layout_mm, rec.fs_hz), rec)
    contacts = rec.contact_times_s
    onset = rec.t_s[np.argmax(rec.slipping > 0.5)]
    assert score.physical_limit_s == contacts[2] - onset
    assert score.scored > 0 and 0 <= score.missing <= score.scored
    assert len(score.speed_rel_err) == score.scored - score.missing


def test_the_decoding_page_shows_the_slip_reporting_trade_off_curves(tmp_path: Path):
    """Issue 22 asks for the trade-off curves in decoding.md: the page takes them from the
    slip-reporting run in the same folder (its json and plots), says which run, and shows
    nothing when there is none."""
    from grasplink.evaluation import decoding_bench as db
    from grasplink.evaluation import slip_reporting as sr

    assert db.tradeoffs(tmp_path) == []
    row = {
        "missing_from3_pct": 4.0, "dropped_from2_pct": 0.5, "speed_err_p90_pct": 9.0,
        "wrong_direction_pct": 3.0, "first_good_median_intervals": 0.1,
        "first_good_by_third_pct": 80.0, "false_slip_pct": 0.0, "stops_cleared_pct": 95.0,
        "speed_after_observable_pct": 0.0, "cpu_us_per_sample": 40.0,
    }  # fmt: skip
    sweeps = {
        "LOG_REPORT_ODDS": [
            {**row, "value": 3.0, "key": "x", "shipped": False},
            {**row, "value": 9.0, "key": "shipped", "shipped": True},
        ]
    }
    saved = {
        "meta": {"date": "2026-11-28 10:00 UTC", "git": {"commit": "abc1234"}},
        "figures": {"sweeps": sweeps, "sweep_cases": 12},
    }
    (tmp_path / sr.RAW).write_text(json.dumps(saved))
    page = "\n".join(db.tradeoffs(tmp_path))
    assert "## Trade-off curves of the default decoder (issue 22)" in page
    assert "abc1234" in page and "2026-11-28 10:00 UTC" in page
    assert "![LOG_REPORT_ODDS](slip_reporting_LOG_REPORT_ODDS.png)" in page
    assert "| 9 (shipped) | 4.0 | 0.5 |" in page

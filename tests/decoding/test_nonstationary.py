"""The non-stationary benchmark: its signals are what they claim, and its scoring is sound.

The signals must really speed up, stop, reverse, saturate and lose samples;
an oracle that reports the truth must score perfectly and a decoder that
never lets go of its slip flag must fail every stop, so the figures measure
the decoders and not the benchmark.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from grasplink.decoding.base import SlipEstimate
from grasplink.evaluation import decoding_bench as bench
from grasplink.evaluation import nonstationary as ns
from grasplink.profiles.layouts import LAYOUTS_MM

QUICK = ns.signals(quick=True)


def one(category: str, layout: str = "alpha0.1", reverse: bool = False, variant: int = 0):
    label, numbers = ns.VARIANTS[category][variant]
    return ns.Signal(category, label, numbers, layout, reverse, seed=11 + variant)


def oracle(rec: ns.Recorded, period_s: float = 0.01, **override) -> list[SlipEstimate]:
    """Estimates that are the truth itself, on a decoder's 10 ms grid (`velocity_mm_s`: the
    signed speed, its sign the direction told; `direction=False`: the speed without one)."""
    tell_direction = override.pop("direction", True)
    truth = rec.truth
    grid = np.arange(0.0, truth.t_s[-1], period_s)
    v = np.interp(grid, truth.t_s, truth.speed_mm_s)
    x = truth.position_mm[ns._nearest(truth.t_s, grid)]
    out = []
    for t, speed, position in zip(grid, v, x, strict=True):
        moving = abs(speed) >= ns.V_MOVING_MM_S
        fields = {
            "t_s": float(t),
            "slip": moving,
            "velocity_mm_s": float(speed) if moving else 0.0,
            "position_mm": float(position),
            "force_n": 1.0,
            "confidence": 1.0,
        }
        fields.update({k: f(t, speed) if callable(f) else f for k, f in override.items()})
        estimate = SlipEstimate.from_velocity(**fields)
        if not tell_direction:
            estimate = dataclasses.replace(estimate, direction=None, direction_confidence=None)
        out.append(estimate)
    return out


# -- the set ---------------------------------------------------------------------------------


def test_the_full_set_covers_every_category_layout_direction_and_seed():
    full = ns.signals(quick=False)
    for category, variants in ns.VARIANTS.items():
        mine = [s for s in full if s.category == category]
        ways = 1 if category == "grip-no-slip" else 2
        assert len(mine) == len(variants) * len(ns.LAYOUTS) * ways * ns.SEEDS
    assert {s.layout for s in full} == set(ns.LAYOUTS)
    assert len({s.seed for s in full if s.layout == "alpha0.1"}) > 100  # seeds differ
    assert len(QUICK) < len(full) / 10
    assert {s.category for s in QUICK} == set(ns.CATEGORIES)
    assert {s.reverse for s in QUICK} == {False, True}


def test_signals_are_deterministic_by_seed():
    signal = one("stick-slip", "fibonacci", reverse=True)
    a, b = signal.make(), signal.make()
    assert np.array_equal(a.force_n, b.force_n) and np.array_equal(a.t_s, b.t_s)
    c = dataclasses.replace(signal, seed=signal.seed + 1).make()
    assert not np.array_equal(a.force_n[: len(c.force_n)], c.force_n[: len(a.force_n)])


@pytest.mark.parametrize("reverse", [False, True])
@pytest.mark.parametrize(
    ("category", "first", "last"), [("accelerating", 21, 98), ("decelerating", 98, 31)]
)
def test_speed_changes_from_first_to_last_ridge_within_one_pass(category, first, last, reverse):
    truth = one(category, reverse=reverse).make().truth
    contacts = truth.contact_times_s
    speed = np.abs(np.interp(contacts, truth.t_s, truth.speed_mm_s))
    assert speed[0] == pytest.approx(first, rel=0.05)
    assert speed[-1] == pytest.approx(last, rel=0.02)
    assert np.all(np.diff(speed) > 0) if last > first else np.all(np.diff(speed) < 0)


@pytest.mark.parametrize("layout", ["alpha0.1", "fibonacci", "alpha0.3", "uniform4"])
def test_stick_slip_stops_twice_on_the_skin_for_0_2_to_0_5_s(layout):
    truth = one("stick-slip", layout).make().truth
    stops = ns.motion(truth).stops
    assert len(stops) == 3  # two mid-slip, one at the end
    for start, end in stops[:2]:
        assert 0.2 <= end - start <= 0.5 + 0.01
        edge = np.interp(start, truth.t_s, truth.position_mm)
        assert 0 < edge < sum(truth.layout_mm)


@pytest.mark.parametrize("layout", ["alpha0.1", "fibonacci", "alpha0.3", "uniform4"])
@pytest.mark.parametrize("reverse", [False, True])
def test_a_reversal_makes_contacts_both_ways_with_the_short_object(layout, reverse):
    truth = one("reversal", layout, reverse).make().truth
    m = ns.motion(truth)
    assert [sign for _, _, sign in m.runs] == ([-1, 1] if reverse else [1, -1])
    turn = m.runs[1][0]
    before = truth.contact_times_s[truth.contact_times_s < turn]
    after = truth.contact_times_s[truth.contact_times_s > turn]
    assert len(before) >= (2 if layout == "alpha0.3" else 3) and len(after) >= 2
    assert m.stops == [m.stops[-1]]  # the turning point is not a stop


def test_a_partial_start_begins_with_the_object_over_the_skin_at_rest():
    truth = one("partial-start").make().truth
    skin = sum(truth.layout_mm)
    assert 0.25 * skin <= truth.position_mm[0] <= 0.6 * skin
    assert truth.speed_mm_s[0] == 0 and truth.force_n[0] > 0.5


def test_saturation_clips_part_of_the_slip_only():
    rec = one("saturation").make()
    moving = np.abs(rec.truth.speed_mm_s) > 0
    railed = rec.force_n[moving] >= ns.FULL_SCALE_N
    assert 0.1 < railed.mean() < 0.5
    assert rec.force_n.max() == ns.FULL_SCALE_N


def test_10_db_snr_is_the_pulse_height_over_the_white_noise():
    layout = LAYOUTS_MM["alpha0.1"]
    height = ns.pulse_height_n(layout)
    quiet = one("snr10").make().force_n[:100]  # at rest before the slip: noise and drift only
    assert 20 * np.log10(height / np.std(np.diff(quiet)) * np.sqrt(2)) == pytest.approx(10, abs=1.5)


@pytest.mark.parametrize("variant", range(6))
def test_rates_and_dropped_samples_keep_losses_bridgeable(variant):
    signal = one("rates-drops", variant=variant)
    rec = signal.make()
    assert rec.fs_hz == signal.numbers[0]
    lost = 1 - len(rec.t_s) / len(rec.truth.t_s)
    assert 0.01 < lost < 0.06
    steps = np.diff(rec.t_s) * rec.fs_hz
    assert steps.max() <= 8.5  # every loss is bridged, none resets a decoder
    assert np.array_equal(rec.t_s, rec.truth.t_s[np.isin(rec.truth.t_s, rec.t_s)])


def test_grip_changes_without_slip_never_move_the_object():
    for variant in range(3):
        truth = one("grip-no-slip", variant=variant).make().truth
        assert not np.any(truth.speed_mm_s) and np.ptp(truth.grip_n) > 0.9


# -- the scoring -------------------------------------------------------------------------------


@pytest.mark.parametrize("category", ["stick-slip", "reversal", "decelerating", "partial-start"])
def test_an_oracle_scores_perfectly(category):
    rec = one(category, "fibonacci").make()
    score = ns.score(oracle(rec), rec)
    assert score.scored > 20 and score.missing == 0
    assert np.max(score.speed_rel_err) < 1e-9 and np.max(score.position_err_mm) < 1e-9
    assert score.directed > 20 and score.wrong_direction == 0
    assert score.clear_s and max(score.clear_s) <= 0.01
    assert score.false_slip == 0 and score.rest_updates > 0
    assert score.confidence_total[-1] == score.directed == score.confidence_right[-1]


def test_a_flag_that_never_clears_fails_every_stop_and_every_rest():
    rec = one("stick-slip").make()
    score = ns.score(oracle(rec, slip=True), rec)
    assert len(score.clear_s) == 3 and all(np.isinf(score.clear_s))
    assert score.false_slip == score.rest_updates > 0
    figures = ns.summarise([score])
    assert figures["cleared_in_time_pct"] == 0.0 and figures["clear_p90_s"] is None


def test_the_opposite_direction_is_wrong_only_while_the_truth_moves_at_5_mm_s_or_more():
    rec = one("reversal").make()
    score = ns.score(oracle(rec, velocity_mm_s=lambda t, v: -v if v else 1.0), rec)
    truth_v = np.abs(
        np.interp(np.arange(0, rec.truth.t_s[-1], 0.01), rec.truth.t_s, rec.truth.speed_mm_s)
    )
    assert score.wrong_direction == score.directed == int((truth_v >= 5).sum())
    assert score.confidence_right.sum() == 0


def test_speed_is_scored_from_the_third_contact_and_again_from_the_second_after_a_stop():
    rec = one("stick-slip", "fibonacci").make()
    truth = rec.truth
    m = ns.motion(truth)
    windows = ns.scored_windows(truth, m)
    contacts = np.sort(truth.contact_times_s)
    first_run = contacts[(contacts >= m.runs[0][0]) & (contacts < m.runs[0][1])]
    if len(first_run) >= 3:
        assert windows[0][0] == first_run[2]
    later = contacts[(contacts >= m.runs[1][0]) & (contacts < m.runs[1][1])]
    if len(later) >= 2 and len(first_run) >= 1:
        assert any(w[0] == max(later[1], contacts[2]) for w in windows)


def test_positions_off_the_skin_are_counted_beyond_a_millimetre():
    rec = one("constant").make()
    skin = sum(rec.truth.layout_mm)
    score = ns.score(oracle(rec, position_mm=skin + 30.0), rec)
    assert score.off_skin == score.positions > 0
    assert ns.score(oracle(rec, position_mm=skin + 0.9), rec).off_skin == 0


def test_missing_speeds_are_counted_not_scored():
    rec = one("accelerating").make()
    score = ns.score(oracle(rec, velocity_mm_s=None), rec)
    assert score.missing == score.scored > 0 and len(score.speed_rel_err) == 0
    assert ns.summarise([score])["missing_pct"] == 100.0


@pytest.mark.parametrize("category", ["reversal", "constant"])
def test_a_speed_without_a_direction_is_a_speed_and_never_a_wrong_direction(category):
    """Issue 22: a decoder may tell |speed| before (or without) the direction. It counts
    for the speed error and against missing speed, and only a told direction can be
    wrong; this reverse slip's direction is not told at all."""
    rec = one(category, reverse=True).make()
    told = ns.score(oracle(rec), rec)
    untold = ns.score(oracle(rec, direction=False), rec)
    assert untold.scored == told.scored > 0 and untold.missing == told.missing == 0
    assert np.allclose(untold.speed_rel_err, 0.0) and np.allclose(untold.speed_mag_err, 0.0)
    assert told.directed > 0 and told.wrong_direction == 0
    assert untold.directed == untold.wrong_direction == 0


def test_a_signal_job_runs_each_decoder_in_3_and_256_sample_chunks_alike():
    signal = one("stick-slip", "alpha0.1")
    done = ns.signal_job(signal, {"tracker": {}, "ratio": {}}, ns.CHUNKS)
    for score in done["scores"].values():
        assert set(score.cpu_us) == {3, 256} and score.chunk_invariant
        assert score.updates > 100


# -- the tables --------------------------------------------------------------------------------


def _results() -> dict:
    done = []
    for signal in QUICK[::3]:
        rec = signal.make()
        score = ns.score(oracle(rec), rec)
        score.cpu_us = {3: 10.0, 256: 5.0}
        done.append({"signal": signal, "scores": {"tracker": score}})
    results = ns.aggregate(done, {"tracker": {}})
    results.update(signals=len(done), workers=2, quick=True)
    return results


def test_the_report_has_the_targets_and_a_table_per_category():
    results = _results()
    before = {k: 1.0 for k in ns.CONSTANT_FIGURES}
    now = {k: 2.0 for k in ns.CONSTANT_FIGURES}
    text = "\n".join(ns.render(results, "tracker", before, now))
    for title in ns.CATEGORIES.values():
        assert title in text
    assert "| wrong direction, all estimates | 0.0 | ≤ 5 | yes |" in text
    regression = (
        "| no regression, constant-speed target set: speed p90 % | 2.00 | ≤ 1.00 (last run) |"
    )
    assert regression + " **no** |" in text
    assert "µs/sample 3 / 256" in text and "| tracker |" in text
    assert ns.REGRESSION_NOTE in text  # a flagged step says where its cause is told


def test_no_regression_note_only_under_a_flagged_step():
    results = _results()
    same = {k: 1.0 for k in ns.CONSTANT_FIGURES}
    text = "\n".join(ns.render(results, "tracker", same, dict(same)))
    assert "≤ 1.00 (last run) | yes |" in text
    assert ns.REGRESSION_NOTE not in text


def test_the_constant_speed_baseline_is_the_last_run_of_the_same_grid(tmp_path):
    entry = {
        "decoder": "tracker",
        "default_settings": True,
        "target": {"speed_p90_pct": 4.2, "missing_pct": 0.0},
        "false_slip_pct": 0.5,
    }
    (tmp_path / "decoding.json").write_text(
        '{"quick": false, "decoders": {"tracker (default)": '
        + __import__("json").dumps(entry)
        + "}}"
    )
    before = bench.previous_constant(tmp_path, quick=False)
    assert before["speed_p90_pct"] == 4.2 and before["missing_pct"] == 0.0
    assert before["false_slip_pct"] == 0.5 and before["first_good_ratio"] is None
    assert bench.previous_constant(tmp_path, quick=True) is None
    assert bench.previous_constant(tmp_path / "nowhere", quick=False) is None


def test_a_shipped_scene_is_decoded_from_its_can_log_and_scored_like_a_signal():
    from grasplink.controllers import build_controllers

    path = bench.find_checkout(Path(__file__).parent) / "scenes" / "nonstationary_stick_slip.toml"
    done = ns.scene_job(str(path), build_controllers, {"ratio": {}})
    for kind in ("can", "csv"):
        score = done["scores"]["ratio"][kind]
        assert len(score.clear_s) == 3  # two stops mid-slip and one at the end
        assert score.updates > 300 and set(score.cpu_us) == {3}
    report = ns.scene_path([], build_controllers, {"ratio": {}})
    assert ns.render_scenes(report, "ratio") == []

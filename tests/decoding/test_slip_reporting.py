"""The slip-reporting figures (issue 22) on hand-made estimate streams, and the benchmark end
to end on a tiny plan.

The streams: a slip at 10 mm/s over a skin of 10 mm spacings, ridges met at 1, 2 and 3 s,
stopping at 3.2 s 2 mm past the third ridge: the next contact was due at 4.0 s, when the
stop becomes observable.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from grasplink.decoding.base import SlipEstimate
from grasplink.evaluation import slip_reporting as sr
from grasplink.simulators.synth import SkinRecording

FS = 400
LAYOUT = (10.0, 10.0, 10.0, 10.0)
UPDATE_S = 0.01
END_S = 5.0
OBSERVABLE_S = 4.0


def truth(sign: int = 1, layout: tuple[float, ...] = LAYOUT, stop_s: float = 3.2) -> SkinRecording:
    """At rest until 0.5 s, 10 mm/s (the edge from 5 mm before the first ridge met) until
    `stop_s`, at rest until 5 s."""
    t = np.arange(round(END_S * FS)) / FS
    v = np.where((t >= 0.5) & (t < stop_s), 10.0, 0.0)
    travel = np.clip(t - 0.5, 0.0, stop_s - 0.5) * 10.0
    skin = sum(layout)
    x = -5.0 + travel if sign > 0 else skin + 5.0 - travel
    met = [1.0 + k for k in range(len(layout) + 1) if 1.0 + k < stop_s]  # the first ridges
    # are 10 mm apart in every layout used here
    return SkinRecording(
        t_s=t,
        force_n=np.zeros_like(t),
        position_mm=x,
        speed_mm_s=sign * v,
        slipping=(v > 0).astype(float),
        grip_n=np.full_like(t, 5.0),
        contact_times_s=np.array(met),
        layout_mm=layout,
        fs_hz=FS,
    )


def stream(rule) -> list[SlipEstimate]:
    """An update every 10 ms; `rule(t)` gives (slip, speed, direction)."""
    out = []
    for k in range(round(END_S / UPDATE_S)):
        t = round(k * UPDATE_S, 6)
        slip, speed, direction = rule(t)
        out.append(
            SlipEstimate(
                t, slip, speed, None, 5.0, 0.9, direction, None if direction is None else 0.9
            )
        )
    return out


def told(clear_s: float = 4.05, direction_from_s: float = 3.1, flicker_s: float | None = None):
    """Slip from 1 s; a speed of 10 mm/s without a direction from 2 s, with +1 from
    `direction_from_s`; slip and speed cleared from `clear_s` (once more slip at
    `flicker_s`)."""

    def rule(t):
        if flicker_s is not None and abs(t - flicker_s) < 1e-9:
            return True, 10.0, None
        if t < 1.0 or t >= clear_s - 1e-9:
            return False, None, None
        if t < 2.0:
            return True, None, None
        return True, 10.0, (1 if t >= direction_from_s - 1e-9 else None)

    return stream(rule)


def test_a_speed_without_direction_is_a_speed_not_missing():
    score = sr.score(told(direction_from_s=10.0), truth())  # never a direction
    assert score.moving_from3 == 20  # 3.0-3.2 s
    assert score.missing_from3 == 0
    assert score.moving_from2 == 120 and score.missing_from2 == 0  # 2.0-3.2 s
    assert score.direction_eligible == 20 and score.direction_told == 0
    assert score.directed == 0  # no direction told: nothing to be wrong
    nothing = sr.score(stream(lambda t: (t >= 1.0, None, None)), truth())
    assert nothing.missing_from3 == nothing.moving_from3 == 20


def test_a_told_direction_the_wrong_way_counts_and_the_right_way_does_not():
    backwards = truth(sign=-1)  # the truth moves -; the stream tells + from 3.1 s
    wrong = sr.summarise([sr.score(told(), backwards)])
    assert wrong["wrong_direction_pct"] == 100.0
    assert wrong["direction_told_pct"] == 50.0  # 3.1-3.2 of 3.0-3.2 s
    right = sr.summarise([sr.score(told(), truth())])
    assert right["wrong_direction_pct"] == 0.0


def test_the_speed_error_is_of_magnitudes():
    half = sr.score(stream(lambda t: (True, 5.0, -1)), truth())  # -1: the wrong way
    assert np.allclose(half.speed_err, 0.5)


def test_a_stop_reported_while_the_object_slides_is_missing_speed_and_a_dropped_flag():
    """The belt and the reflex get nothing from "stopped, 0 mm/s" while the object moves:
    it counts as missing (not as a speed with a 100 % error), and the flag as dropped."""
    stopped = sr.score(stream(lambda t: (False, 0.0, None)), truth())
    assert stopped.missing_from3 == stopped.moving_from3 == 20
    assert stopped.dropped_from2 == stopped.moving_from2 == 120
    assert len(stopped.speed_err) == 0
    flagged = sr.score(told(), truth())
    assert flagged.dropped_from2 == 0
    blinking = sr.summarise([sr.score(stream(lambda t: (t >= 1.0 and t % 0.5 < 0.25, 10.0,
                                                        None)), truth())])  # fmt: skip
    assert 40.0 <= blinking["dropped_from2_pct"] <= 60.0


def test_the_loop_kind_slides_onto_the_skin_and_stops_or_slides_off():
    """The loop set: the edge starts 8 mm before the skin (either end), ridges are met at
    the case's speed, and each case ends at rest: on the skin (a stop) or past its far end
    (slid off); seeds draw both."""
    skin_mm = sum(sr.LAYOUTS_MM["alpha0.1"])
    ends = []
    for seed in range(1, 9):
        reverse = seed % 2 == 0
        case = sr.Case("loop", "30 mm/s", (30,), "alpha0.1", reverse, seed)
        rec = case.make().truth
        moving = np.abs(rec.speed_mm_s) > 1.0
        assert np.abs(rec.speed_mm_s[moving]).max() == pytest.approx(30.0, abs=0.5)
        assert rec.t_s[moving][0] == pytest.approx(sr.LOOP_ONSET_S, abs=0.01)
        assert len(rec.contact_times_s) >= 3 and not moving[-1]
        travel = rec.position_mm[-1] if not reverse else skin_mm - rec.position_mm[-1]
        assert 0.0 < travel < skin_mm or travel > skin_mm + sr.LOOP_OBJECT_MM / 2, travel
        ends.append(travel < skin_mm)
    assert any(ends) and not all(ends)


def test_first_estimate_within_10_percent_in_intervals_after_the_third_contact():
    from_two = sr.score(told(), truth())  # right from 2 s: one interval before the 3rd
    assert from_two.first_good == pytest.approx([-1.0])
    late = sr.score(stream(lambda t: (True, 10.5 if t >= 3.05 else 12.0, None)), truth())
    assert late.first_good == pytest.approx([0.05])  # 12 is 20 % off; 10.5 within 10 %
    never = sr.summarise([sr.score(stream(lambda t: (True, 12.0, None)), truth())])
    assert never["first_good_median_intervals"] is None and never["first_good_never"] == 1


def test_a_stop_is_observable_when_the_next_contact_is_due_and_absent():
    stop = sr.score(told(), truth()).stops
    assert len(stop) == 1
    assert stop[0].observable_s == pytest.approx(OBSERVABLE_S, abs=1e-6)
    assert stop[0].judged
    assert stop[0].delay_s == pytest.approx(0.05, abs=1e-6)  # cleared at 4.05 s
    backwards = sr.score(told(), truth(sign=-1)).stops  # the next ridge is the one below
    assert backwards[0].observable_s == pytest.approx(OBSERVABLE_S, abs=1e-6)


def test_a_stop_cleared_late_or_flickering_back_is_not_cleared_in_time():
    late = sr.summarise([sr.score(told(clear_s=4.2), truth())])
    assert late["stops_cleared_pct"] == 0.0
    assert late["stop_delay_p90_s"] == pytest.approx(0.2, abs=1e-6)
    in_time = sr.summarise([sr.score(told(clear_s=4.1), truth())])
    assert in_time["stops_cleared_pct"] == 100.0
    flicker = sr.score(told(clear_s=4.05, flicker_s=4.5), truth())  # slip again at 4.5 s
    assert flicker.stops[0].delay_s == pytest.approx(0.51, abs=1e-6)  # for good from 4.51


def test_a_stop_past_the_last_ridge_is_not_judged():
    short = (10.0, 10.0)  # ridges at 0, 10, 20: the edge stops at 22 mm, none ahead
    score = sr.score(told(), truth(layout=short))
    assert score.stops[0].observable_s is None and not score.stops[0].judged
    assert sr.summarise([score])["stops_past_last_ridge"] == 1


def test_speed_at_rest_and_after_the_stop_report_was_due():
    """After the stop became observable (4.0 s) its report is due within 0.15 s (target
    4); a speed after that is a speed at rest."""
    score = sr.score(told(clear_s=4.05), truth())
    assert score.after_observable == 84  # 4.16 ... 4.99 s
    assert score.after_observable_speed == 0  # gone at 4.05 s: in time
    lingering = sr.score(told(clear_s=4.3), truth())
    assert lingering.after_observable_speed == 14  # 4.16 ... 4.29 s
    assert score.rest_speed == 70  # 3.35 ... 4.04 s: 0.15 s or more into the rest
    assert score.rest_updates == 35 + 165  # 0.15-0.5 s and 3.35-5.0 s


def test_unique_from_the_second_contact_only_where_the_first_spacings_agree():
    assert sr.unique_from_second((4.0,) * 21)
    assert not sr.unique_from_second((19.0, 12.0, 5.0, 8.0, 4.0, 3.0, 33.0))
    assert sr.unique_from_second((10.0, 50.0, 10.5))  # within 10 %


def test_headline_figures_from_the_truth_ridge_crossings():
    rec = truth(layout=(10.0, 10.0, 10.0, 25.0))  # first and last spacings differ: 3 needed
    assert sr.ridge_crossings_s(rec) == pytest.approx([1.0, 2.0, 3.0], abs=1e-3)
    good = sr.headline_figures(told(), rec)
    assert good["contact_needed"] == 3 and good["contact_needed_s"] == pytest.approx(3.0, abs=1e-3)
    assert good["first_speed_s"] == pytest.approx(2.0) and good["first_ok"] is True
    assert good["last_speed_s"] == pytest.approx(4.04)
    assert good["last_ok"] is True  # 0.84 s after the stop: within one interval (1 s)
    assert good["rest_ok"] is True and good["speed_after_observable_updates"] == 0
    lingering = sr.headline_figures(told(clear_s=4.5), rec)
    assert lingering["last_ok"] is False  # 1.29 s after the stop
    assert lingering["rest_ok"] is False  # 4.16 ... 4.49 s: after the report was due
    assert lingering["speed_after_observable_updates"] == 34
    late = sr.headline_figures(stream(lambda t: (True, 10.0 if t >= 3.3 else None, 1)), rec)
    assert late["first_ok"] is False  # 0.3 s after the 3rd contact: beyond the detector's delay


def test_headline_figures_owe_no_last_speed_where_the_contact_needed_never_came():
    """Stopped after two contacts on a layout needing three: no speed shown is right (the
    slip flagged, the speed not told), not a last speed missing; with the third contact
    before the stop, a slip shown without a speed still misses it."""
    layout = (10.0, 10.0, 10.0, 25.0)  # first and last spacings differ: 3 contacts needed
    flag_only = stream(lambda t: (1.0 <= t < 2.6, None, None))
    early = sr.headline_figures(flag_only, truth(layout=layout, stop_s=2.5))
    assert early["contact_needed_s"] is None and early["first_speed_s"] is None
    assert early["last_ok"] is None and early["rest_ok"] is True
    owed = sr.headline_figures(flag_only, truth(layout=layout))
    assert owed["contact_needed_s"] == pytest.approx(3.0, abs=1e-3)
    assert owed["last_ok"] is False and owed["first_ok"] is False


def test_sweep_settings_reach_the_tracker():
    odds = sr.build_decoder("tracker", LAYOUT, FS, sr.settings_for("LOG_REPORT_ODDS", 3.0))
    assert math.isclose(odds.LOG_REPORT_ODDS, math.log(3.0))
    dips = sr.build_decoder("tracker", LAYOUT, FS, sr.settings_for("DIP_PRIOR_MM", 0.4))
    assert dips.DIP_PRIOR_MM == dips.DIP_PRIOR_CHANGING_MM == 0.4
    noise = sr.build_decoder("tracker", LAYOUT, FS, sr.settings_for("threshold", 3.0))
    assert noise.detector.threshold == 3.0
    points = sr.sweep_points(sr.QUICK)
    for name, values in points.items():
        assert sum(key == "shipped" for _, key in values) == 1, name


TINY = sr.Plan(
    name="tiny",
    layouts=("alpha0.1",),
    seeds=1,
    variants={"constant": (4,), "stop": (1,), "held-grip": (2,)},
    sweep_layouts=("alpha0.1",),
    sweep_variants={"stop": (1,), "held-grip": (2,)},
    sweeps=("threshold",),
    sweep_values=2,
    cost_cases=1,
    headline=True,
)


@pytest.mark.slow
def test_the_benchmark_runs_end_to_end_on_a_tiny_plan(tmp_path: Path):
    from grasplink.controllers import build_controllers

    root = Path(__file__).resolve().parents[2]
    figures = sr.run_benchmark(
        TINY, tmp_path, root, controllers_for=build_controllers, workers=1, log=lambda _: None
    )
    page = (tmp_path / sr.PAGE).read_text()
    assert "## Targets" in page and "## The headline loop" in page
    assert (tmp_path / "slip_reporting_threshold.png").stat().st_size > 0
    raw = json.loads((tmp_path / sr.RAW).read_text())
    assert raw["figures"]["all"]["cases"] == 5  # 35 mm/s and the stop both ways, one held
    assert raw["figures"]["all"]["cpu_us_baseline"] > 0  # the MMSE beside the decoder
    rows = figures["sweeps"]["threshold"]
    assert [r["value"] for r in rows] == [3.0, 4.5, 7.0] and rows[1]["shipped"]
    assert figures["kinds"]["stop"]["stops_judged"] == 2
    assert figures["headline"]["contacts_s"]  # the loop's slip met ridges


def test_motion_past_the_last_ridge_is_not_scored():
    """Past the last ridge ahead no contact can come: a decoder cannot tell that the object
    still slides, so those updates count neither as missing nor as dropped (as a stop
    there is not judged), and are counted apart."""
    rec = truth(stop_s=4.8)  # at 10 mm/s the edge passes the last ridge (40 mm) at 5.0 s ...
    rec.position_mm[:] = rec.position_mm + 5.0  # ... moved on 5 mm: at 4.5 s
    quiet = sr.score(told(clear_s=4.5), rec)  # slip and speed end as the edge passes it
    assert quiet.beyond_last == 30  # 4.5-4.8 s
    assert quiet.dropped_from2 == 0 and quiet.missing_from3 == 0
    inside = sr.score(told(clear_s=4.4), rec)  # ... 0.1 s before it: counted
    assert inside.dropped_from2 == 10 and inside.missing_from3 == 10


def test_a_trial_reaches_the_detectors_watch_settings_by_name_and_refuses_unknown_ones():
    """`build_decoder`'s "watch" setting (`benchmarks/tune_tracker.py --try watch.NAME=V`)."""
    decoder = sr.build_decoder(
        "tracker", (6.0, 8.0), 400.0, {"watch": {"tail_trough": 1.0, "drop_fraction": 0.4}}
    )
    watch = decoder.detector.settings.watch
    assert watch.tail_trough is True and watch.drop_fraction == 0.4
    with pytest.raises(ValueError, match="no WatchSettings field 'tail_trouf'"):
        sr.build_decoder("tracker", (6.0, 8.0), 400.0, {"watch": {"tail_trouf": 1.0}})


def test_build_decoder_takes_a_trials_kink_bank_fields_and_names_an_unknown_one():
    """A `hinges` trial (tune_tracker's `hinges.NAME`) reaches the kink bank's settings;
    a field HingeSettings does not have is refused by name."""
    layout = (10.0, 20.0)
    decoder = sr.build_decoder("tracker", layout, 400, {"hinges": {"merge_widths": 1.0}})
    assert decoder.detector.settings.hinges.merge_widths == 1.0
    shipped = sr.build_decoder("tracker", layout, 400, {})
    assert shipped.detector.settings.hinges.merge_widths != 1.0
    with pytest.raises(ValueError, match="merge_width"):
        sr.build_decoder("tracker", layout, 400, {"hinges": {"merge_width": 1.0}})


def test_held_out_seeds_are_other_cases_of_the_same_plan_and_out_of_range_ones_refused():
    """`benchmarks/held_out_seeds.py` runs the full plan on seeds no rule was tuned on: the
    same kinds, variants, layouts and directions, none of the tuned cases' seeds."""
    from dataclasses import replace

    tuned = sr.cases(sr.FULL)
    held = sr.cases(replace(sr.FULL, first_seed=3))
    assert len(held) == len(tuned)
    assert not {c.seed for c in held} & {c.seed for c in tuned}
    shape = [(c.kind, c.variant, c.layout, c.reverse) for c in tuned]
    assert [(c.kind, c.variant, c.layout, c.reverse) for c in held] == shape
    with pytest.raises(ValueError, match="out of the 10"):
        sr.cases(replace(sr.FULL, first_seed=8))  # seeds 8..10: 10 is the next variant's


def test_flag_chatter_counts_runs_under_50_ms_but_not_the_first_or_last():
    """One update of slip at 4.5 s inside the rest (10 ms up, then down): two changes, one
    run under 50 ms between them; the slip itself (1 s to 4.05 s) and the rests around it
    are runs of seconds. 5 s of updates: 12 short runs per minute."""
    rec = truth()
    steady = sr.score(told(), rec)
    assert steady.short_flag_runs == 0
    flicker = sr.score(told(flicker_s=4.5), rec)
    assert flicker.short_flag_runs == 1
    assert sr.summarise([flicker])["chatter_per_min"] == pytest.approx(60.0 / 4.99)

"""A speed is shown only while the ridge its own track predicts next is not overdue
(`overdue_speed`, `TrackerDecoder.OVERDUE_SPEED`): the flag stays the posterior's, the
speed goes once the contact it predicts is later than the report's schedule allows."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasplink.decoding import overdue_speed
from grasplink.decoding.kernels import posterior as posterior_kernels
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
from tests.decoding.plan_cases import plan_case

LAYOUT_MM = [10.0, 4.0, 12.0, 8.0]  # ridges at 0, 10, 14, 26, 34 mm


def one_track(v_mm_s: float, sigma_v_mm_s: float, t_s: float = 1.0) -> tuple:
    """A steady track slipping forward at v, its last contact at ridge 2 (14 mm) at t, its
    speed's sigma `sigma_v_mm_s` (its position known): the kernels' `Tracks` tuple."""
    P = np.zeros((1, 4, 4))
    P[0, 1, 1] = sigma_v_mm_s**2
    return tuple(
        posterior_kernels.Tracks(
            score=np.zeros(1), X=np.array([[14.0, v_mm_s, 0.0, 0.0]]), P=P, m=np.zeros(1),
            t=np.array([t_s]), stop=np.array([math.nan]), dirn=np.array([1]),
            ridge=np.array([2]), run=np.array([3]), n=np.array([3]),
            ids=np.zeros((1, 4), np.int64), before=np.zeros(1),
        )
    )  # fmt: skip


def due_s(decoder: TrackerDecoder, tracks: tuple, span_rel: float, late_rel: float) -> float:
    K = overdue_speed.report_constants(decoder._K, span_rel, late_rel)
    skin = tuple(posterior_kernels.Skin(pos=decoder._pos, K=K))
    columns = np.zeros(2 * (decoder.count + 1), np.int64)  # the next ridge decides
    return float(overdue_speed.next_due_s(tracks, decoder._silence, skin, np.zeros(1), columns)[0])


def test_a_sure_track_is_overdue_its_interval_late_rel_and_latency_after_its_contact():
    """50 mm/s, 12 mm to the next ridge: due 0.24 s on, 15 % late allowed, the detector's
    latency for 1.2 mm at 50 mm/s (24 ms) - the schedule's time, nothing more."""
    decoder = TrackerDecoder(LAYOUT_MM, 1000.0)
    due = due_s(decoder, one_track(50.0, 0.0), 0.5, 0.15)
    assert due == pytest.approx(1.0 + 0.24 * 1.15 + 0.024, abs=1e-9)
    assert due_s(decoder, one_track(50.0, 0.0), 0.5, 0.0) == pytest.approx(1.264, abs=1e-9)


def test_an_unsure_speed_waits_three_sigma_capped_at_span_rel_of_the_interval():
    """sigma_v 20 of 50 mm/s (a two-contact twin): 3 sigma of its timing would be 0.29 s,
    1.2 intervals; capped at 1/6 its 3 sigma is half the interval."""
    decoder = TrackerDecoder(LAYOUT_MM, 1000.0)
    uncapped = due_s(decoder, one_track(50.0, 20.0), 0.5, 0.0)
    capped = due_s(decoder, one_track(50.0, 20.0), 1 / 6, 0.0)
    assert uncapped == pytest.approx(1.0 + 0.24 + 3 * 0.24 * 20 / 50 + 0.024, abs=1e-9)
    assert capped == pytest.approx(1.0 + 0.24 * 1.5 + 0.024, abs=1e-9)


def test_a_ridge_often_missed_leaves_it_to_the_one_after():
    """alpha0.3 (4, 3, 48, 29 mm): its 3 mm ridge is told 46 % of the time, the 4 mm one 92
    %, the others 100 % (`DETECT_P`): at P(missed) 0.05 a track before the 3 mm ridge waits
    for the 48 mm one after it, one before the 4 mm ridge for the 3 mm one too (0.08 x
    0.54 = 0.04); the coast end past the last ridge is never missed."""
    decoder = TrackerDecoder([4.0, 3.0, 48.0, 29.0], 1000.0)
    columns = overdue_speed.report_columns(decoder._log_miss, 3, math.log(0.05))
    forward = columns[: decoder.count + 1]  # rows by the ridge of the last contact, 0-5
    assert forward.tolist() == [1, 1, 0, 0, 0, 0]
    every = overdue_speed.report_columns(decoder._log_miss, 3, 0.0)
    assert every.tolist() == [0] * 12
    with pytest.raises(ValueError, match="must be <= 0"):
        overdue_speed.report_columns(decoder._log_miss, 3, 0.1)


def test_overdue_counts_the_time_on_the_rail_as_unseen():
    assert overdue_speed.overdue(1.3, 1.31)
    assert not overdue_speed.overdue(1.3, 1.3)
    assert not overdue_speed.overdue(1.3, 1.35, blind_s=0.1)


@pytest.mark.parametrize("span_rel,late_rel", [(0.0, 0.1), (-1.0, 0.1), (0.2, -0.1)])
def test_bad_report_constants_are_named(span_rel, late_rel):
    decoder = TrackerDecoder(LAYOUT_MM, 1000.0)
    with pytest.raises(ValueError, match=r"span_rel .* late_rel"):
        overdue_speed.report_constants(decoder._K, span_rel, late_rel)


def decoded(kind: str, seed: int, tuning: dict) -> tuple[list, list[sr.StopScore]]:
    """The tracker's estimates of a full-plan case (by kind and seed) with `tuning`, and
    its scored stops."""
    rec = plan_case(kind, seed).make()
    decoder = sr.build_decoder("tracker", rec.truth.layout_mm, rec.fs_hz, {"tuning": tuning})
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    return estimates, sr.score(estimates, rec.truth).stops


def speeds_after_due(estimates: list, stops: list[sr.StopScore]) -> list[float]:
    """The times of updates giving a speed after a stop's report was due."""
    late = []
    for stop in stops:
        if stop.observable_s is None:
            continue
        due = stop.observable_s + sr.CLEAR_WITHIN_S
        late += [e.t_s for e in estimates if due < e.t_s < stop.end_s and (e.speed_mm_s or 0) > 0]
    return late


# full-plan cases giving a speed after a stop's report was due on 4bd69df, by class
# (`benchmarks/after_due_cases.py --seeds 3`; kind, seed, updates then):
# - the schedule's timing sigma capped at half the interval (3 sigma: 1.5 intervals): a
#   two-contact twin at 50 mm/s, sigma_v 20, its next ridge 12 mm on, due 1.47 s against a
#   stop ending 1.35 s (200 Hz);
SPAN_CASES = [("rates-drops", 130_520, 14)]
# - LATE_REL's 15 % of a long interval beyond the stop's 0.15 s: a 21 mm interval at
#   35 mm/s (95120), and a speeding track's ridge due late at 118 mm/s (85200) and 100 Hz
#   (135320)
LATE_CASES = [("stop", 95_120, 2), ("stick-slip", 85_200, 3), ("rates-drops", 135_320, 2)]
OFF = {"OVERDUE_SPEED": 0.0}


@pytest.mark.parametrize("kind,seed,updates", SPAN_CASES + LATE_CASES)
def test_no_speed_after_a_stops_report_was_due(kind, seed, updates):
    estimates, stops = decoded(kind, seed, {})
    assert not speeds_after_due(estimates, stops)


@pytest.mark.parametrize("kind,seed,updates", SPAN_CASES + LATE_CASES)
def test_off_these_cases_give_a_speed_after_due(kind, seed, updates):
    """The same cases with the overdue speed off: as on 4bd69df (the tests above can fail)."""
    estimates, stops = decoded(kind, seed, OFF)
    assert len(speeds_after_due(estimates, stops)) == updates


@pytest.mark.parametrize("kind,seed,updates", SPAN_CASES + LATE_CASES)
def test_the_flag_is_the_posteriors_either_way(kind, seed, updates):
    """Only the speed is withheld: every update's slip flag as with it off."""
    on, _ = decoded(kind, seed, {})
    off, _ = decoded(kind, seed, OFF)
    assert [e.slip for e in on] == [e.slip for e in off]


def test_the_reports_ridge_is_never_past_the_one_the_posterior_stops_at():
    """alpha0.3 again, with the posterior's own stop (`LOG_STOP`, P 0.2): the 4 mm ridge's
    silence (missed with P 0.08) is a stop to the posterior, so the report reads that ridge
    (0), not the 3 mm one after it; before the 3 mm ridge (0.54) it still waits for the next."""
    decoder = TrackerDecoder([4.0, 3.0, 48.0, 29.0], 1000.0)
    log_p = overdue_speed.report_log_p(0.05, decoder.LOG_STOP)
    assert log_p == pytest.approx(math.log(0.2))
    columns = overdue_speed.report_columns(decoder._log_miss, 3, log_p)
    assert columns[: decoder.count + 1].tolist() == [0, 1, 0, 0, 0, 0]
    assert overdue_speed.report_log_p(0.05, None) == pytest.approx(math.log(0.05))
    assert overdue_speed.report_log_p(0.5, math.log(0.2)) == pytest.approx(math.log(0.5))
    assert overdue_speed.report_log_p(0.0, None) == -math.inf


# full-plan cases giving a speed after a stop's report was due on 8a8786d (37 updates in
# all, `benchmarks/after_due_cases.py --seeds 3`), by the rule that clears them, with that
# rule off (kind, seed, updates, tuning):
# - OVERDUE_STOP_RIDGE: 4 mm ridges, the report waiting for the ridge after the one the
#   posterior stops at (due: inf), the speed shown until the posterior's later due time;
# - OVERDUE_PROBE_REGIME: the stop's step found late by the step probe after contacts told
#   in time, revived the track with the probes' 0.21 s wait (100 Hz);
# - OVERDUE_LATCH: withheld at 1.31 s, then a braking twin of the same contacts chosen,
#   its ridge due 37 ms later.
# (OVERDUE_LATCH until a contact costs decelerating slips 4.6 points of missing speed; it
# ships for 0.05 s, OVERDUE_LATCH_S: 0.1 point.)
WITHHELD_CASES = [
    ("stick-slip", 86_111, 4, {}, {"OVERDUE_STOP_RIDGE": 0.0}),
    ("rates-drops", 130_111, 2, {}, {"OVERDUE_STOP_RIDGE": 0.0}),
    ("rates-drops", 136_321, 14, {}, {"OVERDUE_PROBE_REGIME": 0.0}),
    ("rates-drops", 130_101, 2, {}, {"OVERDUE_LATCH": 0.0}),
]


@pytest.mark.parametrize("kind,seed,updates,on,off", WITHHELD_CASES)
def test_no_speed_after_due_where_the_report_reads_the_posteriors_stop(
    kind, seed, updates, on, off
):
    estimates, stops = decoded(kind, seed, on)
    assert not speeds_after_due(estimates, stops)


@pytest.mark.parametrize("kind,seed,updates,on,off", WITHHELD_CASES)
def test_with_its_rule_off_the_speed_after_due_stays_and_the_flag_is_the_same(
    kind, seed, updates, on, off
):
    """The control (the test above can fail): that rule off gives the speed after due it
    cleared; only speeds differ, every update's flag is as with it on."""
    with_rule, _ = decoded(kind, seed, on)
    off_estimates, stops = decoded(kind, seed, off)
    assert len(speeds_after_due(off_estimates, stops)) == updates
    assert [e.slip for e in with_rule] == [e.slip for e in off_estimates]


def test_the_latch_lasts_its_window_from_the_first_withheld_update_and_only_that_contact():
    """`overdue_speed.latched`: withheld first at 1.31 s, a twin of that contact is held
    for 0.05 s after; another contact, or past the window, is not."""
    assert overdue_speed.latched(7, 7, 1.31, 1.33, 0.05)
    assert overdue_speed.latched(7, 7, 1.31, 1.35, 0.05)
    assert not overdue_speed.latched(7, 7, 1.31, 1.37, 0.05)
    assert not overdue_speed.latched(8, 7, 1.31, 1.33, 0.05)
    assert overdue_speed.latched(7, 7, 1.31, 9.0, math.inf)


def test_a_window_shorter_than_the_twins_wait_leaves_its_speed():
    """The control for the window: 130101's twin showed its speed 10-20 ms after the first
    withheld update (1.32, 1.33 s), so a 5 ms latch leaves both updates."""
    estimates, stops = decoded("rates-drops", 130_101, {"OVERDUE_LATCH_S": 0.005})
    assert len(speeds_after_due(estimates, stops)) == 2

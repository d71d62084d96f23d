"""A slip that stopped unseen and went on reaches its next ridge later, never sooner.

The tracker branches every slipping track at a contact into "stopped unseen, restarted
at the next ridge" with the speed unknown; a stopped track into "restarted here". Such
a restart had one prior whatever the time since: a contact 0.18 s after a ridge at
15 mm/s became the restart at the ridge 33 mm on (185 mm/s), and those tracks, waiting
for a second contact, held the slip off for seconds while the object slid on
(`benchmarks/missing_speed_causes.py`: alpha0.1 15 mm/s, seed 50210). Now the restart is
weighed by P(speed >= distance / time) under the speed prior (`kernels.branch._log_reach`):
a slipping track's (`RESTART_REACH`) and a stopped track's (`STOPPED_REACH`), both on by
default. In the traced case the restart was a stopped track's - stopped at the probe's
step at 4.15 s, restarted two ridges on, past the 3 mm ridge it took as missed - so its
tests set STOPPED_REACH."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasplink.decoding.kernels import branch as kernel
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

# constant 15 mm/s over alpha0.1: ridges at 48 (3.90 s) and 51 mm (4.11 s, told by the
# step probe at 4.15 s), a noise contact at 4.328 s, the next ridge at 84 mm (6.31 s)
CASE = sr.Case("constant", "15 mm/s", (15,), "alpha0.1", False, 50210)


def _constants(dec: TrackerDecoder) -> np.ndarray:
    return kernel.pack_constants(dec._branch_constant_values())


def test_reach_is_the_speed_priors_tail():
    dec = TrackerDecoder(LAYOUTS_MM["alpha0.1"], 400.0)
    c = _constants(dec)
    need = 33.0 / 0.178  # mm/s
    z = math.log(need / dec.SPEED_PRIOR_MM_S) / dec.SPEED_PRIOR_LOG_SIGMA
    expected = math.log(0.5 * math.erfc(z / math.sqrt(2.0)))
    assert kernel._log_reach(33.0, 0.178, 1.0, c) == pytest.approx(expected, rel=1e-9)
    assert expected < math.log(0.06)
    # a restart that comes late (5 mm in 1 s) costs next to nothing; none left to cover, 0
    assert kernel._log_reach(5.0, 1.0, 1.0, c) > math.log(0.95)
    assert kernel._log_reach(0.0, 0.1, 1.0, c) == 0.0
    assert kernel._log_reach(-1.0, 0.1, 1.0, c) == 0.0
    assert kernel._log_reach(33.0, 0.178, 0.0, c) == 0.0  # off


def _restarts_far_ahead(tuning: dict) -> float:
    """The best score, against the best track's, of a track restarted (speed unknown) at
    the last ridge (84 mm) by the noise contact at 4.328 s, just after it was decided."""
    rec = CASE.make()
    dec = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz, tuning=tuning)
    until = rec.t_s <= 4.40
    ns.feed(dec, rec.t_s[until], rec.force_n[until], sr.CHUNK)
    B = dec._tracks
    last = dec.count - 1
    far = (B.run == 1) & (B.n >= 2) & (B.ridge == last) & (B.dirn > 0)
    assert len(B) and np.any(np.abs(B.t - 4.328) < 0.01), "the noise contact was not decided"
    return float(B.score[far].max() - B.score.max()) if far.any() else -math.inf


def test_a_restart_cannot_outrun_the_slip():
    assert _restarts_far_ahead({"STOPPED_REACH": 1.0}) < math.log(0.1)


def test_without_the_reach_that_restart_is_nearly_the_best():
    """STOPPED_REACH 0 (off) leaves that restart as the tracker before had it: the
    case still shows it (so the test above checks the rule, not a changed signal)."""
    assert _restarts_far_ahead({"STOPPED_REACH": 0.0}) > math.log(0.5)


def test_a_stopped_tracks_reach_clears_a_stop_whose_step_reads_as_its_restart():
    """STOPPED_REACH weighs a stopped track's restart too: the stick-slip stop whose own
    friction step, just after it, read as the restart at the next ridge
    (test_restart_confirm's case) is cleared in time with neither the restart rule nor the
    step's shape; without it, not."""
    from tests.decoding.test_restart_confirm import BARE, STICK_SLIP, stop_delays

    assert max(stop_delays(STICK_SLIP, {**BARE, "STOPPED_REACH": 1.0})) <= sr.CLEAR_WITHIN_S
    assert max(stop_delays(STICK_SLIP, BARE)) > sr.CLEAR_WITHIN_S


def _gap_reports(tuning: dict) -> list:
    """test_quantised_input's rail case with speed dips (alpha0.1, 40 mm/s, seed 1, ADC
    counts): the estimates while the edge crosses the last gap, 51 -> 84 mm (2.55-3.30 s)."""
    from tests.decoding.test_quantised_input import adc

    rec = synth.slip_recording(
        LAYOUTS_MM["alpha0.1"], 40.0, reverse=False, dips=True, onset_s=1.0, seed=1
    )
    x = rec.force_n.copy()
    before = rec.t_s < 0.9
    x[before] = np.maximum(0.0, np.random.default_rng(1).normal(-0.01, 0.02, before.sum()))
    dec = TrackerDecoder(rec.layout_mm, rec.fs_hz, tuning=tuning)
    estimates, _ = ns.feed(dec, rec.t_s, adc(x), 3)
    return [e for e in estimates if 2.95 <= e.t_s <= 3.30]


def test_a_restart_past_the_last_ridge_no_longer_holds_a_gap_stopped():
    """The probe's step at 2.52 s (the ridge at 51 mm) branches the tracks stopped at the
    step at 2.415 s (48 mm) into a restart at the last ridge, 84 mm: 36 mm in 0.107 s,
    335 mm/s. No ridge follows it, so no silence refutes it, and its restart on a step is
    no slip yet (RESTART_CONFIRM): it kept the slip reported stopped through the 33 mm gap
    (0.83 s at 40 mm/s). Weighed by its reach it goes, and the slip is reported going on at
    its speed - 37.0 mm/s, the dips' bias every speed of this case has (`test_quantised_
    input`'s median). Without the reach, the ramp hold over a stop (RAMP_OVER_STOP, s32)
    now raises the flag over part of that gap, without a speed; it is off for the
    counterfactual, as is the ridge-shaped step's prior (`LOG_SHAPE_RIDGE_STOP`, s34), with
    which the step at 2.415 s is seldom the stop in the first place."""
    on = _gap_reports({"STOPPED_REACH": 1.0})
    assert on and all(e.slip and 0.9 * 40.0 <= e.speed_mm_s <= 40.0 for e in on)
    off = _gap_reports({"STOPPED_REACH": 0.0, "RAMP_OVER_STOP": 0.0, "LOG_SHAPE_RIDGE_STOP": 0.0})
    assert off and not any(e.slip for e in off)

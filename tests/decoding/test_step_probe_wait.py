"""A stop's own step found late by the step probe, and the probes' wait (issue 22: speed
after a stop's report was due, target 0).

`TrackerDecoder._latency_floor`: a track whose last contact the probes found late waits as
long for its next before its silence is read as a stop - under the FSR's hysteresis the
kink bank misses held ridge pulses and the probes find them ~0.2 s late. The step probe
finds small steps at their hold: a stop's friction step (thesis ch. 4.3), or on the loop's
FSR a held ridge. `STEP_PROBE_WAIT` 0 gives a track whose last contact is the step
probe's no wait; `STEP_PROBE_REGIME` N only when none of the N contacts before that one
came late (hysteresis holds ridge pulses run after run; a late step after contacts told
in time is a stop's). Figures: docs/decoding.md, *Gaps*."""

from __future__ import annotations

import numpy as np

from grasplink.decoding.contacts import STEP_IDS, ContactEvent
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

# the full plan's rates-drops case (100 Hz, stick-slip 47 mm/s, uniform4 reversed) whose
# first stop (0.84 - 1.33 s) was cleared by silence at 0.86 s; its step, found by the step
# probe at 1.02 s (onset 0.840 s, told a step), was taken for the ridge then due and the
# track slipped on at 49 mm/s with the probes' wait: a speed until 1.17 s (16 updates
# after the stop's report was due)
LATE_STEP = sr.Case(
    "rates-drops", "100 Hz, stick-slip 47 mm/s", (100, "stick-slip"), "uniform4", True, 136321
)


def after_due_speeds(case: sr.Case, tuning: dict) -> int:
    """Updates after a stop's report was due (observable + 0.15 s) carrying a speed."""
    rec = case.make()
    decoder = sr.build_decoder("tracker", rec.truth.layout_mm, rec.fs_hz, {"tuning": tuning})
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    return sr.score(estimates, rec.truth).after_observable_speed


def test_without_the_step_probes_wait_the_late_step_gives_no_speed_after_due():
    assert after_due_speeds(LATE_STEP, {"STEP_PROBE_WAIT": 0.0}) == 0


def test_after_contacts_told_in_time_the_late_step_gives_no_speed_after_due():
    """`STEP_PROBE_REGIME` 3 (off by default: the first held ridge of a loop's run loses
    its wait too, test_tracker_probe_wait): the contacts before the step were told in
    time, so it waits for no probe."""
    assert after_due_speeds(LATE_STEP, {"STEP_PROBE_REGIME": 3.0}) == 0


def test_with_the_step_probes_wait_the_speed_after_due_stays():
    """The control, the shipped posterior (`STEP_PROBE_REGIME` 0, `STEP_PROBE_WAIT` 1) with
    the report reading its wait too (`OVERDUE_PROBE_REGIME` 0; shipped 3 clears the case,
    test_overdue_speed): the wait for that contact gives the speed after due (so the tests
    above check the rules, not a changed signal)."""
    tuning = {"STEP_PROBE_WAIT": 1.0, "STEP_PROBE_REGIME": 0.0, "OVERDUE_PROBE_REGIME": 0.0}
    assert after_due_speeds(LATE_STEP, tuning) > 0


def _contact(cid: int, t_s: float, late: bool, fs_hz: float) -> ContactEvent:
    index = round(t_s * fs_hz)
    emit = index + (100 if late else 2)
    return ContactEvent(cid, t_s, index, emit, 8.0, 1.0, 0.01, 0.002)


def test_a_late_step_after_late_contacts_keeps_its_wait():
    """A step probe's late contact keeps the probes' wait after a late contact (the held
    ridges of a hysteresis run) and loses it after contacts told in time."""
    fs_hz = 400.0
    decoder = TrackerDecoder(np.full(8, 4.0), fs_hz, tuning={"STEP_PROBE_REGIME": 3.0})
    held = [_contact(0, 0.5, False, fs_hz), _contact(1, 0.6, True, fs_hz)]
    decoder._contacts = [*held, _contact(STEP_IDS, 0.7, True, fs_hz)]
    late = {1, STEP_IDS}
    assert decoder._step_probe_regime(late, 3) == {1, STEP_IDS}
    decoder._contacts = [_contact(0, 0.5, False, fs_hz), _contact(STEP_IDS, 0.7, True, fs_hz)]
    assert decoder._step_probe_regime({STEP_IDS}, 3) == set()

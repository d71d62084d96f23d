"""The contact detector's first pulse/step verdict on the headline loop's signal (issue 22).

While the headline object slips its level rises (more of it over the sensor, ~2 N/s) and
the FSR's hysteresis holds each ridge pulse's fall up: over the 0.1 s before an onset the
level may show no trend at all, and a pulse looked like a step at its first verdict - the
tracker then branched "the slip stopped there" and said "no slip" while the object slid.
The object's stop (the friction term's step, thesis ch. 4.3, while the reflex raises the
grip) must stay a step. The signal is the loop's, open loop (`contact_truth`), with its
pulses, dips and noise drawn by each seed; fed 3 samples at a time.
"""

from __future__ import annotations

import pytest

from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation.contact_truth import (
    HEADLINE_STOP_S,
    MATCH_S,
    detect,
    headline_replica,
)

SEEDS = range(1, 13)
MID_SLIP_PULSE_SHARE = 0.65  # measured 23 of 30 (0.77); 10 of 30 before the fix


@pytest.fixture(scope="module")
def told() -> list:
    out = []
    for seed in SEEDS:
        rec = headline_replica(seed)
        out.append((rec, detect(rec.t_s, rec.force_n, rec.fs_hz)))
    return out


def test_ridge_pulses_on_the_rising_level_of_a_slip_are_pulses_at_their_first_verdict(told):
    """Ridge contacts after the first and 0.15 s or more before the stop (the first has no
    trend before it to tell; the last is overrun by the stop's step)."""
    found = pulses = 0
    for rec, result in told:
        for crossing in rec.contact_times_s:
            if not 1.3 < crossing < HEADLINE_STOP_S - 0.15:
                continue
            near = [e for e in result.contacts if abs(e.t_s - crossing) <= MATCH_S]
            if not near:
                continue
            found += 1
            verdict = result.first_verdict.get(near[0].id)
            pulses += verdict is not None and verdict.pulse is True
    assert found >= 2 * len(SEEDS), found  # the detector finds them (30 of 36 seen)
    assert pulses >= MID_SLIP_PULSE_SHARE * found, (pulses, found)


def test_the_stop_of_the_headline_slip_is_a_step_at_its_first_verdict(told):
    """The level steps when the object sticks and rises on with the reflex's grip: no pulse
    falling back (11 of 12 seeds before the fix: one told a pulse)."""
    for rec, result in told:
        near = [e for e in result.contacts if abs(e.t_s - HEADLINE_STOP_S) <= 0.01]
        assert near, [round(e.t_s, 3) for e in result.contacts]
        verdict = result.first_verdict.get(near[0].id)
        assert verdict is not None and verdict.pulse is False, (verdict, near[0])
        # told within the hold (0.1 s) and a little: soon enough for the stop report
        assert verdict.emit_index / rec.fs_hz - near[0].t_s <= 0.12


def test_a_stop_on_the_falling_tail_of_a_short_spacings_pulse_is_a_step():
    """uniform4 at 12 mm/s, reversed, stopping where the next 4 mm ridge was due
    (slip_reporting's stop case, seed 96011): the level relaxes on with the last pulse's
    tail, which the slip-fall rule read as a pulse falling back (told a pulse before)."""
    from grasplink.evaluation import slip_reporting as sr
    from grasplink.evaluation.contact_truth import stick_time_s

    layout = "uniform4"
    label, numbers = sr.VARIANTS["stop"][0]
    rec = sr.Case("stop", label, numbers, layout, True, 96011).make()
    stop = stick_time_s(rec.truth)
    assert stop is not None
    result = detect(rec.t_s, rec.force_n, rec.fs_hz)
    near = [e for e in result.contacts if abs(e.t_s - stop) <= 0.01]
    assert near, [round(e.t_s - stop, 3) for e in result.contacts]
    verdict = result.first_verdict.get(near[0].id)
    assert verdict is not None and verdict.pulse is False, (verdict, near[0])


def test_a_stop_rising_from_a_tail_still_falling_under_its_onset_is_a_step_at_the_hold():
    """stick-slip at 118 mm/s over alpha0.1 (slip_reporting's seed 80220): the first stop's
    step rises 0.14 N from the trough the last pulse's tail fell to, only 0.05 N over the
    level the watch takes as its base (the tail still falling before the onset): measured
    from that base it is too small for a step and told unclear a second later. Measured
    from the trough (`WatchSettings.tail_trough`, off by default: the tracker still takes
    the step for the ridge then due, so it cleared no more stops, full plan, 2 seeds) it
    is a step at the hold."""
    from grasplink.decoding.contacts import ContactDetector, DetectorSettings, WatchSettings
    from grasplink.evaluation import slip_reporting as sr

    label, numbers = sr.VARIANTS["stick-slip"][2]
    assert label == "118 mm/s"
    rec = sr.Case("stick-slip", label, numbers, "alpha0.1", False, 80220).make()
    stop = next(s for s, _ in ns.motion(rec.truth).stops)
    settings = DetectorSettings(watch=WatchSettings(tail_trough=True))
    detector = ContactDetector(rec.fs_hz, settings)
    contacts, first = [], {}
    for i in range(0, len(rec.t_s), 3):
        events, checks = detector.feed(rec.t_s[i : i + 3], rec.force_n[i : i + 3])
        contacts += events
        for check in checks:
            first.setdefault(check.id, check)
    near = [e for e in contacts if abs(e.t_s - stop) <= 0.01]
    assert near, [round(e.t_s - stop, 3) for e in contacts]
    verdict = first.get(near[0].id)
    assert verdict is not None and verdict.pulse is False, (verdict, near[0])
    assert verdict.emit_index / rec.fs_hz - near[0].t_s <= 0.12

"""A tail kink's time (`detector.tail_onsets`): the kink bank's hinge peak lies late on a
falling tail, so a tail kink's contact is moved back and its one-sigma widened to what
was measured. Judged against the true onsets: late, overconfident contacts read as a
spacing that does not fit (a 3-4 mm pair taken as one spacing twice; a braking slip's
speed misread, `test_tracker_braking` fibonacci-75101 at 8.7 % before)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from grasplink.decoding.contacts import ContactDetector, DetectorSettings, HingeSettings
from grasplink.decoding.detector.tail_kinks import ON_RESIDUAL_Z, TailKinkSettings
from grasplink.decoding.detector.tail_onsets import SPREAD_SHARE, tail_placed
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

ON = DetectorSettings(hinges=HingeSettings(tails=TailKinkSettings(residual_z=ON_RESIDUAL_Z)))
OFF = DetectorSettings(hinges=HingeSettings(tails=replace(TailKinkSettings(), residual_z=0.0)))
LAYOUTS = ("alpha0.1", "alpha0.3", "fibonacci", "uniform4")
SPEEDS_MM_S = (12.0, 20.0, 35.0, 57.0)  # (slow slips: coarse scales, the late peaks)
SEEDS = (7, 8, 9)  # (not the benchmarks' seeds 1-2)
MATCH_S = 0.08  # a tail contact's true onset: the nearest within this
# measured on this set (moved back and widened / the kink bank's own time, LATE_SHARE and
# SPREAD_SHARE 0): median offset -0.5 / +12.7 ms, within 2 sigma 53 of 62 / 19 of 46
MEDIAN_MAX_S = 0.006
WITHIN_2_SIGMA_MIN = 0.8


def _tail_contacts() -> list[tuple[float, float]]:
    """(time - true onset, sigma) of every contact the tail test adds on the set."""
    out = []
    for name in LAYOUTS:
        for speed in SPEEDS_MM_S:
            for reverse, seed in ((r, s) for r in (False, True) for s in SEEDS):
                rec = synth.slip_recording(LAYOUTS_MM[name], speed, reverse=reverse, seed=seed)
                truth = np.asarray(rec.contact_times_s)
                on, _ = ContactDetector(rec.fs_hz, ON).feed(rec.t_s, rec.force_n)
                off, _ = ContactDetector(rec.fs_hz, OFF).feed(rec.t_s, rec.force_n)
                ids_off = {(e.emit_index, e.z) for e in off}
                for e in on:
                    if (e.emit_index, e.z) in ids_off:
                        continue  # (a contact the rise check passes: timed as before)
                    d = e.t_s - truth
                    j = int(np.argmin(np.abs(d)))
                    if abs(d[j]) <= MATCH_S:
                        out.append((float(d[j]), e.sigma_s))
    return out


def test_tail_contacts_are_timed_at_their_onsets_within_their_sigma():
    rows = np.array(_tail_contacts())
    assert len(rows) >= 20, len(rows)
    offsets, sigmas = rows[:, 0], rows[:, 1]
    assert abs(float(np.median(offsets))) <= MEDIAN_MAX_S, np.median(offsets)
    assert float(np.mean(np.abs(offsets) <= 2.0 * sigmas)) >= WITHIN_2_SIGMA_MIN, rows


@pytest.mark.parametrize("placed", [4, 16])
def test_a_tail_kink_is_moved_back_and_widened_by_its_finding_scale(placed):
    n, delta, wide = tail_placed(1000, 0.2, placed, 32)
    assert n + delta == pytest.approx(1000.2 - 0.4 * 32)
    assert 0.25 * wide + 0.3 == pytest.approx(max(0.25 * placed + 0.3, SPREAD_SHARE * 32))
    assert -0.5 <= delta <= 0.5

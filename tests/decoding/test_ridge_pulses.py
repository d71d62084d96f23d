"""The kink each ridge's pulse makes at its onset (`decoding.ridge_pulses`, issue 22:
constant speed missing from the 3rd contact on alpha0.3).

A ridge's pulse starts on the previous one's tail (thesis ch. 5.3.1), so how visible its
contact is depends on the pulse before it, not on the spacing before alone: the 4 mm
ridge after alpha0.3's first (found ~35 % of the time, benchmarks/detector_contacts.py
--spacings) is no 4 mm ridge after a 3 mm one (found ~99 %), and a 3 mm ridge after the
48 mm gap makes no kink at all. `detector_contacts.py --spacings` tables the true
contacts by it (`contact_truth.onset_kinks_met`)."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding.ridge_pulses import onset_kinks, pulse_heights
from grasplink.evaluation.contact_truth import onset_kinks_met, ridges_met
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

ALPHA03 = LAYOUTS_MM["alpha0.3"]  # (4, 3, 48, 29)


def test_a_pulse_grows_with_the_spacing_before_it():
    heights = pulse_heights(np.array([3.0, 4.0, 10.0, 48.0]))
    assert np.all(np.diff(heights) > 0)
    assert heights[2] == pytest.approx(1.0 - np.exp(-1.0))


def test_a_short_spacing_after_a_tall_pulse_hides_the_ridge():
    length = float(sum(ALPHA03))
    forward = onset_kinks(np.array([length, *ALPHA03]))
    backward = onset_kinks(np.array([length, *ALPHA03[::-1]]))
    assert forward[0] == pytest.approx(pulse_heights(np.array([length]))[0])  # nothing before
    assert forward[1] < 0.1  # 4 mm after the first ridge's tall pulse
    assert backward[4] > 0.2  # 4 mm after a 3 mm ridge's small one
    assert backward[3] < 0.0  # 3 mm after the 48 mm gap: the old pulse still falls faster
    assert min(forward[3], backward[2]) > 0.9  # after a long gap: a full pulse


@pytest.mark.parametrize("before", [[], [[4.0, 3.0]], [84.0, 0.0], [84.0, -3.0]])
def test_kinks_need_positive_spacings(before):
    with pytest.raises(ValueError, match="spacings before each ridge"):
        onset_kinks(np.array(before))


def test_each_true_contact_is_keyed_by_its_ridge_and_kink():
    """Forward over alpha0.3 the contacts meet ridges 0-4 in order, backward 4-0; their
    kinks are the layout's in travel order (the skin's length before the first)."""
    length = float(sum(ALPHA03))
    for reverse in (False, True):
        rec = synth.slip_recording(ALPHA03, 20.0, reverse=reverse, seed=3)
        met = ridges_met(rec)
        order = [4, 3, 2, 1, 0] if reverse else [0, 1, 2, 3, 4]
        assert [i for i, _ in met] == order
        assert {way for _, way in met} == {-1 if reverse else 1}
        spacings = ALPHA03[::-1] if reverse else ALPHA03
        expected = onset_kinks(np.array([length, *spacings]))
        assert onset_kinks_met(rec) == pytest.approx(list(expected))

"""The loop benchmark kind's open-loop physics (`contact_truth.loop_recording`)."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.evaluation.contact_truth import loop_recording
from grasplink.profiles.layouts import LAYOUTS_MM

LAYOUT = tuple(LAYOUTS_MM["alpha0.1"])


@pytest.mark.parametrize("sign", [1, -1])
def test_an_object_beyond_either_end_leaves_the_skin_empty_until_it_moves_on(sign):
    """Before the pull the object lies 8 mm beyond the end it enters from: nothing on the
    skin. Reversed, the FSR model was told the forward direction, so it counted the object
    as covering the skin (4.4 N) until it moved."""
    start_mm = -8.0 if sign > 0 else sum(LAYOUT) + 8.0
    speed = [[0, 0], [1.0, 0], [1.001, 40 * sign], [2.5, 40 * sign], [2.501, 0]]
    rec = loop_recording(LAYOUT, speed, start_mm, [[0, 5], [3, 5]], seed=1, duration_s=2.0)
    before = rec.force_n[rec.t_s < 0.9]
    assert np.mean(before) < 0.2

"""The tracker's hypothesis set stays bounded on an endless stream of grasp-slip-release cycles."""

from __future__ import annotations

import numpy as np

from grasplink.decoding.registry import make_decoder
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth


def test_hypotheses_stay_bounded_over_many_slips_without_a_gap():
    layout = LAYOUTS_MM["alpha0.1"]
    slip = synth.slip_recording(layout, 60.0, seed=1).force_n
    rest = np.full(320, slip[0]) + np.random.default_rng(0).normal(0, 0.02, 320)
    cycle = np.concatenate([slip, rest])  # no time gap: the decoder is never reset
    decoder = make_decoder("tracker", layout, 400)
    sizes = []
    for k in range(30):
        t = (k * len(cycle) + np.arange(len(cycle))) / 400.0
        decoder.feed(t, cycle)
        sizes.append(len(decoder._tracks))
    # Every contact ever seen used to keep tracks alive: 686 after 20 cycles, growing.
    assert max(sizes[10:]) <= max(sizes[:10]) + 10
    assert max(sizes) < 200

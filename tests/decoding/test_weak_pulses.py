"""Noise that crosses the kink threshold falls back like a pulse, but stands only a few
white-noise units high; a ridge pulse stands far higher (issue 22 item 3: no false slip
on a held object). The detector tells each pulse's height in noise units
(`PulseCheck.height_snr`); the tracker takes a pulse under `WEAK_PULSE_SNR` for no
evidence of a slip."""

from __future__ import annotations

import numpy as np

from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation.contact_truth import MATCH_S, detect
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators.synth import scripted_recording

ALPHA = tuple(LAYOUTS_MM["alpha0.1"])


def held(duration_s: float, seed: int):
    """An object at rest over all of alpha0.1, 5 N grip, thesis-like noise and drift."""
    start_mm = float(sum(ALPHA)) + ns.LEAD_MM
    return scripted_recording(
        ALPHA, [[0.0, 0.0]], start_mm=start_mm, duration_s=duration_s, seed=seed
    )


def test_noise_pulses_on_a_held_object_stand_under_the_weak_pulse_bar():
    """Ten minutes held (the held tests' seed): the noise contacts told pulses stand
    1.9-2.4 noise units high (before: their verdict counted like a ridge pulse's)."""
    rec = held(600.0, seed=60)
    told = detect(rec.t_s, rec.force_n, rec.fs_hz, chunk=256)
    heights = [v.height_snr for v in told.first_verdict.values() if v.pulse is True]
    assert len(heights) >= 2, heights
    assert all(h is not None and h < TrackerDecoder.WEAK_PULSE_SNR for h in heights), heights


def test_ridge_pulses_of_a_slow_slip_stand_far_above_the_bar():
    """A 10 mm/s slip over alpha0.1 in the same noise: every ridge contact found and told
    a pulse stands well above the bar, the slip's first two by far."""
    skin_mm = float(sum(ALPHA))
    speed = [[0.0, 0.0], [0.3, 0.0], [0.32, 10.0], [0.32 + (skin_mm + 12) / 10.0, 10.0]]
    rec = scripted_recording(ALPHA, speed, start_mm=-6.0, duration_s=speed[-1][0], seed=61)
    told = detect(rec.t_s, rec.force_n, rec.fs_hz)
    truth = np.sort(rec.contact_times_s)
    ridge = []
    for e in told.contacts:
        v = told.first_verdict.get(e.id)
        if v is not None and v.pulse is True and np.min(np.abs(truth - e.t_s)) <= MATCH_S:
            ridge.append(v.height_snr)
    assert len(ridge) >= 4, ridge
    assert all(h is not None and h >= 2 * TrackerDecoder.WEAK_PULSE_SNR for h in ridge), ridge
    assert min(ridge[:2]) >= 10.0, ridge

"""A stop's step on an earlier ridge pulse's rise, judged with that pulse's course out
(`detector.pulse_under`, `WatchSettings.pulse_under_step`)."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding.contacts import ContactDetector, DetectorSettings
from grasplink.decoding.detector import pulse_under
from grasplink.decoding.detector.events import PulseCheck
from grasplink.decoding.detector.watch import WatchSettings

FS_HZ = 400.0
RISE_S = 0.03  # the earlier pulse's rise (onset to peak): a ridge at ~40 mm/s
GAP_S = 0.035  # the second event this long after it: on its rise, before its peak


def _thesis_pulse(t_s: np.ndarray, onset_s: float, height_n: float, start_n: float = 0.0):
    """Thesis ch. 5.3.1's segment from `onset_s`: from `start_n` to `height_n` at RISE_S,
    then height u e^(1 - u); 0 before."""
    u = np.maximum(t_s - onset_s, 0.0) / RISE_S
    g = u * np.exp(1.0 - u)
    return np.where(u < 1.0, start_n + (height_n - start_n) * g, height_n * g) * (u > 0)


def _signal(second: str) -> tuple[np.ndarray, np.ndarray]:
    """A 0.5 N ridge pulse at 1.0 s on a flat 1 N level, then GAP_S later a stop (its
    pulse runs on in time, a 0.15 N step adds: thesis ch. 4.3, 5.3.1) or a ridge (a 0.5 N
    pulse that replaces the first from its value)."""
    t_s = np.arange(int(2.5 * FS_HZ)) / FS_HZ
    first = _thesis_pulse(t_s, 1.0, 0.5)
    at = 1.0 + GAP_S
    if second == "stop":
        force = first + 0.15 * np.clip((t_s - at) / 0.008, 0.0, 1.0)
    else:
        start = float(_thesis_pulse(np.array([at]), 1.0, 0.5)[0])
        force = np.where(t_s < at, first, _thesis_pulse(t_s, at, 0.5, start))
    force = 1.0 + force + np.random.default_rng(3).normal(0.0, 0.003, len(t_s))
    return t_s, force


def _verdict_at(second: str, on: bool) -> bool | None:
    """The pulse verdict of the contact nearest the second event."""
    return _check_at(second, on).pulse


def _check_at(second: str, on: bool) -> PulseCheck:
    """The pulse check of the contact nearest the second event."""
    t_s, force = _signal(second)
    detector = ContactDetector(FS_HZ, DetectorSettings(watch=WatchSettings(pulse_under_step=on)))
    events, checks = [], []
    for i in range(0, len(t_s), 4):
        ev, ck = detector.feed(t_s[i : i + 4], force[i : i + 4])
        events += ev
        checks += ck
    at = 1.0 + GAP_S
    near = [e for e in events if abs(e.t_s - at) < 0.01]
    assert near, f"no contact at {at} s: {[round(e.t_s, 3) for e in events]}"
    told = [c for c in checks if c.id == near[0].id]
    assert len(told) == 1, f"the contact judged {told}"
    return told[0]


def test_stop_on_pulse_rise_is_a_step_with_its_course_out() -> None:
    """The stop's step rides the earlier pulse's rise and falls back with its decay: the
    watch alone tells a pulse; with that pulse's course out it stays up - a step."""
    assert _verdict_at("stop", False) is True
    check = _check_at("stop", True)
    assert check.pulse is False
    assert check.under  # the tracker reads its shape as a stop's (`TrackerDecoder._step_shape`)


def test_ridge_on_pulse_rise_is_no_step() -> None:
    """A ridge contact there replaces the earlier pulse and decays with it: with the
    course out the rise still falls back, and the verdict stays the watch's own (here
    unclear at the watch's end: the earlier rise taken out as a trend)."""
    off = _verdict_at("ridge", False)
    assert off is not False
    assert _verdict_at("ridge", True) is off


def test_fit_recovers_a_pulse_from_its_rise() -> None:
    """Height and rise fitted over the level from the onset to before the peak (a 10 ms
    moving mean), as the watch has them at a second onset on the rise."""
    half = 2
    offsets = np.arange(-half, round(0.8 * RISE_S * FS_HZ))
    level = 0.5 * pulse_under.smoothed(offsets, RISE_S * FS_HZ, half)
    course = pulse_under.fit(level, offsets, half, FS_HZ)
    assert course is not None
    assert course.height == pytest.approx(0.5, rel=0.1)
    assert course.rise / FS_HZ == pytest.approx(RISE_S, rel=0.15)


def test_no_fit_without_samples_or_rise() -> None:
    offsets = np.arange(2)
    assert pulse_under.fit(np.ones(2), offsets, 0, FS_HZ) is None  # too few samples
    flat = np.arange(10)
    assert pulse_under.fit(-np.ones(10), flat, 0, FS_HZ) is None  # no rise: height 0

"""A step beyond doubt (sharp, tall, flat: `contacts.sharp_flat_step`) is told at the sure
hold, half the step hold, and the tracker takes it as no ridge the slip went on from: a
stop right where the next ridge was due is told within issue 22's 0.15 s of becoming
observable, not by the silence after the ridge after it."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding.contacts import ContactDetector
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

FS_HZ = 400.0
ONSET_S = 0.8


def told(x: np.ndarray) -> list:
    """The detector's verdicts on the contact nearest ONSET_S, fed 3 samples at a time."""
    t = np.arange(len(x)) / FS_HZ
    detector = ContactDetector(FS_HZ)
    events, checks = [], []
    for i in range(0, len(x), 3):
        ev, ck = detector.feed(t[i : i + 3], x[i : i + 3])
        events += ev
        checks += ck
    near = [e for e in events if abs(e.t_s - ONSET_S) <= 0.02]
    assert near, [round(e.t_s, 3) for e in events]
    return [c for c in checks if c.id == near[0].id]


def held(seed: int) -> np.ndarray:
    t = np.arange(0.0, 2.0, 1.0 / FS_HZ)
    return 2.0 + 0.01 * np.random.default_rng(seed).standard_normal(len(t))


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_sharp_tall_step_is_told_a_sure_step_half_the_hold_after_its_onset(seed):
    """0.3 N (30 noise units) in 5 ms that stays: told a step 0.05 s after its onset (plus
    the level filter's half width), marked sure; it was told at the 0.1 s hold."""
    t = np.arange(0.0, 2.0, 1.0 / FS_HZ)
    x = held(seed) + 0.3 * np.clip((t - ONSET_S) / 0.005, 0.0, 1.0)
    first = told(x)[0]
    detector = ContactDetector(FS_HZ)
    assert first.pulse is False and first.sure
    onset = round(ONSET_S * FS_HZ)
    assert first.emit_index <= onset + detector.watcher.sure_hold + detector.watcher.level_half + 2


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_ridge_pulse_held_up_by_hysteresis_is_no_sure_step(seed):
    """A ridge pulse on a hysteretic skin: 0.3 N rising over 20 ms, then falling only 15 %
    in 0.3 s. It may be told a step at the hold, never a sure one (its rise is slow)."""
    t = np.arange(0.0, 2.0, 1.0 / FS_HZ)
    u = np.clip((t - ONSET_S) / 0.02, 0.0, 1.0)
    fall = np.clip((t - ONSET_S - 0.02) / 0.3, 0.0, 1.0)
    x = held(seed) + 0.3 * u * (1.0 - 0.15 * fall)
    assert not any(c.sure for c in told(x))


# stops right where the next ridge was due (observable within 15 ms of the stop): the stop's
# step came at the due ridge's time and was taken for it (cleared 0.186 and 0.153 s after
# observable before the sure step); label, variant index, layout, reverse, seed (`sr.cases`)
DUE_RIDGE_STOPS = [
    ("stop", 1, "uniform4", False, 96_100),
    ("stick-slip", 0, "uniform4", False, 86_000),
]


@pytest.mark.parametrize("kind,variant,layout,reverse,seed", DUE_RIDGE_STOPS)
def test_a_stop_where_the_next_ridge_was_due_is_told_within_0_15_s(
    kind, variant, layout, reverse, seed
):
    label, numbers = sr.VARIANTS[kind][variant]
    rec = sr.Case(kind, label, numbers, layout, reverse, seed).make()
    decoder = sr.build_decoder("tracker", rec.truth.layout_mm, rec.fs_hz, {})
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    judged = [s for s in sr.score(estimates, rec.truth).stops if s.judged]
    assert judged
    near = [s for s in judged if abs(s.observable_s - s.start_s) <= 0.015]
    assert near, [(s.start_s, s.observable_s) for s in judged]
    assert all(s.delay_s <= sr.CLEAR_WITHIN_S for s in near), [s.delay_s for s in near]

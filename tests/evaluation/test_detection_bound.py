"""The oracle detector of the 10 dB bound (`evaluation/detection_bound.py`): its statistic
is the matched filter's (N(0, 1) on noise plus a line, the pulse's SNR on the pulse), the
scan is the same filter at every onset, and a speed needs two told, decided contacts."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.evaluation import detection_bound as db
from grasplink.evaluation.contact_truth import PulseTrain
from grasplink.simulators.effects import skin

FS_HZ = 400.0


def _train(times_s, alpha_n, rise_s, length_s: float = 2.0) -> tuple[PulseTrain, np.ndarray]:
    """A train of pulses each starting on the previous one's tail, and its samples."""
    t = np.arange(int(length_s * FS_HZ)) / FS_HZ
    x = np.zeros(len(t))
    starts, level = [], 0.0
    for i, t0 in enumerate(times_s):
        if i:
            p = i - 1
            level = float(skin.pulse(t0 - times_s[p], alpha_n[p], rise_s[p], starts[p]))
        starts.append(level)
    for i, t0 in enumerate(times_s):
        end = times_s[i + 1] if i + 1 < len(times_s) else np.inf
        seg = (t >= t0) & (t < end)
        x[seg] = skin.pulse(t[seg] - t0, alpha_n[i], rise_s[i], starts[i])
    train = PulseTrain(
        np.array(times_s, float),
        np.array(alpha_n, float),
        np.array(starts, float),
        np.array(rise_s, float),
        x,
    )
    return train, x


def test_statistic_is_the_pulses_snr_without_noise_and_ignores_a_line():
    train, x = _train([0.5, 0.8], [1.0, 0.6], [0.03, 0.03])
    line = 3.0 + 0.7 * np.arange(len(x)) / FS_HZ
    first = db.template(train, 0, FS_HZ)
    at = int(np.ceil(train.times_s[0] * FS_HZ))
    assert first.norm_n > 0
    assert db.statistic(x + line, at, first, 0.1) == pytest.approx(first.norm_n / 0.1, rel=1e-6)
    # the second starts on the first's tail: its filter reads that tail's bend as well
    second = db.template(train, 1, FS_HZ)
    at = int(np.ceil(train.times_s[1] * FS_HZ))
    k = at + second.offsets
    tail = skin.pulse(k / FS_HZ - 0.5, 1.0, 0.03, 0.0)
    want = (second.norm_n + float(second.weights @ tail)) / 0.1
    assert db.statistic(x + line, at, second, 0.1) == pytest.approx(want, rel=1e-6)


def test_statistic_on_white_noise_is_unit_normal():
    train, _ = _train([0.5], [1.0], [0.03])
    tmpl = db.template(train, 0, FS_HZ)
    rng = np.random.default_rng(5)
    x = rng.normal(0.0, 0.2, 40000) + np.linspace(-1.0, 1.0, 40000)
    stats = np.array([db.statistic(x, at, tmpl, 0.2) for at in range(100, 39800, 7)])
    assert abs(np.mean(stats)) < 0.05
    assert np.std(stats) == pytest.approx(1.0, abs=0.05)


def test_scan_is_the_bank_s_largest_statistic_at_each_onset():
    train, x = _train([0.4, 0.55, 1.1], [1.0, 0.5, 0.8], [0.02, 0.02, 0.05])
    bank = [db.template(train, i, FS_HZ) for i in range(3)]
    rng = np.random.default_rng(9)
    noisy = x + rng.normal(0.0, 0.1, len(x))
    stat = db.scan(noisy, bank, 0.1)
    for at in (60, 161, 222, 440, 700):
        want = max(db.statistic(noisy, at, t, 0.1) for t in bank)
        assert stat[at] == pytest.approx(want, rel=1e-9, abs=1e-9)
    peak = int(np.argmax(stat))  # at an onset (samples 160, 220, 440)
    assert min(abs(peak - onset) for onset in (160, 220, 440)) <= 3


def test_events_merge_crossings_closer_than_the_merge_time():
    stat = np.zeros(400)
    stat[[10, 12, 100, 101, 300]] = 5.0
    assert db.events(stat, 4.0, FS_HZ) == 3  # 10 and 12 are 5 ms apart: one
    assert db.events(stat, 6.0, FS_HZ) == 0


def test_a_speed_needs_two_told_contacts_decided_by_then():
    contacts = np.array([1.0, 2.0, 3.0, 4.0])
    told = np.array([True, False, True, True])
    decided = contacts + 0.1
    t = np.array([2.5, 3.05, 3.2, 4.2])
    assert db.speed_possible(t, contacts, told, decided).tolist() == [False, False, True, True]
    # among the last 3 only: at 4.2 the last three are 2, 3, 4 (two told)
    assert db.speed_possible(t, contacts, told, decided, last=3).tolist() == [
        False,
        False,
        True,
        True,
    ]
    told = np.array([True, False, False, True])
    assert db.speed_possible(t, contacts, told, decided).tolist() == [False] * 3 + [True]
    assert db.speed_possible(t, contacts, told, decided, last=3).tolist() == [False] * 4

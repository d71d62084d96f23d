"""A contact told a step is a stop's level change or a ridge pulse held up by the FSR's
hysteresis (`detector.step_shape`): told apart by how the samples up to the verdict
rose - a stop's fast and monotone, a held pulse's slow or past the level it holds -
at every input rate and with noise."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding.detector import step_shape as ss

ONSET_S = 0.5
VERDICT_S = 0.6  # the watcher's hold: about 0.1 s after the onset


def play(x: np.ndarray, width_n: float = 0.2) -> np.ndarray:
    """A play (backlash) operator of `width_n`: the FSR's hysteresis (thesis ch. 3.4)."""
    y, half, out = float(x[0]), width_n / 2.0, np.empty(len(x))
    for k, v in enumerate(x):
        y = min(max(y, v - half), v + half)
        out[k] = y
    return out


def verdict(x: np.ndarray, fs_hz: float) -> int:
    onset, at = round(ONSET_S * fs_hz), round(VERDICT_S * fs_hz)
    return ss.classify(ss.measure(x, onset, at, fs_hz), fs_hz)


def level(fs_hz: float, noise_n: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(0.0, 1.0, 1.0 / fs_hz)
    return t, 2.0 + noise_n * np.random.default_rng(seed).standard_normal(len(t))


@pytest.mark.parametrize("fs_hz", [100.0, 200.0, 400.0, 1000.0])
@pytest.mark.parametrize(("noise_n", "least"), [(0.005, 20), (0.02, 17)])
def test_a_stop_is_a_fast_monotone_level_change(fs_hz, noise_n, least):
    """The object sticks: the level moves 0.15 N over 5 ms of braking and stays - told so
    every time in little noise, at 7.5 noise units nearly every time."""
    told = []
    for seed in range(20):
        t, x = level(fs_hz, noise_n, seed)
        told.append(verdict(x + 0.15 * np.clip((t - ONSET_S) / 0.005, 0.0, 1.0), fs_hz))
    assert told.count(ss.STOP_LIKE) >= least, told


@pytest.mark.parametrize(
    ("fs_hz", "rise_s"), [(100.0, 0.05), (200.0, 0.025), (400.0, 0.025), (1000.0, 0.025)]
)
@pytest.mark.parametrize("noise_n", [0.005, 0.02])
def test_a_ridge_pulse_held_up_on_a_rising_level_is_no_stop(fs_hz, rise_s, noise_n):
    """A ridge pulse 0.25 N high rising over 25 ms (1.25 mm at 50 mm/s) on a level rising
    0.5 N/s (the object covering more of the sensor), read through 0.2 N of hysteresis:
    it rises and stays (a step to the watcher), but not as a stop's level does. At 100 Hz
    a rise within 2.5 samples (25 ms) cannot be told from a stop's: 50 ms (25 mm/s)."""
    for seed in (1, 2, 3):
        t, x = level(fs_hz, noise_n, seed)
        u = np.clip(t - ONSET_S, 0.0, None) / rise_s
        pulse = 0.25 * u * np.exp(1.0 - u)
        held = play(x + 0.5 * t + pulse)
        assert verdict(held, fs_hz) == ss.RIDGE_LIKE, (fs_hz, seed)


@pytest.mark.parametrize(("fs_hz", "rise_s"), [(100.0, 0.025), (200.0, 0.012)])
def test_below_227_hz_a_rise_going_on_past_its_one_sample_step_is_a_ridge(fs_hz, rise_s):
    """The same held pulse rising within the samples called fast (2.5 at 100 and 200 Hz):
    its level goes on rising after its largest one-sample step, a stop's does not -
    RIDGE_LIKE, where the rise read in whole samples alone (`read_then` False) calls it
    a stop's."""
    told, whole = [], []
    for seed in range(20):
        t, x = level(fs_hz, 0.005, seed)
        u = np.clip(t - ONSET_S, 0.0, None) / rise_s
        held = play(x + 0.5 * t + 0.25 * u * np.exp(1.0 - u))
        shape = ss.measure(held, round(ONSET_S * fs_hz), round(VERDICT_S * fs_hz), fs_hz)
        told.append(ss.classify(shape, fs_hz))
        whole.append(ss.classify(shape, fs_hz, read_then=False))
    assert told.count(ss.RIDGE_LIKE) == 20, told
    assert whole.count(ss.STOP_LIKE) == 20, whole


def test_the_rise_after_the_step_is_read_from_samples_up_to_the_verdict_only():
    """A verdict one sample past the step reads no rise after it (nothing is guessed),
    whatever the samples after the verdict do."""
    x = np.concatenate([np.full(30, 2.0), [2.3, 2.45, 2.6, 2.6]])
    step_n, then_n = ss._one_sample_step(x, 30, 30)
    assert (step_n, then_n) == (pytest.approx(0.3), 0.0)
    step_n, then_n = ss._one_sample_step(x, 30, 31)
    assert then_n == pytest.approx(0.15)
    step_n, then_n = ss._one_sample_step(x, 30, 33)
    assert then_n == pytest.approx(0.225)  # the mean of 2.45 and 2.6, less 2.3


def test_a_fast_peak_well_over_the_level_held_is_peaked_not_a_plain_stop():
    """0.4 N in 5 ms falling back to 0.2 N (its fall held halfway): a pulse held up, or a
    stop landing on a ridge's pulse - AMBIGUOUS, neither a stop's plain step nor a slow rise;
    the same rise falling back a tenth is a stop's step."""
    fs_hz = 400.0
    t, x = level(fs_hz, 0.005, 1)
    rise = np.clip((t - ONSET_S) / 0.005, 0.0, 1.0)
    fall = np.clip((t - ONSET_S - 0.005) / 0.02, 0.0, 1.0)
    assert verdict(x + 0.4 * rise * (1.0 - 0.5 * fall), fs_hz) == ss.AMBIGUOUS
    assert verdict(x + 0.4 * rise * (1.0 - 0.1 * fall), fs_hz) == ss.STOP_LIKE


def test_a_jump_off_a_falling_tail_to_a_level_under_it_is_peaked():
    """A stop on a ridge pulse's falling tail (stop kind, 12 mm/s): the level jumps 0.27 N
    within a sample and relaxes while the tail under it falls on, to a level held below
    the median of the 60 ms before - no rise above that base, but a jump off the tail's
    base carried to the onset: AMBIGUOUS (a stop on a pulse, or a pulse), not a slow ridge
    rise. The same tail with no jump is no stop."""
    fs_hz = 400.0
    t, x = level(fs_hz, 0.005, 1)
    tail = 0.3 * np.exp(-(t - ONSET_S + 0.2) / 0.08) * (t > ONSET_S - 0.2)
    after = np.clip(t - ONSET_S, 0.0, None)
    jump = 0.27 * (t > ONSET_S) * np.exp(-after / 0.03)
    assert verdict(x + tail + jump, fs_hz) == ss.AMBIGUOUS
    assert verdict(x + tail, fs_hz) == ss.RIDGE_LIKE


def test_a_level_no_higher_than_before_is_no_stop():
    fs_hz = 400.0
    t, x = level(fs_hz, 0.005, 1)
    assert verdict(x - 0.1 * (t > ONSET_S), fs_hz) == ss.RIDGE_LIKE


def test_samples_not_held_tell_nothing_and_a_bad_rate_is_named():
    fs_hz = 400.0
    _, x = level(fs_hz, 0.005, 1)
    assert ss.measure(x, 5, 60, fs_hz) is None  # no level before the onset
    assert ss.measure(x, 200, len(x), fs_hz) is None  # the verdict's sample not held
    x[198] = np.nan
    assert ss.measure(x, 200, 240, fs_hz) is None
    assert ss.classify(None, fs_hz) == ss.UNTOLD
    with pytest.raises(ValueError, match="sample rate"):
        ss.measure(x, 200, 240, 0.0)


@pytest.mark.parametrize("chunk", [1, 3, 7, 400])
def test_recent_samples_tell_a_late_verdict_by_the_rise_however_chunked(chunk):
    """A verdict told 0.5 s after its onset (a revision) is read on the rise it told of;
    one told long after `RECENT_S` (at least that long is held) finds its samples gone:
    untold, never guessed."""
    fs_hz = 400.0
    _, x = level(fs_hz, 0.005, 1)
    x = np.concatenate([x, x, x])  # 3 s
    x[round(ONSET_S * fs_hz) :] += 0.15  # a stop's step ...
    onset = round(ONSET_S * fs_hz)
    x[onset + 120 :] += 0.5  # ... and a slow grip rise long after it
    recent = ss.Recent(fs_hz)
    told = {}
    for i in range(0, len(x), chunk):
        recent.append(x[i : i + chunk])
        n = min(i + chunk, len(x))
        for late in (40, 200, 900):
            if onset + late < n and late not in told:
                told[late] = recent.verdict(onset, onset + late)
    assert told == {40: ss.STOP_LIKE, 200: ss.STOP_LIKE, 900: ss.UNTOLD}
    with pytest.raises(ValueError, match="sample rate"):
        ss.Recent(0.0)

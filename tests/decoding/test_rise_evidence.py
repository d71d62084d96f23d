"""Soft evidence of the ridges a track skips or finds due (`decoding.rise_evidence`).

A sub-threshold ridge pulse (under the detector's threshold, as 10 dB SNR leaves half of
them) still shows as a rise where a track predicts it; flat noise does not. In a clean
signal nothing changes (the gate and the floor at log(1 - DETECT_P)); bad input gives no
evidence rather than a false one, or a clear error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasplink.decoding import rise_evidence as rev
from grasplink.decoding.detector.step_shape import Recent
from grasplink.decoding.ridge_pulses import RISE_MM
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.simulators.synth import slip_recording

FS_HZ = 400.0
SPEED_MM_S = 57.0  # the snr10 kind's
LOG_MISS = math.log(1.0 - 0.99)  # the tracker's penalty for a missed ridge after 5+ mm


def _evidence(x: np.ndarray, white_n: float = 1.0) -> rev.RiseEvidence:
    recent = Recent(FS_HZ)
    recent.append(x)
    return rev.RiseEvidence(FS_HZ, recent, lambda block: (white_n, 8), 50, 1e-3)


def _pulse(n: int, onset: int, height: float) -> np.ndarray:
    """A ridge pulse (u e^(1 - u), u the travel since the onset over RISE_MM) at 57 mm/s."""
    u = np.clip((np.arange(n) - onset) / FS_HZ * SPEED_MM_S / RISE_MM, 0.0, None)
    return height * u * np.exp(1.0 - u)


def _z(seed: int, height: float, at: int = 200) -> float:
    rng = np.random.default_rng(seed)
    x = rng.standard_normal(400) + _pulse(400, 200, height)
    ev = _evidence(x)
    width = ev.width_for(np.array([SPEED_MM_S]))
    return float(ev.z_at(np.array([float(at)]), width, 400)[0])


def test_sub_threshold_pulse_stands_apart_from_flat_noise():
    # a pulse 2.5 noise units high: under the probe's 4.5-unit threshold at its median
    seeds = range(40)
    pulse = np.array([_z(s, 2.5) for s in seeds])
    flat = np.array([_z(s, 0.0) for s in seeds])
    assert np.median(pulse) < rev.TOLD_Z  # sub-threshold: the detector would not tell it
    median_h = 5.0  # the told pulses' (10 dB: 5-7 units)
    gain_pulse = rev.skip_score(pulse, median_h, np.full(40, LOG_MISS), 0.3)
    gain_flat = rev.skip_score(flat, median_h, np.full(40, LOG_MISS), 0.3)
    # a ridge where the track predicts one: evidence for; flat noise: against
    assert np.mean(gain_pulse) > 0.5
    assert np.mean(gain_flat) < -1.0
    assert np.mean(gain_pulse) - np.mean(gain_flat) > 2.0
    # ... read at the predicted onset: 40 ms off, the same pulse tells little
    off = np.array([_z(s, 2.5, at=216) for s in seeds])
    assert np.median(off) < 0.5 * np.median(pulse)


def test_flat_place_in_clean_signal_keeps_the_detector_penalty():
    # told pulses 30 units high and nothing at the predicted time: as sure as DETECT_P
    z = np.array([-1.0, 0.0, 1.0])
    assert np.array_equal(rev.skip_score(z, 30.0, np.full(3, LOG_MISS)), np.full(3, LOG_MISS))
    # a rise as high as a told one is another contact's: no evidence either way
    assert rev.skip_score(np.array([6.0]), 5.0, np.array([LOG_MISS]))[0] == LOG_MISS
    # and a gain is bounded
    assert rev.skip_score(np.array([4.0]), 5.0, np.array([LOG_MISS]))[0] == rev.CLIP


def test_clean_slip_decodes_bit_for_bit_with_the_evidence_on():
    rec = slip_recording((4.0, 3.0, 48.0, 29.0), 22.0, seed=3)  # alpha0.3, clean

    def decode(tuning: dict) -> list:
        decoder = TrackerDecoder([4.0, 3.0, 48.0, 29.0], rec.fs_hz, tuning=tuning)
        out = []
        for i in range(0, len(rec.t_s), 3):
            out += decoder.feed(rec.t_s[i : i + 3], rec.force_n[i : i + 3])
        return [(e.t_s, e.slip, e.speed_mm_s, e.position_mm, e.confidence) for e in out]

    plain = decode({"RISE_EVIDENCE": 0.0})
    assert any(s for _, s, *_ in plain)  # a slip decoded
    assert decode({"RISE_EVIDENCE": 1.0, "RISE_H_LOW": 0.3}) == plain


def test_evidence_gate_opens_only_for_weak_told_pulses():
    ev = _evidence(np.zeros(100))
    assert not ev.blind(10.0)  # none told
    for k, height in enumerate((30.0, 40.0, 35.0)):
        ev.note_height(k, height)
    assert not ev.blind(10.0)
    for k, height in enumerate((4.0, 5.0, 6.0, 3.0), start=3):
        ev.note_height(k, height)
    assert ev.blind(10.0)
    ev.note_height(99, math.nan)  # ignored
    ev.note_height(100, None)
    assert ev.blind(10.0)


def test_bad_input_gives_no_evidence_or_a_clear_error():
    rng = np.random.default_rng(5)
    x = rng.standard_normal(400) + _pulse(400, 200, 2.5)
    x[210] = np.nan
    ev = _evidence(x)
    width = ev.width_for(np.array([SPEED_MM_S]))
    # a NaN sample in the windows read: no evidence (NaN), scored as the plain miss
    z = ev.z_at(np.array([200.0]), width, 400)
    assert np.isnan(z[0])
    assert rev.skip_score(z, 5.0, np.array([LOG_MISS]))[0] == LOG_MISS
    clean = _evidence(rng.standard_normal(400))
    # times outside the samples held, or after the decision index, or not finite: NaN
    for onset, before in ((-500.0, 400), (2000.0, 400), (200.0, 210), (math.nan, 400)):
        assert np.isnan(clean.z_at(np.array([onset]), width, before)[0])
    # no noise known yet: NaN
    unknown = rev.RiseEvidence(FS_HZ, clean.recent, lambda block: None, 50, 1e-3)
    assert np.isnan(unknown.z_at(np.array([200.0]), width, 400)[0])
    with pytest.raises(ValueError, match="median z"):
        rev.log_ratio(np.array([1.0]), 0.0)
    with pytest.raises(ValueError, match="median z"):
        rev.log_ratio(np.array([1.0]), math.nan)
    with pytest.raises(ValueError, match="low end"):
        rev.log_ratio(np.array([1.0]), 5.0, h_low=3.0)
    with pytest.raises(ValueError, match="sample rate"):
        rev.RiseEvidence(0.0, clean.recent, lambda block: None, 50, 1e-3)


def test_each_onset_reads_the_same_z_to_the_bit_read_together_or_alone():
    # `silence` reads every due ridge in one call (`z_each`): each z must be the one a
    # call with that onset alone gives, whatever else is read with it (replays, chunking)
    rng = np.random.default_rng(11)
    x = 1e3 + rng.standard_normal(800) + _pulse(800, 300, 2.5)  # a level: rounding shows
    x[700] = np.nan
    ev = _evidence(x)
    widths = ev.width_for(np.array([10.0, 57.0, 118.0, 57.0, 22.0, 57.0, 57.0, 57.0]))
    onsets = np.array([120.0, 300.0, 310.5, -900.0, 450.0, math.nan, 690.0, 785.0])
    together = ev.z_each(onsets, widths, 790)
    alone = np.array(
        [ev.z_at(onsets[k : k + 1], widths[k : k + 1], 790)[0] for k in range(len(onsets))]
    )
    assert np.array_equal(together, alone, equal_nan=True)
    assert np.isfinite(together[[0, 1, 2, 4]]).all()  # read
    assert np.isnan(together[[3, 5, 6, 7]]).all()  # not held, not finite, a NaN sample read
    # one median per z: the numbers of one call per median
    z, medians = np.array([0.5, 2.5, 3.0, -1.0]), np.array([5.0, 5.0, 2.0, 8.0])
    each = [rev.log_ratio(z[k : k + 1], float(medians[k]))[0] for k in range(len(z))]
    assert np.array_equal(rev.log_ratio(z, medians), np.array(each))
    with pytest.raises(ValueError, match="median z"):
        rev.log_ratio(z, np.array([5.0, 0.0, 2.0, 8.0]))

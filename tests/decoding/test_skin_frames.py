"""The one front end from skin TPDO values to timed samples in newtons (decoding.skin_frames)."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from grasplink.decoding.io import skin_tpdo
from grasplink.decoding.skin_frames import (
    SEQUENCE_KEY,
    SampleObjects,
    SkinCalibration,
    SkinFrames,
)
from grasplink.errors import ConfigError
from grasplink.profiles import objects as obj

SLOT = obj.SKIN_SAMPLE_SLOTS


@pytest.mark.parametrize(
    ("bits", "zero", "needle"),
    [(12, 4095, "not below full scale"), (12, 5000, "not below full scale"), (0, 0, "ADC bits")],
)
def test_a_degenerate_calibration_is_refused_by_name(bits, zero, needle):
    with pytest.raises(ConfigError, match=needle):
        SkinCalibration(bits, 98067.0, zero)


def test_counts_become_newtons_from_the_zero_offset_to_full_scale():
    calibration = SkinCalibration(12, 98067.0, 95)
    newtons = SampleObjects.of_skin(calibration, 3).to_newton(np.array([95, 4095, 0]))
    assert newtons[0] == 0.0
    assert newtons[1] == pytest.approx(98.067, rel=1e-12)
    assert newtons[2] < 0  # below the offset: a negative force, not a wrapped count
    low_mn, high_mn = calibration.static_force_range_mn()
    assert low_mn < newtons[2] * 1e3 and high_mn > 98067.0


def test_a_tpdo_without_sample_slots_gives_no_samples_and_counts_no_packet():
    frames = SkinFrames(SampleObjects.of_skin(SkinCalibration(12, 98067.0, 0), 3), 400.0)
    t_s, force_n = frames.feed(0, {(obj.SKIN_STATIC_FORCE_MN, 0): 1200})
    assert len(t_s) == len(force_n) == 0
    assert frames.stats.packets == 0


def test_frames_unpacked_by_the_eds_mapping_become_samples_on_the_sequence_grid():
    pdo = skin_tpdo()
    assert pdo.codec.tpdo_keys(pdo.cob_id)[:3] == ((SLOT, 1), (SLOT, 2), (SLOT, 3))
    frames = SkinFrames(SampleObjects.of_skin(pdo.calibration, pdo.samples_per_pdo), pdo.rate_hz)
    out_t, out_f = [], []
    for n in range(4):
        data = struct.pack("<HHHB", 100 * n, 100 * n + 1, 100 * n + 2, n)
        assert len(data) == pdo.length
        values = pdo.codec.decode(pdo.cob_id, data)
        assert values[SEQUENCE_KEY] == n
        t_s, force_n = frames.feed(1000 + n * 7500, values)  # 3 samples at 400 Hz: 7.5 ms
        out_t += list(t_s)
        out_f += list(force_n)
    out_t += list(frames.flush()[0])
    assert np.allclose(np.diff(out_t), 1 / 400.0)
    counts = [100 * n + k for n in range(4) for k in range(3)]
    expected = SampleObjects.of_skin(pdo.calibration, 3).to_newton(np.array(counts))
    assert out_f == list(expected[: len(out_f)])


def test_a_single_analogue_value_without_a_sequence_is_timed_by_arrival():
    """A vendor's analogue input (CiA 401 6401h) sampled on SYNC: one sample a frame, its
    units scaled to newtons, sample times on the grid its arrivals lay."""
    objects = SampleObjects(((0x6401, 1),), newtons_per_unit=0.01, zero_units=100)
    frames = SkinFrames(objects, 100.0)
    out_t, out_f = [], []
    for n in range(40):
        t_s, force_n = frames.feed(5_000 + n * 10_000, {(0x6401, 1): 100 + n})
        out_t += list(t_s)
        out_f += list(force_n)
    t_s, force_n = frames.flush()
    out_t += list(t_s)
    out_f += list(force_n)
    assert len(out_t) == 40
    assert np.allclose(np.diff(out_t), 0.01)
    assert np.allclose(out_f, 0.01 * np.arange(40))


def test_a_tpdos_counts_become_the_same_newtons_as_an_array_of_them_bit_for_bit():
    """`to_newton` takes a frame's few counts (a list) in floats: numpy's numbers exactly."""
    rng = np.random.default_rng(7)
    for zero, per_count in [(0, 98067.0 / 4095 / 1e3), (95, 0.0239), (2048.5, 1e-3 / 3)]:
        objects = SampleObjects((), per_count, zero)
        counts = [int(c) for c in rng.integers(0, 65536, 64)] + [-3, 0, 4095]
        listed = objects.to_newton(counts)
        assert listed.dtype == np.float64
        assert listed.tobytes() == objects.to_newton(np.array(counts)).tobytes()


def test_sample_times_are_numpys_tick_over_rate_plus_shift_bit_for_bit():
    """The stream times a packet's samples in floats; the same bits as numpy's arrays."""
    frames = SkinFrames(SampleObjects.of_skin(SkinCalibration(12, 98067.0, 0), 3), 400.0)
    stream = frames.stream
    got = []
    for n in range(3000):  # 22.5 s, a clock 533 ppm slow: drift corrections on
        t_s, _ = frames.feed(1000 + n * 7504 + (n % 7) * 40, {**_counts(3), SEQUENCE_KEY: n % 256})
        got.append(t_s)
    # the last packet's times as numpy makes them, from the stream's grid and shift now
    n = stream._released
    ticks = stream._tick0 + n * 3 + np.arange(3)
    assert got[-1].tobytes() == (ticks / stream.rate_hz + stream._shift_s).tobytes()
    assert stream._shift_s != 0.0


def _counts(per: int) -> dict:
    return {(SLOT, k + 1): 1000 + k for k in range(per)}

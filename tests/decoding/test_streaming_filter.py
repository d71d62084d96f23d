"""filters.SosFilter: the one streaming filter of the skin decoders.

Band-passes, the static-force low-pass and the contact detector's FIR
kernels all run through it, so a recording fed in pieces (CAN frames of 1-3
samples) decodes to the same bits as the recording fed at once.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from grasplink.decoding import filters
from grasplink.decoding.base import StaticForce
from grasplink.decoding.filters import SosFilter

DECODING = Path(filters.__file__).parent


def feed_in_pieces(f: SosFilter, x: np.ndarray, sizes: list[int]) -> np.ndarray:
    out, start, k = [], 0, 0
    while start < len(x):
        size = sizes[k % len(sizes)]
        out.append(f(x[start : start + size]))
        start += size
        k += 1
    return np.concatenate(out)


DESIGNS = {
    "band-pass 0.5-30 Hz": filters.bandpass_sos(0.5, 30.0, 400.0, order=1),
    "4th-order band-pass 0.3-3 Hz at 1 kHz": signal.butter(
        4, [0.3, 3.0], btype="bandpass", fs=1000.0, output="sos"
    ),
    "static low-pass 2 Hz": signal.butter(2, 2.0, fs=400.0, output="sos"),
}


@pytest.mark.parametrize("design", sorted(DESIGNS))
def test_pieces_of_any_size_give_the_one_shot_bits(design):
    sos = DESIGNS[design]
    x = 50.0 + np.random.default_rng(1).normal(0, 0.3, 3000)
    whole = SosFilter(sos)(x)
    reference, _ = signal.sosfilt(sos, x, zi=signal.sosfilt_zi(sos) * x[0])
    np.testing.assert_array_equal(whole, reference)  # sosfilt, settled on the first sample
    for sizes in ([1], [3], [2, 1, 3], [5, 17, 1], [1000]):
        np.testing.assert_array_equal(feed_in_pieces(SosFilter(sos), x, sizes), whole)


@pytest.mark.parametrize("design", sorted(DESIGNS))
def test_the_compiled_loop_carries_sosfilts_state_bit_for_bit(design):
    """The state after each piece is sosfilt's too (a gap's reset, a later piece)."""
    sos = DESIGNS[design]
    x = np.random.default_rng(2).normal(3.0, 1.0, 500)
    f = SosFilter(sos)
    f(x[:1])
    zi = signal.sosfilt_zi(sos) * x[0]
    _, zi = signal.sosfilt(sos, x[:1], zi=zi)
    for start in range(1, 500, 7):
        y = f(x[start : start + 7])
        reference, zi = signal.sosfilt(sos, x[start : start + 7], zi=zi)
        np.testing.assert_array_equal(y, reference)
        np.testing.assert_array_equal(f._zi, zi)


def test_an_unnormalised_section_is_refused_by_name():
    sos = np.array([[1.0, 0.0, 0.0, 2.0, 0.0, 0.0]])
    with pytest.raises(ValueError, match="a0 = 1"):
        SosFilter(sos)


@pytest.mark.parametrize("width", [2, 4, 8, 16, 32])
def test_fir_kernels(width):
    k = np.arange(width + 1, dtype=np.float64) - width / 2.0
    taps = (k / np.sum(k * k))[::-1]  # the contact detector's LS slope kernel
    x = np.random.default_rng(width).normal(7.0, 0.5, 800)
    f = SosFilter.fir(taps)
    y = feed_in_pieces(f, x, [1, 3, 12])
    direct = np.convolve(np.concatenate([np.full(width, x[0]), x]), taps, mode="valid")
    np.testing.assert_allclose(y, direct, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(y, SosFilter.fir(taps)(x))
    # settled on the first sample: a constant input has slope 0 from the start
    assert np.max(np.abs(SosFilter.fir(taps)(np.full(50, 80.0)))) < 1e-10


def test_reset_settles_again_on_the_next_sample():
    f = SosFilter(DESIGNS["static low-pass 2 Hz"])
    f(np.full(100, 1.0))
    f.reset()
    np.testing.assert_allclose(f(np.full(10, 20.0)), 20.0)


def test_static_force_runs_on_the_shared_filter():
    x = 5.0 + np.random.default_rng(3).normal(0, 0.05, 1200)
    force = StaticForce(400.0)
    sos = signal.butter(2, 2.0, fs=400.0, output="sos")
    np.testing.assert_array_equal(feed_in_pieces(force._filter, x, [3]), SosFilter(sos)(x))


def test_no_other_streaming_filter_copy_in_the_decoders():
    """Carried-state filtering lives in filters.SosFilter only (was copied three times)."""
    pattern = re.compile(r"\b(sosfilt_zi|lfilter_zi|lfilter)\s*\(|zi\s*=|\ba1\s*\*")
    offenders = []
    for path in sorted(DECODING.glob("*.py")):
        if path.name == "filters.py":
            continue
        for number, line in enumerate(path.read_text().splitlines(), start=1):
            if pattern.search(line):
                offenders.append(f"{path.name}:{number}: {line.strip()}")
    assert not offenders, offenders

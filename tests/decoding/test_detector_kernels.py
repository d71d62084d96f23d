"""The contact detector's compiled per-block path (`kernels.detector`) tells what the numpy
code it replaced told (`reference.contacts`, the numpy detector of 0858d90, run in this
process on the same samples), and scipy's lfilter for the FIR loop: to the bit.

To the bit on any CPU, not within a tolerance: the compiled path is + - * / abs and
comparisons in the numpy code's order (no exp, log, BLAS or sum of another order), which
IEEE 754 rounds alike everywhere; numba compiles without fast-math (no contraction into
fused multiply-adds) and scipy's lfilter loop is ISO C (GCC contracts none there either).
The rest of the detector (noise medians, verdict regressions) is the same Python and numpy
code in both, run in one process. The input signals are made here, so they carry this
CPU's rounding of the simulator's exp and sin into both detectors alike."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from scipy import signal

from grasplink.decoding.contacts import ContactDetector
from grasplink.decoding.filters import SosFilter, lattice_median
from grasplink.decoding.kernels.detector import (
    channel_hinge,
    fir_run,
    hinge_maxima,
    lattice_median_of,
    step_scale,
)
from tests.decoding.reference.contacts import ContactDetector as NumpyDetector

FS_HZ = 400.0
CHUNK = 3  # what a CAN frame brings (the state is compared after this chunking)
CHUNKS = (1, 3, 7, 50, 256)


def signals() -> dict[str, np.ndarray]:
    """Inputs that take every path: a slip and rest, quantised with rails, grip steps."""
    from grasplink.profiles.layouts import LAYOUTS_MM
    from grasplink.simulators import synth

    layout = LAYOUTS_MM["alpha0.1"]
    slip = synth.slip_recording(layout, 60.0, seed=1).force_n
    rest = np.full(320, slip[0]) + np.random.default_rng(0).normal(0, 0.02, 320)
    fast = synth.slip_recording(layout, 200.0, seed=2, noise_scale=2.0).force_n
    # on the lower rail first (blocks wait for a noise), ADC steps, clipped at the top
    lsb = 0.0244
    railed = np.concatenate([np.zeros(150), fast, np.full(80, fast[-1])])
    railed = np.minimum(np.round(railed / lsb) * lsb, 0.85 * float(np.max(fast)))
    steps = synth.static_recording(
        layout, [[0.0, 2.0], [1.5, 5.0], [3.0, 3.0], [4.5, 6.0]], duration_s=6.0, seed=3
    ).force_n
    slow = synth.slip_recording(layout, 25.0, seed=4, reverse=True, dips=True).force_n
    return {
        "slip": np.concatenate([slip, rest]),
        "slow": slow,
        "railed": railed,
        "steps": steps,
        "short": slip[:40],
    }


SIGNALS = signals()


def _code(value: bool | None) -> float:
    return -1.0 if value is None else float(value)


def told(detector, x: np.ndarray, chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """Contacts (all fields) and verdicts (id, emit, pulse, trend_on; None as -1), in the
    order of the sample that decided them."""
    t = np.arange(len(x)) / FS_HZ
    events, checks = [], []
    for i in range(0, len(x), chunk):
        ev, ck = detector.feed(t[i : i + chunk], x[i : i + chunk])
        events += [tuple(float(v) for v in e) for e in ev]
        checks += [
            (float(c.id), float(c.emit_index), _code(c.pulse), _code(c.trend_on)) for c in ck
        ]
    events.sort(key=lambda e: (e[3], e[0]))
    checks.sort(key=lambda c: (c[1], c[0]))
    return np.array(events).reshape(-1, 8), np.array(checks).reshape(-1, 4)


def state(detector) -> dict[str, np.ndarray]:
    """What the numeric path holds after the last sample: z rows, level, step differences
    (the numpy detector holds them itself, the compiled one in its parts)."""
    out: dict[str, np.ndarray] = {}
    for i, ch in enumerate(detector.channels):
        out[f"rows{i}"] = ch.rows.view().copy()
        out[f"rows{i}_at"] = np.array([ch.z_start, ch.next_n, ch.next_test])
    level = getattr(detector, "watcher", detector)  # (the pulse watcher holds the level)
    out["level"] = level._level.copy()
    out["level_at"] = np.array([level._level_start])
    scales = detector.steps.scales if hasattr(detector, "steps") else detector._scales
    for i, sc in enumerate(scales):
        out[f"step{i}"] = sc.d.copy()
        out[f"step{i}_at"] = np.array([sc.start, sc.next])
    return out


def _bits(a: np.ndarray) -> np.ndarray:
    return np.asarray(a, dtype=np.float64).view(np.int64)


@pytest.mark.parametrize("chunk", CHUNKS)
@pytest.mark.parametrize("name", sorted(SIGNALS))
def test_compiled_detector_matches_the_numpy_detectors_events(name: str, chunk: int) -> None:
    """Every contact (its id, time, indices, strength, jump, scale, sigma) and verdict, to
    the bit, in every chunking."""
    events, checks = told(ContactDetector(FS_HZ), SIGNALS[name], chunk)
    expected_events, expected_checks = told(NumpyDetector(FS_HZ), SIGNALS[name], chunk)
    assert len(events) == len(expected_events) and len(checks) == len(expected_checks)
    np.testing.assert_array_equal(_bits(events), _bits(expected_events))
    np.testing.assert_array_equal(_bits(checks), _bits(expected_checks))
    if name != "short":
        assert len(events) and len(checks)


@pytest.mark.parametrize("name", sorted(SIGNALS))
def test_compiled_detector_rows_match_the_numpy_detectors_rows(name: str) -> None:
    """z, hinge, slope after and readiness by centre, the level and the step differences,
    to the bit, and where each starts."""
    detector, expected = ContactDetector(FS_HZ), NumpyDetector(FS_HZ)
    told(detector, SIGNALS[name], CHUNK)
    told(expected, SIGNALS[name], CHUNK)
    want = state(expected)
    got = state(detector)
    assert got.keys() == want.keys()
    for key, value in got.items():
        assert value.shape == want[key].shape, key
        if key.endswith("_at"):
            np.testing.assert_array_equal(value, want[key], err_msg=key)
        else:
            np.testing.assert_array_equal(_bits(value), _bits(want[key]), err_msg=key)


@pytest.mark.parametrize("name", ["slip", "slow", "steps", "railed"])
def test_compiled_detector_tells_the_same_in_any_chunking(name: str) -> None:
    """Including a start on the lower rail, where blocks wait for a noise: a recording fed
    whole (chunks of several blocks) is told as it would be live."""
    by_chunk = {
        chunk: told(ContactDetector(FS_HZ), SIGNALS[name], chunk)
        for chunk in (*CHUNKS, 127, 128, 1000, len(SIGNALS[name]))
    }
    assert len(by_chunk[3][0])
    for chunk in by_chunk:
        np.testing.assert_array_equal(by_chunk[chunk][0], by_chunk[3][0])
        np.testing.assert_array_equal(by_chunk[chunk][1], by_chunk[3][1])


@pytest.mark.parametrize("length", [2, 3, 5, 11, 33, 80])
def test_compiled_fir_matches_scipy_lfilter_bit_for_bit(length: int) -> None:
    rng = np.random.default_rng(length)
    taps = rng.normal(size=length)
    x = rng.normal(3.0, 2.0, 400)
    zi = signal.lfilter_zi(taps, [1.0, 0.0]) * x[0]
    expected, expected_state = signal.lfilter(taps, [1.0, 0.0], x, zi=zi)
    state, y = zi.copy(), np.empty(len(x))
    for i in range(0, len(x), 7):  # in pieces, state carried
        fir_run(taps, state, x[i : i + 7], y[i : i + 7])
    np.testing.assert_array_equal(_bits(y), _bits(expected))
    np.testing.assert_array_equal(_bits(state), _bits(expected_state))


def test_compiled_fir_spreads_nan_and_inf_as_lfilter_does() -> None:
    taps = np.array([0.25, -0.5, 0.125])
    x = np.array([1.0, np.inf, 2.0, 3.0, np.nan, 4.0, 5.0, 6.0])
    zi = np.zeros(2)
    expected, _ = signal.lfilter(taps, [1.0, 0.0], x, zi=zi)
    y = np.empty(len(x))
    fir_run(taps, zi.copy(), x, y)
    np.testing.assert_array_equal(y, expected)  # (NaN where lfilter has NaN)


def test_compiled_fir_of_no_samples_keeps_the_state() -> None:
    state = np.array([1.0, 2.0])
    fir_run(np.array([1.0, 2.0, 3.0]), state, np.zeros(0), np.zeros(0))
    np.testing.assert_array_equal(state, [1.0, 2.0])


def test_a_one_tap_level_filter_still_runs_as_a_gain() -> None:
    """Under 100 Hz the level is one sample: SosFilter.fir's one-tap section, not a kernel."""
    detector = ContactDetector(60.0)
    x = 3.0 + np.random.default_rng(0).normal(0, 0.05, 200)
    detector.feed(np.arange(len(x)) / 60.0, x)
    level = detector.watcher
    assert not level._level_filter.is_fir
    np.testing.assert_array_equal(level._level, x[-len(level._level) :])


def test_compiled_hinge_holds_slopes_until_a_centre_completes() -> None:
    taps = SosFilter.fir(np.array([0.5, -0.5]))
    t, state = taps.fir_state(1.0)
    after = np.empty(3)
    hinge, slope_after = channel_hinge(np.array([1.0, 2.0]), t, state, after, 0)
    assert len(hinge) == len(slope_after) == 0  # 2 slopes held, w = 3
    hinge, slope_after = channel_hinge(np.array([4.0, 8.0]), t, state, after, 2)
    # slopes 0, 0.5, 1, 2 (settled on 1: the first is 0); w = 3: one centre completes
    np.testing.assert_array_equal(slope_after, [2.0])
    np.testing.assert_array_equal(hinge, [2.0])
    np.testing.assert_array_equal(after, [0.5, 1.0, 2.0])


def _maxima_as_numpy_had_them(rows, i0, i1, w, threshold, needed):
    """The numpy code's test (contacts._local_maxima before the kernels), for edge cases."""
    z = rows[0]
    found = []
    for h in (z[i0 : i1 + 1] >= threshold).nonzero()[0].tolist():
        i = i0 + h
        zc = z[i]
        if z[i - 1] >= zc or z[i + 1] > zc:
            continue
        if zc <= z[i - w : i].max() or zc < z[i + 1 : i + w + 1].max():
            continue
        if rows[2, i] < needed * rows[1, i]:
            continue
        found.append(i)
    return found


@pytest.mark.parametrize(
    "z",
    [
        [0, 1, 5, 1, 0, 6, 6, 0, 0, 0],  # ties: the first
        [0, np.nan, 1, 5, 1, np.nan, 0, 0, 0, 0],  # NaN in the window (numpy's max: NaN)
        [0, 0, 5, np.inf, 5, 0, 0, 0, 0, 0],  # inf is a maximum too
        [0, 0, 0, 0, 0, 0, 0, 0, 0, 0],  # nothing above the threshold
    ],
)
def test_compiled_maxima_match_the_numpy_test_at_the_edges(z: list[float]) -> None:
    rows = np.zeros((4, len(z)))
    rows[0] = z
    rows[1] = 1.0
    rows[2] = np.linspace(0.0, 1.0, len(z))
    for w, needed in ((1, 0.0), (2, 0.0), (2, 0.5)):
        i0, i1 = w, len(z) - 1 - w
        expected = _maxima_as_numpy_had_them(rows, i0, i1, w, 4.5, needed)
        found = np.empty(i1 - i0 + 1, dtype=np.int64)
        told = hinge_maxima(rows, i0, i1, w, 4.5, needed, found)
        assert found[:told].tolist() == expected


def test_compiled_maxima_of_an_empty_range_are_none() -> None:
    assert hinge_maxima(np.zeros((4, 8)), 5, 4, 2, 4.5, 0.1, np.empty(0, dtype=np.int64)) == 0


@pytest.mark.parametrize("seed", range(4))
def test_compiled_lattice_median_matches_the_numpy_one_bit_for_bit(seed: int) -> None:
    """A block's noise (`HingeBank._block_done`) from the compiled median is numpy's: on
    continuous values, on ADC lattices (ties, the cell interpolation and its floor), on
    one value repeated, one value and none."""
    rng = np.random.default_rng(seed)
    sets = [np.zeros(0), np.array([0.7]), np.full(50, 0.0244), np.array([0.0, 0.0, 0.5])]
    for n in (2, 3, 4, 49, 50):
        sets += [np.abs(rng.normal(0, 1, n)) for _ in range(20)]
        sets += [np.abs(np.round(rng.normal(0, 1.5, n)) * 0.0244) for _ in range(20)]
        sets += [np.abs(np.round(rng.normal(0, 0.4, n)) * 0.0061) for _ in range(20)]
    for values in sets:
        for floor in (0.0, 0.01, None):
            want = lattice_median(values, floor=floor)
            got = lattice_median_of(values, -np.inf if floor is None else floor)
            assert np.float64(got).tobytes() == np.float64(want).tobytes(), (values, floor)


def test_compiled_lattice_median_leaves_a_nan_to_numpy() -> None:
    assert np.isnan(lattice_median_of(np.array([0.1, np.nan, 0.2]), 0.0))


def _raw_blocks() -> list[np.ndarray]:
    """Blocks of 50 as the noise floor reads them: free noise, ADC steps, either rail
    (with noise off it, ties at both ends), constant, tiny values, a lone step."""
    rng = np.random.default_rng(5)
    lsb = 0.0244
    noise = rng.normal(2.0, 0.02, 50)
    stepped = np.round(rng.normal(2.0, 0.05, 50) / lsb) * lsb
    low = np.maximum(np.round(rng.normal(0.0, 0.03, 50) / lsb) * lsb, 0.0)
    high = np.minimum(stepped, float(np.median(stepped)))
    both = np.concatenate([np.zeros(12), np.full(12, 3.0), rng.normal(1.5, 0.1, 26)])
    lone = np.full(50, 1.0)
    lone[20:] = 1.5
    return [
        noise, stepped, low, high, both, np.full(50, 0.7), rng.normal(0.0, 1e-13, 50), lone,
        np.concatenate([np.zeros(9), rng.normal(1.0, 0.1, 41)]),  # under the share
        np.array([1.0]), np.zeros(0), np.array([-0.0, 0.0, 1.0, 1.0]),
    ]  # fmt: skip


@pytest.mark.parametrize("index", range(len(_raw_blocks())))
def test_compiled_rail_and_step_match_the_numpy_ones(index: int) -> None:
    """A raw block's rail and smallest step (`NoiseFloor.raw_stats`) as `filters.on_rail`
    and `filters.resolution` tell them, to the bit."""
    from grasplink.decoding.filters import RAIL_SHARE, on_rail, resolution
    from grasplink.decoding.kernels.detector import rail_and_step

    block = _raw_blocks()[index]
    rail, step = rail_and_step(block, RAIL_SHARE)
    assert (rail, np.float64(step).tobytes()) == (
        int(on_rail(block)),
        np.float64(resolution(block)).tobytes(),
    )


def test_compiled_rail_and_step_leave_a_nan_to_numpy() -> None:
    from grasplink.decoding.kernels.detector import rail_and_step

    rail, step = rail_and_step(np.array([1.0, np.nan, 1.0]), 0.2)
    assert rail == -1 and np.isnan(step)


def test_compiled_step_scale_with_nothing_to_test_only_filters() -> None:
    taps = np.array([0.5, 0.5, -0.5, -0.5])
    state = signal.lfilter_zi(taps, [1.0, 0.0]) * 2.0
    d = np.zeros(16)
    found, adj = np.empty(0, dtype=np.int64), np.empty(0)
    assert step_scale(np.array([2.0, 2.0, 3.0]), taps, state, d, 4, 0, -1, 2, found, adj) == 0
    np.testing.assert_array_equal(d[4:7], [0.0, 0.0, 0.5])
    np.testing.assert_array_equal(d[:4], 0.0)


def test_feeding_nothing_tells_nothing_and_changes_nothing() -> None:
    detector = ContactDetector(400.0)
    assert detector.feed(np.zeros(0), np.zeros(0)) == ([], [])
    assert detector.samples.n == 0 and detector.channels[0].held == 0


def test_a_deep_copy_of_a_detector_runs_on_alone() -> None:
    """The channels' numbers live side by side in one bank (one kernel steps them all); a
    decoder's reset restores a deep copy of its pristine state, so a copy must be one piece
    of its own: fed the rest of a signal it tells what the original tells, and the
    original, fed after it, is untouched by it."""
    import copy

    x = SIGNALS["slip"]
    t = np.arange(len(x)) / FS_HZ
    half = len(x) // 2
    original = ContactDetector(FS_HZ)
    for i in range(0, half, 3):
        original.feed(t[i : min(i + 3, half)], x[i : min(i + 3, half)])
    clone = copy.deepcopy(original)
    assert clone.hinges.bank.rows[0] is clone.channels[0].rows.data
    assert clone.hinges.bank.ints is not original.hinges.bank.ints
    assert clone.steps.watcher is clone.watcher and clone.hinges.noise is clone.noise

    def rest(detector: ContactDetector) -> list:
        out = []
        for i in range(half, len(x), 3):
            events, checks = detector.feed(t[i : i + 3], x[i : i + 3])
            out += [*events, *checks]
        return out

    told_by_clone = rest(clone)
    assert told_by_clone
    assert rest(original) == told_by_clone


def test_channels_the_kernel_does_not_take_are_left_as_they_were() -> None:
    """A channel whose next centres leave the block of its known noise (or with no noise
    known) is the Python path's: the kernel changes nothing of it."""
    from grasplink.decoding.kernels.detector import NOT_TAKEN, channels_fast

    x = SIGNALS["slip"][:400]
    detector = ContactDetector(FS_HZ)
    detector.feed(np.arange(len(x)) / FS_HZ, x)
    bank = detector.hinges.bank
    bank.ints[:, -1] = -1  # no channel knows its block's noise
    ints, state, after = bank.ints.copy(), bank.state.copy(), bank.after.copy()
    needs_python = channels_fast(
        np.array([1.0, 1.1, 1.2]), bank.numbers, bank.rows, detector.hinges.constants, bank.told
    )
    assert needs_python
    assert (bank.status == NOT_TAKEN).all() and (bank.counts == 0).all()
    np.testing.assert_array_equal(bank.ints, ints)
    np.testing.assert_array_equal(bank.state, state)
    np.testing.assert_array_equal(bank.after, after)


def test_the_kernel_takes_the_centres_of_channels_waiting_for_a_noise() -> None:
    """On a rail no block shows its noise and every channel's centres wait for one: the
    kernel appends them to those waiting (hinge, slope after and |hinge| as the Python
    path's `channel_hinge`), rather than leaving each channel to Python every block."""
    from grasplink.decoding.kernels.detector import TAKEN, channel_hinge, channels_fast
    from grasplink.decoding.kernels.layout import CH_ABS_N, CH_HELD, CH_WAIT_N

    detector = ContactDetector(FS_HZ)
    x = np.zeros(60)  # the lower rail: blocks wait for a noise (the first one too)
    detector.feed(np.arange(len(x)) / FS_HZ, x)
    bank = detector.hinges.bank
    waiting = bank.ints[:, CH_WAIT_N].copy()
    assert (waiting > 0).all()
    new = np.array([0.0, 0.3, 0.1])
    expected = []
    for c, w in enumerate(ch.width for ch in detector.channels):
        state, after = bank.state[c, :w].copy(), bank.after[c, :w].copy()
        held = int(bank.ints[c, CH_HELD])
        expected.append(channel_hinge(new, bank.taps[c, : w + 1], state, after, held))
    abs_n = bank.ints[:, CH_ABS_N].copy()
    channels_fast(new, bank.numbers, bank.rows, detector.hinges.constants, bank.told)
    assert (bank.status == TAKEN).all() and (bank.taken == len(new)).all()
    np.testing.assert_array_equal(bank.ints[:, CH_WAIT_N], waiting + len(new))
    for c, (hinge, slope_after) in enumerate(expected):
        told = slice(waiting[c], waiting[c] + len(new))
        np.testing.assert_array_equal(bank.wait[c, 0, told], hinge)
        np.testing.assert_array_equal(bank.wait[c, 1, told], slope_after)
        np.testing.assert_array_equal(
            bank.block_abs[c, abs_n[c] : abs_n[c] + len(new)], np.abs(hinge)
        )


@pytest.mark.parametrize("chunk", [3, 7])
def test_a_long_rail_tells_what_the_numpy_detector_tells(chunk: int) -> None:
    """10 s on the lower rail (an idle skin), then a slip, twice: the centres that waited
    for a noise longer than `noise_blocks` are dropped undetected and the bank's `wait`
    rows never overflow; the contacts are the numpy detector's, to the bit."""
    slip = SIGNALS["slip"][:900]
    x = np.concatenate([np.zeros(4000), slip, np.zeros(4000), slip])
    compiled, numpy_detector = ContactDetector(FS_HZ), NumpyDetector(FS_HZ)
    got, expected = told(compiled, x, chunk), told(numpy_detector, x, chunk)
    assert len(got[0]) > 4
    np.testing.assert_array_equal(got[0], expected[0])
    np.testing.assert_array_equal(got[1], expected[1])


def test_step_scales_the_kernel_has_no_room_for_are_left_as_they_were() -> None:
    """A scale whose store is full is the Python path's (it grows the store there): the
    kernel changes nothing of it, and says so (-1)."""
    from grasplink.decoding.kernels.detector import scales_fast

    x = SIGNALS["slip"][:400]
    detector = ContactDetector(FS_HZ)
    detector.feed(np.arange(len(x)) / FS_HZ, x)
    bank = detector.steps.bank
    scales = detector.steps.scales
    full = tuple(store[: scales[s].store.size] for s, store in enumerate(bank.stores))
    ints, state = bank.ints.copy(), bank.state.copy()
    held = [store.copy() for store in full]
    needs_python = scales_fast(
        np.array([1.0, 1.1, 1.2]), bank.ints, bank.taps, bank.state, full, bank.found,
        bank.found_adj, bank.counts, bank.first,
    )  # fmt: skip
    assert needs_python
    assert (bank.counts == -1).all()
    np.testing.assert_array_equal(bank.ints, ints)
    np.testing.assert_array_equal(bank.state, state)
    for store, before in zip(full, held, strict=True):
        np.testing.assert_array_equal(store, before)


def _scan_as_numpy_had_it(
    level,
    next_k,
    index,
    base,
    fall,
    fall_credit,
    trend,
    width,
    peak0,
    history,
    hold,
    min_rise,
    drop,
    decay,
    noise,
    step_rise,
):
    """The numpy code's look at new level samples (contacts._advance before the kernels)."""
    k = np.arange(next_k, next_k + len(level))
    since = k - index
    credit = fall * np.minimum(since, fall_credit)
    raw = level - base + credit
    d = raw - trend * (since + width)
    peak = np.maximum.accumulate(np.maximum(d - credit, peak0))
    history = np.concatenate([history, peak])
    keep = max(0, hold - next_k + 1)
    held = np.array([(level - base)[:keep], raw[:keep], d[:keep]])
    rise = np.maximum(history.searchsorted(0.9 * peak), min_rise)
    ok = (peak >= 4.0 * noise) & (peak - d >= drop * peak) & (since <= decay * rise)
    fell = False
    if next_k < hold:
        deferred = (k < hold) & (history.searchsorted(0.8 * peak) <= step_rise)
        fell = bool((ok & deferred).any())
        hit = (ok & ~deferred).nonzero()[0]
    else:
        hit = ok.nonzero()[0]
    return (int(hit[0]) if len(hit) else -1), fell, history, held


@pytest.mark.parametrize("seed", range(12))
def test_compiled_watch_scan_matches_the_numpy_watch(seed: int) -> None:
    """Pulses, steps and ramps under a watch, looked at a few samples at a time."""
    from grasplink.decoding.kernels.detector import ScanFrom, ScanSettings, Watched, watch_scan

    rng = np.random.default_rng(seed)
    n, index, hold = 120, 50, 50 + int(rng.integers(5, 60))
    u = np.arange(n) / rng.uniform(3.0, 30.0)
    shape = [u * np.exp(1.0 - u), np.minimum(u, 1.0), 0.05 * u][seed % 3]
    level = 1.0 + rng.uniform(0.1, 2.0) * shape + rng.normal(0, 0.02, n) + 0.001 * np.arange(n)
    args = dict(
        base=1.0,
        fall=rng.uniform(0, 0.01),
        fall_credit=12,
        trend=rng.uniform(0, 0.003),
        width=5,
        min_rise=2,
        drop=0.3,
        decay=6.0,
        noise=0.01,
        step_rise=8,
    )
    history, held = np.empty(n + 1), np.empty((3, hold - index + 1))
    hist_n = held_n = 0
    expected_history = np.zeros(0)
    peak, next_k = -np.inf, index
    while next_k < index + n:
        m = int(rng.integers(1, 8))
        new = level[next_k - index : next_k - index + m]
        hit, fell, expected_history, expected_held = _scan_as_numpy_had_it(
            new, next_k, index, peak0=peak, history=expected_history, hold=hold, **args
        )
        watch = Watched(
            index, args["base"], args["fall"], args["trend"], args["noise"], hold, history, held
        )
        at = ScanFrom(next_k=next_k, peak=peak, hist_n=hist_n, held_n=held_n)
        settings = ScanSettings(**{key: args[key] for key in ScanSettings._fields})
        told = watch_scan(new, tuple(watch), tuple(at), tuple(settings))
        assert told == (hit, fell)
        hist_n += len(new)
        np.testing.assert_array_equal(history[:hist_n], expected_history)
        keep = expected_held.shape[1]
        np.testing.assert_array_equal(held[:, held_n : held_n + keep], expected_held)
        held_n += keep
        peak, next_k = float(history[hist_n - 1]), next_k + len(new)


def test_the_decoders_warm_up_loads_every_detector_kernel() -> None:
    """The live loop's first frames and first contact wait for no detector kernel: the
    tracker's warm-up (a throwaway decoder on a synthetic slip) reaches every one."""
    child = (
        "import json\n"
        "from grasplink.decoding.kernels import detector\n"
        "from grasplink.decoding.tracker import TrackerDecoder\n"
        "from grasplink.profiles.layouts import LAYOUTS_MM\n"
        "TrackerDecoder(LAYOUTS_MM['alpha0.1'], 400).warm_up()\n"
        "print(json.dumps({n: len(getattr(detector, n).signatures) for n in detector.__all__}))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", child], capture_output=True, text=True, check=True, timeout=600
    )
    counts = json.loads(done.stdout.strip().splitlines()[-1])
    assert counts and all(counts.values()), counts

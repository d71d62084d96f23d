"""The tracker's branching as one compiled kernel (`kernels.branch`, called by
`TrackerDecoder._branch`): the children pools it builds are those the numpy code built
(`reference.tracker`, the numpy `_branch` of 0858d90, run in this process on the same
inputs), in the same order: the int columns (which children exist, their ridges, runs,
contact ids) exactly, the floats within the allowance `reference.compare` derives from
the arithmetic - 0 (the same bits) where no exp, log or matrix product reaches a number.

The inputs are every branching of real decodes (the non-stationary set's quick signals and
the gateway benchmark's slip cycle, 3 samples at a time), the steps and step probes first,
and edge cases built from one of them."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cache

import numpy as np
import pytest

from grasplink.decoding.contacts import STEP_IDS, ContactEvent
from grasplink.decoding.kernels import branch as kernel
from grasplink.decoding.tracker import _F_WIDTH, _I_WIDTH, TrackerDecoder, _Bank
from grasplink.evaluation import nonstationary
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth
from tests.decoding.reference import tracker as reference
from tests.decoding.reference.compare import (
    MAGNIFY,
    allowance,
    assert_within,
    perturbed_runs,
)

KEEP_STEPS, KEEP_PROBES, KEEP_TOTAL = 40, 20, 160


@dataclass(frozen=True)
class Call:
    """One `_branch` call's inputs: the decoder (layout, rate), its tracks and null score,
    the contact, and the step verdict on it (None: not a step)."""

    layout: str
    fs: int
    floats: np.ndarray
    ints: np.ndarray
    null: float
    ev: ContactEvent
    step: tuple[bool | None] | None = None


def recordings() -> list[tuple[str, np.ndarray, np.ndarray, int]]:
    """(layout name, t, x, fs) of the decoded signals."""
    out = []
    for signal in nonstationary.signals(True):
        rec = signal.make()
        out.append((signal.layout, np.asarray(rec.t_s), np.asarray(rec.force_n), rec.fs_hz))
    rec = synth.slip_recording(LAYOUTS_MM["alpha0.1"], 60.0, fs_hz=400, seed=1)
    rest = np.random.default_rng(1).normal(float(rec.force_n[0]), 0.02, 320)
    x = np.tile(np.concatenate([rec.force_n, rest]), 3)
    out.append(("alpha0.1", np.arange(len(x)) / 400.0, x, 400))
    return out


@cache
def decoder(layout: str, fs: int) -> TrackerDecoder:
    """One decoder per layout and rate (building one takes a while); each case sets the
    state `_branch` reads."""
    return TrackerDecoder(LAYOUTS_MM[layout], fs)


def capture(layout: str, t: np.ndarray, x: np.ndarray, fs: int) -> list[Call]:
    """Every `_branch` call of one decode."""
    dec = TrackerDecoder(LAYOUTS_MM[layout], fs)
    calls: list[Call] = []
    branch = dec._branch

    def recorded(ev: ContactEvent) -> _Bank:
        step = (dec._steps[ev.id],) if ev.id in dec._steps else None
        before = dec._tracks
        calls.append(Call(layout, fs, before._f.copy(), before._i.copy(), dec._null, ev, step))
        return branch(ev)

    dec._branch = recorded  # type: ignore[method-assign]
    for start in range(0, len(t), 3):
        dec.process(t[start : start + 3], x[start : start + 3])
    return calls


@cache
def calls() -> list[Call]:
    """The steps and probes (rarer kinds) first, then an even spread of the rest."""
    every = [call for rec in recordings() for call in capture(*rec)]
    steps = [c for c in every if c.step is not None]
    probes = [c for c in every if c.ev.id >= STEP_IDS and c.step is None]
    rest = [c for c in every if c.step is None and c.ev.id < STEP_IDS]
    picked = steps[:: max(1, len(steps) // KEEP_STEPS)][:KEEP_STEPS]
    picked += probes[:: max(1, len(probes) // KEEP_PROBES)][:KEEP_PROBES]
    room = KEEP_TOTAL - len(picked)
    return picked + rest[:: max(1, len(rest) // room)][:room]


def edge_cases() -> list[Call]:
    """Inputs the signals seldom or never give: no tracks (a contact and a step probe), one
    track, a bank of a real call with a NaN speed, an infinite dip variance and a -inf
    score (at a contact and at a probe), and a contact at a track's own time with exact
    timing."""
    model = next(c for c in calls() if len(c.floats) >= 8 and c.step is None and c.fs == 400
                 and c.ev.id < STEP_IDS)  # fmt: skip
    ev = model.ev
    probe = ev._replace(id=ev.id + STEP_IDS)
    f, i = model.floats, model.ints
    odd = f.copy()
    odd[0, kernel.F_V] = np.nan
    odd[1, kernel.P33] = np.inf
    odd[2, kernel.F_SCORE] = -np.inf
    return [
        replace(model, floats=f[:0], ints=i[:0]),
        replace(model, floats=f[:0], ints=i[:0], ev=probe, step=(None,)),
        replace(model, floats=f[:1], ints=i[:1]),
        replace(model, floats=odd),
        replace(model, ev=ev._replace(t_s=float(f[3, kernel.F_T]), sigma_s=0.0)),
        replace(model, floats=odd, ev=probe, step=(None,)),
    ]


def set_state(call: Call) -> TrackerDecoder:
    dec = decoder(call.layout, call.fs)
    dec._tracks, dec._null = _Bank(call.floats.copy(), call.ints.copy()), call.null
    dec._steps = {} if call.step is None else {call.ev.id: call.step[0]}
    return dec


def check(call: Call, seed: int) -> tuple[_Bank, bool]:
    """Branch `call` compiled and in numpy; the pools must agree (module doc). Returns the
    compiled pool and whether the call is near a threshold (a perturbed numpy run built
    other children)."""
    dec = set_state(call)
    want, want_null = reference.branch(dec, call.ev)
    runs = perturbed_runs(lambda: reference.branch(dec, call.ev)[0], seed)
    magnified = perturbed_runs(lambda: reference.branch(dec, call.ev)[0], seed, MAGNIFY)
    got = dec._branch(call.ev)
    assert dec._null == want_null  # sums of the same constants

    def alike(pools: list[_Bank], ints: np.ndarray) -> list[np.ndarray]:
        return [p._f for p in pools if p._i.shape == ints.shape and np.array_equal(p._i, ints)]

    near = len(alike(runs, want._i)) < len(runs)
    expected = want._f
    if got._i.shape != want._i.shape or not np.array_equal(got._i, want._i):
        # only where the arithmetic could have built those children too
        assert near and alike(runs, got._i), f"call {seed}: other children than numpy's"
        expected = alike(runs, got._i)[0]
    allowed = allowance(expected, alike(runs, got._i), alike(magnified, got._i))
    assert_within(got._f, expected, allowed, f"call {seed}")
    return got, near


def test_compiled_branch_matches_the_numpy_children_pools():
    kinds = {"step": 0, "probe": 0, "near": 0}
    for k, call in enumerate(calls()):
        _, near = check(call, k)
        kinds["step"] += call.step is not None
        kinds["probe"] += call.ev.id >= STEP_IDS
        kinds["near"] += near
    assert kinds["step"] >= 20 and kinds["probe"] >= 10  # the rarer branch kinds are in
    assert kinds["near"] <= len(calls()) // 20, kinds  # thresholds rarely within reach


def test_compiled_branch_keeps_the_numpy_codes_edge_cases():
    cases = edge_cases()
    pools = [check(call, 1000 + k)[0] for k, call in enumerate(cases)]
    assert len(pools[0]) == 2 * decoder(cases[0].layout, cases[0].fs).count  # births only
    assert len(pools[1]) == 0  # a probe on no tracks: no children
    assert np.isnan(pools[3]._f).any() and np.isinf(pools[3]._f).any()  # odd numbers pass


def test_compiled_branch_of_no_tracks_at_a_probe_is_the_shared_empty_bank():
    """A probe on no tracks has no children: `_branch` gives the one empty bank, as
    before (the replay memo compares banks by identity)."""
    call = edge_cases()[1]
    assert set_state(call)._branch(call.ev) is _Bank.empty()


def test_the_comparison_tells_a_one_ulp_change_where_the_arithmetic_is_exact():
    """The allowance is 0 where no exp, log or matrix product reaches a number (a track's
    time, its contact's sigma): a one-ulp change there fails the comparison; a change of
    the same size in a Kalman-updated speed is allowed."""
    call = next(c for c in calls() if len(c.floats) >= 8 and c.step is None and c.ev.id < STEP_IDS)
    dec = set_state(call)
    want, _ = reference.branch(dec, call.ev)

    def pools() -> np.ndarray:
        return reference.branch(dec, call.ev)[0]._f

    allowed = allowance(want._f, perturbed_runs(pools, 7), perturbed_runs(pools, 7, MAGNIFY))
    kalman = np.nonzero(allowed[:, kernel.F_V] > 0)[0]
    assert len(kalman) and (allowed[:, kernel.F_T] == 0).all()
    got = want._f.copy()
    got[0, kernel.F_T] = np.nextafter(got[0, kernel.F_T], np.inf)
    with pytest.raises(AssertionError, match="beyond their allowance"):
        assert_within(got, want._f, allowed)
    got = want._f.copy()
    got[kalman[0], kernel.F_V] = np.nextafter(got[kalman[0], kernel.F_V], np.inf)
    assert_within(got, want._f, allowed)


def test_a_banks_fields_are_the_kernels_columns():
    """The tracker's field views read the columns the kernels write (one layout, defined
    in kernels.layout, which the numpy reference reads too): each field of a track
    round-trips through its column."""
    floats = np.arange(2 * _F_WIDTH, dtype=float).reshape(2, _F_WIDTH)
    ints = np.arange(2 * _I_WIDTH).reshape(2, _I_WIDTH)
    bank = _Bank(floats, ints)
    assert bank.score[1] == floats[1, kernel.F_SCORE] and bank.t[0] == floats[0, kernel.F_T]
    assert bank.X[1, 1] == floats[1, kernel.F_V] and bank.P[0, 3, 3] == floats[0, kernel.P33]
    assert bank.run[1] == ints[1, kernel.I_RUN] and bank.ids[0, -1] == ints[0, kernel.I_LAST]
    assert bank.model[0] == ints[0, kernel.I_MODEL]
    assert bank.before[1] == floats[1, kernel.F_BEFORE]
    assert (_F_WIDTH, _I_WIDTH) == (reference._F_WIDTH, reference._I_WIDTH) == (26, 12)


def test_compiled_branch_constants_are_packed_by_name():
    dec = decoder("alpha0.1", 400)
    values = dec._branch_constant_values()
    packed = kernel.pack_constants(values)
    assert packed[kernel.LOG_RESTART] == dec.LOG_RESTART
    assert packed[kernel.STALE_S] == dec._stale_s
    with pytest.raises(ValueError, match="stale_s"):
        kernel.pack_constants({k: v for k, v in values.items() if k != "stale_s"})


class _Rebirth(TrackerDecoder):
    LOG_REBIRTH = math.log(0.2)


@cache
def rebirth_decoder(layout: str, fs: int) -> TrackerDecoder:
    return _Rebirth(LAYOUTS_MM[layout], fs)


def test_compiled_branch_matches_numpy_with_births_the_slips_way(monkeypatch):
    """`LOG_REBIRTH` on (a slip going on its way from a ridge its tracks do not place):
    the compiled births match the numpy code's, and they are other births than with it
    off (the best slipping track's score lifts those of its own way)."""

    def slips(c: Call) -> bool:
        return bool((np.isnan(c.floats[:, kernel.F_STOP]) & (c.ints[:, kernel.I_N] >= 2)).any())

    slipping = [c for c in calls() if c.ev.id < STEP_IDS and slips(c)][:40]
    assert len(slipping) >= 20
    off = [decoder(c.layout, c.fs) for c in slipping]
    monkeypatch.setitem(globals(), "decoder", rebirth_decoder)
    lifted = 0
    for k, (call, plain) in enumerate(zip(slipping, off, strict=True)):
        got, _ = check(call, 2000 + k)
        plain._tracks, plain._null = _Bank(call.floats.copy(), call.ints.copy()), call.null
        plain._steps = {} if call.step is None else {call.ev.id: call.step[0]}
        lifted += int(
            (got._f[:, kernel.F_SCORE] > plain._branch(call.ev)._f[:, kernel.F_SCORE]).any()
        )
    assert lifted >= len(slipping) // 4, lifted

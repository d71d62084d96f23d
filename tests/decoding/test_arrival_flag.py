"""A slip flagged from its arrival onto an unloaded sensor (`decoding.arrival_flag`).

The cases: alpha0.1 (19, 12, 5, 8, 4, 3, 33 mm, the closed loop's skin), the object's edge
8 mm off the skin, a slip from 1.0 s at 20 mm/s - through (its first ridge at 1.41 s, the
second 19 mm on at 2.36 s) or stopping 12 mm on (4 mm onto the skin, before the second)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from grasplink.decoding import arrival_flag
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth
from tests.decoding.plan_cases import decode_case

LAYOUT = LAYOUTS_MM["alpha0.1"]
SPEED_MM_S = 20.0


def _slide_on(travel_mm: float, tuning: dict):
    """(estimates, truth) of a slip onto the skin from 8 mm off, `travel_mm` at 20 mm/s
    from 1.0 s, then at rest until 6 s."""
    moved_s = travel_mm / SPEED_MM_S
    profile = [[0.0, 0.0], [1.0, 0.0], [1.02, SPEED_MM_S], [1.0 + moved_s, SPEED_MM_S]]
    profile += [[1.02 + moved_s, 0.0], [6.0, 0.0]]
    rec = synth.scripted_recording(LAYOUT, profile, start_mm=-8.0, duration_s=6.0, seed=7)
    dec = TrackerDecoder(LAYOUT, rec.fs_hz, tuning=tuning)
    estimates, _ = ns.feed(dec, rec.t_s, rec.force_n, sr.CHUNK)
    return estimates, rec


def test_waiting_p_falls_with_the_silence():
    dec = TrackerDecoder(LAYOUT, 400.0)
    rows = (0, dec.count)
    latency = dec._max_latency
    p = [
        arrival_flag.waiting_p(e, rows, dec._waiting, dec._K, latency)
        for e in (0.0, latency, 0.5, 1.0, 2.0, 4.0)
    ]
    assert p[0] == p[1] == 1.0  # nothing could have been told yet
    assert all(a > b for a, b in itertools.pairwise(p[1:]))
    assert 0.0 < p[-1] < arrival_flag.HOLD_P
    with pytest.raises(ValueError, match="no rows"):
        arrival_flag.waiting_p(1.0, (), dec._waiting, dec._K, latency)


def test_the_latch_holds_until_another_arrival():
    latch = arrival_flag.ArrivalFlag()
    assert not latch.note(-1, False)  # no arrival
    assert latch.note(3, False)
    assert not latch.note(3, True)  # the posterior took over
    assert not latch.note(3, False)  # ... for good: its "no slip" is its own
    assert latch.note(9, False)  # a new arrival


@pytest.mark.parametrize("flag_p", [arrival_flag.HOLD_P, 0.0], ids=["flag", "off"])
def test_a_slip_onto_the_skin_is_flagged_at_its_first_contact(flag_p):
    estimates, rec = _slide_on(60.0, {"ARRIVAL_FLAG_P": flag_p})
    first, second = np.sort(rec.contact_times_s)[:2]
    flagged = [e for e in estimates if e.slip]
    early = [e for e in flagged if e.t_s < second]
    if not flag_p:  # without the rule: nothing before the second ridge contact
        assert not early
        return
    # told within the detector's latency and a block, held until the second contact
    assert flagged[0].t_s - first <= 0.1, flagged[0].t_s
    between = [e for e in estimates if flagged[0].t_s <= e.t_s < second]
    assert all(e.slip for e in between)
    # one contact tells neither the speed nor the way it came in
    assert all(e.speed_mm_s is None and e.direction is None for e in early)


@pytest.mark.parametrize("flag_p", [arrival_flag.HOLD_P, 1e-9], ids=["flag", "no-silence"])
def test_a_slip_that_arrives_and_stops_is_cleared_by_its_silence(flag_p):
    estimates, rec = _slide_on(12.0, {"ARRIVAL_FLAG_P": flag_p, "ARRIVAL_STALL_N": 0.0})
    first = float(np.sort(rec.contact_times_s)[0])
    assert len(rec.contact_times_s) == 1
    late = [e.t_s for e in estimates if e.slip and e.t_s > first + 2.0]
    if flag_p < 1e-6:  # the control: without the silence bound it stays flagged
        assert late
        return
    # its second ridge overdue for all but the slowest slips (1.9 s measured)
    assert not late, late[:3]
    assert not [e for e in estimates if e.speed_mm_s not in (None, 0.0)]


@pytest.mark.parametrize("stall_n", [arrival_flag.STALL_N, 0.0], ids=["stall", "off"])
def test_a_slip_that_arrives_and_stops_is_cleared_by_its_flat_level(stall_n):
    """The object stops at 1.62 s, 4 mm onto the skin: the level no longer rises (no more
    skin covered). Its next ridge would have been due at 2.36 s (the stop's observable
    moment), the clearing allowed until 2.51 s; silence alone clears it at 3.31 s."""
    estimates, rec = _slide_on(12.0, {"ARRIVAL_STALL_N": stall_n})
    stop = sr.score(estimates, rec).stops[0]
    assert stop.judged
    if not stall_n:
        assert stop.delay_s > sr.CLEAR_WITHIN_S
        return
    assert stop.delay_s <= 0.0, stop.delay_s  # cleared before it was observable (2.02 s)


def test_a_slow_slip_onto_the_skin_is_no_stall():
    """20 mm/s through: the level rises as the object covers the skin (and dips after the
    arrival pulse), never flat for 0.2 s: the flag holds from the arrival on."""
    estimates, rec = _slide_on(60.0, {})
    first, second = np.sort(rec.contact_times_s)[:2]
    shown = [e for e in estimates if first + 0.1 <= e.t_s < second + 0.1]
    assert all(e.slip for e in shown)


@pytest.mark.parametrize("history", [8, 2])
def test_the_arrival_contact_kept_between_updates_is_the_one_a_scan_finds(history):
    """The tracker keeps its arrival contact between updates (`_arrival_contact`, looked up
    again only once contacts or their load verdicts changed): after every packet it is
    the last contact held whose verdict reads an unloaded sensor, as a scan of the history
    finds it - through the slip's contacts coming, replayed and, with a short history,
    dropped."""
    moved_s = 60.0 / SPEED_MM_S
    profile = [[0.0, 0.0], [1.0, 0.0], [1.02, SPEED_MM_S], [1.0 + moved_s, SPEED_MM_S]]
    profile += [[1.02 + moved_s, 0.0], [6.0, 0.0]]
    rec = synth.scripted_recording(LAYOUT, profile, start_mm=-8.0, duration_s=6.0, seed=7)
    dec = TrackerDecoder(LAYOUT, rec.fs_hz, history=history)
    seen: set[int] = set()
    for start in range(0, len(rec.t_s), sr.CHUNK):
        chunk = slice(start, start + sr.CHUNK)
        dec.feed(rec.t_s[chunk], rec.force_n[chunk])
        scanned = next(
            ((c.id, c.t_s, c.index) for c in reversed(dec._contacts) if dec._unloaded.get(c.id)),
            None,
        )
        assert dec._arrival_contact() == scanned, rec.t_s[start]
        seen.add(-1 if scanned is None else scanned[0])
    assert len(seen) >= 2  # an arrival came (and, with a short history, went)


def test_the_waiting_probability_is_the_posterior_kernels_own():
    """`kernels.posterior.log_waiting`, the public face of the posterior's waiting tables,
    gives the kernel's own numbers bit for bit."""
    from grasplink.decoding.kernels import posterior as pk

    dec = TrackerDecoder(LAYOUT, 400.0)
    log, finite, before = dec._waiting
    for row in (0, dec.count - 1, dec.count, 2 * dec.count - 1):
        for elapsed in (-1.0, 0.0, 0.05, 0.7, 3.0):
            kernel = pk._log_waiting(elapsed, row, log, finite, before, dec._K)
            assert pk.log_waiting(elapsed, row, dec._waiting, dec._K) == kernel


def _reversal_arrival(tuning: dict):
    """(update times, flags) of the full plan's reversal at 41 -> 39 mm/s on alpha0.7 (seed
    103000): the 25 mm object's edge onto the empty skin at 0.46 s (told a step 0.1 s
    on: it lies on the skin after), its 2nd ridge at 0.63 s, then 64 mm to the next."""
    _, _, estimates = decode_case("reversal", 103000, tuning)
    return np.array([e.t_s for e in estimates]), np.array([e.slip for e in estimates])


def test_an_arrival_told_a_step_keeps_its_flag():
    t, flags = _reversal_arrival({})
    assert flags[(t >= 0.5) & (t <= 1.2)].all()  # from the arrival to past the 2nd ridge
    # before s27 it ended at 0.57 s (the level's ramp hold, `level_ramp`, off: it holds
    # this flag too while the object slides on)
    t, flags = _reversal_arrival({"ARRIVAL_STEP_KEEP": 0.0, "RAMP_HOLD": 0.0})
    assert not flags[(t >= 0.6) & (t <= 1.2)].any()

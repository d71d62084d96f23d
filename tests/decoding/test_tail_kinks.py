"""Ridge contacts on a pulse's falling tail (issue 22: constant speed missing from the 3rd
contact). After a short spacing the new pulse starts from the previous one's tail, so the
force does not rise at the onset - the tail only stops falling. The kink bank's rise check
dropped those kinks (alpha0.3's 4 and 7 mm ridges after the tall first pulse);
`detector.tail_kinks` gives them back when the tail before them is a pulse's decay and
the level after stands above that decay's extrapolation, and still drops the slow bend at
the end of a decay, a grip ramp's end and noise on a flat level."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from grasplink.decoding.contacts import ContactDetector, DetectorSettings, HingeSettings
from grasplink.decoding.detector.tail_kinks import ON_RESIDUAL_Z, TailKinkSettings, tail_kink
from grasplink.evaluation.contact_truth import MATCH_S, onset_kinks_met
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

FS_HZ = 400.0
WHITE_N = 0.02  # thesis-like
SETTINGS = TailKinkSettings(residual_z=ON_RESIDUAL_Z)  # (as shipped)
ON = DetectorSettings(hinges=HingeSettings(tails=SETTINGS))
OFF = DetectorSettings(hinges=HingeSettings(tails=replace(SETTINGS, residual_z=0.0)))


def _pulse(n: int, onset: int, rise: float, alpha: float, start: float) -> np.ndarray:
    """Thesis ch. 5.3.1's pulse from `start` at `onset` (samples), as the simulator's."""
    u = np.maximum(np.arange(n) - onset, 0) / rise
    shape = u * np.exp(1.0 - u)
    return np.where(u < 1.0, start + (alpha - start) * shape, alpha * shape)


def _two_pulses(seed: int, second: bool) -> tuple[np.ndarray, int]:
    """A tall pulse (the first ridge met) and, 4 mm later at 40 mm/s, the next ridge's
    pulse starting on its tail (alpha 1 - e^-0.4); the second onset's sample."""
    n, rise, first = 600, 12.5, 200  # 1.25 mm at 40 mm/s: 12.5 samples
    onset = first + 40  # 4 mm at 40 mm/s: 0.1 s
    x = _pulse(n, first, rise, 1.0, 0.0)
    if second:
        start = float(x[onset])
        x = np.where(np.arange(n) < onset, x, _pulse(n, onset, rise, 0.33, start))
    rng = np.random.default_rng(seed)
    return x + rng.normal(0.0, WHITE_N, n) + 3.0, onset


SEEDS = range(10)
WIDTHS = (8, 16, 32)  # the scales (samples) that see a 4 mm kink at 40 mm/s
# measured: the kink passes 24 of 30; of the decay alone, 10 of 5550 samples tested
KINK_FOUND_MIN = 20
DECAY_PASSED_MAX = 20


def test_a_kink_on_a_pulses_tail_is_a_contact_and_the_decay_alone_is_not():
    """The second pulse's onset on the first one's tail passes; the same tail without the
    second pulse (the slow bend of a decay, where the coarse scales' hinge peaks) almost
    never does, tested at every sample from the peak on."""
    kinks = decays = 0
    for seed in SEEDS:
        x, onset = _two_pulses(seed, second=True)
        kinks += sum(tail_kink(x, onset, w, WHITE_N, FS_HZ, SETTINGS) for w in WIDTHS)
        x, _ = _two_pulses(seed, second=False)
        decays += sum(
            tail_kink(x, k, w, WHITE_N, FS_HZ, SETTINGS) for w in WIDTHS for k in range(215, 400)
        )
    assert kinks >= KINK_FOUND_MIN, kinks
    assert decays <= DECAY_PASSED_MAX, decays


@pytest.mark.parametrize("width", [2, 8, 32])
def test_a_grip_ramps_end_and_a_flat_level_are_no_contacts(width):
    rng = np.random.default_rng(3)
    n = 600
    ramp = np.interp(np.arange(n), [0, 200, 300, n], [4.0, 4.0, 3.0, 3.0])
    flat = np.full(n, 4.0)
    for level in (ramp, flat):
        x = level + rng.normal(0.0, WHITE_N, n)
        assert not any(tail_kink(x, k, width, WHITE_N, FS_HZ, SETTINGS) for k in range(150, 560))


def test_bad_positions_are_no_contacts():
    x, onset = _two_pulses(0, second=True)
    assert not tail_kink(x, 5, 8, WHITE_N, FS_HZ, SETTINGS)  # no tail before it held
    assert not tail_kink(x, len(x) - 3, 8, WHITE_N, FS_HZ, SETTINGS)  # the scale after not held
    assert not tail_kink(x, onset, 8, WHITE_N, FS_HZ, replace(SETTINGS, residual_z=0.0))


# constant slips over the layouts with weak kinks (seed 7: not the benchmarks' seeds 1-2)
LAYOUTS = ("alpha0.1", "alpha0.3", "fibonacci", "uniform4")
SPEEDS_MM_S = (12.0, 35.0, 90.0)
WEAK_KINK = 0.13  # `ridge_pulses.onset_kinks` under this: 4-53 % found before
# measured on this set: kinks under 0.13 found 17 of 27 (12 with the test off); the rest
# 223 of 225 either way; false contacts 11 (7 off: a pulse's tail meeting a rising level)
WEAK_FOUND_MIN = 16
FALSE_MAX = 15


def test_weak_kinks_on_constant_slips_are_found():
    found = {"on": [0, 0, 0], "off": [0, 0, 0]}  # weak found, the rest found, false
    weak = rest = 0
    for name in LAYOUTS:
        for speed in SPEEDS_MM_S:
            for reverse in (False, True):
                rec = synth.slip_recording(LAYOUTS_MM[name], speed, reverse=reverse, seed=7)
                truth = rec.contact_times_s
                kinks = onset_kinks_met(rec)
                weak += sum(k < WEAK_KINK for k in kinks)
                rest += sum(k >= WEAK_KINK for k in kinks)
                for key, settings in (("on", ON), ("off", OFF)):
                    events, _ = ContactDetector(rec.fs_hz, settings).feed(rec.t_s, rec.force_n)
                    told = np.array([e.t_s for e in events])
                    for c, k in zip(truth, kinks, strict=True):
                        hit = bool(len(told)) and bool(np.min(np.abs(told - c)) <= MATCH_S)
                        found[key][0 if k < WEAK_KINK else 1] += hit
                    found[key][2] += sum(not np.any(np.abs(truth - t) <= MATCH_S) for t in told)
    assert (weak, rest) == (27, 225)  # (the set the bounds were measured on)
    assert found["on"][0] >= WEAK_FOUND_MIN > found["off"][0], found
    assert found["on"][1] >= found["off"][1], found
    assert found["on"][2] <= FALSE_MAX, found


def test_tail_kinks_are_the_same_whatever_the_chunking():
    """Judged on the samples up to the kink's scale after it, all held when the kink bank
    tests a candidate: chunking changes no contact. (This signal has a tail kink.)"""
    rec = synth.slip_recording(LAYOUTS_MM["alpha0.3"], 35.0, reverse=True, seed=7)

    def told(chunk: int) -> list:
        detector = ContactDetector(rec.fs_hz, ON)
        events = []
        for i in range(0, len(rec.t_s), chunk):
            events += detector.feed(rec.t_s[i : i + chunk], rec.force_n[i : i + chunk])[0]
        return [(e.t_s, e.index, e.emit_index, e.z) for e in events]

    whole = told(len(rec.t_s))
    off, _ = ContactDetector(rec.fs_hz, OFF).feed(rec.t_s, rec.force_n)
    assert len(whole) > len(off)
    for chunk in (1, 3, 50):
        assert told(chunk) == whole, chunk

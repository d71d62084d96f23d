"""The skin node's own signal: 12-bit ADC counts over CAN, and a sensor sitting on its rail.

Issue 11: the default decoder gave the wrong slip direction on the skin
node's CAN stream (the same run's float CSV decoded right) and ~400 mm/s
speeds on the headline scene. Root cause: every noise estimate was a
median, and a median of quantised values (or of a signal clipped at 0 N
before the object reaches the sensor) sticks to a lattice point or to 0:
thresholds fell to a fraction of the real noise and noise became "ridge
contacts". These tests feed the decoders what the node sends.
"""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding import filters
from grasplink.decoding.contacts import ContactDetector
from grasplink.decoding.io import skin_tpdo
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation.scoring import along_truth
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

CALIBRATION = skin_tpdo().calibration
ADC_STEP_N = CALIBRATION.n_per_count  # ~0.024 N


def adc(force_n: np.ndarray) -> np.ndarray:
    """What the skin node's TPDO carries, back in newtons: whole counts, clipped at 0."""
    top = CALIBRATION.full_counts - CALIBRATION.zero_counts
    counts = np.clip(np.round(force_n / ADC_STEP_N), 0, top)
    return counts * ADC_STEP_N


def decode(layout, t: np.ndarray, x: np.ndarray, chunk: int = 3):
    decoder = TrackerDecoder(layout, 400.0)
    out = []
    for start in range(0, len(t), chunk):  # as CAN frames bring them
        out += decoder.feed(t[start : start + chunk], x[start : start + chunk])
    return out


def signs_and_errors(rec: synth.SkinRecording, estimates) -> tuple[int, int, float, int]:
    """(speeds while slipping, of which a wrong direction, median speed error, false slips);
    a speed without a direction counts as its magnitude (scoring.along_truth)."""
    t = np.array([e.t_s for e in estimates])
    slipping = np.interp(t, rec.t_s, rec.slipping) > 0.5
    truth = np.interp(t, rec.t_s, rec.speed_mm_s)
    v, direction = along_truth(estimates, truth)
    given = slipping & np.isfinite(v) & (v != 0)
    wrong = int(np.count_nonzero(given & (direction != 0) & (direction != np.sign(truth))))
    error = float(np.median(np.abs(v[given] - truth[given]) / np.abs(truth[given])))
    false = sum(1 for e, s in zip(estimates, slipping, strict=True) if e.slip and not s)
    return int(given.sum()), wrong, error, false


# -- the statistics ---------------------------------------------------------------------------
@pytest.mark.parametrize("sigma_n", [0.02, 0.04])
def test_noise_sigma_of_adc_counts_is_not_pinned_to_the_lattice(sigma_n):
    """White noise of about one ADC step: the plain median |difference| sits on half a step
    or a whole one (~20 % off on average, 0 or double per block); the lattice median does not."""
    rng = np.random.default_rng(5)
    truth = np.hypot(sigma_n, ADC_STEP_N / np.sqrt(12.0))  # what a detector sees
    blocks = [adc(3.0 + rng.normal(0, sigma_n, 50)) for _ in range(400)]
    ratios = [filters.mad_sigma(np.diff(b)) / np.sqrt(2.0) / truth for b in blocks]
    assert abs(np.mean(ratios) - 1.0) < 0.08
    assert np.std(ratios) < 0.2


def test_lattice_median_is_the_median_on_continuous_data():
    x = np.random.default_rng(1).normal(0, 1, 301)
    assert filters.lattice_median(x) == np.median(x)
    assert filters.lattice_median(np.full(10, 2.5)) == 2.5  # no spread: nothing to spread ties over


def test_a_rail_is_told_from_quantised_noise_and_ramps():
    rng = np.random.default_rng(2)
    assert filters.on_rail(np.maximum(0.0, rng.normal(0.0, 0.02, 50)))  # clipped at 0 N
    assert filters.on_rail(adc(rng.normal(-0.01, 0.02, 50)))  # ADC count 0
    assert filters.on_rail(np.full(50, 1.5))
    assert not filters.on_rail(adc(3.0 + rng.normal(0, 0.02, 50)))
    assert not filters.on_rail(adc(np.linspace(2.0, 2.12, 50)))  # a slow ramp over 5 steps
    assert not filters.on_rail(rng.normal(0, 0.02, 50))
    assert filters.resolution(adc(3.0 + rng.normal(0, 0.05, 50))) == pytest.approx(ADC_STEP_N)


# -- the decoder --------------------------------------------------------------------------------
@pytest.mark.parametrize("layout", ["alpha0.1", "alpha0.5", "alpha0.9"])
def test_reverse_slip_through_the_adc_keeps_its_sign(layout):
    """The issue's case: 20 mm/s reverse; before the fix 11-55 % of speeds had the wrong
    sign (median error 50-180 %) through the ADC and none from the float signal."""
    rec = synth.slip_recording(LAYOUTS_MM[layout], 20.0, reverse=True, seed=1)
    given, wrong, error, false = signs_and_errors(
        rec, decode(rec.layout_mm, rec.t_s, adc(rec.force_n))
    )
    _, _, error_float, _ = signs_and_errors(rec, decode(rec.layout_mm, rec.t_s, rec.force_n))
    assert given >= 50 and wrong == 0 and false == 0
    assert error <= max(0.02, 2 * error_float)


def test_adc_noise_alone_is_no_slip():
    """A held object over CAN: white noise of about one ADC step (was 23 % false slip)."""
    rng = np.random.default_rng(3)
    t = np.arange(8000) / 400.0
    for layout in (LAYOUTS_MM["alpha0.1"], LAYOUTS_MM["fibonacci"]):
        x = adc(5.0 + rng.normal(0, synth.NOISE_WHITE_N, len(t)))
        estimates = decode(layout, t, x, chunk=3)
        assert not any(e.slip for e in estimates)
        events, _ = ContactDetector(400.0).feed(t, x)
        assert len(events) <= 2  # a false contact every 10 s at most


RAIL_CASES = [(40.0, False, 1), (25.0, True, 2), (40.0, False, 3)]


def rail_start(speed: float, reverse: bool, seed: int) -> tuple[synth.SkinRecording, np.ndarray]:
    """The headline scene's start: the FSR reads 0 N (noise clipped) until the object lands,
    0.1 s before it slips, with speed dips at every ridge."""
    rec = synth.slip_recording(
        LAYOUTS_MM["alpha0.1"], speed, reverse=reverse, dips=True, onset_s=1.0, seed=seed
    )
    x = rec.force_n.copy()
    before = rec.t_s < 0.9
    x[before] = np.maximum(0.0, np.random.default_rng(seed).normal(-0.01, 0.02, before.sum()))
    return rec, x


@pytest.mark.parametrize("speed,reverse,seed", RAIL_CASES)
def test_sensor_on_its_rail_before_the_object_arrives(speed, reverse, seed):
    """The clipped stretch shows no noise, so it says nothing about it; before the fix its
    near-zero noise estimate turned every poke above the rail into a contact (speeds up to
    ~380 mm/s, mostly the wrong way, and slips flagged on a resting object)."""
    rec, x = rail_start(speed, reverse, seed)
    for signal in (x, adc(x)):
        estimates = decode(rec.layout_mm, rec.t_s, signal)
        given, wrong, _, false = signs_and_errors(rec, estimates)
        assert given >= 100 and wrong == 0 and false == 0
        fastest = max(e.speed_mm_s or 0.0 for e in estimates)
        assert fastest <= 1.25 * speed, f"{fastest:.0f} mm/s"


DIPS_DEFECT = (
    "speed median 5.1-7.3 % > 5 % with speed dips at every ridge: the tracker that replaced "
    "the constant-speed one (issue 9) has a narrow dip prior (0.1 mm); no wrong sign, no false slip"
    " (the dip prior's curve: docs/benchmarks/slip_reporting.md, DIP_PRIOR_MM)"
)
# seed 1's ADC stream reads the last gap (51 -> 84 mm, 0.83 s) as the slip going on at its
# dip-biased speed (37.0 for 40 mm/s, 7.4 %): 155 speeds at a median 5.8 %. The float
# stream's coin (P(slip) ~0.45 there) fell to a stop, whose speed 0 the median does not
# count: 111 speeds at 3.5 % (test_restart_reach: the restart past the last ridge that held
# the stop, refuted by the stopped tracks' reach). Since the ridge-shaped step's prior
# (`LOG_SHAPE_RIDGE_STOP`, s34) the float stream too reads that gap as the slip going on,
# as it is, at the same dip-biased speed: a median of 6.2 %
GAP_READ_AS_SLIP = DIPS_DEFECT + "; seed 1: its last gap is read as slipping, at the dips' bias"


def _xfail(reason: str) -> pytest.MarkDecorator:
    return pytest.mark.xfail(strict=True, reason=reason)


@pytest.mark.parametrize(
    "speed,reverse,seed,quantised",
    [
        pytest.param(40.0, False, 1, False, marks=_xfail(GAP_READ_AS_SLIP)),
        pytest.param(40.0, False, 1, True, marks=_xfail(GAP_READ_AS_SLIP)),
        pytest.param(25.0, True, 2, False, marks=_xfail(DIPS_DEFECT)),
        # within 5 % since a slip onto the empty skin enters at an end (`decoding.arrival`:
        # 4.7 %; 5.5 % with ARRIVAL_EMPTY_N 0, the start prior alone)
        (40.0, False, 3, False),
    ],
)
def test_speed_after_the_rail_with_dips(speed, reverse, seed, quantised):
    """The median speed error over the speeds given while slipping (a stop reported during
    the slip gives none, and is not counted)."""
    rec, x = rail_start(speed, reverse, seed)
    _, _, error, _ = signs_and_errors(
        rec, decode(rec.layout_mm, rec.t_s, adc(x) if quantised else x)
    )
    assert error <= 0.05

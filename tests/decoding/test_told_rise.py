"""`told_rise`: a contact's own rise read at each ridge child's speed - a pulse rises there,
a bend of the level onto a ramp (hysteresis letting go onto the coverage rise) does not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasplink.decoding import rise_evidence as rev
from grasplink.decoding import told_rise
from grasplink.decoding.detector.events import ContactEvent
from grasplink.decoding.detector.step_shape import Recent
from grasplink.decoding.kernels.layout import F_SCORE, F_STOP, F_V, F_WIDTH, I_LAST, I_RUN, I_WIDTH
from grasplink.decoding.ridge_pulses import RISE_MM

FS_HZ = 400.0
WHITE_N = 0.02  # the loop scenes' white noise
ONSET = 300  # the contact's onset (global sample index)
SPEED_MM_S = 40.0


def _evidence(x: np.ndarray) -> rev.RiseEvidence:
    recent = Recent(FS_HZ)
    recent.append(x)
    return rev.RiseEvidence(FS_HZ, recent, lambda block: (WHITE_N, 8), 50, 1e-3)


BEND_LAG = 12  # samples from the told onset to the bend (the headline: 1.496 -> ~1.525 s)
TAIL_LEAD = 50  # samples from the earlier ridge's onset to ONSET (`_signal("tail")`)


def _signal(
    kind: str, seed: int = 3, n: int = 600, pulse_n: float = 0.15, lead: int = TAIL_LEAD
) -> np.ndarray:
    """0.6 N and white noise, and from ONSET a ridge pulse at SPEED_MM_S (0.7 N), or the
    coverage ramp taking over a flat level (1.6 N/s) BEND_LAG samples after ONSET: the
    headline loop's 1.496 s, told on the 80 ms scale ~30 ms before the level lets go."""
    rng = np.random.default_rng(seed)
    tau_s = np.clip((np.arange(n) - ONSET) / FS_HZ, 0.0, None)
    if kind == "pulse":
        u = tau_s * SPEED_MM_S / RISE_MM
        shape = 0.7 * u * np.exp(1.0 - u)
    elif kind == "tail":  # a ridge's pulse at 20 mm/s `lead` before ONSET, falling there
        u = np.clip((np.arange(n) - ONSET + lead) / FS_HZ, 0.0, None) * 20.0 / RISE_MM
        v = tau_s * SPEED_MM_S / RISE_MM
        shape = 0.7 * u * np.exp(1.0 - u) + pulse_n * v * np.exp(1.0 - v)
    else:
        shape = 1.6 * np.clip(tau_s - BEND_LAG / FS_HZ, 0.0, None)
    return 0.6 + shape + WHITE_N * rng.standard_normal(n)


def _children(speeds_mm_s: list[float], contact_id: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """Ridge children of the contact (run >= 2, slipping) at those speeds, then one that
    took it for clutter (its last contact another) and one stopped."""
    n = len(speeds_mm_s) + 2
    floats, ints = np.zeros((n, F_WIDTH)), np.zeros((n, I_WIDTH), np.int64)
    floats[:, F_STOP] = math.nan
    floats[:, F_V] = [*speeds_mm_s, SPEED_MM_S, SPEED_MM_S]
    ints[:, I_LAST] = contact_id
    ints[:, I_RUN] = 2
    ints[-2, I_LAST] = contact_id - 1
    floats[-1, F_STOP] = 1.0
    return floats, ints


def _contact(emit_after: int, contact_id: int = 7) -> ContactEvent:
    return ContactEvent(contact_id, ONSET / FS_HZ, ONSET, ONSET + emit_after, 5.0, 2.0, 0.08, 0.01)


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_a_bend_onto_a_ramp_loses_and_a_ridge_pulse_does_not(seed):
    speeds = [20.0, 40.0, 65.0]
    for kind, loses in (("bend", True), ("pulse", False)):
        floats, ints = _children(speeds)
        evidence = _evidence(_signal(kind, seed))
        rows, z = told_rise.ridge_loss(floats, ints, _contact(64), evidence, log_loss=-4.0)
        assert rows.tolist() == [0, 1, 2]
        assert np.all(np.isfinite(z))
        expected = np.array([-4.0 if loses else 0.0] * 3 + [0.0, 0.0])
        assert floats[:, F_SCORE] == pytest.approx(expected), (kind, z)
        if kind == "pulse":
            assert np.all(z > 10.0), z  # tens of noise units, far over Z_MAX


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_with_tail_z_a_ridge_on_a_falling_tail_is_not_read_but_a_bend_still_is(seed):
    """A ridge after a short spacing starts on the previous pulse's fall: the level goes on
    falling through its rise, so the probe cannot read the rise there - the ridge is not
    judged by it (no z, no loss). A bend onto the ramp comes off a flat level: still read,
    still loses."""
    floats, ints = _children([20.0, 40.0])
    evidence = _evidence(_signal("tail", seed))
    _, _, trend = rev_trend(evidence, [20.0, 40.0])
    assert np.all(trend < -3.0), trend
    _, z = told_rise.ridge_loss(floats, ints, _contact(64), evidence, tail_z=3.0)
    assert np.isnan(z).all() and not floats[:, F_SCORE].any()
    floats, ints = _children([20.0, 40.0, 65.0])
    bend = _evidence(_signal("bend", seed))
    _, z = told_rise.ridge_loss(floats, ints, _contact(64), bend, log_loss=-4.0, tail_z=3.0)
    assert np.all(np.isfinite(z)) and floats[:3, F_SCORE] == pytest.approx([-4.0] * 3)


TAIL_END_LEAD = 80  # samples from a lone pulse's onset to ONSET: its fall ends there


@pytest.mark.parametrize("seed", [1, 2, 3, 4, 5])
def test_with_tail_fall_z_a_small_pulse_in_a_fall_is_spared_a_falls_end_is_read(seed):
    """A ridge after a short spacing has a small pulse on the previous one's steep fall:
    the level falls on through the rise's window (z far under 0) and the rise is not read.
    Where a fall ends with no ridge (loop_least_force's 2.55 s) the level flattens after
    the bend: z near 0, read, the ridge child loses."""
    speeds = [20.0, 40.0]
    floats, ints = _children(speeds)
    small = _evidence(_signal("tail", seed, pulse_n=0.05))
    _, z, trend = rev_trend(small, speeds)
    assert np.all(trend < -3.0) and np.all(z < -6.0), (trend, z)
    _, z = told_rise.ridge_loss(
        floats, ints, _contact(64), small, log_loss=-4.0, tail_z=3.0, tail_fall_z=6.0
    )
    assert np.isnan(z).all() and not floats[:, F_SCORE].any()
    floats, ints = _children(speeds)
    end = _evidence(_signal("tail", seed, pulse_n=0.0, lead=TAIL_END_LEAD))
    _, z, trend = rev_trend(end, speeds)
    assert np.all(trend < -3.0) and np.all(z > -6.0), (trend, z)
    _, z = told_rise.ridge_loss(
        floats, ints, _contact(64), end, log_loss=-4.0, tail_z=3.0, tail_fall_z=6.0
    )
    assert np.all(np.isfinite(z)) and floats[:2, F_SCORE] == pytest.approx([-4.0] * 2)


def rev_trend(
    evidence: rev.RiseEvidence, speeds_mm_s: list[float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The windows of children at those speeds, the probe's z and the level's trend just
    before ONSET on each."""
    width = evidence.width_for(np.array(speeds_mm_s))
    onsets = np.full(len(speeds_mm_s), float(ONSET))
    z, trend = evidence.z_and_trend_each(onsets, width, ONSET + 64)
    return width, z, trend


def test_a_contact_told_at_once_is_not_read_nor_one_on_the_rail():
    # decided 4 samples after its onset: the probe's window is not yet held - no evidence
    floats, ints = _children([40.0])
    _, z = told_rise.ridge_loss(floats, ints, _contact(4), _evidence(_signal("bend")))
    assert np.isnan(z).all() and not floats[:, F_SCORE].any()
    # a window touching the upper rail reads flat: no evidence either
    rail = [(ONSET / FS_HZ + 0.01, ONSET / FS_HZ + 0.5)]
    _, z = told_rise.ridge_loss(floats, ints, _contact(64), _evidence(_signal("bend")), rail)
    assert np.isnan(z).all() and not floats[:, F_SCORE].any()


def test_bad_settings_are_refused_by_name():
    floats, ints = _children([40.0])
    with pytest.raises(ValueError, match="told rise"):
        told_rise.ridge_loss(floats, ints, _contact(64), _evidence(_signal("bend")), log_loss=1.0)
    with pytest.raises(ValueError, match="told rise"):
        told_rise.ridge_loss(floats, ints, _contact(64), _evidence(_signal("bend")), z_max=math.nan)

"""The silence bound on slip dropped (`evaluation/silence_bound.py`) on hand-built truths:
a steady slide is never silent past due, a slide that slows mid-gap is from the look-alike
stop's due time to the next contact, a real stop is cleared (and is no sliding update)."""

from __future__ import annotations

import numpy as np

from grasplink.evaluation import silence_bound as sb
from grasplink.evaluation import slip_reporting as sr
from grasplink.simulators.synth import SkinRecording

FS_HZ = 400
LAYOUT_MM = (10.0, 10.0, 10.0, 10.0)  # ridges at 0, 10, 20, 30, 40 mm
UPDATE_S = 0.01


def _truth(knots: list[tuple[float, float]], start_mm: float, length_s: float) -> SkinRecording:
    """The edge on a signed speed profile (linear between knots), contacts where it
    crosses a ridge; no force (the bound reads the truth only)."""
    t = np.arange(int(length_s * FS_HZ)) / FS_HZ
    v = np.interp(t, [k[0] for k in knots], [k[1] for k in knots])
    x = start_mm + np.concatenate([[0.0], np.cumsum((v[1:] + v[:-1]) / 2) / FS_HZ])
    rec = SkinRecording(
        t,
        np.zeros(len(t)),
        x,
        v,
        (np.abs(v) > 0).astype(float),
        np.full(len(t), 5.0),
        np.zeros(0),
        LAYOUT_MM,
        FS_HZ,
    )
    rec.contact_times_s = sr.ridge_crossings_s(rec)
    return rec


def _updates(truth: SkinRecording) -> np.ndarray:
    return truth.t_s[:: round(UPDATE_S * FS_HZ)]


def _down(truth: SkinRecording, t: np.ndarray, wait_s: float = 0.0) -> np.ndarray:
    contacts = truth.contact_times_s
    return sb.silent_down(t, contacts, contacts, sb.stop_due_s(truth, contacts), wait_s)


def test_a_steady_slide_is_never_silent_past_due():
    truth = _truth([(0.0, 0.0), (0.2, 0.0), (0.201, 20.0), (3.0, 20.0)], -5.0, 3.0)
    t = _updates(truth)
    dropped, scored = sb.dropped_where(t, _down(truth, t), truth)
    assert scored > 100
    assert dropped == 0


def test_a_slide_halving_its_speed_mid_gap_is_silent_from_due_to_the_next_contact():
    # 20 mm/s until 0.1 s past the ridge at 20 mm, then 10 mm/s: the look-alike stop
    # after that contact is observable when 20 mm/s would reach 30 mm (0.5 s on) and
    # due 0.15 s later; the true contact comes 0.1 + 8 / 10 s after the ridge.
    t_c = 0.3 + 25.0 / 20.0  # the edge starts 5 mm before the first ridge, after 0.3 s
    slow = t_c + 0.1
    truth = _truth(
        [(0.0, 0.0), (0.3, 0.0), (0.3 + 1e-6, 20.0), (slow, 20.0), (slow + 1e-6, 10.0), (4, 10)],
        -5.0,
        4.0,
    )
    contacts = truth.contact_times_s
    c = int(np.argmin(np.abs(contacts - t_c)))
    t = _updates(truth)
    down = _down(truth, t)
    due = contacts[c] + 10.0 / 20.0 + sr.CLEAR_WITHIN_S
    next_contact = contacts[c + 1]
    assert abs(next_contact - (contacts[c] + 0.1 + 8.0 / 10.0)) < 0.01
    last_before_due = t[t <= due].max()
    expected = (t >= last_before_due) & (t < next_contact)
    window = (t > contacts[c]) & (t < next_contact)
    assert np.array_equal(down[window], expected[window])
    dropped, _ = sb.dropped_where(t, down, truth)
    assert dropped == int(expected.sum()) > 20


def test_a_stop_is_not_sliding_and_is_cleared_unless_the_decoder_waits():
    # 20 mm/s to the edge at 25 mm, stopped for 1.5 s: observable when 20 mm/s would
    # have reached 30 mm.
    stop_s = 0.3 + 30.0 / 20.0
    truth = _truth(
        [
            (0.0, 0.0),
            (0.3, 0.0),
            (0.3 + 1e-6, 20.0),
            (stop_s, 20.0),
            (stop_s + 0.03, 0.0),
            (stop_s + 1.5, 0.0),
        ],
        -5.0,
        stop_s + 1.5,
    )
    t = _updates(truth)
    down = _down(truth, t)
    assert sb.dropped_where(t, down, truth)[0] == 0  # before the stop: steady
    assert down[t > stop_s + 0.5].all()  # at rest: down from its report's due time on
    assert sb.stops_cleared(t, down, truth) == (1, 1)
    assert sb.stops_cleared(t, _down(truth, t, wait_s=0.05), truth) == (0, 1)


def test_a_contact_counts_only_once_known():
    t = np.array([0.0, 0.1, 0.2, 0.3])
    contacts = np.array([0.05, 0.15])
    assert sb.last_known(t, contacts, contacts).tolist() == [-1, 0, 1, 1]
    assert sb.last_known(t, contacts, contacts + 0.1).tolist() == [-1, -1, 0, 1]


def test_the_level_moves_only_while_the_object_changes_its_cover():
    # a 90 mm object (over a 40 mm skin) slides on from 5 mm before the first ridge
    truth = _truth([(0.0, 20.0), (6.0, 20.0)], -5.0, 6.0)
    t = _updates(truth)
    move = sb.motion_level_move_n(truth, t, object_length_mm=90.0)
    covering = (truth.position_mm[:: round(UPDATE_S * FS_HZ)] > 5.0 + 0.25 * 20.0) & (
        truth.position_mm[:: round(UPDATE_S * FS_HZ)] < 40.0
    )
    full = t > (40.0 + 5.0) / 20.0 + 0.25  # the skin covered all along the window
    full &= t < (90.0 + 5.0) / 20.0  # ... until the rear edge reaches the skin
    assert (move[covering] > 0.05).all()
    assert np.allclose(move[full], 0.0)


def test_the_white_noise_is_read_past_a_slow_drift():
    rng = np.random.default_rng(3)
    x = 0.02 * rng.standard_normal(4000) + np.linspace(0.0, 1.0, 4000)
    assert abs(sb.white_noise_n(x) - 0.02) < 0.002

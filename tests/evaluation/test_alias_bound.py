"""The 10 dB bound without the ridge identities (`evaluation/alias_bound.py`): on hand-built
contact sets, a uniform skin leaves two contacts' speed open, an aperiodic one is fixed by
three, a skipped ridge costs its P(miss), and a ridge the speed says was crossed unseen
costs it too."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.evaluation import alias_bound as ab

CONSTANT = ab.AliasSettings(rel=0.1, dv_dx_per_s=0.0)  # speeds within 10 %, times +-5 ms
SPEED_MM_S = 40.0


def _layout(spacings_mm: tuple[float, ...], p_det: float = 0.7) -> ab.Layout:
    n = len(spacings_mm) + 1
    return ab.Layout(spacings_mm, np.full(n, p_det), np.full(n, 0.05))


def _times(layout: ab.Layout, ridges: list[int], direction: int = 1) -> np.ndarray:
    """Contact times of the edge at SPEED_MM_S over travel-order `ridges`."""
    return 0.5 + layout.travel(direction)[0][ridges] / SPEED_MM_S


def _speeds(layout: ab.Layout, times_s: np.ndarray, settings: ab.AliasSettings) -> set[int]:
    """The fitting hypotheses' speeds (rounded, mm/s), both directions."""
    out: set[int] = set()
    for direction in (1, -1):
        pos, p_det, _ = layout.travel(direction)
        c = ab.chain(pos, times_s, p_det, settings)
        out |= {round(float(v)) for v in c.speed_mm_s[c.fits]}
    return out


def test_two_contacts_on_a_uniform_skin_leave_the_speed_open():
    layout = _layout((4.0,) * 10)
    times = _times(layout, [3, 4])
    speeds = _speeds(layout, times, CONSTANT)
    assert {40, 80, 120} <= speeds  # one ridge apart, or two, or three: 4 mm per 0.1 s each
    unanimous, likelihood, _ = ab.assess(layout, times, times[-1] + 0.01, CONSTANT)
    assert not unanimous
    assert not likelihood


def test_three_contacts_on_an_aperiodic_skin_fix_the_speed():
    layout = _layout((7.0, 64.0, 13.0))
    two = _times(layout, [0, 1])
    assert ab.assess(layout, two, two[-1] + 0.01, CONSTANT)[:2] == (False, False)
    three = _times(layout, [0, 1, 2])
    unanimous, likelihood, v_map = ab.assess(layout, three, three[-1] + 0.01, CONSTANT)
    assert unanimous and likelihood
    assert v_map == pytest.approx(SPEED_MM_S)
    assert _speeds(layout, three, CONSTANT) == {40}


def test_a_speed_that_may_change_with_the_travel_lets_the_aliases_back():
    layout = _layout((7.0, 64.0, 13.0))
    three = _times(layout, [0, 1, 2])
    smooth = ab.AliasSettings(rel=0.1, dv_dx_per_s=1.0)
    assert len(_speeds(layout, three, smooth)) > 1
    assert not ab.assess(layout, three, three[-1] + 0.01, smooth)[0]


def test_a_skipped_ridge_fits_and_pays_its_miss():
    spacings = (7.0, 40.0, 13.0, 30.0)
    layout = _layout(spacings, p_det=0.7)
    times = _times(layout, [0, 2, 3])  # ridge 1 missed
    assert ab.true_fits(layout, 1, np.array([0, 2, 3]), times, CONSTANT)
    pos, p_det, _ = layout.travel(1)
    c = ab.chain(pos, times, p_det, CONSTANT)
    assert c.fits[2, 3]
    assert c.speed_mm_s[2, 3] == pytest.approx(SPEED_MM_S)
    # the only fitting path to (2, 3): ridge 0 told, 1 missed, 2 and 3 told
    assert c.weight[2, 3] == pytest.approx(0.7 * 0.3 * 0.7 * 0.7)
    _, likelihood, v_map = ab.assess(layout, times, times[-1] + 0.01, CONSTANT)
    assert likelihood and v_map == pytest.approx(SPEED_MM_S)


def test_a_wrong_speed_does_not_fit_the_true_ridges():
    layout = _layout((7.0, 64.0, 13.0))
    times = _times(layout, [0, 1, 2])
    times[2] += 0.5  # the last interval far slower than the first
    assert not ab.true_fits(layout, 1, np.array([0, 1, 2]), times, CONSTANT)


def test_ridges_the_speed_says_were_crossed_unseen_cost_their_miss():
    layout = _layout((4.0,) * 5, p_det=0.9)
    pos, p_det, lag = layout.travel(1)
    speed = np.full((6, 6), SPEED_MM_S)
    t_last = 1.0
    # 0.25 s after ridge 0 at 40 mm/s the edge passed ridges 1 and 2 (0.1, 0.2 s + 0.05 s)
    after = ab.after_miss(pos, p_det, lag, speed, t_last, t_last + 0.25)
    assert after[0, 0] == pytest.approx(0.1**2)
    assert after[0, 4] == pytest.approx(0.1)  # from ridge 4 only ridge 5 is ahead
    assert after[0, 5] == pytest.approx(1.0)


def test_run_bound_holds_a_determined_speed_through_a_silence():
    layout = _layout((7.0, 64.0, 13.0))
    contact = _times(layout, [0, 1, 2, 3])
    told = np.array([True, True, True, False])
    decided = contact + 0.05
    t_upd = np.arange(contact[2], contact[3] + 0.5, 0.01)
    b = ab.run_bound(layout, 1, contact, told, decided, t_upd, CONSTANT)
    assert b.truth_fits
    assert not b.unanimous_now[0]  # the third not decided yet
    assert b.unanimous_now[10] and b.likelihood_now[10]
    assert b.unanimous_held[-1] and b.likelihood_held[-1]
    # the 4th contact passes untold: the last two told (1 and 2) are still among the last 3
    late = t_upd > contact[3]
    assert b.unanimous_held[late].all()
    assert b.unanimous_fresh[late].all()
    assert not b.wrong.any()

"""The slip flag held while the skin's level ramps (`decoding.level_ramp`).

The case: the full plan's loop kind at 30 mm/s on alpha0.3 (4, 3, 48, 29 mm), forward,
seed 161200: the 90 mm object slides onto the skin from 8 mm before it (arrival 1.27 s),
the FSR's hysteresis absorbs the 2nd and 3rd ridges, and the next is 48 mm on (3.16 s).
Without the hold the flag drops from 1.71 s (the arrival flag's silence) to 3.82 s while
the level climbs about 1.4 N/s (the object covering more skin)."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding import level_ramp
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
from tests.decoding.plan_cases import decode_case, score_case

FS_HZ = 400.0


def _loop(tuning: dict):
    """(update times, flags, speeds, truth) of the loop case, decoded with its grip
    commands as `slip_reporting.case_job` does."""
    case = next(
        c
        for c in sr.cases(sr.FULL)
        if c.kind == "loop" and c.seed == 161200 and c.variant == "30 mm/s"
    )
    rec = case.make()
    dec = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz, tuning=tuning)
    for t_s, force_n in sr.loop_grip_commands(case):
        dec.note_grip_command(t_s, force_n)
    estimates, _ = ns.feed(dec, rec.t_s, rec.force_n, sr.CHUNK)
    t = np.array([e.t_s for e in estimates])
    flags = np.array([e.slip for e in estimates])
    return t, flags, [e.speed_mm_s for e in estimates], rec.truth


def test_the_flag_is_held_while_the_object_slides_on_between_ridges():
    t, flags, speeds, truth = _loop({"RAMP_HOLD": 1.0})
    gap = (t >= 2.2) & (t <= 3.1)  # between the arrival's flag and the 48 mm ridge
    assert (np.interp(t[gap], truth.t_s, truth.speed_mm_s) > 20.0).all()
    assert flags[gap].all()
    assert all(speeds[k] is None for k in np.flatnonzero(gap))  # a ramp tells no speed


def test_without_it_the_flag_drops_there():
    t, flags, _, _ = _loop({"RAMP_HOLD": 0.0})
    gap = (t >= 2.2) & (t <= 3.1)
    assert not flags[gap].any()


def test_the_hold_ends_at_rest():
    t, flags, _, truth = _loop({"RAMP_HOLD": 1.0})
    rest = np.interp(t, truth.t_s, truth.speed_mm_s) == 0.0
    late = rest & (t > truth.t_s[np.flatnonzero(truth.speed_mm_s)[-1]] + 0.3)
    assert late.any() and not flags[late].any()


def _stick(tuning: dict):
    """(update times, flags, the stop's (start, end) s, when it became observable) of the
    full plan's stick-slip at 14 mm/s on alpha0.1, reversed, seed 80121: the level ramps
    up while the object slides, steps up as it sticks at 3.115 s (the last ridge 17 ms
    before) and falls about 2 N/s through the stick to 3.485 s."""
    rec, _, estimates = decode_case("stick-slip", 80121, tuning, "14 mm/s")
    stop = next(s for s in sr.score(estimates, rec.truth).stops if 3.0 < s.start_s < 3.2)
    t = np.array([e.t_s for e in estimates])
    return t, np.array([e.slip for e in estimates]), (stop.start_s, stop.end_s), stop.observable_s


def test_one_way_a_level_turning_in_a_stick_holds_no_flag():
    t, flags, (_, end), observable = _stick({"RAMP_ONE_WAY": 2.0})
    stick = (t > observable) & (t < end)
    assert stick.sum() >= 15 and not flags[stick].any()


def test_held_any_way_the_turn_raises_the_flag_in_the_stick():
    t, flags, (_, end), observable = _stick({})  # shipped: RAMP_ONE_WAY 0
    stick = (t > observable) & (t < end)
    assert flags[stick].any()


def _windows(level: np.ndarray, steps: int = 4, window_s: float = 0.05) -> np.ndarray:
    return level[-(steps + 1) * round(window_s * FS_HZ) :]


def test_a_ramp_a_flat_level_and_a_step():
    rng = np.random.default_rng(0)
    t = np.arange(400) / FS_HZ
    noise = 0.02 * rng.standard_normal(len(t))
    step = level_ramp.step_min_n(0.05, FS_HZ, 0.2, 1.5, 0.02)
    assert step == pytest.approx(1.5 * np.sqrt(np.pi) * 0.02 / np.sqrt(20))  # noise's bound
    assert level_ramp.ramp_way(_windows(0.5 * t + noise), 4, step) != 0  # 10 mm/s sliding on
    assert level_ramp.ramp_way(_windows(-0.5 * t + noise), 4, step) != 0  # ... or off
    assert level_ramp.ramp_way(_windows(0.05 * t + noise), 4, step) == 0  # drift
    # a stop's step, then flat: one window's step, not a ramp
    assert level_ramp.ramp_way(_windows(np.where(t > 0.9, 0.3, 0.0) + noise), 4, step) == 0
    # a ridge's pulse (a few samples above half height) on a flat level makes no ramp
    pulse = 0.8 * np.exp(-0.5 * ((t - 0.93) / 0.002) ** 2)
    assert level_ramp.ramp_way(_windows(noise + pulse), 4, step) == 0
    assert level_ramp.ramp_way(None, 4, step) == 0  # samples no longer held


def test_a_ramp_tells_its_way():
    rng = np.random.default_rng(1)
    t = np.arange(400) / FS_HZ
    noise = 0.02 * rng.standard_normal(len(t))
    step = level_ramp.step_min_n(0.05, FS_HZ, 0.2, 1.5, 0.02)
    assert level_ramp.ramp_way(_windows(0.5 * t + noise), 4, step) == 1  # covering more
    assert level_ramp.ramp_way(_windows(-0.5 * t + noise), 4, step) == -1  # ... or less
    assert level_ramp.ramp_way(_windows(noise), 4, step) == 0  # at rest
    assert level_ramp.ramp_way(None, 4, step) == 0


def test_heavy_noise_asks_a_steeper_ramp():
    quiet = level_ramp.step_min_n(0.05, FS_HZ, 0.2, 1.5, 0.001)
    loud = level_ramp.step_min_n(0.05, FS_HZ, 0.2, 1.5, 0.2)
    assert quiet == pytest.approx(0.2 * 0.05)  # the slope's bound
    assert loud > 5 * quiet


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="window"):
        level_ramp.step_min_n(0.0, FS_HZ, 0.2, 1.5, 0.02)
    with pytest.raises(ValueError, match="must be >= 0"):
        level_ramp.step_min_n(0.05, FS_HZ, -0.2, 1.5, 0.02)
    with pytest.raises(ValueError, match="steps must be >= 1"):
        level_ramp.ramp_way(np.zeros(10), 0, 0.01)


def _chatter(tuning: dict) -> int:
    """Runs of the flag under 50 ms (`slip_reporting`'s flag chatter) in the full plan's
    constant 8 mm/s slip on alpha0.9 (6, 20, 58 mm), seed 54001: after the 1st ridge the
    next is 58 mm on (7 s), the level ramping slowly as the object covers more skin."""
    return score_case("constant", 54001, tuning, "8 mm/s").short_flag_runs


def test_with_the_flag_up_a_slow_ramp_holds_at_half_its_step_without_chatter():
    """The medians' test near its least step passes and fails from one update to the next;
    held on at half that step once up (`RAMP_KEEP_SHARE` 0.5), the flag chatters a third
    as often (158 runs under 50 ms without it, 58 with)."""
    assert _chatter({}) <= 70
    assert _chatter({"RAMP_KEEP_SHARE": 1.0}) >= 150

"""The end of a slip: a stop's small step on the falling tail of the last ridge pulse, and
stops the benchmark's signals make (light grip past the last ridge, 10 dB noise)."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding.contacts import ContactDetector
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation.decoders import make_decoder

FS_HZ = 400.0
PULSE_S = 0.5  # the last ridge pulse (thesis ch. 5.3.1 shape: alpha u e^(1 - u))
EVENT_S = 0.7  # on its falling tail: a stop's step, or the next ridge's pulse


def ridge_pulse(t: np.ndarray, at_s: float, height_n: float, rise_s: float) -> np.ndarray:
    u = np.clip((t - at_s) / rise_s, 0.0, None)
    return height_n * u * np.exp(1.0 - u)


def tail_signal(event: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """2 N held, a 0.8 N ridge pulse rising in 50 ms; on its tail 0.2 s later either the
    object stops (the friction term's 0.15 N step, in 20 ms, the tail relaxing on) or the
    next ridge's pulse replaces the tail (0.4 N, rising in 20 ms); 0.01 N white noise."""
    t = np.arange(0.0, 1.6, 1.0 / FS_HZ)
    x = 2.0 + 0.01 * np.random.default_rng(seed).standard_normal(len(t))
    if event == "stop":
        x += ridge_pulse(t, PULSE_S, 0.8, 0.05)
        x += 0.15 * np.clip((t - EVENT_S) / 0.02, 0.0, 1.0)
    else:
        before = t < EVENT_S
        x += np.where(before, ridge_pulse(t, PULSE_S, 0.8, 0.05), 0.0)
        level = ridge_pulse(np.array([EVENT_S]), PULSE_S, 0.8, 0.05)[0]
        rise = np.clip((t - EVENT_S) / 0.02, 0.0, 1.0)
        fresh = ridge_pulse(t, EVENT_S, 0.4, 0.02)
        x += np.where(before, 0.0, np.where(rise < 1.0, level + (0.4 - level) * rise, fresh))
    return t, x


def verdict_at(t: np.ndarray, x: np.ndarray, at_s: float) -> bool | None:
    events, checks = ContactDetector(FS_HZ).feed(t, x)
    near = [e for e in events if abs(e.t_s - at_s) <= 0.02]
    assert near, f"no contact within 20 ms of {at_s} s: {[round(e.t_s, 3) for e in events]}"
    told = [c.pulse for c in checks if c.id == near[0].id]
    assert told, "no verdict on the contact"
    return told[0]


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_small_step_on_the_falling_tail_of_a_pulse_is_told_a_step(seed):
    """The ridge goes on relaxing when the object stops: the level falls on after the
    step, yet stays up over the tail continued."""
    t, x = tail_signal("stop", seed)
    assert verdict_at(t, x, EVENT_S) is False


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_ridge_pulse_on_the_falling_tail_of_the_last_is_told_a_pulse(seed):
    """A ridge pulse replaces the tail and falls back faster than the tail did."""
    t, x = tail_signal("pulse", seed)
    assert verdict_at(t, x, EVENT_S) is True


def clear_times(category: str, variant: str, layout: str, reverse: bool, repeat: int) -> list:
    signal = next(
        s
        for s in ns.signals(False)
        if (s.category, s.variant, s.layout, s.reverse, s.repeat)
        == (category, variant, layout, reverse, repeat)
    )
    rec = signal.make()
    decoder = make_decoder("tracker", rec.truth.layout_mm, rec.fs_hz)
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, ns.PACKET)
    return ns.score(estimates, rec).clear_s


@pytest.mark.parametrize(
    "variant, layout, reverse",
    [
        ("22 mm/s", "alpha0.1", False),
        ("22 mm/s", "fibonacci", False),
        ("57 mm/s", "alpha0.3", False),
    ],
)
def test_a_stop_past_the_last_ridge_with_a_light_grip_clears_the_flag_within_0_3_s(
    variant, layout, reverse
):
    """Grip 3 N: the friction term's step is ~0.14 N, on the last pulse's falling tail."""
    clears = clear_times("grip-steps", variant, layout, reverse, 0)
    assert all(c <= ns.CLEAR_WITHIN_S for c in clears), clears


@pytest.mark.parametrize(
    "variant, layout, reverse, repeat",
    [("57 mm/s", "alpha0.1", False, 0), ("21->98 mm/s", "alpha0.1", True, 0)],
)
def test_a_stop_past_the_last_ridge_in_10_db_noise_clears_the_flag_within_0_3_s(
    variant, layout, reverse, repeat
):
    """White noise a tenth of the ridge pulses' power and slow drift: the stop's step is a
    few noise units of a 20 ms difference of means, more of a 40 ms one."""
    clears = clear_times("snr10", variant, layout, reverse, repeat)
    assert all(c <= ns.CLEAR_WITHIN_S for c in clears), clears

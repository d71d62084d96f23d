"""The trend a watch takes out, with an earlier pulse in its window out (`prior_trend`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from grasplink.decoding.contacts import ContactDetector, DetectorSettings
from grasplink.decoding.detector.prior_trend import trend_past_pulse
from grasplink.decoding.detector.watch import WatchSettings

FS_HZ = 400.0
RISE_N_S = 0.2  # the level's slow rise under both contacts


def _trends_at_contacts(on: bool) -> list[tuple[float, float]]:
    """(onset s, trend N/s) of each kink contact's watch: a ridge-like pulse (0.4 N, 4 ms
    rise, 30 ms decay) at 1.0 s on a 0.2 N/s rise, and a flat 0.25 N step 50 ms later."""
    t_s = np.arange(int(2.0 * FS_HZ)) / FS_HZ
    since = np.maximum(t_s - 1.0, 0.0)
    pulse = 0.4 * (1.0 - np.exp(-since / 0.004)) * np.exp(-since / 0.03)
    force_n = 1.0 + RISE_N_S * t_s + pulse + np.where(t_s >= 1.05, 0.25, 0.0)
    force_n += np.random.default_rng(1).normal(0.0, 0.004, len(t_s))
    detector = ContactDetector(FS_HZ, DetectorSettings(watch=WatchSettings(trend_past_pulse=on)))
    seen: list[tuple[float, float]] = []
    start = detector.watcher.start

    def noting(cid: int, index: int, emit: int | None = None):  # type: ignore[no-untyped-def]
        watch = start(cid, index, emit)
        if watch is not None and emit is not None:
            seen.append((index / FS_HZ, watch.trend * FS_HZ))
        return watch

    detector.watcher.start = noting  # type: ignore[method-assign]
    for i in range(0, len(t_s), 4):
        detector.feed(t_s[i : i + 4], force_n[i : i + 4])
    return seen


def test_step_after_pulse_takes_out_the_rise_not_the_pulse() -> None:
    """The step 50 ms after a pulse: its window holds the pulse's rise and tail (1.46 N/s
    read off it), the trend before the pulse is the rise's 0.2 N/s."""
    swollen = _trends_at_contacts(False)
    fixed = _trends_at_contacts(True)
    assert [round(t, 2) for t, _ in fixed] == [round(t, 2) for t, _ in swollen]
    assert len(fixed) == 2 and fixed[1][0] == pytest.approx(1.05, abs=0.005)
    assert swollen[1][1] > 5 * RISE_N_S
    assert fixed[1][1] == pytest.approx(RISE_N_S, abs=0.05)
    assert fixed[0][1] == pytest.approx(swollen[0][1])  # nothing before the first


@pytest.mark.parametrize(
    ("trends", "expected"),
    [
        ([(950, 960, 0.001)], 0.001),  # an earlier onset in the window: the smaller
        ([(950, 960, 0.009)], 0.004),  # ... its trend larger: the window's own
        ([(890, 960, 0.001)], 0.004),  # onset before the window: the window's own
        ([(950, 1001, 0.001)], 0.004),  # not decided by this onset's decision: not seen
        ([(999, 960, 0.001)], 0.004),  # the same onset (within 2 samples): not earlier
        ([(890, 900, 0.0), (950, 960, 0.002)], 0.002),  # the latest earlier one
        ([(950, 960, math.nan)], 0.004),  # none measured there (no long trend): its own
        ([], 0.004),
    ],
)
def test_trend_past_pulse(trends: list[tuple[int, int, float]], expected: float) -> None:
    assert trend_past_pulse(trends, 1000, 1000, 900, 0.004) == pytest.approx(expected)

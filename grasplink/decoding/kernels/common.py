"""What more than one kernel needs: numpy's scalar rules, a track's travel, constants packed
by name."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from grasplink.decoding.kernels import jit

# ids of the small steps the detector's step probe finds (their own series, from here on)
PROBE_IDS = 1_000_000_000


def pack(names: tuple[str, ...], values: Mapping[str, float], kernel: str) -> np.ndarray:
    """A kernel's constants as one float array in the order of `names` (one argument, read
    by index): every name given, no other."""
    missing, unknown = set(names) - set(values), set(values) - set(names)
    if missing or unknown:
        raise ValueError(
            f"{kernel} constants: missing {sorted(missing)}, unknown {sorted(unknown)}"
        )
    return np.array([float(values[name]) for name in names])


@jit()
def maximum(a: float, b: float) -> float:
    """np.maximum of two numbers: NaN if either is, the second on a tie (+0 against -0)."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a > b else b


@jit()
def minimum(a: float, b: float) -> float:
    """np.minimum of two numbers: NaN if either is, the second on a tie."""
    if a != a:
        return a
    if b != b:
        return b
    return a if a < b else b


@jit()
def travel(
    s: float, v: float, a: float, d: float, m: float, t: float, g: float, dip_recovery_s: float
) -> float:
    """Travel at g of a slipping track last told at t (travel s, speed v, acceleration a,
    dip d with multiplier m): the speed changing at a (bounded to 0.25-4x), less the ridge
    dip still recovering."""
    tau = maximum(0.0, g - t)
    v_end = minimum(maximum(v + a * tau, 0.25 * v), 4.0 * v)
    decay = np.exp(-tau / dip_recovery_s)
    return s + 0.5 * (v + v_end) * tau - d * m * (1.0 - decay)


@jit()
def ring_slot(contact_id: int, ring_len: int) -> int:
    """Where a contact's pulse verdict sits in the tracker's ring of verdicts: the kink
    bank's contacts in its first half, the probes' in its second (the two id series run
    at their own pace: one shared slot number let a probe's verdict overwrite a recent
    kink contact's - PROBE_IDS is a multiple of 256 - and a slip lost its pulse)."""
    half = ring_len // 2
    return contact_id % half + (half if contact_id >= PROBE_IDS else 0)


@jit()
def medians_way(x: np.ndarray, windows: int, step: float) -> int:
    """`level_ramp.ramp_way` on `windows` equal windows of `x` (oldest first): +1 when the
    median of every window is at least `step` over the one before, -1 when every one is
    at least `step` under, else 0. Each window sorted as np.sort sorts (NaN last), the
    median of an even count the mean of the middle two: the same floats as the numpy."""
    m = len(x) // windows
    up = True
    down = True
    before = 0.0
    for k in range(windows):
        row = np.sort(x[k * m : (k + 1) * m])
        median = 0.5 * (row[(m - 1) // 2] + row[m // 2])
        if k:
            d = median - before
            up = up and d >= step
            down = down and d <= -step
        before = median
    return 1 if up else (-1 if down else 0)

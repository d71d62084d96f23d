"""A tail kink on the first load's pulse: timed where the kink bank peaks, not moved back.

`tail_onsets` moves a tail kink's contact back by `LATE_SHARE` of the scale that found it
(16 ms at 40 ms, 32 ms at 80 ms): measured on tails of pulses that rise on an object
already over the skin, whose decay bends the coarse hinges late. The first pulse of a slip
onto an empty skin (`decoding.arrival`: the sensor read unloaded before it) is the
object's first load: there the kink bank's own peak was not late (issue 22, alpha0.3
forward, constant, 8-35 mm/s, 3 seeds: the contact after such an arrival told 13-50 ms
early, moved back; 6 ms early to 5 ms late at the peak itself), and the early time made
the slip's two-contact speed 11-23 % high (seeds 51310, 51400).

So a tail kink whose last told contact before it came onto an unloaded sensor (its mean
level over `arrival.LEVEL_S` before that onset under the empty level by `arrival.EMPTY_Z`
of its sigma) keeps the kink bank's time; its one-sigma stays widened as `tail_onsets`
widens it (the coarse scale's peak is no sharper for it). Shipped on
(`TailKinkSettings.arrival_empty_n`; 0: off). Full plan, one run
(`benchmarks/tune_tracker_kinds.py --full --try tails.arrival_empty_n=0.2`, against it
off): constant missing 5.3 -> 4.5 % (3 seeds); every moving kind 22.4 -> 21.6 % (2 seeds),
wrong direction, stops cleared and held objects unchanged; its price, some p90s up where
more speeds are given (docs/decoding.md, "Tail kinks").
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from grasplink.decoding import arrival


def on_first_load(
    x: np.ndarray,
    x_start: int,
    onsets: Iterable[tuple[int, int]],
    n: int,
    fs_hz: float,
    white: Callable[[int], float | None],
    empty_n: float,
) -> bool:
    """Whether the tail kink at global sample `n` sits on the first load's pulse: the
    last contact told before it (`onsets`: (onset index, emit index) of the contacts told,
    `Ledger.onsets`) came onto an unloaded sensor (`arrival.unloaded_before`). `x` holds
    the samples from global index `x_start`; `white(index)` is the white noise (N per
    sample) at a sample, None while unknown. `empty_n` 0 turns the rule off."""
    if not empty_n > 0:
        return False
    before = [m for m, _ in onsets if m < n]
    if not before:
        return False

    def mean(start: int, stop: int) -> float | None:
        i0, i1 = start - x_start, stop - x_start
        if i0 < 0 or i1 > len(x):
            return None  # (not held: not told)
        return float(np.add.reduce(x[i0:i1]) / (i1 - i0))

    return arrival.unloaded_before(max(before), fs_hz, mean, white, empty_n)

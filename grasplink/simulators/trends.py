"""A part's next commands, guessed from its last ones, so its physics can run ahead.

A closed loop's physics runs ahead of the network only as far as it knows the commands
(`engine.Simulation`). Held commands were the one guess: a gateway ramping a grip under
its slew limit then forced chunk-by-chunk physics for the whole ramp, because the command
changes every chunk - by steps that repeat (-15, -15, -30 mN when the ramp steps on each
7.5 ms skin packet over 10 ms chunks). Numpy's call overhead makes a one-chunk block cost
about ten times a chunk of a long one, so the ramp's chunks were most of the physics.

The steps are continued when they repeat: the engine checks each guess against the
command the nodes then give and rolls back when it was wrong, so a guess changes how
much is computed, never what. Values are continued in decimal, from their shortest
repr, so a command a node gives as counts / 1000 is guessed to the bit (9.786 less
0.015 is 9.771 here, where floats make it 9.771000000000001): a ramp's guesses hold.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from decimal import Decimal

# Longest period of repeating steps looked for.
MAX_PERIOD = 4
# A period counts once its steps came this many times in a row: twice let -15, -15 of a
# ramp stepping -15, -15, -30 pass for a period of one, and every third guess failed.
REPEATS = 3
# Commands a part keeps: enough for the longest period to repeat.
HISTORY = REPEATS * MAX_PERIOD + 1


def continue_steps(history: Sequence[float], count: int) -> list[float]:
    """`count` values after `history` (oldest first): its steps continued when the last
    REPEATS·p of them repeat with a period p <= MAX_PERIOD (the shortest such p), else
    the last value held. A constant history holds, as does one with a NaN or an infinity."""
    if not history:
        raise ValueError("continue_steps: no history to continue")
    last = history[-1]
    if count <= 0:
        return []
    window = history[-HISTORY:]
    if (
        len(window) < REPEATS + 1
        or window.count(last) == len(window)  # held: most parts, most chunks, no decimals
        or not all(math.isfinite(v) for v in window)
    ):
        return [last] * count
    values = [Decimal(repr(v)) for v in window]
    steps = [b - a for a, b in itertools.pairwise(values)]
    period = next(
        (
            p
            for p in range(1, MAX_PERIOD + 1)
            if len(steps) >= REPEATS * p
            and all(steps[-k] == steps[-k - p] for k in range(1, (REPEATS - 1) * p + 1))
        ),
        None,
    )
    if period is None or not any(steps[-period:]):
        return [last] * count
    cycle = steps[-period:]
    out: list[float] = []
    value = values[-1]
    for k in range(count):
        value += cycle[k % period]
        out.append(float(value))
    return out

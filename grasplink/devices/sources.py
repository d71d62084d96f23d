"""Where a sensing node's physical signal comes from.

A node samples its source at its own configured rate; the source answers
for sample indices, not times, so time stays an exact integer count. With
no scene attached a sensor reads a constant (zero unless told): the node
simulates nothing a scene did not ask for. Simulators plug in here.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import ArrayLike


class SampleSource(Protocol):
    def samples(self, t0_us: int, start_index: int, count: int, rate_hz: int) -> np.ndarray:
        """Physical values (float64) of samples start_index .. start_index+count-1.

        Sample k falls at t0_us + k * 1e6 // rate_hz (the node's sample clock).
        """
        ...


@runtime_checkable
class FinalSource(SampleSource, Protocol):
    """A source that says which samples are final, so a node may convert them ahead in
    one pass (a source without it is read packet by packet, as it asks)."""

    def final_until_us(self) -> int | None:
        """The latest time whose samples are final (asking again gives the same values);
        None when every sample is."""
        ...


class ConstantSource:
    """A sensor at rest: every sample reads `value`."""

    def __init__(self, value: float = 0.0):
        self.value = float(value)

    def samples(self, t0_us: int, start_index: int, count: int, rate_hz: int) -> np.ndarray:
        return np.full(count, self.value)

    def final_until_us(self) -> int | None:
        return None


class FunctionSource:
    """A signal given as a vectorised function of time in seconds (tests, demos)."""

    def __init__(self, fn: Callable[[np.ndarray], ArrayLike]):
        self.fn = fn

    def samples(self, t0_us: int, start_index: int, count: int, rate_hz: int) -> np.ndarray:
        index = np.arange(start_index, start_index + count, dtype=np.int64)
        times_us = t0_us + index * 1_000_000 // rate_hz
        return np.asarray(self.fn(times_us / 1e6), dtype=np.float64)

    def final_until_us(self) -> int | None:
        return None

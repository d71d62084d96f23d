"""The contact detector's buffers: arrays appended to in place, rows of a bank that a kernel
steps, the recent samples every part reads."""

from __future__ import annotations

from typing import Any

import numpy as np

from grasplink.decoding.filters import RAIL_SHARE, on_rail


class Series:
    """An array appended to in place and cut from the front by moving what is kept down.

    The detector extends a dozen arrays by a few samples every block; a
    concatenate copies the whole array each time, a slice write copies only
    the new samples. `view` is what is held (valid until the next append or
    cut); rows (`rows` > 0) share one index along the last axis. The storage
    grows (doubling) only when an append would not fit, and a cut keeps it:
    bounded by the longest stretch held.
    """

    __slots__ = ("data", "size")

    def __init__(self, capacity: int = 64, rows: int = 0):
        shape = (rows, max(1, capacity)) if rows else (max(1, capacity),)
        self.data: np.ndarray = np.empty(shape)
        self.size = 0

    def extend(self, count: int) -> np.ndarray:
        """`count` more entries (the caller fills them): their view."""
        start, end = self.size, self.size + count
        if end > self.data.shape[-1]:
            data = np.empty((*self.data.shape[:-1], max(end, 2 * self.data.shape[-1])))
            data[..., :start] = self.data[..., :start]
            self.data = data
        self.size = end
        return self.data[..., start:end]

    def append(self, values: np.ndarray) -> np.ndarray:
        """Write `values` after what is held; the new view of all."""
        self.extend(len(values))[...] = values
        return self.data[..., : self.size]

    def keep_last(self, keep: int) -> np.ndarray:
        """Drop all but the last `keep` entries; the new view of all."""
        self.data[..., :keep] = self.data[..., self.size - keep : self.size]
        self.size = keep
        return self.data[..., :keep]

    def view(self) -> np.ndarray:
        return self.data[..., : self.size]


class BankInt:
    """An int of a bank's member (a hinge channel, a step scale), held in its bank's int
    row (`owner.bank.ints[owner.index, col]`), where a kernel reads and writes it."""

    def __init__(self, col: int):
        self.col = col

    def __get__(self, owner_of: Any, owner: type | None = None) -> int:
        # `item`: the Python int straight away (indexing makes a numpy scalar first, then
        # int() of it; read tens of times a block, on every channel)
        return owner_of.bank.ints.item(owner_of.index, self.col)

    def __set__(self, owner_of: Any, value: int) -> None:
        owner_of.bank.ints[owner_of.index, self.col] = value


class BankRows(Series):
    """A `Series` whose count is held in a bank's int row (`ints[index, col]`), where a
    kernel that appends to it finds it."""

    __slots__ = ("col", "index", "ints")

    def __init__(self, ints: np.ndarray, index: int, col: int, capacity: int, rows: int = 0):
        self.ints, self.index, self.col = ints, index, col
        super().__init__(capacity, rows=rows)

    @property
    def size(self) -> int:
        return self.ints.item(self.index, self.col)  # (a Python int, as `BankInt`)

    @size.setter
    def size(self, value: int) -> None:
        self.ints[self.index, self.col] = value

    def __getstate__(self) -> tuple[np.ndarray, np.ndarray, int, int]:
        # (a copy: the count is the bank's, copied with it)
        return self.data, self.ints, self.index, self.col

    def __setstate__(self, state: tuple[np.ndarray, np.ndarray, int, int]) -> None:
        self.data, self.ints, self.index, self.col = state


class Samples:
    """The recent samples (times `t`, values `x`, the first at global index `start`) and how
    many came in (`n`): every part reads them."""

    def __init__(self, capacity: int):
        self.n = 0  # samples received
        self.series = Series(capacity, rows=2)
        self.t, self.x = self.series.view()  # views (same index)
        self.start = 0

    def append(self, t: np.ndarray, x: np.ndarray) -> None:
        self.n += len(x)
        new = self.series.extend(len(x))
        new[0], new[1] = t, x
        self.t, self.x = self.series.view()

    def time(self, n: int, delta: float) -> float:
        """The time of sample n moved by `delta` of a sample (sub-sample timing)."""
        i = n - self.start
        t = self.t
        if delta >= 0 and i + 1 < len(t):
            return float(t[i] + delta * (t[i + 1] - t[i]))
        if delta < 0 and i - 1 >= 0:
            return float(t[i] + delta * (t[i] - t[i - 1]))
        return float(t[i])

    def clipped(self, start: int, stop: int) -> bool:
        """Do samples start..stop pile up at their maximum (the sensor's upper rail)? A
        level clipped there stays whatever happens: no step to tell."""
        i0, i1 = start - self.start, stop - self.start + 1
        if i0 < 0 or i1 > len(self.x):
            return False
        x = self.x[i0:i1]
        return bool(on_rail(x)) and bool(np.count_nonzero(x == x.max()) >= RAIL_SHARE * len(x))

    def room(self, keep: int) -> int:
        """Samples to come before `trim(keep)` would cut (one entry each)."""
        return 2 * keep - len(self.t)

    def trim(self, keep: int) -> None:
        """Keep the last `keep` samples once twice that many are held."""
        if len(self.t) > 2 * keep:
            cut = len(self.t) - keep
            self.t, self.x = self.series.keep_last(keep)
            self.start += cut


class Found:
    """A kernel's output buffers for the indices (and values) it finds, grown when short."""

    def __init__(self, capacity: int):
        self.indices = np.empty(capacity, dtype=np.int64)
        self.values = np.empty(capacity)

    def room(self, count: int) -> np.ndarray:
        """The index buffer, with room for `count` (grown when short: values with it)."""
        if count > len(self.indices):
            self.indices = np.empty(2 * count, dtype=np.int64)
            self.values = np.empty(2 * count)
        return self.indices


def mean(x: np.ndarray) -> float:
    """np.mean's number (its sum over the count) without its wrappers."""
    return np.add.reduce(x) / len(x)

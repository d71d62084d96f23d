"""The tracker's pruning as one kernel: which tracks of a pool to keep, best first.

Pure selection (sorts, integer keys, comparisons): the kernel picks the same tracks as
the numpy code it replaced, bit for bit. See `TrackerDecoder._prune` for what is kept.
"""

from __future__ import annotations

import numpy as np

from grasplink.decoding.kernels import jit
from grasplink.decoding.kernels.layout import (
    I_DIRN,
    I_FIRST,
    I_LAST,
    I_MODEL,
    I_N,
    I_RIDGE,
    I_RUN,
    I_WIDTH,
)

# the dedup key's int-column part: the last three contact ids, ridge, direction and model
# weighted (mod 2^64, as the chained int64 multiply-adds of the numpy code wrapped)
KEY_M = 1000003
KEY_WEIGHTS = np.zeros(I_WIDTH, np.int64)
KEY_WEIGHTS[[I_LAST, I_LAST - 1, I_LAST - 2]] = [KEY_M**3, KEY_M**2, KEY_M]
KEY_WEIGHTS[[I_RIDGE, I_DIRN, I_MODEL]] = [16, 4, 4]


@jit()
def _heads(sorted_values: np.ndarray) -> np.ndarray:
    """True where a run of equal values starts."""
    head = np.empty(len(sorted_values), np.bool_)
    if len(sorted_values):
        head[0] = True
    for i in range(1, len(sorted_values)):
        head[i] = sorted_values[i] != sorted_values[i - 1]
    return head


@jit()
def _first_of_each(key: np.ndarray) -> np.ndarray:
    """True at the first occurrence of each value (an open-addressing hash set: linear in
    the pool, where sorting the keys to find each run's head is n log n)."""
    size = len(key)
    slots = 1
    while slots < 2 * size:
        slots *= 2
    used = np.zeros(slots, np.bool_)
    stored = np.empty(slots, np.int64)
    first = np.zeros(size, np.bool_)
    for r in range(size):
        k = key[r]
        h = (k ^ (k >> 29)) * np.int64(-7046029254386353131)  # mixed: ids sit in high bits
        slot = (h >> 17) & (slots - 1)
        while used[slot] and stored[slot] != k:
            slot = (slot + 1) & (slots - 1)
        if not used[slot]:
            used[slot] = True
            stored[slot] = k
            first[r] = True
    return first


@jit()
def prune_choice(
    score: np.ndarray,
    stop: np.ndarray,
    ints: np.ndarray,
    recent: np.ndarray,
    held: np.ndarray,
    negligible: float,
    max_hypotheses: int,
    per_start: int,
) -> np.ndarray:
    """Rows of the pool to keep, best score first.

    One per dedup key (the int columns weighted by `KEY_WEIGHTS`, wrapping mod 2^64, plus
    2 if slipping and 1 if restarted): the first in score order; none more than
    `negligible` + 20 below the best score; one-contact tracks only if they start at a `recent`
    contact; of the others the best `max_hypotheses`, plus the best `per_start` of each
    start contact in `held`.
    """
    size = len(score)
    order = np.argsort(-score, kind="mergesort")
    key = np.empty(size, np.int64)
    for r in range(size):
        row = order[r]
        total = np.int64(0)
        for c in range(ints.shape[1]):
            total += ints[row, c] * KEY_WEIGHTS[c]
        if np.isnan(stop[row]):
            total += 2
        if ints[row, I_RUN] == 1:
            total += 1
        key[r] = total
    keep = _first_of_each(key)
    floor = score[order[0]] - negligible - 20.0  # (the numpy code's order)
    multi = np.empty(size, np.int64)  # kept tracks with two or more contacts, in order
    count = 0
    for r in range(size):
        row = order[r]
        if keep[r] and not score[row] >= floor:
            keep[r] = False
        if ints[row, I_N] == 1:
            if keep[r]:
                keep[r] = False
                last = ints[row, I_LAST]
                for c in recent:
                    if last == c:
                        keep[r] = True
                        break
        elif keep[r]:
            multi[count] = r
            count += 1
    idx = multi[:count]
    ok = np.arange(count) < max_hypotheses
    if count and len(held):
        firsts = np.empty(count, np.int64)
        for j in range(count):
            firsts[j] = ints[order[idx[j]], I_FIRST]
        by_start = np.argsort(firsts, kind="mergesort")
        starts = firsts[by_start]
        head = _heads(starts)
        held_sorted = np.sort(held)
        group_head = 0
        for j in range(count):
            if head[j]:
                group_head = j
            at = min(np.searchsorted(held_sorted, starts[j]), len(held_sorted) - 1)
            if j - group_head < per_start and held_sorted[at] == starts[j]:
                ok[by_start[j]] = True
    for j in range(count):
        if not ok[j]:
            keep[idx[j]] = False
    chosen = np.empty(size, np.int64)
    n = 0
    for r in range(size):
        if keep[r]:
            chosen[n] = order[r]
            n += 1
    return chosen[:n]

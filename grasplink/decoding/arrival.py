"""A slip onto an empty skin enters at an end: where the tracker's new tracks may start.

Physics: the object's load reaches the one FSR through the skin it covers, so the sensor
reads its unloaded level (0 N, give or take its offset and drift) until an object lies on
the skin. An object slipping from rest mid-skin covers the ridges behind its leading edge
(the thesis object is 90 mm long, the skins 84-90 mm): the sensor is loaded before its
first contact. One whose first contact comes with the sensor unloaded has just slid onto
the skin: its edge met the first ridge of its way (either end). So a track born at such a
contact at ridge r > 0 of its travel order needs the edge to have crossed ridges 0..r-1
unseen: its start prior is the first ridge's times P(each of those missed) (the tracker's
detection model), not the spacing before r (where a slip starting on the skin would
begin).

Why it matters (issue 22, constant speed): on alpha0.3 (4, 3, 48, 29 mm) a slip's two
first contacts 4 mm apart, the 3 mm ridge after them unfound (found ~1 time in 5 there),
are as well explained by the way back starting at the 48 mm gap's far ridge and skipping
its 3 mm ridge - 1.75 times the speed, nothing more to come - and that alias holds a third
of the slipping posterior until the 48 mm ridge (`benchmarks/two_contact_hypotheses.py`).
It starts with the object already over 77 mm of the skin; the sensor read nothing.

Measured (`benchmarks/two_contact_hypotheses.py --levels --seeds 1`, full plan): the mean
level over the 20 ms before an arrival's first ridge contact lies within -0.13..0.14 N on
every kind with clean noise; before any contact with the object on the skin (its 2nd
ridge on, a reversal's or restart's first) it is 0.27 N or more. `EMPTY_N` sits between;
the level must lie under it by 3 sigma of its mean (the detector's white noise), so under
heavy noise (10 dB) no contact is told unloaded and nothing changes.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

#: the sensor reads "unloaded" under this (N): its offset and drift stay within ~0.14 N on
#: the benchmark's clean kinds; 3 mm of the object on the skin reads 0.27 N or more
EMPTY_N = 0.2
#: how far under `EMPTY_N` the level's mean must lie, in its own sigmas
EMPTY_Z = 3.0
#: the level is read over this long before the contact's onset (the efference copy's window)
LEVEL_S = 0.02


def unloaded(level_n: float | None, white_n: float | None, samples: int, empty_n: float) -> bool:
    """Whether the sensor read unloaded before a contact: its mean level over `samples`
    samples (None: not held) under `empty_n` by `EMPTY_Z` sigmas of that mean, with white
    noise `white_n` per sample (None: not yet measured - then not told)."""
    if level_n is None or white_n is None or samples < 1 or not empty_n > 0:
        return False
    return level_n + EMPTY_Z * white_n / math.sqrt(samples) < empty_n


def unloaded_before(
    onset: int,
    fs_hz: float,
    mean: Callable[[int, int], float | None],
    white: Callable[[int], float | None],
    empty_n: float,
) -> bool:
    """`unloaded` over the `LEVEL_S` before the sample `onset`: `mean(start, stop)` the mean
    of the samples start..stop-1 (None: not held), `white(index)` the white noise at a
    sample (None: not yet measured). One reading for the tracker's new tracks and the kink
    bank's tail kinks (`detector.arrival_tail`)."""
    samples = max(1, round(LEVEL_S * fs_hz))
    start = onset - samples
    return unloaded(mean(start, onset), white(start), samples, empty_n)


def entry_adjustment(log_prior: np.ndarray, log_miss: np.ndarray) -> np.ndarray:
    """(2, R) log adjustment of a new track's score at ridge r of each way (travel order)
    when its contact came onto an unloaded sensor: from the start prior at r to the first
    ridge's times every ridge before r missed (0 at the first ridge)."""
    if log_prior.shape != log_miss.shape or log_prior.ndim != 2:
        raise ValueError(
            f"arrival: start prior {log_prior.shape} and miss table {log_miss.shape} "
            "must both be (ways, ridges)"
        )
    missed = np.concatenate(
        [np.zeros((log_miss.shape[0], 1)), np.cumsum(log_miss[:, :-1], axis=1)], axis=1
    )
    return log_prior[:, :1] + missed - log_prior

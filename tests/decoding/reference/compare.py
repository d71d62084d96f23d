"""How far a compiled kernel may be from its numpy reference, derived from the arithmetic.

Both compute the same formulas in the same order. IEEE 754 rounds + - * / and sqrt
correctly, so those give the same bits on any CPU and in either implementation (numba
compiles without fast-math: no reassociation, no contraction into fused multiply-adds
unless a kernel asks for one). What may differ is the rest (`reference.tracker.Ops`): exp,
log and erf (numpy's SIMD loops on one CPU, libm on another, numba's libm calls; each
within a few ulps of the true value) and the small matrix products (BLAS's kernel: fused
or not, its order of terms, depends on the CPU).

The allowance is the first-order effect of those differences on each output: the reference
is run again VARIANTS times with every such result moved by a random share of ULPS ulps
(exp, log, erf: two implementations each within 4 ulps of the true value differ by at most
8) or of TERMS x eps x |A| |B| (a 4-term dot product's rounding bound, 4 eps |A||B|, for
each of two implementations), and an output may differ from the reference by SAFETY times
the largest excursion seen (random shares add up like independent errors, about the square
root of the number of terms; SAFETY covers the spread of that estimate and terms that line
up). Checked once against another CPU: the children pools numpy built on an AVX-512 machine
(the golden file this replaced) were within 1/4 of the allowance of this reference on an AVX2
machine, wherever the allowance is not 0 (where it is, they differed by the ulps of the
decoder's tables, built with numpy's log there: tables both sides share in one process).
An output no such
operation reaches has an allowance of 0: it must be equal to the bit. Cancellation is
accounted for by construction (a difference of two nearly equal exp() results moves as
much as it would between two CPUs), which a fixed relative tolerance is not.

A decision on computed numbers (a comparison, an argmax) can flip within that allowance:
a call whose decisions differ in any perturbed run is near a threshold, and the kernel may
take any decision the reference took in one of its runs; such calls are counted, and the
tests bound their share.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from tests.decoding.reference.tracker import ops

ULPS = 8.0
TERMS = 8
SAFETY = 8.0
VARIANTS = 4


def perturbed_runs(compute: Callable[[], Any], seed: int) -> list[Any]:
    """compute() VARIANTS times, each with exp/log/erf and matrix products perturbed."""
    rng = np.random.default_rng(seed)
    runs = []
    for _ in range(VARIANTS):
        with ops.perturbed(rng, ULPS, TERMS):
            runs.append(compute())
    return runs


def _gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b|, 0 where both are the same NaN or infinity, inf where only one is."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    same = (a == b) | (np.isnan(a) & np.isnan(b))
    with np.errstate(invalid="ignore"):
        gap = np.abs(a - b)
    return np.where(same, 0.0, np.where(np.isnan(gap), np.inf, gap))


def allowance(reference: np.ndarray, runs: list[np.ndarray]) -> np.ndarray:
    """Per element: SAFETY x the largest excursion of the perturbed runs from the reference."""
    if not runs:
        return np.zeros(np.shape(reference))
    return SAFETY * np.max([_gap(run, reference) for run in runs], axis=0)


def assert_within(
    got: np.ndarray, reference: np.ndarray, allowed: np.ndarray, what: str = ""
) -> None:
    """Every element of got within its allowance of the reference (NaN where NaN, an
    infinity where the same infinity; 0 allowed: the same bits)."""
    gap = _gap(got, reference)
    bad = gap > allowed
    if bad.any():
        at = tuple(int(i) for i in np.argwhere(bad)[0])
        raise AssertionError(
            f"{what}: {int(bad.sum())} of {bad.size} values beyond their allowance; first at "
            f"{at}: got {np.asarray(got)[at]!r}, reference {np.asarray(reference)[at]!r}, "
            f"allowed {allowed[at]!r}"
        )

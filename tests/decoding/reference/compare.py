"""How far a compiled kernel may be from its numpy reference, derived from the arithmetic.

Both compute the same formulas in the same order. IEEE 754 rounds + - * / and sqrt
correctly, so those give the same bits on any CPU and in either implementation (numba
compiles without fast-math: no reassociation, no contraction into fused multiply-adds
unless a kernel asks for one). What may differ is the rest (`reference.tracker.Ops`): exp,
log and erf (numpy's SIMD loops on one CPU, libm on another, numba's libm calls; each
within a few ulps of the true value) and the small matrix products (BLAS's kernel: fused
or not, its order of terms, depends on the CPU).

The allowance is the first-order effect of those differences on each output, measured on
the reference itself: it is run again with every such result moved by a random share of
ULPS ulps (exp, log, erf: two implementations each within 4 ulps of the true value differ by
at most 8) or of TERMS x eps x |A| |B| (a 4-term dot product's rounding bound, 4 eps |A||B|,
for each of two implementations), and with the Kalman update's intermediates, computed from
those, moved by an ulp (`Ops.rnd`: once its inputs differ, a result may round the other way,
and the update cancels - P - K P0 is far smaller than its terms, so an ulp of a term is many
of the result). VARIANTS runs so, and VARIANTS more with every move MAGNIFY times larger,
whose excursions divided by MAGNIFY are the same first-order effect without the rounding of
the output hiding it (a move of a fraction of the result's ulp often changes no bit: four
runs can all show 0 where another CPU's BLAS shows a difference - seen with OpenBLAS's
Nehalem kernel, which fuses no multiply-add). An output may differ from the reference by
SAFETY times the largest of these excursions, plus an ulp either way of its own value (once
its inputs differ its last rounding may fall the other way, whatever the size of the
difference): random shares add up like independent errors,
about the square root of the number of terms; SAFETY covers the spread of that estimate and
terms that line up. Checked once against another CPU: the children pools numpy built on an
AVX-512 machine (the golden file this replaced) were within a third of the allowance of this
reference on an AVX2 machine, wherever the allowance is not 0 (where it is, they differed by
the ulps of the decoder's tables, built with numpy's log there: tables both sides share in
one process). An output no such operation reaches has an allowance of 0: it must be equal to
the bit. Cancellation is accounted for by construction (a difference of two nearly equal
exp() results moves as much as it would between two CPUs), which a fixed relative tolerance
is not.

A decision on computed numbers (a comparison, an argmax) can flip within that allowance:
a call whose decisions differ in any (unmagnified) perturbed run is near a threshold, and
the kernel may take any decision the reference took in one of its runs; such calls are
counted, and the tests bound their share. Magnified runs that decided otherwise are left
out of the allowance (their rows do not line up).
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
MAGNIFY = 2.0**10


def perturbed_runs(compute: Callable[[], Any], seed: int, magnify: float = 1.0) -> list[Any]:
    """compute() VARIANTS times, each with exp/log/erf, matrix products and the Kalman
    update's intermediates perturbed (`magnify` times the bounds)."""
    rng = np.random.default_rng([seed, int(magnify)])
    runs = []
    for _ in range(VARIANTS):
        with ops.perturbed(rng, ULPS, TERMS, magnify):
            runs.append(compute())
    return runs


def _gap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """|a - b|, 0 where both are the same NaN or infinity, inf where only one is."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    same = (a == b) | (np.isnan(a) & np.isnan(b))
    with np.errstate(invalid="ignore"):
        gap = np.abs(a - b)
    return np.where(same, 0.0, np.where(np.isnan(gap), np.inf, gap))


def allowance(
    reference: np.ndarray, runs: list[np.ndarray], magnified: list[np.ndarray] = ()
) -> np.ndarray:
    """Per element: SAFETY x the largest excursion from the reference of the perturbed runs
    and of the magnified runs (divided by MAGNIFY), and 2 ulps of the reference's value
    (its last rounding, either way); 0 where no run moved it."""
    gaps = [_gap(run, reference) for run in runs]
    gaps += [_gap(run, reference) / MAGNIFY for run in magnified]
    gaps = [np.where(np.isinf(gap), 0.0, gap) for gap in gaps]  # a NaN is no size
    if not gaps:
        return np.zeros(np.shape(reference))
    effect = np.max(gaps, axis=0)
    # where reached, the output's own last rounding may fall either way too
    last = np.where(np.isfinite(reference), 2.0 * np.spacing(np.abs(reference)), 0.0)
    return np.where(effect > 0, SAFETY * effect + last, 0.0)


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

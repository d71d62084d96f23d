"""Compiled kernels of the decoders' per-contact work (numba).

Why compiled: the tracker's contact step and the contact detector work on arrays of tens
to hundreds of entries, where numpy's per-call overhead (about a microsecond a call, some
hundreds of calls a contact) is most of the cost, and the loop latency target (skin TPDO
to belt/hand RPDO, p99 <= 2 ms live) leaves no room for it. A kernel does the same
arithmetic in one call.

Rules every kernel here keeps:
- `jit` below: compiled ahead of first use and cached on disk (`cache=True`), so a live
  gateway never stalls on a compile; numpy's error model (x / 0 is inf or nan, as the
  numpy code it replaces, not an exception); no fast-math (IEEE order of operations).
- Same formulas, same order of children and of operations as the numpy code: results
  agree to the last few ulps (numpy's SIMD exp/log and BLAS's FMAs round differently
  from LLVM's), which the decoders' tests and the accuracy benchmark check.
- Plain arrays and scalars in and out: no Python objects, so the sans-IO decoder stays
  the owner of its state.
- `nogil`: a kernel releases the GIL for its call (it touches no Python object), so the
  live gateway's heartbeat thread (`bus.runner`, the pacer) runs while the decoder is in
  a contact step instead of waiting for the call to end.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numba

__all__ = ["jit"]


def jit(*signature: Any) -> Callable[[Callable[..., Any]], Any]:
    """numba.njit with the package's settings; `signature` (optional) compiles eagerly."""
    options: dict[str, Any] = {
        "cache": True,
        "error_model": "numpy",
        "fastmath": False,
        "nogil": True,
    }
    if signature:
        return numba.njit(*signature, **options)
    return numba.njit(**options)

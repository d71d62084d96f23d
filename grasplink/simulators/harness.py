"""Run effects outside a scene: fixed input signals in, output signals out.

Used by effect tests (and benchmarks) to step effects chunk by chunk over a
time grid, proving that chunked and one-shot stepping give the same output.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, TypeVar

import numpy as np

from grasplink.core.params import Params
from grasplink.simulators.core import Context, Effect, Io

US_PER_S = 1_000_000
_E = TypeVar("_E", bound=Effect)


def sample_times_us(rate_hz: int, duration_s: float) -> np.ndarray:
    count = round(duration_s * rate_hz)
    return np.arange(count, dtype=np.int64) * US_PER_S // rate_hz


def context(seed: int = 1, rate_hz: int = 1000, layout_mm=None, nodes=None) -> Context:
    rates = {"physics": rate_hz, "skin": rate_hz, "emg": rate_hz}
    return Context("test", seed, rates, layout_mm, nodes or {})


def make(kind_cls: type[_E], ctx: Context, **params: Any) -> _E:
    p = Params(dict(params), "test", "effect")
    effect = kind_cls(p, ctx)
    p.finish()
    return effect


def run(
    effects: list[Effect],
    times_us: np.ndarray,
    inputs: Mapping[str, np.ndarray] | None = None,
    chunk: int | None = None,
) -> dict[str, np.ndarray]:
    """Step `effects` (already in order, one domain) over `times_us` in chunks of `chunk`."""
    inputs = {k: np.asarray(v, dtype=np.float64) for k, v in (inputs or {}).items()}
    outputs: dict[str, list[np.ndarray]] = {}
    chunk = chunk or len(times_us)
    for start in range(0, len(times_us), chunk):
        span = slice(start, min(start + chunk, len(times_us)))
        current: dict[str, np.ndarray] = {k: v[span] for k, v in inputs.items()}

        def read(name: str, times: np.ndarray, current=current) -> np.ndarray:
            if name not in current:
                raise KeyError(f"no signal {name} in this harness run")
            return current[name]

        def write(name: str, values: np.ndarray, current=current) -> None:
            current[name] = values

        io = Io(times_us[span], read, write)
        for effect in effects:
            effect.step(io)
        for name in dict.fromkeys(n for e in effects for n in e.outputs):
            outputs.setdefault(name, []).append(current[name])
    return {k: np.concatenate(v) for k, v in outputs.items()}

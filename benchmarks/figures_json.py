"""A benchmark's figures JSON: what its measure writes and its render reads, nothing else.

Each benchmark that writes a doc is measure -> figures JSON (kept beside the doc) ->
render from that JSON alone, so a doc can be re-rendered, or its wording changed,
without measuring again. The JSON holds everything the render shows, the machine and
the library versions included, read when the figures were measured.
"""

from __future__ import annotations

import json
import math
import os
import platform
import sys
from pathlib import Path
from typing import Any

import numpy as np

SIGNIFICANT = 6  # digits kept of each float: clocks on a shared machine are not finer


def environment(**versions: str) -> dict[str, Any]:
    """The machine and interpreter the figures were measured on; `versions`: the libraries
    the benchmark exercises (name -> version)."""
    return {
        "platform": sys.platform,
        "machine": platform.machine(),
        "cpu_count": os.cpu_count(),
        "python": platform.python_version(),
        "versions": dict(versions),
    }


def _rounded(value: Any) -> Any:
    if isinstance(value, float) and math.isfinite(value) and value != 0.0:
        return float(f"{value:.{SIGNIFICANT}g}")
    if isinstance(value, dict):
        return {key: _rounded(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [_rounded(item) for item in value]
    return value


def _dumps(value: Any, depth: int) -> str:
    """JSON with objects and lists of objects one item a line, lists of numbers on one line
    (a few hundred lines for thousands of samples, and readable diffs of the rest)."""
    pad, inner = " " * depth, " " * (depth + 1)
    if isinstance(value, dict) and value:
        items = (f"{inner}{json.dumps(str(k))}: {_dumps(v, depth + 1)}" for k, v in value.items())
        return "{\n" + ",\n".join(items) + f"\n{pad}}}"
    if isinstance(value, list) and any(isinstance(item, dict | list) for item in value):
        items = (f"{inner}{_dumps(item, depth + 1)}" for item in value)
        return "[\n" + ",\n".join(items) + f"\n{pad}]"
    return json.dumps(value, ensure_ascii=False)


def write(path: Path, figures: dict[str, Any]) -> dict[str, Any]:
    """Write `figures` to `path` and return them as the render will read them back."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(_dumps(_rounded(figures), 0) + "\n")
    return read(path)


def read(path: Path) -> dict[str, Any]:
    figures: dict[str, Any] = json.loads(path.read_text())
    return figures


def percentile(values: list[float], q: float) -> float:
    """The q-th percentile [0, 100] of `values`, interpolated; NaN for none."""
    return float(np.percentile(np.asarray(values, dtype=float), q)) if len(values) else float("nan")


def rank_percentile(values: list[float], share: float) -> float:
    """The nearest-rank percentile, `share` in [0, 1]: a value that occurred (a latency
    tail is a sample, not an interpolation between two)."""
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(share * len(ordered)))]


def slope_per_min(t_s: list[float], values: list[float]) -> float:
    """Least-squares slope of `values` per minute of `t_s` [s]; NaN for fewer than two."""
    if len(t_s) < 2:
        return float("nan")
    return float(np.polyfit(np.asarray(t_s) / 60.0, np.asarray(values), 1)[0])

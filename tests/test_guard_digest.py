"""benchmarks/guard_digest.py: the digest commits quote tells bit-identical output from any
other (the hashing; the input set is compare_trees.py's, run by the script itself)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

_PATH = Path(__file__).resolve().parents[1] / "benchmarks" / "guard_digest.py"
_spec = importlib.util.spec_from_file_location("guard_digest", _PATH)
assert _spec is not None and _spec.loader is not None
guard = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(guard)


def runs() -> tuple[list[str], list[np.ndarray]]:
    rng = np.random.default_rng(0)
    names = ["('ns', 0, 3)", "('ns', 0, 256)", "('static', 0, 3)"]
    estimates = [rng.normal(size=(n, 6)) for n in (5, 2, 4)]
    estimates[1][1, 2] = np.nan  # an unknown speed
    return names, estimates


def test_the_same_estimates_give_the_same_16_digit_digest():
    names, estimates = runs()
    digest = guard.digest(names, estimates)
    assert len(digest) == 16 and int(digest, 16) >= 0
    assert guard.digest(list(names), [e.copy() for e in estimates]) == digest


def test_one_ulp_anywhere_a_renamed_or_reordered_run_changes_the_digest():
    names, estimates = runs()
    digest = guard.digest(names, estimates)
    nudged = [e.copy() for e in estimates]
    nudged[2][3, 5] = np.nextafter(nudged[2][3, 5], np.inf)
    assert guard.digest(names, nudged) != digest
    assert guard.digest([names[0], names[1], "('case', 0, 3)"], estimates) != digest
    assert guard.digest(names[::-1], estimates[::-1]) != digest
    moved = [estimates[0], estimates[1][:1], np.concatenate([estimates[1][1:], estimates[2]])]
    assert guard.digest(names, moved) != digest  # an estimate moved to the next run

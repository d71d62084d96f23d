"""The tracker guard digest: one short hash of every estimate the skin tracker makes on a fixed
input set, to tell at a glance whether a change left its output bit for bit as it was.

    .venv/bin/python benchmarks/guard_digest.py [TREE] [--quick]

TREE is a checkout (default: this one; e.g. `git worktree add /tmp/base REV`), run in its
own interpreter. The input set is compare_trees.py's: 600 non-stationary signals (26 with
--quick) in 3- and 256-sample chunks, the decoding benchmark's target cases and its static
recordings. Prints the digest (the first 16 hex digits of SHA-256 over each run's name and
its estimates' float64 bits: time, slip, speed, position, force, confidence) and how many
estimates it covers. Commits quote it as "quick guard <digest>" or "full guard <digest>".

Bit-level, so machine-specific: numpy's exp, log and sin (SIMD loops chosen by the CPU),
BLAS and libm round differently on another CPU, and the simulated inputs and the decoder's
numbers move by ulps. Compare two trees' digests computed on one machine; a digest from
another machine says nothing. When they differ, compare_trees.py says by how much.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from compare_trees import collect


def digest(names: Sequence[str], runs: Sequence[np.ndarray]) -> str:
    """16 hex digits of SHA-256 over each run's name and its estimates' float64 bytes."""
    h = hashlib.sha256()
    for name, run in zip(names, runs, strict=True):
        h.update(str(name).encode())
        h.update(np.ascontiguousarray(run, dtype=np.float64).tobytes())
    return h.hexdigest()[:16]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tree", type=Path, nargs="?", default=Path(__file__).resolve().parents[1])
    parser.add_argument("--quick", action="store_true", help="26 non-stationary signals")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "estimates.npz"
        collect(args.tree.resolve(), args.quick, out)
        with np.load(out) as data:
            names = [str(n) for n in data["names"]]
            runs = [data[f"arr_{k}"] for k in range(len(names))]
    kind = "quick" if args.quick else "full"
    count = sum(len(run) for run in runs)
    print(f"{kind} guard {digest(names, runs)} ({count} estimates, {len(runs)} runs)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

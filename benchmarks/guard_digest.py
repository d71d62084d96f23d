"""The guard digest: one short hash of every estimate the skin decoders make on a fixed input
set, to tell at a glance whether a change left their output bit for bit as it was.

    .venv/bin/python benchmarks/guard_digest.py [TREE] [--quick] [--decoders LIST]

TREE is a checkout (default: this one; e.g. `git worktree add /tmp/base REV`), run in its
own interpreter. The input set is compare_trees.py's: 600 non-stationary signals (26 with
--quick, and for every decoder but the tracker) in 3- and 256-sample chunks, the decoding
benchmark's target cases and its static recordings. Every decoder of the tree's registry
(default; --decoders: some of them). Prints a digest per decoder (the first 16 hex digits
of SHA-256 over each run's name and its estimates' float64 bits: time, slip, speed,
position, force, confidence), how many estimates it covers, and one over all of them.
Commits quote the tracker's as "quick guard <digest>" or "full guard <digest>" (its line
reads as before the other decoders were added) and the whole as "all <digest>".

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
    parser.add_argument("--decoders", default="all", help='comma-separated names, or "all"')
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "estimates.npz"
        collect(args.tree.resolve(), args.quick, out, tuple(args.decoders.split(",")))
        with np.load(out) as data:
            names = [str(n) for n in data["names"]]
            decoders = [str(d) for d in data["decoders"]]
            runs = [data[f"arr_{k}"] for k in range(len(names))]
    kind = "quick" if args.quick else "full"
    for name in dict.fromkeys(decoders):
        mine = [k for k, d in enumerate(decoders) if d == name]
        count = sum(len(runs[k]) for k in mine)
        told = digest([names[k] for k in mine], [runs[k] for k in mine])
        label = "" if name == "tracker" else f"{name} "
        print(f"{kind} guard {label}{told} ({count} estimates, {len(mine)} runs)")
    if len(set(decoders)) > 1:
        count = sum(len(run) for run in runs)
        print(f"{kind} guard all {digest(names, runs)} ({count} estimates, {len(runs)} runs)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Decoding benchmark: what skin-decoding accuracy costs in time, for every decoder.

Writes decoding.md (tables), decoding_pareto.png and decoding.json into
docs/benchmarks/ of the checkout the current folder is in (or `--out DIR`):

1. every decoder and its main settings over synthesised recordings (all
   thesis layouts, 6-143 mm/s, both directions, sample rates, noise, speed
   dips and tip contacts, static grip steps), and the default decoder the
   figures recommend;
2. the CAN path: every shipped slip scene run through the skin node (12-bit
   ADC, 3 samples per TPDO1, the node's timing) and decoded from its CAN log
   as `grasplink decode R/can.asc` does, beside the same runs' skin.csv.

The work lives in `grasplink.evaluation.decoding_bench` (also `grasplink
bench decode`); this driver only parses arguments.

Run: `make bench` or `.venv/bin/python benchmarks/bench_decoding.py [--quick] [--out DIR]`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from grasplink.controllers import build_controllers
from grasplink.errors import GrasplinkError
from grasplink.evaluation.decoding_bench import run_benchmark


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="reduced synthetic grid (< 2 min)")
    parser.add_argument("--out", type=Path, default=None, help="default: docs/benchmarks/")
    parser.add_argument(
        "--scenes", type=Path, default=None, help="default: scenes/ of the checkout"
    )
    args = parser.parse_args(argv)
    try:
        results, out = run_benchmark(
            quick=args.quick,
            out=args.out,
            scenes_dir=args.scenes,
            controllers_for=build_controllers,
        )
    except GrasplinkError as exc:
        print(f"bench_decoding: error: {exc}", file=sys.stderr)
        return 1
    print(f"recommended default decoder: {results['recommended_default']}; wrote {out}/decoding.md")
    return 0


if __name__ == "__main__":
    sys.exit(main())

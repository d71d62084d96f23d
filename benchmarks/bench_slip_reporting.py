"""Slip reporting benchmark (issue 22): speed as soon as the contacts give it, stops at once.

Writes slip_reporting.md, slip_reporting.json and one slip_reporting_<CONSTANT>.png per
trade-off curve into docs/benchmarks/ of the checkout the current folder is in (or
`--out DIR`):

1. the default decoder over wide sets of every layout, both directions, several seeds:
   constant speed 8-95 mm/s; accelerating, decelerating, stick-slip, stops mid-skin,
   reversals, 10 dB SNR, saturation, 100/200/1000 Hz with drops; held objects;
2. the headline loop (`scenes/loop_headline.toml`) run and its can.asc decoded;
3. the trade-off curves: the tracker's direction odds threshold, dip prior, stale-track
   age and the detector's threshold, each swept on a reduced set.

The work lives in `grasplink.evaluation.slip_reporting`; this driver only parses
arguments. `--quick` takes a few minutes.

Run: `.venv/bin/python benchmarks/bench_slip_reporting.py [--quick] [--out DIR]`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from grasplink.controllers import build_controllers
from grasplink.errors import GrasplinkError
from grasplink.evaluation.decoding_bench import default_out_dir, find_checkout
from grasplink.evaluation.slip_reporting import PAGE, PLANS, run_benchmark, target_rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="reduced sets (a few minutes)")
    parser.add_argument("--out", type=Path, default=None, help="default: docs/benchmarks/")
    parser.add_argument("--workers", type=int, default=2, help="worker processes (at most 2)")
    args = parser.parse_args(argv)
    try:
        out = args.out or default_out_dir()
        root = find_checkout(Path.cwd().resolve()) or find_checkout(Path(__file__).resolve())
        if root is None:
            raise GrasplinkError("no grasplink checkout to take scenes/loop_headline.toml from")
        figures = run_benchmark(
            PLANS["quick" if args.quick else "full"],
            out,
            root,
            controllers_for=build_controllers,
            workers=args.workers,
        )
    except GrasplinkError as exc:
        print(f"bench_slip_reporting: error: {exc}", file=sys.stderr)
        return 1
    for label, value, bound, met in target_rows(figures):
        shown = "-" if value is None else f"{value:.2f}"
        print(f"{'MET ' if met else 'MISS' if met is False else '  - '} {label}: {shown} ({bound})")
    print(f"wrote {out}/{PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

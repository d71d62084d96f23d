"""Closed-loop benchmark: does the feedback (and the reflex) stop the slip, trial by trial?

Writes loop.md (tables, verdict against the thesis, mechanisms), loop.png
(stopped share, slip distance and effort against slip speed) and loop.json
(every trial's outcome) into docs/benchmarks/ of the checkout the current
folder is in (or `--out DIR`):

1. every feedback mode (none, slip occurrence, slip speed, grip force,
   force + slip), each with and without the reflex at the thesis's 45 mm/s,
   over slip speeds 10-150 mm/s and ten seeds of the virtual wearer, in the
   loop of scenes/loop_headline.toml (skin, gateway, belt, wearer, EMG,
   hand, object);
2. force + slip with loop_headline's 30 mm/s reflex threshold, for the
   speeds between what this loop's wearer can stop and the thesis's limit.

The work lives in `grasplink.evaluation.loop` (also `grasplink bench loop`);
this driver only parses arguments.

Run: `make bench` or `.venv/bin/python benchmarks/bench_loop.py [--quick] [--out DIR]
[--workers N]`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from grasplink.controllers import build_controllers
from grasplink.errors import GrasplinkError
from grasplink.evaluation.loop import console_table, report_to


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="reduced grid (< 2 min)")
    parser.add_argument("--out", type=Path, default=None, help="default: docs/benchmarks/")
    parser.add_argument(
        "--workers", type=int, default=None, help="processes running trials (default: all cores)"
    )
    parser.add_argument("--dask", default=None, help="a Dask scheduler tcp://HOST:PORT instead")
    args = parser.parse_args(argv)
    try:
        results, out = report_to(
            quick=args.quick,
            out=args.out,
            controllers_for=build_controllers,
            workers=args.workers,
            dask=args.dask,
        )
    except GrasplinkError as exc:
        print(f"bench_loop: error: {exc}", file=sys.stderr)
        return 1
    print(console_table(results))
    print(f"wrote {out}/loop.md, loop.json, loop.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

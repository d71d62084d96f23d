"""The least-force task in the closed loop: slip-speed against slip-occurrence feedback.

Writes docs/benchmarks/loop_task.md, .json and .png (grasplink/evaluation/loop_task.py).
Usage: `python benchmarks/bench_loop_task.py [--quick] [--out DIR] [--workers N]`.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from grasplink.controllers import build_controllers
from grasplink.evaluation.decoding_bench import default_out_dir
from grasplink.evaluation.loop_task import run_report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one seed (8 trials)")
    parser.add_argument("--out", type=Path, default=None, help="default: docs/benchmarks/")
    parser.add_argument("--workers", type=int, default=2, help="processes running trials")
    args = parser.parse_args(argv)
    out = args.out if args.out is not None else default_out_dir()
    results = run_report(
        out, controllers_for=build_controllers, quick=args.quick, workers=args.workers
    )
    high = results["figures"]["compare"]["high"]
    print(
        f"high speeds: slip speed {high['verdict']} slip occurrence "
        f"({high['diff_pct']:+.0f} points)"
    )
    print(f"wrote {out}/loop_task.md, loop_task.json, loop_task.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

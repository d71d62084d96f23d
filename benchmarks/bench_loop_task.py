"""The least-force task in the closed loop: slip-speed against slip-occurrence feedback.

Writes docs/benchmarks/loop_task.md, .json and .png (grasplink/evaluation/loop_task.py).
Usage: `python benchmarks/bench_loop_task.py [--quick] [--out DIR] [--workers N | --dask
tcp://HOST:PORT]` (also `grasplink bench loop --task least-force`);
`--report-only loop_task.json` re-renders the doc and plot from a run's figures.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from grasplink.controllers import build_controllers
from grasplink.errors import GrasplinkError
from grasplink.evaluation.decoding_bench import default_out_dir
from grasplink.evaluation.loop_task import headline, plot_report, render, report_to


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="one seed (14 trials: 8 dry, 6 wet)")
    parser.add_argument("--out", type=Path, default=None, help="default: docs/benchmarks/")
    parser.add_argument(
        "--workers", type=int, default=None, help="local processes (default: every core)"
    )
    parser.add_argument("--dask", default=None, metavar="tcp://HOST:PORT")
    parser.add_argument("--report-only", type=Path, default=None, metavar="JSON")
    args = parser.parse_args(argv)
    if args.report_only is not None:
        out = args.out if args.out is not None else default_out_dir()
        try:
            results = json.loads(args.report_only.read_text())
        except (OSError, ValueError) as exc:
            print(f"bench_loop_task: error: {args.report_only}: {exc}", file=sys.stderr)
            return 1
        out.mkdir(parents=True, exist_ok=True)
        plot_report(results, out / "loop_task.png")
        (out / "loop_task.md").write_text(render(results))
        print(f"rendered {out}/loop_task.md, loop_task.png from {args.report_only}")
        return 0
    try:
        results, out = report_to(
            quick=args.quick,
            out=args.out,
            controllers_for=build_controllers,
            workers=args.workers,
            dask=args.dask,
        )
    except GrasplinkError as exc:
        print(f"bench_loop_task: error: {exc}", file=sys.stderr)
        return 1
    print(headline(results))
    print(f"wrote {out}/loop_task.md, loop_task.json, loop_task.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())

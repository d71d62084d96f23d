"""Gateway benchmark: loop latency, slip onset to belt command, capacity, memory.

Measures (`gateway_measure`), keeps the figures in docs/benchmarks/gateway.json, then
renders docs/benchmarks/gateway.md and gateway.png from that JSON alone
(`gateway_render`), so the doc can be rendered again without measuring.

Run: `make bench` or `.venv/bin/python benchmarks/bench_gateway.py [--quick]` (about 15
minutes; --quick: a few); re-render: `bench_gateway.py --report-only
docs/benchmarks/gateway.json`. `--only sync` measures section 5 (batching per SYNC) alone
into OUT/gateway_sync.json and replaces that section in OUT/gateway.md (a few minutes).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import figures_json
import gateway_render

DOCS = Path(__file__).resolve().parents[1] / "docs" / "benchmarks"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="short runs (smoke test)")
    parser.add_argument("--out", type=Path, default=DOCS, help="where the doc and plot go")
    parser.add_argument(
        "--figures", type=Path, help="where the figures JSON goes (default: OUT/gateway.json)"
    )
    parser.add_argument(
        "--report-only", type=Path, metavar="JSON", help="render from saved figures, no runs"
    )
    parser.add_argument("--only", choices=("sync",), help="measure one part alone into its section")
    args = parser.parse_args(argv)
    if args.only == "sync":
        return only_sync(args)
    if args.report_only:
        figures = figures_json.read(args.report_only)
    else:
        import gateway_measure  # grasplink and the simulators: only when measuring

        figures = figures_json.write(
            args.figures or args.out / "gateway.json", gateway_measure.measure(args.quick)
        )
    print(gateway_render.write(figures, args.out).read_text())
    return 0


def only_sync(args: argparse.Namespace) -> int:
    """Section 5 alone: measured (or read back with --report-only) into gateway_sync.json,
    then spliced into gateway.md."""
    if args.report_only:
        figures = figures_json.read(args.report_only)
    else:
        import can
        import gateway_measure

        rounds, seconds, live_s = (1, 5.0, 5.0) if args.quick else (3, 30.0, 20.0)
        measured = {
            "sync": gateway_measure.sync_batching(seconds, rounds, live_s),
            "environment": figures_json.environment(**{"python-can": can.__version__}),
        }
        figures = figures_json.write(args.figures or args.out / "gateway_sync.json", measured)
    doc = gateway_render.splice_sync(figures, args.out / "gateway.md")
    print("\n".join(gateway_render.sync_section(figures["sync"], figures)))
    print(f"(spliced into {doc})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

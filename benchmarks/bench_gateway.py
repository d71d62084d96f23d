"""Gateway benchmark: loop latency, slip onset to belt command, capacity, memory.

Measures (`gateway_measure`), keeps the figures in docs/benchmarks/gateway.json, then
renders docs/benchmarks/gateway.md and gateway.png from that JSON alone
(`gateway_render`), so the doc can be rendered again without measuring.

Run: `make bench` or `.venv/bin/python benchmarks/bench_gateway.py [--quick]` (about 15
minutes; --quick: a few); re-render: `bench_gateway.py --report-only
docs/benchmarks/gateway.json`.
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
    args = parser.parse_args(argv)
    if args.report_only:
        figures = figures_json.read(args.report_only)
    else:
        import gateway_measure  # grasplink and the simulators: only when measuring

        figures = figures_json.write(
            args.figures or args.out / "gateway.json", gateway_measure.measure(args.quick)
        )
    print(gateway_render.write(figures, args.out).read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())

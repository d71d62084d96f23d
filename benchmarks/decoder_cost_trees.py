"""The default decoder's CPU per sample in this tree against a base tree, in one run.

    .venv/bin/python benchmarks/decoder_cost_trees.py BASE [--rounds N] [--repeats K]
        [--base-try NAME=VALUE,...]

Decodes slip_reporting's cost cases (the full plan's, as the page's "Cost beside the
faithful thesis MMSE") and 8 forward loop cases 3 samples at a time, in a child process
per tree (PYTHONPATH set to the tree), the trees asked in turn N times; each child
reports the least of K passes. Prints each round's pair and the median ratio this/base:
a page regenerated at another time (or beside another job) cannot say whether the decoder
got dearer, a ratio measured in one run can. `--base-try` sets TrackerDecoder class
attributes in the base's child only: with BASE `.` it prices one rule (e.g.
`. --base-try TOLD_RISE_LOG=0`: this tree with the rule against the same tree without it).
`--kinds K[,K]` decodes those kinds' cases instead (the full plan's first seed, both
directions): a rule that acts only where the kind does (e.g. rates-drops, the one kind
sampled below 400 Hz) is priced there.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import sys, time
from grasplink.decoding.registry import make_decoder
from grasplink.decoding.tracker import TrackerDecoder
for item in filter(None, sys.argv[2].split(",")):
    name, value = item.split("=")
    if not hasattr(TrackerDecoder, name):
        sys.exit(f"--base-try {name}: TrackerDecoder has no such setting")
    setattr(TrackerDecoder, name, float(value))
from dataclasses import replace
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
kinds = list(filter(None, sys.argv[3].split(",")))
if kinds:
    unknown = sorted(set(kinds) - set(sr.FULL.variants))
    if unknown:
        sys.exit(f"--kinds {','.join(unknown)}: no such kind in the full plan")
    variants = {k: sr.FULL.variants[k] for k in kinds}
    chosen = sr.cases(replace(sr.FULL, seeds=1, variants=variants))
else:
    todo = sr.cases(sr.FULL)
    picked = sorted(sr.cost_cases(sr.FULL, todo), key=str)
    chosen = picked + [c for c in todo if c.kind == "loop" and not c.reverse][:8]
recs = [(c, c.make()) for c in chosen]
best = None
for _ in range(int(sys.argv[1])):
    n, t0 = 0, time.process_time()
    for c, r in recs:
        ns.feed(make_decoder("tracker", sr.LAYOUTS_MM[c.layout], r.fs_hz), r.t_s, r.force_n, 3)
        n += len(r.t_s)
    us = (time.process_time() - t0) / n * 1e6
    best = us if best is None else min(best, us)
print(best)
"""


def cost_us(tree: Path, repeats: int, tries: str = "", kinds: str = "") -> float:
    env = {**os.environ, "PYTHONPATH": str(tree)}
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(repeats), tries, kinds],
        env=env,
        cwd=tree,
        capture_output=True,
        text=True,
        check=False,
    )
    if out.returncode:
        raise SystemExit(f"{tree}: the cost child failed: {out.stderr.strip()[-800:]}")
    return float(out.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", type=Path, help="a checkout of the base tree")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--base-try", default="", help="NAME=VALUE,... in the base's child")
    parser.add_argument("--kinds", default="", help="K[,K]: these kinds' cases, seed 0")
    args = parser.parse_args(argv)
    if not (args.base / "grasplink" / "__init__.py").is_file():
        parser.error(f"{args.base} is not a grasplink checkout (no grasplink/__init__.py)")
    ratios = []
    for k in range(args.rounds):
        base = cost_us(args.base.resolve(), args.repeats, args.base_try, args.kinds)
        this = cost_us(ROOT, args.repeats, kinds=args.kinds)
        ratios.append(this / base)
        print(f"round {k + 1}: base {base:.2f} us/sample, this {this:.2f}, ratio {ratios[-1]:.3f}")
    print(f"median ratio this/base: {statistics.median(ratios):.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

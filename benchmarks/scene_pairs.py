"""A scene's speed in this tree against another, run for run, for a loaded machine.

    .venv/bin/python benchmarks/scene_pairs.py DIR [--scene NAME] [--runs N]

`bench_scenes.py --against DIR` takes each tree's best of a few runs per round: on two
cores shared with a load of 10 that best moves by +-6 % between two copies of one tree.
Here each tree runs in a warmed child of its own (`tree_script.served_in_tree`), and the
children take turns run by run (which goes first alternates), so consecutive runs of the
two trees meet nearly the same load; each pair gives a ratio of CPU seconds (DIR's over
this tree's: > 1 is faster here) and their median is the figure. The least and the
median CPU of each tree are printed too (ms per run, and x real time per core).
"""

from __future__ import annotations

import argparse
import os
import statistics
from pathlib import Path

from shipped_scenes import scene_path
from tree_script import ask, served_in_tree

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import sys, time
from grasplink.controllers import simulation
from grasplink.simulators.scene import load_scene

scene_path = sys.argv[1]
simulation(load_scene(scene_path)).run()  # warm: imports, compiled kernels
print("ready", flush=True)
for _ in sys.stdin:
    sim = simulation(load_scene(scene_path))
    t0 = time.process_time()
    sim.run()
    print(f"{time.process_time() - t0:.6f} {sim.scene.duration_s}", flush=True)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("against", type=Path, help="the other tree (the base)")
    parser.add_argument("--scene", default="loop_headline")
    parser.add_argument("--runs", type=int, default=30, help="runs per tree")
    args = parser.parse_args()
    scene = scene_path(args.scene)
    if args.runs < 1:
        raise SystemExit(f"--runs {args.runs}: at least one run per tree")
    trees = (args.against, ROOT)
    cpu: tuple[list[float], list[float]] = ([], [])
    duration_s = 0.0
    with (
        served_in_tree(trees[0], CHILD, str(scene)) as base,
        served_in_tree(trees[1], CHILD, str(scene)) as here,
    ):
        children = (base, here)
        for k, child in enumerate(children):
            ask(child, None, what=f"{args.scene} in {trees[k]}")  # "ready"
        for run in range(args.runs):
            for k in (0, 1) if run % 2 == 0 else (1, 0):
                answer = ask(children[k], "run", what=f"{args.scene} in {trees[k]}")
                seconds, duration = answer.split()
                cpu[k].append(float(seconds))
                duration_s = float(duration)
    ratios = [b / h for b, h in zip(*cpu, strict=True)]
    print(f"{args.scene}, {args.runs} runs per tree, load average {os.getloadavg()[0]:.1f}")
    for tree, runs in zip(trees, cpu, strict=True):
        least, median = min(runs), statistics.median(runs)
        print(
            f"  {tree}: least {least * 1e3:.1f} ms ({duration_s / least:.1f}x real time), "
            f"median {median * 1e3:.1f} ms ({duration_s / median:.1f}x)"
        )
    print(
        f"  this tree against {trees[0]}: median of the pairs' ratios "
        f"{statistics.median(ratios):.3f}, of the least {min(cpu[0]) / min(cpu[1]):.3f}"
    )


if __name__ == "__main__":
    main()

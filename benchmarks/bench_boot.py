"""Boot cost: what powering a scene's network on costs, in this tree and older ones.

    .venv/bin/python benchmarks/bench_boot.py [--against DIR ...] [--scene NAME] [--rounds N]

A scene's run starts with `LockstepNetwork.start()`: every node boots, and a master
provisions each over SDO (loop_headline's gateway writes 186 objects, most of them PDO
parameters) before it starts them, all at t = 0 in virtual time. That is a fixed cost
per run, paid by every scene and every test that boots a network; a 6 s loop scene pays
it once. Each tree runs in a warmed child of its own (`tree_script.served_in_tree`),
asked in turn round after round, so the trees meet the same machine load; each answer is
the least CPU of `--repeats` boots. Prints per tree the least and the median over the
rounds (ms of CPU), each tree's median over this tree's (the speed-up here) and the SDO
requests the nodes answered (deterministic: the same wherever provisioning is the same).
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path

from shipped_scenes import scene_path
from tree_script import ask, served_in_tree

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import sys, time
from grasplink.controllers import simulation
from grasplink.core.frames import SDO_RX_BASE
from grasplink.simulators.scene import load_scene

scene_path, repeats = sys.argv[1], int(sys.argv[2])
simulation(load_scene(scene_path)).run()  # warm: imports, compiled kernels
print("ready", flush=True)
for _ in sys.stdin:
    best = float("inf")
    for _ in range(repeats):
        sim = simulation(load_scene(scene_path))
        requests = [0]
        sim.network.taps.append(
            lambda t, f, o: requests.__setitem__(0, requests[0] + (
                SDO_RX_BASE < getattr(f, "can_id", 0) <= SDO_RX_BASE + 127))
        )
        t0 = time.process_time()
        sim.network.start()
        best = min(best, time.process_time() - t0)
    print(f"{best * 1e3:.4f} {requests[0]}", flush=True)
"""


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", type=Path, nargs="*", default=[], help="older trees")
    parser.add_argument("--scene", default="loop_headline")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--repeats", type=int, default=3, help="boots per answer (least)")
    args = parser.parse_args()
    scene = scene_path(args.scene)
    trees = [ROOT, *args.against]
    times: dict[Path, list[float]] = {tree: [] for tree in trees}
    requests: dict[Path, str] = {}
    children = [served_in_tree(tree, CHILD, str(scene), str(args.repeats)) for tree in trees]
    served = [child.__enter__() for child in children]
    try:
        for tree, child in zip(trees, served, strict=True):
            ask(child, None, what=f"boot in {tree}")  # "ready"
        for round_ in range(args.rounds):
            order = list(zip(trees, served, strict=True))
            for tree, child in order if round_ % 2 == 0 else order[::-1]:
                ms, count = ask(child, "boot", what=f"boot in {tree}").split()
                times[tree].append(float(ms))
                requests[tree] = count
    finally:
        for child in children:
            child.__exit__(None, None, None)
    first = statistics.median(times[ROOT])
    print(f"{args.scene}: network start, ms of CPU over {args.rounds} rounds")
    for tree in trees:
        median = statistics.median(times[tree])
        print(
            f"  {tree!s:40} least {min(times[tree]):7.2f}  median {median:7.2f}  "
            f"it/this {median / first:5.3f}  SDO requests {requests[tree]}"
        )


if __name__ == "__main__":
    main()

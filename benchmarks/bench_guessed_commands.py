"""Guessed commands against held ones: what continuing a ramp's steps saves a closed loop.

A coupled scene's physics runs ahead as far as its commands go as guessed
(`simulators/trends.py`); before, the one guess was the command held. This runs each
scene both ways in one process, interleaved (the machine is shared: a ratio of the same
process's runs, not an absolute time), with the held guess put in place of
`continue_steps`, and prints:

- what is deterministic, so two trees and two runs compare exactly: effect steps,
  blocks of each part (one chunk long, longer), rollbacks;
- CPU per run, min and median of the rounds, and their ratio (held / guessed).

Both ways record the same files byte for byte
(tests/simulators/test_batched_paths.py); this measures only the cost.

Run: `.venv/bin/python benchmarks/bench_guessed_commands.py [--rounds N] [SCENE ...]`
(default: loop_headline).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

from shipped_scenes import scene_paths

from grasplink.controllers import simulation
from grasplink.simulators import engine
from grasplink.simulators.scene import load_scene

GUESSED: Callable[[list[float], int], list[float]] = engine.continue_steps


def held(history: list[float], count: int) -> list[float]:
    """The guess before `trends`: the last command, held."""
    return [history[-1]] * count


def run(path: Path, guess: Callable[[list[float], int], list[float]]) -> dict:
    """One run with `guess` in the engine: its CPU and what it computed."""
    engine.continue_steps = guess  # type: ignore[assignment]
    try:
        sim = simulation(load_scene(path))
        blocks = [[0, 0] for _ in sim.parts]
        compute = sim._compute

        def counted(part, t0_us, t_end_us, schedule, _compute=compute):  # type: ignore[no-untyped-def]
            blocks[sim.parts.index(part)][len(schedule) > 1] += 1
            _compute(part, t0_us, t_end_us, schedule)

        sim._compute = counted  # type: ignore[method-assign]
        t0 = time.process_time()
        sim.run()
        cpu_s = time.process_time() - t0
    finally:
        engine.continue_steps = GUESSED  # type: ignore[assignment]
    return {
        "cpu_s": cpu_s,
        "effect_steps": sim.effect_steps,
        "blocks": blocks,
        "rollbacks": sim.rollbacks,
        "simulated_s": sim.t_us / 1e6,
    }


def compare(path: Path, rounds: int) -> None:
    ways = {"held": held, "guessed": GUESSED}
    for guess in ways.values():
        run(path, guess)  # warm: imports, compiled kernels
    cpu: dict[str, list[float]] = {name: [] for name in ways}
    last: dict[str, dict] = {}
    for k in range(rounds):
        for name in list(ways)[:: 1 if k % 2 else -1]:  # alternate who goes first
            last[name] = run(path, ways[name])
            cpu[name].append(last[name]["cpu_s"])
    print(f"{path.stem} ({last['held']['simulated_s']:g} s simulated):")
    for name in ways:
        r = last[name]
        parts = ", ".join(f"{one} one-chunk + {more} longer" for one, more in r["blocks"])
        print(
            f"  {name:8s} effect steps {r['effect_steps']}, blocks per part [{parts}],"
            f" rollbacks {r['rollbacks']}; CPU min {1e3 * min(cpu[name]):.0f} ms,"
            f" median {1e3 * statistics.median(cpu[name]):.0f} ms"
        )
    ratio_min = min(cpu["held"]) / min(cpu["guessed"])
    ratio_median = statistics.median(cpu["held"]) / statistics.median(cpu["guessed"])
    print(f"  held / guessed CPU: {ratio_min:.3f} (min), {ratio_median:.3f} (median)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", default=["loop_headline"], help="scene names")
    parser.add_argument("--rounds", type=int, default=10, help="runs each way")
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error("--rounds must be at least 1")
    paths = scene_paths(args.scenes)
    print(f"load average {os.getloadavg()[0]:.1f}; {args.rounds} rounds, interleaved")
    for path in paths:
        compare(path, args.rounds)
    return 0


if __name__ == "__main__":
    sys.exit(main())

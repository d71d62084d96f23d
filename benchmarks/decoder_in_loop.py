"""Why the skin decoder costs more inside the closed loop than its inputs replayed alone.

    .venv/bin/python benchmarks/decoder_in_loop.py [--scene loop_headline] [--rounds 3]

A warm run of the scene with the gateway's decoder wrapped: every call it gets (`feed`
with its samples, `note_grip_command`, the efference copy) is recorded in order, with the
CPU of each `feed`. The same calls are then replayed into a fresh decoder of the same
scene, in the same process, four ways:

- **alone**: back to back, as `check_gateway_unchanged.py --cost` and the decoding pages
  measure it;
- **after a sweep of N MiB**: a numpy sum over N MiB before each call (1 and 16: within
  and beyond this host's L2), which evicts what the decoder had in the caches;
- **after Python work**: a sort of a list of dicts before each call (the interpreter's own
  data and code, as the nodes, the bus and the gateway run between two packets).

Counts first (deterministic: the calls, their sizes, the updates, the notes; the replay's
estimates must equal the loop's, or the script exits 1), then CPU in ms per simulated s,
best of ROUNDS each. If the calls are the same and the answers too, what the loop adds is
not more work but colder work: the sweeps reproduce it.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from grasplink.controllers import build_controllers, simulation
from grasplink.simulators.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
Call = tuple[str, tuple[Any, ...]]


def recorded_loop(path: Path) -> tuple[float, list[Call], list[list[Any]], float, float]:
    """One run: its CPU (s), the decoder's calls, its answers, its feeds' CPU (s), the
    scene's duration (s)."""
    sim = simulation(load_scene(path))
    (gateway,) = sim.controllers
    decoder = gateway.decoder
    feed, note = decoder.feed, decoder.note_grip_command
    calls: list[Call] = []
    answers: list[list[Any]] = []
    feed_cpu_ns = [0]

    def recorded_feed(t_s: np.ndarray, force_n: np.ndarray) -> Any:
        calls.append(("feed", (t_s.copy(), force_n.copy())))
        t0 = time.process_time_ns()
        out = feed(t_s, force_n)
        feed_cpu_ns[0] += time.process_time_ns() - t0
        answers.append(out)
        return out

    def recorded_note(t_s: float, force_n: float) -> bool:
        calls.append(("note_grip_command", (t_s, force_n)))
        return note(t_s, force_n)

    decoder.feed, decoder.note_grip_command = recorded_feed, recorded_note
    t0 = time.process_time()
    sim.run()
    total_s = time.process_time() - t0
    return total_s, calls, answers, feed_cpu_ns[0] / 1e9, sim.scene.duration_s


def replayed(path: Path, calls: list[Call], between: Callable[[], object] | None):
    """The calls into a fresh decoder of the scene: its feeds' answers and CPU (s)."""
    (gateway,) = build_controllers(load_scene(path))
    decoder = gateway.decoder
    answers, cpu_ns = [], 0
    for name, args in calls:
        if between is not None:
            between()
        t0 = time.process_time_ns()
        out = getattr(decoder, name)(*args)
        cpu_ns += time.process_time_ns() - t0
        if name == "feed":
            answers.append(out)
    return answers, cpu_ns / 1e9


def checked_scene(parser: argparse.ArgumentParser, args: argparse.Namespace) -> Path:
    """The shipped scene `args.scene` names; a parser error for it or for `--rounds` < 1."""
    if args.rounds < 1:
        parser.error(f"--rounds must be at least 1, not {args.rounds}")
    path = ROOT / "scenes" / f"{args.scene}.toml"
    if not path.is_file():
        parser.error(f"no scene {path}")
    return path


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="loop_headline", help="a scene with a gateway")
    parser.add_argument("--rounds", type=int, default=3, help="runs per way (best of)")
    args = parser.parse_args(argv)
    path = checked_scene(parser, args)
    simulation(load_scene(path)).run()  # warm: imports, compiled kernels

    sweep_1 = np.ones(1 << 17)  # 1 MiB of float64
    sweep_16 = np.ones(1 << 21)  # 16 MiB
    dicts = [{"k": k} for k in range(2000)]
    ways: dict[str, Callable[[], object] | None] = {
        "alone": None,
        "after a 1 MiB sweep": sweep_1.sum,
        "after a 16 MiB sweep": sweep_16.sum,
        "after Python work": lambda: sorted(dicts, key=lambda d: -d["k"]),
    }
    loop_ms: list[float] = []
    in_loop_ms: list[float] = []
    cost_ms: dict[str, list[float]] = {way: [] for way in ways}
    for _ in range(args.rounds):
        total_s, calls, answers, feed_s, duration_s = recorded_loop(path)
        loop_ms.append(total_s * 1e3 / duration_s)
        in_loop_ms.append(feed_s * 1e3 / duration_s)
        for way, between in ways.items():
            got, cpu_s = replayed(path, calls, between)
            if repr(got) != repr(answers):
                print(f"replay {way}: the decoder answered otherwise than in the loop")
                return 1
            cost_ms[way].append(cpu_s * 1e3 / duration_s)

    kinds = Counter(name for name, _ in calls)
    sizes = Counter(len(a[0]) for name, a in calls if name == "feed")
    updates = Counter(len(out) for out in answers)
    print(f"{args.scene}, {duration_s:g} simulated s (counts: the same every run)")
    print(f"  decoder calls: {dict(kinds)}")
    print(f"  samples per feed: {dict(sorted(sizes.items()))}")
    print(f"  estimates per feed: {dict(sorted(updates.items()))}")
    print("  replayed: every answer the same as in the loop")
    print(f"CPU, ms per simulated s, best of {args.rounds}:")
    print(f"  whole loop                             {min(loop_ms):7.2f}")
    best_alone = min(cost_ms["alone"])
    print(
        f"  decoder inside the loop                {min(in_loop_ms):7.2f}"
        f"  ({min(in_loop_ms) / best_alone:.2f}x alone)"
    )
    for way, ms in cost_ms.items():
        label = f"decoder replayed {way}"
        print(f"  {label:38s} {min(ms):7.2f}  ({min(ms) / best_alone:.2f}x alone)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Streamed against per-tick: what a node telling its ticks ahead saves, and where not.

The lock-step bus asks a streaming node (`core.protocol.StreamingDevice`) for a span of
ticks; `LockstepNetwork(stream=False)` ticks it one by one. Both send the same frames
(tests/test_streamed_ticks.py); this measures their CPU, interleaved in one process,
best of N, as ratios (the machine is shared: absolute times move with its load):

1. a skin node alone on the bus, run in steps of 10-100 ms (a scene's chunk: a span
   ends at the run's end, so short runs leave short spans);
2. scenes run both ways (default: the skin-only slip, the closed loop, the headline);
3. with `--spans`, how each scene's spans went (asks, asks told nothing, ticks told,
   ticks that happened, and the run's Python calls: a count, not a time, so two trees
   compare exactly on a noisy machine): where streaming costs more than it saves, and why.

Run: `.venv/bin/python benchmarks/bench_streamed_ticks.py [--repeats N] [--scenes ...]`.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from shipped_scenes import scene_paths

from grasplink.bus import lockstep
from grasplink.core.frames import NMT_COB_ID, Frame
from grasplink.devices.factory import build_node
from grasplink.devices.sources import FunctionSource

SCENES = ("slip_alpha0.1_20mm_s_forward", "loop_headline", "headline_slip")
STEPS_MS = (10, 15, 20, 30, 50, 100)
SKIN_ALONE_S = 8.0


def skin_alone_ms_per_s(stream: bool, step_us: int) -> float:
    """CPU ms per simulated second of an operational skin node alone on the bus."""
    node = build_node("skin", 0x10, FunctionSource(lambda t: 3 + np.sin(7 * t)))
    net = lockstep.LockstepNetwork([node], stream=stream)
    net.start()
    net.inject(Frame(NMT_COB_ID, bytes([0x01, 0])))
    end_us = round(SKIN_ALONE_S * 1e6)
    t0 = time.process_time()
    for t_us in range(step_us, end_us + 1, step_us):
        net.run_until(t_us)
    return (time.process_time() - t0) * 1e3 / SKIN_ALONE_S


def scene_ms_per_s(stream: bool, path: Path) -> float:
    """CPU ms per simulated second of a scene, its bus streaming or not."""
    from grasplink.controllers import simulation
    from grasplink.simulators.scene import load_scene

    plain = lockstep.LockstepNetwork.__init__

    def init(self: lockstep.LockstepNetwork, *args: object, **kwargs: object) -> None:
        plain(self, *args, **(kwargs | {"stream": stream}))  # type: ignore[arg-type]

    lockstep.LockstepNetwork.__init__ = init  # type: ignore[method-assign]
    try:
        sim = simulation(load_scene(path))
        t0 = time.process_time()
        sim.run()
        return (time.process_time() - t0) * 1e3 / sim.scene.duration_s
    finally:
        lockstep.LockstepNetwork.__init__ = plain  # type: ignore[method-assign]


def span_counts(path: Path) -> dict[str, int]:
    """How a scene's streaming devices' spans went, counted around their own calls."""
    from grasplink.controllers import simulation
    from grasplink.core.protocol import StreamingDevice
    from grasplink.simulators.scene import load_scene

    counts = {"asks": 0, "told nothing": 0, "ticks told": 0, "ticks happened": 0}
    sim = simulation(load_scene(path))
    for device in sim.network.devices:
        if not (isinstance(device, StreamingDevice) and device.streaming):
            continue
        ahead, commit = device.stream_ahead, device.commit_stream

        def counted_ahead(t_us: int, until_us: int, ahead=ahead) -> list:
            ticks = ahead(t_us, until_us)
            counts["asks"] += 1
            counts["told nothing"] += not ticks
            counts["ticks told"] += len(ticks)
            return ticks

        def counted_commit(ticks: int, commit=commit) -> None:
            counts["ticks happened"] += ticks
            commit(ticks)

        device.stream_ahead, device.commit_stream = counted_ahead, counted_commit
    profile = cProfile.Profile()
    profile.runcall(sim.run)
    counts["python calls"] = pstats.Stats(profile).total_calls  # type: ignore[attr-defined]
    return counts


def best_of(repeats: int, measure: Callable[[bool], float]) -> tuple[float, float]:
    """(per-tick, streamed) best of `repeats` rounds, the two interleaved."""
    best = {False: float("inf"), True: float("inf")}
    for _ in range(repeats):
        for stream in (False, True):
            best[stream] = min(best[stream], measure(stream))
    return best[False], best[True]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="rounds (best of)")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES), metavar="NAME")
    parser.add_argument("--no-skin-alone", action="store_true", help="scenes only")
    parser.add_argument("--spans", action="store_true", help="count each scene's spans")
    args = parser.parse_args(argv)
    if args.repeats < 1:
        parser.error("--repeats must be at least 1")
    paths = scene_paths(args.scenes)
    print(f"load average {os.getloadavg()[0]:.1f}; best of {args.repeats}, interleaved")
    print("| run | per-tick ms / simulated s | streamed | per-tick / streamed |")
    print("|---|---:|---:|---:|")
    if not args.no_skin_alone:
        for step_ms in STEPS_MS:
            plain, streamed = best_of(
                args.repeats, lambda s, step=step_ms: skin_alone_ms_per_s(s, step * 1000)
            )
            print(
                f"| skin alone, {step_ms} ms runs | {plain:.2f} | {streamed:.2f} |"
                f" {plain / streamed:.2f} |"
            )
    for path in paths:
        scene_ms_per_s(True, path)  # warm: imports, compiled kernels
        plain, streamed = best_of(args.repeats, lambda s, p=path: scene_ms_per_s(s, p))
        print(f"| {path.stem} | {plain:.2f} | {streamed:.2f} | {plain / streamed:.2f} |")
    if args.spans:
        print("\n| scene | asks | told nothing | ticks told | ticks happened | python calls |")
        print("|---|---:|---:|---:|---:|---:|")
        for path in paths:
            c = span_counts(path)
            print(f"| {path.stem} | " + " | ".join(str(v) for v in c.values()) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

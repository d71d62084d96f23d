"""The skin decoder's CPU on a closed loop's own skin feed, by phase: this tree against a
base tree, in one run.

    .venv/bin/python benchmarks/decoder_loop_phases.py BASE [--scene loop_headline]
        [--rounds 5] [--split 1.0]

One run of the scene in this tree records every call its gateway makes on the decoder
(`decoder_in_loop.recorded_loop`: each feed with its samples, each grip command noted).
The calls are replayed into a fresh decoder of the scene by a served child per tree
(`tree_script.served_in_tree`: no interpreter start or compile per round; a first
replay warms each), the trees asked in turn ROUNDS times. Each replay must answer as the
loop's decoder did (else exit 1: a tree that decodes otherwise is no speed change).
Prints the CPU of the feeds before SPLIT s (the quiet phase: the skin on its rail, then
the object held) and from it on (the slip, the grip), in ms per simulated s, least over
the rounds, and base / this.

Why not the whole loop: the decoder is about a fifth of a closed loop's CPU
(docs/benchmarks/scenes.md), so a decoder change moves the loop's ratio by less than the
shared machine's noise; replayed alone its own cost shows (inside the loop it costs
~1.5x as much, from cold caches: `decoder_in_loop.py`).
"""

from __future__ import annotations

import argparse
import hashlib
import pickle
import sys
import tempfile
from pathlib import Path

from decoder_in_loop import checked_scene, recorded_loop
from tree_script import ask, served_in_tree

ROOT = Path(__file__).resolve().parents[1]

CHILD = """
import hashlib, pickle, sys, time
from pathlib import Path
from grasplink.controllers import build_controllers
from grasplink.simulators.scene import load_scene

calls = pickle.loads(Path(sys.argv[1]).read_bytes())
scene, split = Path(sys.argv[2]), float(sys.argv[3])
for line in sys.stdin:
    (gateway,) = build_controllers(load_scene(scene))
    decoder = gateway.decoder
    cpu_ns, answers = [0, 0], []
    for name, args in calls:
        phase = int(name == "feed" and float(args[0][-1]) >= split)
        t0 = time.process_time_ns()
        out = getattr(decoder, name)(*args)
        cpu_ns[phase] += time.process_time_ns() - t0
        if name == "feed":
            answers.append(out)
    digest = hashlib.sha256(repr(answers).encode()).hexdigest()[:16]
    print(cpu_ns[0], cpu_ns[1], digest, flush=True)
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", type=Path, help="a checkout of the base tree")
    parser.add_argument("--scene", default="loop_headline", help="a scene with a gateway")
    parser.add_argument("--rounds", type=int, default=5, help="replays per tree (least)")
    parser.add_argument("--split", type=float, default=1.0, help="phase boundary (s)")
    args = parser.parse_args(argv)
    path = checked_scene(parser, args)
    if not (args.base / "grasplink").is_dir():
        parser.error(f"{args.base} is no checkout (no grasplink/ in it)")
    _, calls, answers, _, duration_s = recorded_loop(path)
    expected = hashlib.sha256(repr(answers).encode()).hexdigest()[:16]
    trees = {"base": args.base.resolve(), "this": ROOT}
    best: dict[str, list[float]] = {name: [float("inf")] * 2 for name in trees}
    spans = (args.split, duration_s - args.split)  # simulated s per phase
    with tempfile.TemporaryDirectory() as tmp:
        saved = Path(tmp) / "calls.pickle"
        saved.write_bytes(pickle.dumps(calls))
        with (
            served_in_tree(trees["base"], CHILD, str(saved), str(path), str(args.split)) as base,
            served_in_tree(ROOT, CHILD, str(saved), str(path), str(args.split)) as this,
        ):
            children = {"base": base, "this": this}
            for name, child in children.items():  # warm: compiled kernels loaded
                ask(child, "go", what=name)
            for _ in range(args.rounds):
                for name, child in children.items():
                    quiet, rest, digest = ask(child, "go", what=name).split()
                    if digest != expected:
                        print(f"{name}: the decoder answered otherwise than in the loop")
                        return 1
                    for phase, ns in enumerate((quiet, rest)):
                        ms = int(ns) / 1e6 / spans[phase]
                        best[name][phase] = min(best[name][phase], ms)
    print(f"{args.scene}: {len(calls)} decoder calls replayed, every answer the loop's")
    print(f"CPU, ms per simulated s, least of {args.rounds} (base / this):")
    labels = (f"before {args.split:g} s", f"from {args.split:g} s on")
    for phase, label in enumerate(labels):
        b, t = best["base"][phase], best["this"][phase]
        print(f"  {label:16s} base {b:6.2f}  this {t:6.2f}  {b / t:.2f}x")
    whole = [(best[n][0] * spans[0] + best[n][1] * spans[1]) / duration_s for n in trees]
    print(f"  {'whole':16s} base {whole[0]:6.2f}  this {whole[1]:6.2f}  {whole[0] / whole[1]:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())

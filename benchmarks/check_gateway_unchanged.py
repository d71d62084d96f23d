"""Check that this tree's gateway does what a base tree's does, byte for byte, and time it.

    .venv/bin/python benchmarks/check_gateway_unchanged.py BASE [--part runs,replay]
    .venv/bin/python benchmarks/check_gateway_unchanged.py BASE --cost ROUNDS [--profile]

BASE is a checkout (e.g. `git worktree add /tmp/base REV`); each tree runs in its own
interpreter (the same module names).

- **runs**: `check_runs_unchanged.py BASE THIS`: every file `grasplink run` writes for
  each of its scenes (and the float64 bits of every recorded chunk) the same in both trees.
- **replay**: the scene's master (`[controller]`, the gateway in the `loop_*` scenes of
  `REPLAY_SCENES`) is recorded call by call in BASE's run (start, receive, advance,
  next_deadline_us: the arguments, the frames returned, the deadline) together with the
  snapshot it publishes (`latest`, compared by repr when it changes); this tree's master,
  built from the same scene, is fed the same calls and must answer each the same way.
  That checks the gateway's frames, their order and its deadlines, not only what reached
  the bus.
- **--cost ROUNDS**: the gateway alone, the recorded calls of each replay scene replayed in
  each tree (a warmed child per tree, asked in turn ROUNDS times; the least and the median
  CPU of each), in ms of CPU per simulated second and their ratios: what a change of
  the gateway's own work buys, without the nodes, the bus and the physics. `--profile`
  prints this tree's cProfile of one replay of each scene (the top functions by own time).

Prints what differs (the first call or file) and exits 1 when anything does.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import check_runs_unchanged
from tree_script import ask, last_json, run_in_tree, served_in_tree

ROOT = Path(__file__).resolve().parents[1]
REPLAY_SCENES = ("loop_headline", "loop_fast_reflex", "loop_slow_wearer", "loop_vendor_modules")

# Run inside a tree's interpreter. `record SCENE OUT`: the scene's run with its master's
# calls recorded, pickled to OUT. `replay SCENE CALLS`: this tree's master fed them,
# compared call by call (prints a JSON verdict). `serve SCENE CALLS`: warmed, then one
# unchecked replay per line read, its CPU printed. `profile SCENE CALLS`: one replay
# under cProfile.
REPLAY = r"""
import cProfile, json, pickle, pstats, sys, time
from grasplink.controllers import build_controllers, simulation
from grasplink.core.frames import Frame
from grasplink.simulators.scene import load_scene

CALLS = ("start", "receive", "advance", "next_deadline_us")


def frames(out):
    return None if out is None else [(f.can_id, bytes(f.data), f.rtr, f.dlc) for f in out]


def record(scene_path, out_path):
    sim = simulation(load_scene(scene_path))
    (master,) = sim.controllers
    calls = []
    shown = [None]

    def wrap(name):
        call = getattr(master, name)

        def recorded(*args):
            out = call(*args)
            wire = [(a.can_id, bytes(a.data), a.rtr, a.dlc) if isinstance(a, Frame) else a
                    for a in args]
            latest = getattr(master, "latest", None)
            snap = None
            if latest is not shown[0]:
                shown[0] = latest
                snap = repr(latest)
            calls.append((name, wire, out if name == "next_deadline_us" else frames(out), snap))
            return out

        setattr(master, name, recorded)

    for name in CALLS:
        wrap(name)
    sim.run()
    with open(out_path, "wb") as f:
        pickle.dump({"duration_s": sim.scene.duration_s, "calls": calls}, f)


def fresh(scene_path):
    (master,) = build_controllers(load_scene(scene_path))
    return master


def built(calls):  # the calls with their frames built (outside what a cost measures)
    return [(name, [Frame(*a) if isinstance(a, tuple) else a for a in wire])
            for name, wire, _, _ in calls]


def feed(master, calls):
    for name, args in calls:
        yield name, getattr(master, name)(*args)


def replay(scene_path, calls_path):
    with open(calls_path, "rb") as f:
        calls = pickle.load(f)["calls"]
    master = fresh(scene_path)
    shown = None
    answers = feed(master, built(calls))
    for k, ((name, wire, want, want_snap), (_, out)) in enumerate(zip(calls, answers)):
        got = out if name == "next_deadline_us" else frames(out)
        snap = None
        latest = getattr(master, "latest", None)
        if latest is not shown:
            shown = latest
            snap = repr(latest)
        if got != want or snap != want_snap:
            what = "snapshot" if got == want else "answer"
            print(json.dumps({"calls": len(calls), "first_difference": k, "call": name,
                              "what": what, "base": repr(want if got != want else want_snap)[:300],
                              "this": repr(got if got != want else snap)[:300]}))
            return
    frames_out = sum(len(c[2]) for c in calls if c[0] != "next_deadline_us")
    print(json.dumps({"calls": len(calls), "frames": frames_out, "first_difference": None}))


def serve(scene_path, calls_path):
    # warmed twice (imports, compiled kernels), then one replay per line asked: its CPU ms
    # per simulated s
    with open(calls_path, "rb") as f:
        recorded = pickle.load(f)
    calls = built(recorded["calls"])
    for _ in range(2):
        for _ in feed(fresh(scene_path), calls):
            pass
    print("ready", flush=True)
    for _ in sys.stdin:
        master = fresh(scene_path)
        t0 = time.process_time()
        for _ in feed(master, calls):
            pass
        print(1e3 * (time.process_time() - t0) / recorded["duration_s"], flush=True)


def profile(scene_path, calls_path):
    with open(calls_path, "rb") as f:
        calls = built(pickle.load(f)["calls"])
    for _ in feed(fresh(scene_path), calls):  # warm: imports, compiled kernels
        pass
    master = fresh(scene_path)
    prof = cProfile.Profile(time.process_time)  # CPU time: a shared machine's load stays out
    prof.enable()
    for _ in feed(master, calls):
        pass
    prof.disable()
    pstats.Stats(prof).sort_stats("tottime").print_stats(30)


mode = sys.argv[1]
if mode == "record":
    record(sys.argv[2], sys.argv[3])
elif mode == "replay":
    replay(sys.argv[2], sys.argv[3])
elif mode == "serve":
    serve(sys.argv[2], sys.argv[3])
else:
    profile(sys.argv[2], sys.argv[3])
"""


def record(base: Path, tmp: Path) -> dict[str, Path]:
    """Each replay scene's master calls, recorded in `base`'s run."""
    recorded = {}
    for scene in REPLAY_SCENES:
        path = tmp / f"{scene}.calls"
        run_in_tree(
            base,
            REPLAY,
            "record",
            str(ROOT / "scenes" / f"{scene}.toml"),
            str(path),
            what=f"recording {scene}",
        )
        recorded[scene] = path
    return recorded


def check_replay(recorded: dict[str, Path]) -> bool:
    same = True
    for scene, path in recorded.items():
        scene_path = str(ROOT / "scenes" / f"{scene}.toml")
        verdict = last_json(
            run_in_tree(ROOT, REPLAY, "replay", scene_path, str(path), what=f"replaying {scene}")
        )
        if verdict["first_difference"] is None:
            print(
                f"replay {scene}: {verdict['calls']} calls, {verdict['frames']} frames out, "
                "every answer and snapshot the same"
            )
        else:
            same = False
            print(f"replay {scene}: DIFFERS {json.dumps(verdict)}")
    return same


def cost(base: Path, recorded: dict[str, Path], rounds: int) -> None:
    """The gateway alone per scene: one child per tree stays up (warmed), and the two are
    asked in turn, ROUNDS replays each (the order alternating round by round, so a load
    that changes favours neither); the least and the median CPU of each, and their ratios."""
    print(f"gateway alone, ms of CPU per simulated s ({rounds} replays each, trees in turn):")
    for scene, path in recorded.items():
        scene_path = str(ROOT / "scenes" / f"{scene}.toml")
        times: dict[str, list[float]] = {"base": [], "this": []}
        with (
            served_in_tree(base, REPLAY, "serve", scene_path, str(path)) as before,
            served_in_tree(ROOT, REPLAY, "serve", scene_path, str(path)) as after,
        ):
            children = {"base": before, "this": after}
            for name, child in children.items():
                if ask(child, None, what=f"warming {scene} ({name})") != "ready":
                    raise SystemExit(f"warming {scene} ({name}): no ready line")
            for k in range(rounds):
                for name in ("base", "this") if k % 2 == 0 else ("this", "base"):
                    ms = float(ask(children[name], "go", what=f"timing {scene} ({name})"))
                    times[name].append(ms)
        b, t = times["base"], times["this"]
        mid_b, mid_t = statistics.median(b), statistics.median(t)
        print(
            f"  {scene:22s} least: base {min(b):6.2f}  this {min(t):6.2f}  "
            f"ratio {min(b) / min(t):.2f}x;  median: base {mid_b:6.2f}  this {mid_t:6.2f}  "
            f"ratio {mid_b / mid_t:.2f}x"
        )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", type=Path, help="a checkout of the base tree")
    parser.add_argument("--part", default="runs,replay", help="runs, replay or both")
    parser.add_argument("--cost", type=int, metavar="ROUNDS", help="time the gateway alone")
    parser.add_argument("--profile", action="store_true", help="with --cost: cProfile here")
    args = parser.parse_args()
    base = args.base.resolve()
    if not (base / "grasplink").is_dir():
        parser.error(f"{base} is not a grasplink checkout (no grasplink/ in it)")
    parts = set(args.part.split(","))
    if unknown := parts - {"runs", "replay"}:
        parser.error(f"--part: unknown {', '.join(sorted(unknown))}; parts: runs, replay")
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        if args.cost is not None:
            recorded = record(base, tmp)
            if args.profile:
                for scene, path in recorded.items():
                    print(f"== {scene}")
                    scene_path = str(ROOT / "scenes" / f"{scene}.toml")
                    print(
                        run_in_tree(
                            ROOT,
                            REPLAY,
                            "profile",
                            scene_path,
                            str(path),
                            what=f"profiling {scene}",
                        )
                    )
            cost(base, recorded, args.cost)
            return 0
        same = True
        if "runs" in parts:
            same &= check_runs_unchanged.main([str(base), str(ROOT)]) == 0
        if "replay" in parts:
            same &= check_replay(record(base, tmp))
    print("same as the base" if same else "NOT the same as the base")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())

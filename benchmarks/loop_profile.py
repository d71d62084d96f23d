"""Where one closed-loop scene run spends its CPU: by package, and the gateway call by call.

    .venv/bin/python benchmarks/loop_profile.py [--scene loop_headline] [--top 25]
        [--timed RUNS]

One warmed run of the scene (imports and compiled kernels loaded first), then one run
under cProfile in the same process. Printed, per simulated second:

1. own time by package: grasplink's subpackages (simulators, devices, bus, gateway,
   decoding, profiles, core), python-can, canopen, numpy, scipy, numba; a builtin's
   time (dict.get, len, a ufunc's reduce, struct.pack) goes to the package of the
   function that called it, shared by the calls' time when several did;
2. the functions with the most own time (and calls per simulated second);
3. the gateway's "behaviour" (gateway/ but feedback.py; bench_scenes.py's stage split
   calls decoding, PDO decode and feedback by name, the rest behaviour): its functions
   by own time, builtins included, each with its calls per simulated second;
4. the cyclic garbage collector's collections during the unprofiled run, and their
   CPU (`gc.callbacks`): a run allocates and frees in balance, so this is small.

With `--timed RUNS`, instead: the stages of `TIMED` timed inclusively in RUNS unprofiled
runs (each method wrapped, `time.thread_time_ns` around its calls; a wrapper adds ~1 us a
call, and a stage inside another counts in both): ms per run, share of the runs' CPU,
calls and us per call - what a stage costs inside the loop, where its caches are cold
(a tick's numpy calls cost there several times what a warm timeit loop shows).

cProfile (timed by CPU, not the wall clock) charges every Python call ~0.5-1 us more
than it costs: call-heavy code (the bus's per-frame loop, the object store) reads larger
than a sampling profiler shows it, and the run takes 5-8 times its CPU. Read the shares as
where the calls are, and check a cut's worth with the scene's CPU itself
(`scene_pairs.py`, `bench_scenes.py --against`).
"""

from __future__ import annotations

import argparse
import cProfile
import gc
import importlib
import pstats
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

from shipped_scenes import scene_path

from grasplink.controllers import simulation
from grasplink.simulators.scene import load_scene

LIBRARIES = ("can", "canopen", "numpy", "scipy", "numba", "llvmlite")
# gateway/ files whose time bench_scenes.py's stage split names apart from "behaviour"
NOT_BEHAVIOUR = ("grasplink/gateway/feedback.py",)

Func = tuple[str, int, str]
# Stages timed inclusively with --timed: (module, class, method).
TIMED = (
    ("grasplink.decoding.base", "Decoder", "feed"),
    ("grasplink.decoding.contacts", "ContactDetector", "_feed"),
    ("grasplink.decoding.detector.hinges", "HingeBank", "run"),
    ("grasplink.decoding.tracker", "TrackerDecoder", "_report"),
    ("grasplink.decoding.skin_frames", "SkinFrames", "feed"),
    ("grasplink.gateway.service", "Gateway", "_control"),
    ("grasplink.gateway.service", "Gateway", "_commands"),
    ("grasplink.gateway.service", "Gateway", "snapshot"),
    ("grasplink.simulators.engine", "Simulation", "_run_ahead"),
    ("grasplink.simulators.engine", "Simulation", "_snapshot"),
    ("grasplink.simulators.engine", "Simulation", "_publish_until"),
    ("grasplink.simulators.engine", "Simulation", "_read_actuators"),
    ("grasplink.simulators.bindings", "SceneSource", "samples"),
    ("grasplink.devices.skin", "SkinApp", "advance"),
    ("grasplink.devices.skin", "SkinApp", "_counts"),
    ("grasplink.devices.emg", "EmgApp", "advance"),
    ("grasplink.devices.emg", "EmgApp", "_sample_until"),
    ("grasplink.devices.emg", "EmgApp", "_publish_envelope"),
)


def package_of(file: str) -> str | None:
    """grasplink/<sub>, a library's name, or None (a builtin, the standard library)."""
    file = file.replace("\\", "/")
    if "grasplink/" in file:
        rest = file[file.rindex("grasplink/") + len("grasplink/") :]
        return "grasplink/" + rest.split("/")[0].removesuffix(".py")
    if "site-packages/" in file:
        top = file.split("site-packages/")[1].split("/")[0]
        if top in LIBRARIES:
            return "python-can" if top == "can" else top
    return None


def owners(raw: dict, func: Func, seen: frozenset = frozenset()) -> dict[Func, float]:
    """The packaged functions `func`'s own time belongs to ({func: share}): itself if it
    has a package, else its callers', by the time of their calls."""
    if package_of(func[0]) is not None or func in seen or not raw[func][4]:
        return {func: 1.0}
    callers = raw[func][4]
    total = sum(c[3] for c in callers.values()) or 1.0
    out: dict[Func, float] = {}
    for caller, c in callers.items():
        for owner, share in owners(raw, caller, seen | {func}).items():
            out[owner] = out.get(owner, 0.0) + share * c[3] / total
    return out


def gc_during(path: Path) -> tuple[float, Counter]:
    """(CPU s of collections, collections per generation) during one unprofiled run."""
    sim = simulation(load_scene(path))
    spent: list[float] = [0.0]
    counts: Counter = Counter()
    started: list[float] = [0.0]

    def callback(phase: str, info: dict) -> None:
        if phase == "start":
            started[0] = time.process_time()
        else:
            spent[0] += time.process_time() - started[0]
            counts[info["generation"]] += 1

    gc.callbacks.append(callback)
    try:
        sim.run()
    finally:
        gc.callbacks.remove(callback)
    return spent[0], counts


def timed_stages(path: Path, runs: int) -> None:
    """Print each `TIMED` stage's inclusive CPU in `runs` runs (after a warm one)."""
    spent: Counter = Counter()
    calls: Counter = Counter()
    originals = []
    for module, cls_name, name in TIMED:
        cls = getattr(importlib.import_module(module), cls_name)
        original = cls.__dict__[name]
        originals.append((cls, name, original))

        def wrapped(
            *args: Any,
            _call: Callable[..., Any] = original,
            _key: str = f"{cls_name}.{name}",
            **kwargs: Any,
        ) -> Any:
            t0 = time.thread_time_ns()
            try:
                return _call(*args, **kwargs)
            finally:
                spent[_key] += time.thread_time_ns() - t0
                calls[_key] += 1

        setattr(cls, name, wrapped)
    try:
        simulation(load_scene(path)).run()  # warm
        spent.clear()
        calls.clear()
        total_ns = 0
        for _ in range(runs):
            sim = simulation(load_scene(path))
            t0 = time.thread_time_ns()
            sim.run()
            total_ns += time.thread_time_ns() - t0
    finally:
        for cls, name, original in originals:
            setattr(cls, name, original)
    print(f"{path.stem}: {total_ns / runs / 1e6:.0f} ms CPU a run ({runs} runs, wrapped)")
    for key, ns in spent.most_common():
        print(
            f"  {key:34s} {ns / runs / 1e6:7.1f} ms/run {100 * ns / total_ns:5.1f} % "
            f"{calls[key] / runs:7.0f} calls {ns / calls[key] / 1e3:7.1f} us/call"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="loop_headline")
    parser.add_argument("--top", type=int, default=25, help="rows of each function table")
    parser.add_argument("--timed", type=int, metavar="RUNS", help="time TIMED's stages instead")
    args = parser.parse_args()
    path = scene_path(args.scene)
    if args.top < 1:
        raise SystemExit(f"--top {args.top}: at least one row")
    if args.timed is not None:
        if args.timed < 1:
            raise SystemExit(f"--timed {args.timed}: at least one run")
        timed_stages(path, args.timed)
        return
    simulation(load_scene(path)).run()  # warm: imports, compiled kernels
    sim = simulation(load_scene(path))
    t0 = time.process_time()
    sim.run()
    plain_s = time.process_time() - t0
    gc_s, collections = gc_during(path)
    sim = simulation(load_scene(path))
    profile = cProfile.Profile(time.process_time)  # CPU: a loaded host waits unseen
    profile.enable()
    sim.run()
    profile.disable()
    duration_s = sim.scene.duration_s
    raw: dict = pstats.Stats(profile).stats  # type: ignore[attr-defined]
    own: Counter = Counter()  # packaged function -> own time, builtins it called included
    for func, (_, _, tottime, _, _) in raw.items():
        for owner, share in owners(raw, func).items():
            own[owner] += tottime * share
    total = sum(own.values())
    calls = sum(v[1] for v in raw.values())

    def ms(seconds: float) -> str:
        return f"{1e3 * seconds / duration_s:7.2f} ms/s"

    print(
        f"{args.scene}: {duration_s:g} simulated s, {1e3 * plain_s:.0f} ms CPU unprofiled "
        f"({duration_s / plain_s:.1f}x real time), {1e3 * total:.0f} ms under cProfile; "
        f"{calls / duration_s:,.0f} Python calls per simulated s"
    )
    by_package: Counter = Counter()
    for func, seconds in own.items():
        by_package[package_of(func[0]) or "other (standard library)"] += seconds
    print("\nown time by package (a builtin's with its caller's), shares of the profiled run")
    for name, seconds in by_package.most_common():
        print(f"  {name:32s} {ms(seconds)} {100 * seconds / total:5.1f} %")

    def where(func: Func) -> str:
        file = func[0].replace("\\", "/")
        short = file[file.rindex("grasplink/") :] if "grasplink/" in file else Path(file).name
        return f"{short}:{func[1]} {func[2]}"

    print(f"\ntop {args.top} functions by own time (builtins they call included)")
    for func, seconds in own.most_common(args.top):
        per_s = raw[func][1] / duration_s
        print(f"  {100 * seconds / total:5.1f} % {per_s:8.0f} calls/s  {where(func)}")
    behaviour = Counter(
        {
            func: seconds
            for func, seconds in own.items()
            if package_of(func[0]) == "grasplink/gateway"
            and not func[0].replace("\\", "/").endswith(NOT_BEHAVIOUR)
        }
    )
    share = sum(behaviour.values())
    print(
        f"\ngateway behaviour: {ms(share)}, {100 * share / total:.1f} % of the profiled run;"
        f" its top {args.top} functions"
    )
    for func, seconds in behaviour.most_common(args.top):
        per_s = raw[func][1] / duration_s
        print(f"  {100 * seconds / total:5.1f} % {per_s:8.0f} calls/s  {where(func)}")
    print(
        f"\ncyclic GC during one unprofiled run: {sum(collections.values())} collections "
        f"({dict(sorted(collections.items()))} by generation), {ms(gc_s)}"
    )


if __name__ == "__main__":
    main()

"""Work, not seconds: the skin decoder's and the gateway's instructions, this tree against a base.

On a shared machine CPU times drift by 2-3x between days and by tens of percent within a
minute, so a CPU change of 10-20 % cannot be told from seconds measured at different
times. Valgrind's callgrind counts the instructions executed, the same whatever else the
machine does. Each workload runs twice, short and long, in a fresh interpreter per run;
the difference divided by the difference in length is the work per unit with the
interpreter's start and imports taken out.

Workloads (bench_gateway's skin: 60 mm/s slip cycles across alpha0.1, 400 Hz):
- decoder: `TrackerDecoder.process` alone on 3-sample chunks (the skin TPDO); per sample;
- gateway: the gateway and its four nodes in virtual time (`LockstepNetwork`); per simulated
  second (the nodes' work is in it too, the same in both trees).

Compiled kernels (numba) are built for a generic x86-64 CPU in both trees
(`NUMBA_CPU_NAME=generic`) and compiled before the measured runs, outside valgrind: under it
numba would see another CPU than the one its cache was built for and compile inside the
count. The counts are then those of code without the host's vector extensions (numpy's own
loops still pick theirs at run time), a proxy for work, not for seconds on this machine.

Run: `.venv/bin/python benchmarks/bench_work.py [--base REV]` (default base: HEAD~1; needs
valgrind; ~10 minutes on two cores, plus up to a minute per tree to compile its kernels).
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from types import ModuleType

from doc_tables import signed, table

ROOT = Path(__file__).resolve().parents[1]
# (short, long) lengths: decoder in slip cycles, gateway in simulated seconds
LENGTHS = {"decoder": (2, 6), "gateway": (6.0, 18.0)}
UNITS = {"decoder": "skin sample", "gateway": "simulated second"}
# numba's target CPU for every run, in valgrind or not: one cache key for both
CHILD_ENV = {**os.environ, "NUMBA_CPU_NAME": "generic"}
WARM_UP = Path("grasplink/decoding/warm_up.py")  # trees with compiled kernels have it


def compile_kernels(tree: Path) -> None:
    """The tree's decoder kernels compiled (or loaded) for the generic CPU, outside valgrind."""
    if not (tree / WARM_UP).exists():
        return  # a tree from before the kernels
    subprocess.run(
        [sys.executable, "-m", "grasplink.decoding.warm_up"],
        cwd=tree,
        env={**CHILD_ENV, "PYTHONPATH": str(tree)},
        check=True,
        capture_output=True,
    )


def run_workload(tree: Path, workload: str, amount: float) -> None:
    """The workload itself, in this interpreter, importing grasplink from `tree`."""
    sys.path[:0] = [str(tree), str(tree / "benchmarks")]
    bg = gateway_workload()

    import grasplink

    if not Path(grasplink.__file__).resolve().is_relative_to(tree.resolve()):
        raise SystemExit(f"grasplink imported from {grasplink.__file__}, not from {tree}")
    if workload == "decoder":
        import numpy as np

        from grasplink.decoding.tracker import TrackerDecoder
        from grasplink.profiles.layouts import LAYOUTS_MM

        x = np.concatenate([bg.SlipCycle().values] * int(amount))
        t = np.arange(len(x)) / 400.0
        decoder = TrackerDecoder(LAYOUTS_MM[bg.LAYOUT], 400)
        for i in range(0, len(t), 3):
            decoder.process(t[i : i + 3], x[i : i + 3])
    else:
        # built here, not with the gateway benchmark's `lockstep_set`: the base tree's
        # module is imported, and older ones do not have it
        config = bg.gateway_config()
        net = bg.LockstepNetwork([bg.Gateway(config), *bg.set_nodes(config)])
        net.start()
        net.run_for(round(amount * bg.S))


def instructions(tree: Path, workload: str, amount: float) -> int:
    """Instructions callgrind counts for one run of the workload in a fresh interpreter."""
    command = [
        "valgrind", "--tool=callgrind", "--callgrind-out-file=/dev/null",
        sys.executable, __file__, "--child", str(tree), workload, str(amount),
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, env=CHILD_ENV)
    found = re.search(r"Collected\s*:\s*(\d+)", done.stderr)
    if done.returncode != 0 or found is None:
        raise RuntimeError(f"callgrind run failed ({' '.join(command)}):\n{done.stderr[-2000:]}")
    return int(found.group(1))


def per_unit(tree: Path, workload: str) -> float:
    short, long = LENGTHS[workload]
    units = (long - short) * (len_cycle_samples() if workload == "decoder" else 1.0)
    counts = [instructions(tree, workload, amount) for amount in (short, long)]
    return (counts[1] - counts[0]) / units


def len_cycle_samples() -> int:
    sys.path.insert(0, str(ROOT / "benchmarks"))
    return len(gateway_workload().SlipCycle().values)


def gateway_workload() -> ModuleType:
    """The gateway benchmark's measuring module on `sys.path`: `gateway_measure` since the
    measure/render split, `bench_gateway` itself in trees from before it."""
    try:
        return importlib.import_module("gateway_measure")
    except ModuleNotFoundError as exc:
        if exc.name != "gateway_measure":
            raise
        return importlib.import_module("bench_gateway")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="HEAD~1", help="git revision to compare with")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        tree, workload, amount = args.child
        run_workload(Path(tree), workload, float(amount))
        return 0
    if shutil.which("valgrind") is None:
        print("bench_work: needs valgrind (apt-get install valgrind)", file=sys.stderr)
        return 2
    rev = subprocess.run(
        ["git", "-C", str(ROOT), "rev-parse", "--short", args.base],
        capture_output=True,
        text=True,
    )
    if rev.returncode != 0:
        print(f"bench_work: no git revision {args.base!r}: {rev.stderr.strip()}", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="bench-work-") as tmp:
        base = Path(tmp) / "base"
        subprocess.run(
            ["git", "-C", str(ROOT), "worktree", "add", "-q", "--detach", str(base), args.base],
            check=True,
        )
        try:
            for tree in (base, ROOT):
                compile_kernels(tree)
            jobs = [(tree, w) for w in LENGTHS for tree in (base, ROOT)]
            with ThreadPoolExecutor(2) as pool:  # a valgrind process per core
                results = list(pool.map(lambda job: per_unit(*job), jobs))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(base)])
    print(f"instructions per unit, base {rev.stdout.strip()} against this tree (callgrind)\n")
    rows = [
        [w, UNITS[w], f"{before:,.0f}", f"{after:,.0f}", signed(100 * (after / before - 1), 1, "%")]
        for w, before, after in zip(LENGTHS, results[::2], results[1::2], strict=True)
    ]
    print("\n".join(table(["workload", "unit", "base", "this tree", "change"], rows, "llrrr")))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Check that scene runs write byte-identical outputs in this tree and in a base tree.

    .venv/bin/python benchmarks/check_runs_unchanged.py BASE [--scenes NAMES] [--loop]

BASE is a set-up checkout of an older revision (e.g. `git worktree add /tmp/base REV`).
Every scene (default `SCENES`: open loop, closed loop, vendor modules, bus faults, boot)
is run by each tree's `grasplink run SCENE --out DIR` in its own interpreter
(`PYTHONPATH` = that tree, the scene files taken from this tree), and every file in the
two output folders is compared byte for byte: the same file names, the same bytes.
`--loop` also runs `grasplink bench loop --quick` in each tree and compares loop.json
(the trials' outcomes; the machine line and timings left out). Prints one line per scene
with the SHA-256 (first 16 hex digits) over its files, and exits 1 on any difference.

A speed change that claims to leave behaviour as it was cites this script: the scenes
cover the skin, EMG, belt and hand nodes, the gateway's loop, a faulty link and LSS boot.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCENES = (
    "loop_headline",
    "headline_slip",
    "slip_alpha0.1_20mm_s_forward",
    "loop_fast_reflex",
    "loop_vendor_modules",
    "bus_faults",
    "boot",
)
# loop.json keys that measure the machine, not the trials.
LOOP_VOLATILE = ("machine", "seconds", "cpu_s", "wall_s", "elapsed_s", "generated")


def _env(tree: Path) -> dict[str, str]:
    return os.environ | {"PYTHONPATH": str(tree)}


def run_scene(tree: Path, scene: Path, out: Path) -> dict[str, bytes]:
    """Every output file of `tree`'s run of `scene`, by path relative to `out`."""
    argv = [sys.executable, "-m", "grasplink.cli", "run", str(scene), "--out", str(out)]
    subprocess.run(argv, cwd=tree, env=_env(tree), check=True, capture_output=True)
    return {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}


def _strip(value: object) -> object:
    if isinstance(value, dict):
        return {k: _strip(v) for k, v in value.items() if k not in LOOP_VOLATILE}
    if isinstance(value, list):
        return [_strip(v) for v in value]
    return value


def run_loop(tree: Path, out: Path) -> object:
    """`tree`'s quick loop benchmark's figures, without what measures the machine."""
    argv = [sys.executable, "-m", "grasplink.cli", "bench", "loop", "--quick", "--out", str(out)]
    subprocess.run(argv, cwd=tree, env=_env(tree), check=True, capture_output=True)
    return _strip(json.loads((out / "loop.json").read_text()))


def digest(files: dict[str, bytes]) -> str:
    h = hashlib.sha256()
    for name, data in sorted(files.items()):
        h.update(name.encode() + b"\0" + len(data).to_bytes(8, "little") + data)
    return h.hexdigest()[:16]


def compare(name: str, base: dict[str, bytes], this: dict[str, bytes]) -> list[str]:
    problems = [f"{name}: only in base: {f}" for f in sorted(base.keys() - this.keys())]
    problems += [f"{name}: only in this tree: {f}" for f in sorted(this.keys() - base.keys())]
    problems += [
        f"{name}: {f} differs" for f in sorted(base.keys() & this.keys()) if base[f] != this[f]
    ]
    return problems


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("base", type=Path, help="a set-up checkout of the base revision")
    parser.add_argument("--scenes", help="comma-separated scene names (default: SCENES)")
    parser.add_argument("--loop", action="store_true", help="also `grasplink bench loop --quick`")
    args = parser.parse_args(argv)
    base = args.base.resolve()
    if not (base / "grasplink" / "__init__.py").is_file():
        parser.error(f"{base} is not a grasplink checkout (no grasplink/__init__.py)")
    names = args.scenes.split(",") if args.scenes else list(SCENES)
    missing = [n for n in names if not (ROOT / "scenes" / f"{n}.toml").is_file()]
    if missing:
        parser.error(f"no such scene in {ROOT / 'scenes'}: {', '.join(missing)}")
    problems: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        for name in names:
            scene = ROOT / "scenes" / f"{name}.toml"
            before = run_scene(base, scene, Path(tmp) / "base" / name)
            after = run_scene(ROOT, scene, Path(tmp) / "this" / name)
            found = compare(name, before, after)
            problems += found
            verdict = "differs" if found else "same"
            print(f"{name}: {len(after)} files, {digest(after)} ({verdict}; base {digest(before)})")
        if args.loop:
            before_loop = run_loop(base, Path(tmp) / "base_loop")
            after_loop = run_loop(ROOT, Path(tmp) / "this_loop")
            same = before_loop == after_loop
            text = json.dumps(after_loop, sort_keys=True).encode()
            verdict = "same" if same else "differs"
            print(f"bench loop --quick: {digest({'loop.json': text})} ({verdict})")
            if not same:
                problems.append("bench loop --quick: loop.json differs")
    for problem in problems:
        print(problem)
    print("unchanged" if not problems else f"{len(problems)} difference(s)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())

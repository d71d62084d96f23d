"""The runs digest: a short hash per scene of everything `grasplink run` writes, and of the
loop report's results, to tell whether a speed change left a tree's outputs as they were.

    .venv/bin/python benchmarks/check_runs_unchanged.py [TREE ...] [--scenes LIST] [--loop]

Each TREE is a checkout (default: this one; e.g. the base a change started from), run in
its own interpreter with the scene files of this tree. Per scene the digest covers every
file of `grasplink run SCENE --out DIR` (name and bytes: can.asc, the CSVs, summary.json)
and, as the CSVs keep 9 significant digits, the float64 bits of every chunk the engine
hands the recorder (times and every signal, in order). With `--loop` also loop.json of
`grasplink bench loop --quick` (the trials' outcomes and the figures; no timings in it).
With two or more trees the digests are compared: exit 1 if any differs.

Bit-level, so machine-specific (numpy's SIMD loops, libm): compare trees on one machine.
Issue 26 item 4's speed work keeps these equal; commits quote the digests.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from tree_script import last_json, run_in_tree

ROOT = Path(__file__).resolve().parents[1]
SCENES = (
    "loop_headline",
    "headline_slip",
    "slip_alpha0.1_20mm_s_forward",
    "loop_fast_reflex",
    "loop_vendor_modules",
    "loop_slow_wearer",
    "bus_faults",
    "boot",
    "wearer_demo",
    "slip_friction",
    "static_grip_steps",
)

# Run inside the tree's interpreter: only names every tree since the recorder existed has.
COLLECT = r"""
import hashlib, json, sys
from pathlib import Path

import numpy as np

from grasplink import cli
from grasplink.simulators import recording

out_dir, loop, scenes = Path(sys.argv[1]), sys.argv[2] == "1", sys.argv[3:]
digest = None
write_chunk = recording.Recorder.write_chunk


def write_and_hash(self, domain, times_us, values):
    digest.update(domain.encode() + np.ascontiguousarray(times_us, dtype=np.int64).tobytes())
    for name in sorted(values):
        digest.update(name.encode() + np.ascontiguousarray(values[name], np.float64).tobytes())
    write_chunk(self, domain, times_us, values)


recording.Recorder.write_chunk = write_and_hash


def files(folder):
    for path in sorted(folder.iterdir()):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")


result = {}
for scene in scenes:
    digest = hashlib.sha256()
    folder = out_dir / Path(scene).stem
    if cli.main(["run", scene, "--out", str(folder)]) != 0:
        raise SystemExit(f"grasplink run {scene} failed")
    files(folder)
    result[Path(scene).stem] = digest.hexdigest()[:16]
if loop:
    digest = hashlib.sha256()
    folder = out_dir / "loop"
    if cli.main(["bench", "loop", "--quick", "--workers", "1", "--out", str(folder)]) != 0:
        raise SystemExit("grasplink bench loop --quick failed")
    digest.update((folder / "loop.json").read_bytes())
    result["bench loop --quick"] = digest.hexdigest()[:16]
print(json.dumps(result))
"""


def collect(tree: Path, scenes: list[str], loop: bool) -> dict[str, str]:
    """Run the scenes (and the loop report) in `tree`'s own interpreter; a digest for each."""
    paths = [str(ROOT / "scenes" / f"{name}.toml") for name in scenes]
    with tempfile.TemporaryDirectory() as out_dir:
        out = run_in_tree(tree, COLLECT, out_dir, "1" if loop else "0", *paths, what="the runs")
    return last_json(out)  # type: ignore[no-any-return]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trees", type=Path, nargs="*", default=[ROOT])
    parser.add_argument(
        "--scenes", default=",".join(SCENES), help="comma-separated scene names (scenes/NAME.toml)"
    )
    parser.add_argument("--loop", action="store_true", help="also `grasplink bench loop --quick`")
    args = parser.parse_args(argv)
    scenes = [s for s in args.scenes.split(",") if s]
    missing = [s for s in scenes if not (ROOT / "scenes" / f"{s}.toml").is_file()]
    if missing:
        parser.error(f"no such scene in {ROOT / 'scenes'}: {', '.join(missing)}")
    digests = {tree: collect(tree.resolve(), scenes, args.loop) for tree in args.trees}
    names = list(next(iter(digests.values())))
    width = max(len(n) for n in names)
    differ = False
    for name in names:
        row = [digests[tree][name] for tree in args.trees]
        same = len(set(row)) == 1
        differ |= not same
        mark = "" if len(row) == 1 else ("  same" if same else "  DIFFERENT")
        print(f"{name:<{width}}  {'  '.join(row)}{mark}")
    return 1 if differ else 0


if __name__ == "__main__":
    raise SystemExit(main())

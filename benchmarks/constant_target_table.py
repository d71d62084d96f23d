"""The decoding benchmark's constant-speed target-set figures, for one or more trees.

Why: docs/benchmarks/decoding.md flags "no regression, constant-speed target set"
against its previous run, and the full benchmark takes minutes per tree. This
script recomputes only that table - the default decoder over the target cases
of `decoding_bench.cases(quick=False)` with the benchmark's seeds (1000 + the
case's index in the full list) and its static grip steps, scored by
`scoring.score` / `scoring.summarise` exactly as the benchmark does - so a
commit range can be bisected (`--bisect`) in seconds per step. CPU per sample
is left out: it is a timing, not a figure a commit's logic moves.

Each tree runs in its own interpreter with PYTHONPATH pointing at it (the
evaluation's functions are the tree's own; numba kernels compile per tree).

Run:
  .venv/bin/python benchmarks/constant_target_table.py TREE [TREE ...]
  .venv/bin/python benchmarks/constant_target_table.py TREE --bisect \
      --good-median 0.09 --good-p90 0.60     # exit 0 if TREE still gives those

`--cache FILE` (JSON, keyed by the tree's commit) skips trees measured before.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

FIGURES = (
    "speed_median_pct",
    "speed_p90_pct",
    "position_median_mm",
    "position_p90_mm",
    "missing_pct",
    "slip_flag_intervals",
    "first_good_ratio",
    "false_slip_pct",
)
BISECT_SKIP = 125  # `git bisect run`: this commit cannot be measured
STEP = 0.01  # a figure moved when it moved by at least this much (the page's 2 decimals)


def _score_case(job: tuple[int, str, float, bool]) -> object:
    from grasplink.decoding.registry import DEFAULT_DECODER
    from grasplink.evaluation import decoding_bench as db
    from grasplink.evaluation import scoring as ev

    index, layout, speed_mm_s, reverse = job
    case = db.Case(layout, speed_mm_s, reverse)
    rec = case.recording(seed=1000 + index)
    return ev.score(db._factory(DEFAULT_DECODER, {}, rec), rec)


def _score_static(index: int) -> object:
    from grasplink.decoding.registry import DEFAULT_DECODER
    from grasplink.evaluation import decoding_bench as db
    from grasplink.evaluation import scoring as ev

    rec = db.static_cases(False)[index]
    return ev.score(db._factory(DEFAULT_DECODER, {}, rec), rec)


def measure_here(workers: int) -> dict:
    """The target-set figures of the grasplink this interpreter imports."""
    from concurrent.futures import ProcessPoolExecutor

    from grasplink.evaluation import decoding_bench as db
    from grasplink.evaluation import scoring as ev

    jobs = [
        (i, c.layout, c.speed_mm_s, c.reverse)
        for i, c in enumerate(db.cases(False))
        if "target" in c.tags
    ]
    n_static = len(db.static_cases(False))
    with ProcessPoolExecutor(max_workers=workers) as pool:
        scores = list(pool.map(_score_case, jobs))
        statics = list(pool.map(_score_static, range(n_static)))
    figures = ev.summarise(scores)
    false_updates = sum(s.false_slip_updates for s in statics)
    static_updates = sum(s.static_updates for s in statics)
    figures["false_slip_pct"] = 100.0 * false_updates / max(1, static_updates)
    out = {k: figures.get(k) for k in FIGURES}
    out["recordings"] = len(jobs)
    return out


def commit_of(tree: Path) -> str:
    done = subprocess.run(
        ["git", "-C", str(tree), "rev-parse", "HEAD"], capture_output=True, text=True, check=False
    )
    if done.returncode != 0:
        raise SystemExit(f"constant_target_table: {tree} is not a git checkout: {done.stderr}")
    return done.stdout.strip()


def measure_tree(tree: Path, workers: int) -> dict:
    """Run this script's --here mode in a fresh interpreter that imports `tree`'s grasplink."""
    if not (tree / "grasplink" / "__init__.py").is_file():
        raise SystemExit(f"constant_target_table: {tree} has no grasplink/ package")
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run(
        [sys.executable, __file__, "--here", "--workers", str(workers)],
        cwd=tree,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise RuntimeError(f"{tree}: measuring failed:\n{done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def _fmt(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("trees", nargs="*", type=Path, help="checkouts to measure")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--cache", type=Path, default=None, help="JSON: commit -> figures")
    parser.add_argument("--here", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--bisect", action="store_true", help="exit 0 good / 1 moved")
    parser.add_argument("--good-median", type=float, default=None)
    parser.add_argument("--good-p90", type=float, default=None)
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    if args.here:
        import grasplink

        if not Path(grasplink.__file__).resolve().is_relative_to(Path.cwd().resolve()):
            raise SystemExit(f"imported {grasplink.__file__}, not the tree in {Path.cwd()}")
        print(json.dumps(measure_here(args.workers)))
        return 0
    if not args.trees:
        parser.error("give at least one TREE (a grasplink checkout)")
    if args.bisect and (len(args.trees) != 1 or args.good_median is None or args.good_p90 is None):
        parser.error("--bisect needs exactly one TREE, --good-median and --good-p90")
    cache: dict = {}
    if args.cache is not None and args.cache.is_file():
        cache = json.loads(args.cache.read_text())
    rows = []
    for tree in args.trees:
        commit = commit_of(tree)
        if commit not in cache:
            try:
                cache[commit] = measure_tree(tree, args.workers)
            except RuntimeError as exc:
                print(exc, file=sys.stderr)
                if args.bisect:
                    return BISECT_SKIP
                raise SystemExit(1) from exc
            if args.cache is not None:
                args.cache.write_text(json.dumps(cache, indent=1, sort_keys=True) + "\n")
        rows.append((tree, commit, cache[commit]))
    print("| tree | commit | " + " | ".join(FIGURES) + " |")
    print("|---|---|" + "---:|" * len(FIGURES))
    for tree, commit, figures in rows:
        cells = " | ".join(_fmt(figures.get(k)) for k in FIGURES)
        print(f"| {tree} | {commit[:7]} | {cells} |")
    if args.bisect:
        figures = rows[0][2]
        moved = (
            abs(figures["speed_median_pct"] - args.good_median) >= STEP
            or abs(figures["speed_p90_pct"] - args.good_p90) >= STEP
        )
        return 1 if moved else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())

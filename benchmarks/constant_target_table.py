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

`--try NAME=VALUE[,...]` (tune_tracker.py's settings: tracker constants, `tails.NAME`,
`watch.NAME`, ...) measures each tree under that setting too, e.g. to tell which part of
a commit moved a figure. `--cache FILE` (JSON, keyed by commit and setting) skips what
was measured before.
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


def _factory(rec: object, trial: str) -> object:
    """The default decoder for `rec`, as the benchmark makes it, or under a
    tune_tracker.py setting (`--try`: tracker constants, `watch.`/`tails.`/... fields)."""
    from grasplink.decoding.registry import DEFAULT_DECODER
    from grasplink.evaluation import decoding_bench as db

    if not trial:
        return db._factory(DEFAULT_DECODER, {}, rec)
    import tune_tracker

    from grasplink.evaluation import slip_reporting as sr

    config = tune_tracker.config(tune_tracker.parse(trial))
    return lambda: sr.build_decoder(DEFAULT_DECODER, rec.layout_mm, rec.fs_hz, config)


def _score_case(job: tuple[int, str, float, bool, str]) -> object:
    from grasplink.evaluation import decoding_bench as db
    from grasplink.evaluation import scoring as ev

    index, layout, speed_mm_s, reverse, trial = job
    case = db.Case(layout, speed_mm_s, reverse)
    rec = case.recording(seed=1000 + index)
    return ev.score(_factory(rec, trial), rec)


def _score_static(job: tuple[int, str]) -> object:
    from grasplink.evaluation import decoding_bench as db
    from grasplink.evaluation import scoring as ev

    index, trial = job
    rec = db.static_cases(False)[index]
    return ev.score(_factory(rec, trial), rec)


def measure_here(workers: int, trial: str = "") -> dict:
    """The target-set figures of the grasplink this interpreter imports."""
    from concurrent.futures import ProcessPoolExecutor

    from grasplink.evaluation import decoding_bench as db
    from grasplink.evaluation import scoring as ev

    jobs = [
        (i, c.layout, c.speed_mm_s, c.reverse, trial)
        for i, c in enumerate(db.cases(False))
        if "target" in c.tags
    ]
    n_static = len(db.static_cases(False))
    with ProcessPoolExecutor(max_workers=workers) as pool:
        scores = list(pool.map(_score_case, jobs))
        statics = list(pool.map(_score_static, [(i, trial) for i in range(n_static)]))
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


def measure_tree(tree: Path, workers: int, trial: str = "") -> dict:
    """Run this script's --here mode in a fresh interpreter that imports `tree`'s grasplink."""
    if not (tree / "grasplink" / "__init__.py").is_file():
        raise SystemExit(f"constant_target_table: {tree} has no grasplink/ package")
    env = {**os.environ, "PYTHONPATH": str(tree)}
    done = subprocess.run(
        [sys.executable, __file__, "--here", "--workers", str(workers), "--try", trial],
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
    parser.add_argument(
        "--try",
        dest="tries",
        action="append",
        default=[],
        help="also measure each tree under this tune_tracker.py setting (NAME=VALUE[,...])",
    )
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
        print(json.dumps(measure_here(args.workers, args.tries[0] if args.tries else "")))
        return 0
    if not args.trees:
        parser.error("give at least one TREE (a grasplink checkout)")
    if args.bisect and (len(args.trees) != 1 or args.good_median is None or args.good_p90 is None):
        parser.error("--bisect needs exactly one TREE, --good-median and --good-p90")
    cache: dict = {}
    if args.cache is not None and args.cache.is_file():
        cache = json.loads(args.cache.read_text())
    rows = []
    if args.bisect and args.tries:
        parser.error("--bisect measures the shipped settings: no --try")
    for tree in args.trees:
        commit = commit_of(tree)
        for trial in ["", *args.tries]:
            key = commit if not trial else f"{commit} {trial}"
            if key not in cache:
                try:
                    cache[key] = measure_tree(tree, args.workers, trial)
                except RuntimeError as exc:
                    print(exc, file=sys.stderr)
                    if args.bisect:
                        return BISECT_SKIP
                    raise SystemExit(1) from exc
                if args.cache is not None:
                    args.cache.write_text(json.dumps(cache, indent=1, sort_keys=True) + "\n")
            rows.append((f"{tree} {trial}".strip(), commit, cache[key]))
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

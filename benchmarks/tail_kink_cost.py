"""What the tail kinks cost the decoding benchmark's constant-speed target set, and why.

    .venv/bin/python benchmarks/tail_kink_cost.py [--workers 2]

Why: the decoding benchmark flagged its constant-speed target set (speed median 0.09 ->
0.12 %, p90 0.60 -> 0.79 %) and `constant_target_table.py --bisect` put it on a7413e1,
which shipped the tail kinks (`detector/tail_kinks.py`). Over the same recordings, seeds
and scoring (`constant_target_table`'s cases), this splits the cost in two:

1. the detector's contacts against the true ridge crossings (within +-20 ms), with the
   tail kinks and without (`TailKinkSettings.residual_z` 0): those found either way, and
   those only the tail kinks find, with their timing error;
2. the default decoder's scored speed updates (slipping, from the 3rd contact): those
   with a speed either way (their error with and without), and those with a speed only
   with the tail kinks (the missing the tail kinks remove) and when they come.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import constant_target_table as ctt

from grasplink.decoding.contacts import DetectorSettings
from grasplink.evaluation import decoding_bench as db
from grasplink.evaluation import scoring as ev
from grasplink.evaluation.contact_truth import detect

OFF = "tails.residual_z=0"  # the tune_tracker.py setting without the tail kinks
MATCH_S = 0.02


def _jobs() -> list[tuple[int, str, float, bool]]:
    cases = enumerate(db.cases(False))
    return [(i, c.layout, c.speed_mm_s, c.reverse) for i, c in cases if "target" in c.tags]


def _recording(job: tuple[int, str, float, bool]) -> object:
    index, layout, speed_mm_s, reverse = job
    return db.Case(layout, speed_mm_s, reverse).recording(seed=1000 + index)


def timing(job: tuple[int, str, float, bool]) -> list[tuple[float, float]]:
    """Per true crossing: the nearest contact's timing error (s) with and without the tail
    kinks (NaN: none within MATCH_S)."""
    rec = _recording(job)
    on = DetectorSettings()
    off = replace(on, hinges=replace(on.hinges, tails=replace(on.hinges.tails, residual_z=0.0)))
    found = [
        np.array([c.t_s for c in detect(rec.t_s, rec.force_n, rec.fs_hz, settings=s).contacts])
        for s in (on, off)
    ]
    out = []
    for t_true in rec.contact_times_s.tolist():
        pair = []
        for onsets in found:
            err = onsets[np.abs(onsets - t_true) <= MATCH_S] - t_true
            pair.append(float(err[np.argmin(np.abs(err))]) if len(err) else np.nan)
        out.append((pair[0], pair[1]))
    return out


def updates(job: tuple[int, str, float, bool]) -> list[tuple[float, float, float]]:
    """Per scored update (slipping, from the 3rd contact): relative speed error with and
    without the tail kinks (NaN: no speed), s after the 3rd contact."""
    rec = _recording(job)
    per = []
    for trial in ("", OFF):
        estimates, _ = ev.run_decoder(ctt._factory(rec, trial), rec)
        t = np.array([e.t_s for e in estimates])
        v_true = np.interp(t, rec.t_s, rec.speed_mm_s)
        slipping = np.interp(t, rec.t_s, rec.slipping) > 0.5
        onset = ev._onset(rec)
        third = rec.contact_times_s[rec.contact_times_s >= (onset or 0.0)][2]
        v, _ = ev.along_truth(estimates, v_true)
        rel = np.abs(v - v_true) / np.abs(v_true)
        rows = zip(t.tolist(), rel.tolist(), slipping.tolist(), strict=True)
        per.append({round(a, 6): (r, a - third) for a, r, m in rows if m and a >= third})
    on, off = per
    return [(r, off.get(k, (np.nan, 0.0))[0], dt) for k, (r, dt) in on.items()]


def _pct(values: np.ndarray) -> str:
    if not len(values):
        return "none"
    return f"median {np.median(values):.3f} %, p90 {np.quantile(values, 0.9):.3f} %"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    jobs = _jobs()
    with ProcessPoolExecutor(args.workers) as pool:
        crossings = np.array([r for rows in pool.map(timing, jobs) for r in rows])
        scored = np.array([r for rows in pool.map(updates, jobs) for r in rows])
    on, off = np.isfinite(crossings[:, 0]), np.isfinite(crossings[:, 1])
    print(f"{len(jobs)} recordings, {len(crossings)} true ridge crossings:")
    for name, mask, col in (
        ("found either way", on & off, 0),
        ("found only with the tail kinks", on & ~off, 0),
        ("found only without them", ~on & off, 1),
    ):
        err = 1000 * crossings[mask, col]
        text = "none"
        if len(err):
            text = (
                f"timing error median {np.median(err):+.2f} ms, |error| median "
                f"{np.median(np.abs(err)):.2f} ms, p90 {np.quantile(np.abs(err), 0.9):.2f} ms"
            )
        print(f"  {name}: {int(mask.sum())}; {text}")
    same = on & off & (crossings[:, 0] != crossings[:, 1])
    print(f"  found either way but timed differently: {int(same.sum())}")
    have_on, have_off = np.isfinite(scored[:, 0]), np.isfinite(scored[:, 1])
    both = have_on & have_off
    only = have_on & ~have_off
    print(f"{len(scored)} scored updates (slipping, from the 3rd contact):")
    print(f"  speed either way: {int(both.sum())}; with tails {_pct(100 * scored[both, 0])}")
    print(f"    the same updates without them: {_pct(100 * scored[both, 1])}")
    print(
        f"  speed only with the tail kinks: {int(only.sum())}; {_pct(100 * scored[only, 0])}; "
        f"median {np.median(scored[only, 2]) if only.any() else float('nan'):.2f} s after "
        "the 3rd contact"
    )
    print(f"  speed only without them: {int((have_off & ~have_on).sum())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

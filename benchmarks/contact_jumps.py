"""How fast each contact's level jumped, against the truth's speed: a stop's jump or a ridge's rise?

`stop_jumps` takes a contact told a pulse whose jump (to 90 % of its smoothed peak over
the level before, its trend carried: `step_shape.measure`, the samples `despiked`) was as
fast as a stop's step for no ridge of a track moving at v when v x jump is under
`TrackerDecoder.FAST_JUMP_TRAVEL_MM`. This prints what that rests on: every contact the
default decoder found (kink bank) in the full plan's cases, by what made it - *stop* (a
stop starts within `stop_causes.NEAR_STOP_S`, no truth ridge contact within
`stop_causes.RIDGE_MATCH_S`), *stop-ridge* (a ridge right before a stop), *ridge*, *other*
- and by its first verdict (pulse / step), the quartiles (10/25/50/75/90 %) of its jump
time over `WINDOW_S` after its onset and of the travel v x jump at the truth's speed
just before it.

Run: `.venv/bin/python benchmarks/contact_jumps.py --seeds 1`.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import stop_causes as sc

from grasplink.decoding import stop_jumps
from grasplink.decoding.contacts import STEP_IDS
from grasplink.decoding.detector import step_shape
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

KINDS = ("stick-slip", "stop", "rates-drops", "loop", "constant", "accelerating",
         "decelerating", "saturation", "reversal")  # fmt: skip
SPEED_BANDS = ((0.0, 30.0), (30.0, 60.0), (60.0, 100.0), (100.0, 1000.0))


def job(case: sr.Case) -> list[dict]:
    """Each kink-bank contact of the case: label, first verdict, truth speed, jump time."""
    rec = case.make()
    decoder = sc._decoder(case, rec, {})
    decoder.rows, decoder.contacts, decoder.checks, decoder.arrived = [], [], [], []
    ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    stops = ns.motion(rec.truth).stops
    ridges = np.asarray(rec.truth.contact_times_s, dtype=float)
    x = stop_jumps.despiked(np.asarray(rec.force_n, dtype=float))
    t_true, v_true = rec.truth.t_s, np.abs(rec.truth.speed_mm_s)
    first: dict[int, bool | None] = {}
    for check, _ in decoder.checks:
        first.setdefault(check.id, check.pulse)
    out = []
    for c, _ in decoder.contacts:
        if c.id >= STEP_IDS or c.id not in first:
            continue
        label = sc._label(c.t_s, stops, ridges)
        near_ridge = len(ridges) and float(np.min(np.abs(ridges - c.t_s))) <= sc.RIDGE_MATCH_S
        if label == "stop" and near_ridge:
            label = "stop-ridge"
        a, b = np.searchsorted(t_true, [c.t_s - 0.03, c.t_s])
        end = min(len(x) - 1, c.index + round(stop_jumps.WINDOW_S * rec.fs_hz))
        shape = step_shape.measure(x, c.index, end, rec.fs_hz)
        if shape is None or b <= a or not np.isfinite(shape.jump_s):
            continue
        speed = float(v_true[a : b + 1].max())
        out.append({"label": label, "pulse": first[c.id], "v": speed, "jump_s": shape.jump_s})
    return out


def _quartiles(values: list[float]) -> str:
    a = np.asarray(values, dtype=float)
    return " ".join(f"{q:6.2f}" for q in np.percentile(a, [10, 25, 50, 75, 90]))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", default=",".join(KINDS))
    parser.add_argument("--seeds", type=int, default=1)
    args = parser.parse_args(argv)
    kinds = args.kinds.split(",")
    todo = [c for c in sr.cases(replace(sr.FULL, seeds=args.seeds)) if c.kind in kinds]
    with ProcessPoolExecutor(2) as pool:
        rows = [r for out in pool.map(job, todo, chunksize=2) for r in out]
    print(f"{len(todo)} cases ({args.kinds}, full plan, {args.seeds} seed(s)): {len(rows)}")
    print("label       verdict v mm/s      n   jump ms 10/25/50/75/90 %        travel mm")
    for label in ("stop", "stop-ridge", "ridge", "other"):
        for pulse, verdict in ((True, "pulse"), (False, "step")):
            for lo, hi in SPEED_BANDS:
                sel = [r for r in rows if r["label"] == label and r["pulse"] is pulse
                       and lo <= r["v"] < hi]  # fmt: skip
                if not sel:
                    continue
                jumps = [1e3 * r["jump_s"] for r in sel]
                travel = [r["jump_s"] * r["v"] for r in sel]
                print(f"{label:11s} {verdict:7s} {lo:3.0f}-{hi:<4.0f} {len(sel):6d}  "
                      f"{_quartiles(jumps)}  {_quartiles(travel)}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

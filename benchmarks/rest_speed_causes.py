"""Where a speed at rest comes from: the default decoder's at-rest speeds by track.

`slip_reporting.score` counts an update as a *speed at rest* when it lies 0.15 s or more
into a standstill and carries a speed above 0. This tells, for each such update, what
gave the speed:

- *rest*: the first rest (before any motion) or a rest after a run; the edge past the
  last ridge of that run's way (every kind's last rest lies 6 mm past it: `_finish`) or
  not;
- *track*: the track whose speed was shown (the chosen one when a direction is told,
  else the likeliest with a speed) - its last contact at the layout's last ridge of its
  way (*past last*: no contact can come, only the coast end stops it) or before it; how
  long it has coasted since that contact, in intervals at its speed (the last spacing
  over its speed: past the last ridge, one such interval later the slip is off the skin
  or stopped, `coast_bound`); before it, its travel since then over the spacing ahead
  (below 1: its next ridge not yet due).

`--kinds` (default snr10), `--seeds N` (the full plan's first N, default 2) and
`--try NAME=VALUE[,...]` (a tuning) as in `tune_tracker_kinds.py`; `--baseline` also
runs the shipped settings for the same table.

Run: `.venv/bin/python benchmarks/rest_speed_causes.py --try RISE_EVIDENCE=1`.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plan_cases
from stop_causes import pct

from grasplink.decoding.base import SlipEstimate
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

BINS = (0.5, 1.0, 1.5, 2.0, 3.0, np.inf)  # coast since the last ridge's contact, intervals


class _Whose(TrackerDecoder):
    """The default decoder, noting at every update the track whose speed it showed."""

    shown: list[tuple[int, int, float, float, int] | None]

    def _report(self, g: float) -> SlipEstimate:
        out = super()._report(g)
        if not out.speed_mm_s or self._cache is None:
            self.shown.append(None)
            return out
        _, chosen, _, _, _, (fast, _, _, _) = self._cache
        h = chosen[0] if out.direction is not None and chosen is not None else fast
        if h is None:
            self.shown.append(None)
            return out
        last = h.ridge == self.count - 1
        way = (1 - h.dirn) // 2
        # past the last ridge: per the spacing into it; before it: per the one ahead
        gap = float(self._gap[way, h.ridge - 1 if last else h.ridge])
        self.shown.append((int(last), h.n, g - h.t, max(h.v, 1e-9) / gap, h.dirn))
        return out


def job(case: sr.Case, tuning: dict) -> tuple[sr.Case, list[tuple[str, str, str]]]:
    """(case, per at-rest update with a speed: the rest, the track, the coast bin)."""
    rec = case.make()
    truth = rec.truth
    decoder = _Whose(truth.layout_mm, rec.fs_hz, tuning=tuning)
    sr.tell_grip_commands(decoder, case)
    decoder.shown = []
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    t = np.array([e.t_s for e in estimates])
    speed = np.array([e.speed_mm_s or 0.0 for e in estimates])
    edge = np.interp(t, truth.t_s, truth.position_mm)
    skin = sr.ridges_mm(truth.layout_mm)
    m = ns.motion(truth)
    out = []
    for start, end in m.stops:
        before = [r for r in m.runs if r[1] <= start + 1e-9]
        settled = (t >= start + sr.REST_SETTLED_S) & (t < end) & (speed > 0)
        for i in np.flatnonzero(settled):
            if not before:
                rest = "first rest"
            else:
                sign = before[-1][2]
                past = edge[i] >= skin[-1] if sign > 0 else edge[i] <= skin[0]
                rest = "after a run, " + ("past the last ridge" if past else "on the skin")
            shown = decoder.shown[i]
            if shown is None:
                out.append((rest, "?", ""))
                continue
            last, n, since, per_s, _ = shown
            where = f"{'past last' if last else 'before last'}, {min(n, 4)} contacts"
            ivl = next(b for b in BINS if since * per_s <= b)
            bins = f"coast {ivl:g} ivl" if last else f"{ivl:g} x next gap"
            out.append((rest, where, bins))
    return case, out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    plan_cases.add_plan_arguments(parser, "snr10", 2)
    parser.add_argument("--baseline", action="store_true", help="the shipped settings too")
    args = parser.parse_args(argv)
    todo = plan_cases.full_plan_cases(parser, args.kinds, args.seeds, first_seed=args.first_seed)
    tunings = ([{}] if args.baseline else []) + [args.tuning]
    for tuning in tunings:
        with ProcessPoolExecutor(2) as pool:
            results = list(pool.map(job, todo, [tuning] * len(todo), chunksize=2))
        rows: Counter = Counter()
        for _, out in results:
            rows.update(out)
        total = sum(rows.values())
        print(f"\n{len(todo)} cases ({args.kinds}, full plan, {args.seeds} seed(s)), {tuning}")
        print(f"at-rest updates with a speed: {total}")
        for (rest, where, bins), count in sorted(rows.items(), key=lambda r: -r[1]):
            print(f"  {rest:34s} {where:26s} {bins:14s} {count:6d} {pct(count, total):>7s}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

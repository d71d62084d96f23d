"""Which rule withheld the speed: the default decoder's missing-speed updates by cause.

`slip_reporting.score` counts an update as missing its speed while the truth moves (from
its run's 3rd ridge contact, or between the 2nd and the 3rd) and none above 0 is given.
This tells, for each such update, which branch of `TrackerDecoder._report` gave none:

- *range*: slipping tracks with a measured speed exist but do not agree on it (the
  `SPEED_*` rules): the range is given. By the speed track's contacts (2: no interval
  ratio yet) and the share of the slipping posterior agreeing with its speed;
- *stopped*: the likeliest hypothesis is a stop (silence, or a step) while the object moves;
- *no slip*: P(slip) under a half, by the most contacts any track holds (1: none has
  two yet);
- *no speed track*: slip flagged, but no slipping track has a speed (restarted ones).

Then per layout, and the cases with the most missing updates. `--kinds`, `--seeds N` (the
full plan's first N, default 3) and `--try NAME=VALUE[,...]` (a tuning) as in
`tune_tracker_kinds.py`.

Run: `.venv/bin/python benchmarks/missing_speed_causes.py --kinds constant`.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter, defaultdict
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


class _Why(TrackerDecoder):
    """The default decoder, noting at every update why it gave no speed (if it gave none)."""

    causes: list[tuple[str, str]]

    def _report(self, g: float) -> SlipEstimate:
        out = super()._report(g)
        if not len(self._tracks) or self._cache is None:
            self.causes.append(("no slip", "no track"))
            return out
        _, chosen, _, _, _, (fast, share, _, _) = self._cache
        if chosen is None:
            self.causes.append(("no slip", f"most contacts {min(int(self._tracks.n.max()), 4)}"))
        elif chosen[1]:
            self.causes.append(("stopped", ""))
        elif fast is None:
            self.causes.append(("no speed track", ""))
        else:
            band = "share >= 0.5" if share >= 0.5 else "0.3-0.5" if share >= 0.3 else "< 0.3"
            self.causes.append(("range", f"speed track {min(fast.n, 4)} contacts, {band}"))
        return out


def job(case: sr.Case, tuning: dict) -> tuple[sr.Case, list[tuple[bool, str, str]]]:
    """(case, per scored update from the 2nd contact: from the 3rd?, cause, detail; cause
    "" when a speed was given)."""
    rec = case.make()
    truth = rec.truth
    decoder = _Why(truth.layout_mm, rec.fs_hz, tuning=tuning)
    sr.tell_grip_commands(decoder, case)
    decoder.causes = []
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    t = np.array([e.t_s for e in estimates])
    given = np.array([(e.speed_mm_s or 0.0) > 0 for e in estimates])
    v = np.interp(t, truth.t_s, truth.speed_mm_s)
    edge = np.interp(t, truth.t_s, truth.position_mm)
    contacts = np.sort(np.asarray(truth.contact_times_s, dtype=float))
    skin = sr.ridges_mm(truth.layout_mm)
    from2, from3, beyond = (np.zeros(len(t), bool) for _ in range(3))
    for start, end, sign in ns.motion(truth).runs:  # as `slip_reporting.score`
        mine = contacts[(contacts >= start) & (contacts < end)]
        inside = (t >= start) & (t < end)
        beyond |= inside & ((edge >= skin[-1]) if sign > 0 else (edge <= skin[0]))
        if len(mine) >= 2:
            from2 |= inside & (t >= mine[1])
        if len(mine) >= 3:
            from3 |= inside & (t >= mine[2])
    scored = from2 & (np.abs(v) >= sr.V_MOVING_MM_S) & ~beyond
    out = []
    for i in np.flatnonzero(scored):
        cause, detail = ("", "") if given[i] else decoder.causes[i]
        out.append((bool(from3[i]), cause, detail))
    return case, out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    plan_cases.add_plan_arguments(parser, "constant", 3)
    parser.add_argument("--worst", type=int, default=15, help="cases listed")
    args = parser.parse_args(argv)
    todo = plan_cases.full_plan_cases(parser, args.kinds, args.seeds, first_seed=args.first_seed)
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(job, todo, [args.tuning] * len(todo), chunksize=2))
    print(f"{len(todo)} cases ({args.kinds}, full plan, {args.seeds} seed(s)), {args.tuning}")
    for title, third in (("from the 3rd contact", True), ("from the 2nd to the 3rd", False)):
        causes: Counter = Counter()
        layouts: dict[str, Counter] = defaultdict(Counter)
        total = 0
        for case, out in results:
            for from3, cause, detail in out:
                if from3 != third:
                    continue
                total += 1
                layouts[case.layout]["updates"] += 1
                if cause:
                    causes[(cause, detail)] += 1
                    layouts[case.layout][cause] += 1
        missing = sum(causes.values())
        print(f"\n{title}: {total} updates, speed missing in {missing} ({pct(missing, total)})")
        for (cause, detail), count in causes.most_common():
            print(f"  {cause:15s} {detail:40s} {count:7d} {pct(count, total):>7s}")
        for layout, row in sorted(layouts.items()):
            n = row.pop("updates")
            parts = ", ".join(f"{k} {pct(c, n)}" for k, c in row.most_common())
            print(f"  {layout:10s} of {n:6d}: {pct(sum(row.values()), n):>7s} ({parts})")
    worst = []
    for case, out in results:
        mine = [cause for from3, cause, _ in out if from3]
        missed = [c for c in mine if c]
        if missed:
            worst.append((len(missed), len(mine), case, Counter(missed).most_common(2)))
    worst.sort(key=lambda w: -w[0])
    print("\ncases with the most missing updates from the 3rd contact")
    for missed, n, case, top in worst[: args.worst]:
        way = "r" if case.reverse else "f"
        print(f"  {case.layout:10s} {case.variant:14s} {way} {case.seed} {missed:5d}/{n:5d} {top}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

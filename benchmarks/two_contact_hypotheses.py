"""Which hypotheses hold a slip's speed open while it has two contacts, and what an ideal
observer would believe there (issue 22, constant-speed missing).

On alpha0.3 (spacings 4, 3, 48, 29 mm) a forward slip's third ridge follows its second by
3 mm and is found about a fifth of the time, so a slip's speed often rests on two contacts
4 mm apart until the 48 mm ridge. For every constant case of the chosen layout and way
(full plan, `--seeds`), at each update from the truth's 3rd ridge contact until the 4th
(or the last ridge passed), this lists:

- the default decoder's slipping hypotheses (a track holding `BOUND_SHARE` or more of the
  slipping posterior), grouped by their speed over the truth's (1.00: the true alias) and
  way, with their mean share of the slipping mass, and whether the speed was given;
- an *ideal* observer's posterior over the same aliases: a slip at one constant speed
  (log-normal prior, the tracker's `SPEED_PRIOR_*`), starting before any ridge with the
  tracker's start prior, each ridge told with the tracker's detection model
  (`DETECT_P` by the spacing before it) - given the contacts the decoder had decided by
  then (their times and nothing else) and the silence since (a ridge due more than the
  detector's latency ago and not told was missed). It tells whether the decoder's
  ambiguity is in the data or in the decoder.

A track's share comes from the decoder's own posterior kernel run on that track alone
(its log weight is its score plus the kernel's silence and verdict terms; the kernel
returns P(slip) = sigmoid(total - null) for a lone slipping track, so total = null +
logit(P)).

`--levels`: the sensor's mean level before each run's first three ridge contacts, by kind
(what `arrival.EMPTY_N` is chosen from). `--try NAME=VALUE[,...]`: decoder settings, as in
`tune_tracker_kinds.py` (`--try ARRIVAL_EMPTY_N=0`: main's start prior, the ideal without
the arrival too).

Run: `.venv/bin/python benchmarks/two_contact_hypotheses.py --layout alpha0.3 --way f`.
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import tune_tracker

from grasplink.decoding import arrival
from grasplink.decoding.kernels import posterior as posterior_kernels
from grasplink.decoding.tracker import _NO_BLIND, TrackerDecoder, _tracks
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

RATIO_BINS = (0.5, 0.7, 0.8, 0.9, 1.1, 1.2, 1.4, 1.6, 1.9, 2.5, 4.0)


def ratio_bin(r: float) -> str:
    """A speed over the truth's, binned (the aliases sit at 0.75, 1, 1.75, ...)."""
    edges = (0.0, *RATIO_BINS, math.inf)
    for lo, hi in itertools.pairwise(edges):
        if lo <= r < hi:
            return f"{lo:.2f}-{hi:.2f}"
    return "nan"


class _Probe(TrackerDecoder):
    """The default decoder, noting at every update its slipping tracks' speeds and shares."""

    seen: list[tuple[float, list[tuple[int, int, int, float, float]], bool]]

    def _report(self, g: float):
        out = super()._report(g)
        self.seen.append((g, self._slipping(g), (out.speed_mm_s or 0.0) > 0))
        return out

    def _slipping(self, g: float) -> list[tuple[int, int, int, float, float]]:
        """(dirn, ridge, n, |v|, share of the slipping mass) of each slipping track with a
        measured speed."""
        B = self._tracks
        # the soft silence (heavy noise: `rise_evidence`) is not rebuilt per track here
        if not len(B) or (self.RISE_EVIDENCE and self._rise.blind(self.RISE_EVIDENCE_GATE)):
            return []
        verdicts = tuple(
            posterior_kernels.Verdicts(self._ring, self._ring_id, *self._evidence_tables)
        )
        rows = []
        for i in range(len(B)):
            if B.run[i] < 2:
                continue
            one = B.take(np.array([i]))
            blind = self._blind(one.t, g)
            null = float(one.score[0])
            p_slip = posterior_kernels.posterior(
                g, null, _tracks(one), self._schedule(one),
                _NO_BLIND if blind is None else blind, blind is not None, verdicts,
                self._waiting, self._skin,
            )[4]  # fmt: skip
            if not 0.0 < p_slip < 1.0:
                continue  # stopped, or not (yet) evidently a slip
            total = null + math.log(p_slip / (1.0 - p_slip))
            speed = abs(float(B.X[i, 1]))
            rows.append((int(B.dirn[i]), int(B.ridge[i]), int(B.n[i]), speed, total))
        if not rows:
            return []
        top = max(r[4] for r in rows)
        w = np.array([math.exp(r[4] - top) for r in rows])
        w /= w.sum()
        return [(*r[:4], float(s)) for r, s in zip(rows, w, strict=True)]


def ideal(
    dec: TrackerDecoder, told: np.ndarray, g: float, latency_s: float, onto_empty: bool
) -> dict[tuple[int, float], float]:
    """An ideal observer's posterior over (way, speed) at g given contact times `told` (the
    decoder's, sorted) and the silence since: every assignment of the contacts to ridges
    in travel order (each ridge told with probability pd, missed otherwise) at one
    constant speed, the first at the tracker's start prior (`onto_empty`: the first came
    onto an unloaded sensor, so the slip entered at an end: `arrival`). Keys: (way, speed in mm/s
    rounded to 0.1)."""
    post: dict[tuple[int, float], float] = defaultdict(float)
    R = dec.count
    lp = dec._log_prior
    pd = dec._pd[:, :R]
    mu, sig = math.log(dec.SPEED_PRIOR_MM_S), dec.SPEED_PRIOR_LOG_SIGMA
    for di, dirn in enumerate((1, -1)):
        pos = dec._pos[di, :R]
        for ridges in itertools.combinations(range(R), len(told)):
            if len(told) < 2:
                break
            # one speed through the first and last; the others must fit it (2 %)
            v = (pos[ridges[-1]] - pos[ridges[0]]) / (told[-1] - told[0])
            if not v > 0:
                continue
            fit = all(
                abs((pos[r] - pos[ridges[0]]) / v - (c - told[0])) <= 0.02 * (c - told[0]) + 0.004
                for r, c in zip(ridges[1:-1], told[1:-1], strict=True)
            )
            if not fit:
                continue
            log_w = lp[di, ridges[0]] + (dec._entry[di, ridges[0]] if onto_empty else 0.0)
            # the speed prior in log v; the time of the last contact given the first
            # is the Jacobian 1/dt, the same for every hypothesis
            log_w += -0.5 * ((math.log(v) - mu) / sig) ** 2
            told_set = set(ridges)
            for r in range(ridges[0], R):
                due = told[0] + (pos[r] - pos[ridges[0]]) / v
                if r in told_set:
                    log_w += math.log(pd[di, r])
                elif due + latency_s <= g:
                    log_w += math.log1p(-pd[di, r])
                else:
                    break
            post[(dirn, round(v, 1))] += math.exp(log_w)
    total = sum(post.values())
    return {k: w / total for k, w in post.items()} if total > 0 else {}


def job(case: sr.Case, tuning: dict) -> list[tuple[str, float, bool, dict, dict]]:
    """Per scored update between the truth's 3rd and 4th contacts: (phase, truth speed,
    speed given, decoder's share by (way, ratio bin), ideal's share by the same)."""
    rec = case.make()
    truth = rec.truth
    dec = _Probe(truth.layout_mm, rec.fs_hz, tuning=tuning)
    sr.tell_grip_commands(dec, case)
    dec.seen = []
    ns.feed(dec, rec.t_s, rec.force_n, sr.CHUNK)
    contacts = np.sort(np.asarray(truth.contact_times_s, dtype=float))
    skin = sr.ridges_mm(truth.layout_mm)
    sign = -1 if case.reverse else 1
    latency = float(dec._silence_latency)
    out = []
    if len(contacts) < 3:
        return out
    end = contacts[3] if len(contacts) > 3 else math.inf
    for g, rows, given in dec.seen:
        if not contacts[2] <= g < end:
            continue
        v_true = abs(float(np.interp(g, truth.t_s, truth.speed_mm_s)))
        edge = float(np.interp(g, truth.t_s, truth.position_mm))
        if v_true < sr.V_MOVING_MM_S or (edge >= skin[-1] if sign > 0 else edge <= skin[0]):
            continue
        mine: dict = defaultdict(float)
        for dirn, _, n, v, share in rows:
            if share >= dec.BOUND_SHARE:
                mine[(dirn * sign, min(n, 4), ratio_bin(v / v_true))] += share
        # the decoder's contacts from the slip's first on (earlier ones: the lead-in)
        mine_told = sorted((c.t_s, c.id) for c in dec._contacts if contacts[0] - 0.05 <= c.t_s <= g)
        told = np.array([c[0] for c in mine_told])
        onto_empty = bool(
            mine_told and dec.ARRIVAL_EMPTY_N > 0 and dec._unloaded.get(mine_told[0][1])
        )
        theirs: dict = defaultdict(float)
        for (dirn, v), share in ideal(dec, told, g, latency, onto_empty).items():
            theirs[(dirn * sign, len(told), ratio_bin(v / v_true))] += share
        out.append((case.variant, v_true, given, dict(mine), dict(theirs)))
    return out


def level_job(case: sr.Case) -> list[tuple[str, int, float]]:
    """(kind, k, mean level over `arrival.LEVEL_S` before the truth's k-th ridge contact of
    a run, k < 3), and (kind, -1, median level) for a case without contacts."""
    rec = case.make()
    truth = rec.truth
    n = max(1, round(arrival.LEVEL_S * rec.fs_hz))
    contacts = np.sort(np.asarray(truth.contact_times_s, dtype=float))
    out = []
    for start, end, _ in ns.motion(truth).runs:
        mine = contacts[(contacts >= start) & (contacts < end)]
        for k, at in enumerate(mine[:3]):
            i = int(np.searchsorted(rec.t_s, at))
            if i > 0:
                out.append((case.kind, k, float(np.mean(rec.force_n[max(0, i - n) : i]))))
    if not len(contacts):
        out.append((case.kind, -1, float(np.median(rec.force_n))))
    return out


def levels(seeds: int) -> int:
    """The sensor's mean level before a run's first three ridge contacts, per kind (every
    kind of the full plan): an arrival's first reads unloaded, the others loaded."""
    todo = sr.cases(replace(sr.FULL, seeds=seeds))
    with ProcessPoolExecutor(2) as pool:
        rows = [r for out in pool.map(level_job, todo, chunksize=4) for r in out]
    table: dict = defaultdict(list)
    for kind, k, level in rows:
        table[(kind, k)].append(level)
    print(f"{len(todo)} cases, {seeds} seed(s): level (N) over {arrival.LEVEL_S} s before")
    print("  kind          contact  count    min    p10    p50    p90    max  < EMPTY_N")
    for (kind, k), values in sorted(table.items()):
        a = np.array(values)
        q = np.percentile(a, [10, 50, 90])
        which = "held" if k < 0 else f"{k + 1}"
        print(
            f"  {kind:13s} {which:>7s} {len(a):6d} {a.min():6.3f} {q[0]:6.3f} {q[1]:6.3f} "
            f"{q[2]:6.3f} {a.max():6.3f} {100 * np.mean(a < arrival.EMPTY_N):6.0f} %"
        )
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layout", default="alpha0.3")
    parser.add_argument("--way", default="f", choices=("f", "r"))
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--variant", default="", help="one speed only, e.g. '22 mm/s'")
    parser.add_argument("--try", dest="tuning", default={}, type=tune_tracker.parse)
    parser.add_argument("--levels", action="store_true", help="the levels before contacts")
    args = parser.parse_args(argv)
    if args.levels:
        return levels(args.seeds)
    todo = [
        c
        for c in sr.cases(replace(sr.FULL, seeds=args.seeds))
        if c.kind == "constant"
        and c.layout == args.layout
        and c.reverse == (args.way == "r")
        and args.variant in ("", c.variant)
    ]
    with ProcessPoolExecutor(2) as pool:
        results = [u for out in pool.map(job, todo, [args.tuning] * len(todo)) for u in out]
    given = sum(r[2] for r in results)
    print(
        f"{len(todo)} cases ({args.layout} {args.way}, constant, {args.seeds} seeds): "
        f"{len(results)} updates from the 3rd true contact to the 4th, speed given in "
        f"{given} ({100 * given / max(1, len(results)):.1f} %)"
    )
    titles = ("decoder (way, contacts, v/v_true)", "ideal (way, told, v/v_true)")
    for title, col in zip(titles, (3, 4), strict=True):
        mass: dict = defaultdict(float)
        present: dict = defaultdict(int)
        for r in results:
            for key, share in r[col].items():
                mass[key] += share
                present[key] += share >= 0.01
        print(f"\n{title}: mean share of the slipping mass, updates holding >= 1 %")
        for key in sorted(mass, key=lambda k: -mass[k])[:14]:
            way = "same way" if key[0] > 0 else "other way"
            print(
                f"  {way:9s} {key[1]} contacts  v/v_true {key[2]:10s} "
                f"{100 * mass[key] / len(results):5.1f} %  "
                f"in {100 * present[key] / len(results):5.1f} %"
            )
    # how often the ideal observer would itself agree (80 % within 15 %) on the truth
    sure = sum(
        1 for r in results if sum(s for k, s in r[4].items() if k[2] in ("0.90-1.10",)) >= 0.8
    )
    share = 100 * sure / max(1, len(results))
    print(f"\nideal: >= 80 % of its mass within 10 % of the truth in {share:.1f} %")
    by_variant: dict = defaultdict(lambda: [0, 0])
    for r in results:
        by_variant[r[0]][0] += 1
        by_variant[r[0]][1] += r[2]
    print("speed given by variant: " + ", ".join(
        f"{k} {100 * g / n:.0f} % of {n}" for k, (n, g) in sorted(by_variant.items())
    ))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Why the slip flag dropped while the object slid: the default decoder's state, by cause.

`slip_reporting.score` counts an update as *slip dropped* when the truth moves, from its
run's 2nd ridge contact on (until the edge passes the last ridge ahead), and the slip
flag is down. The flag follows the posterior (`kernels.posterior.posterior`): up when
the slipping tracks that are evidently a slip hold half the mass. This re-reads that
posterior at each dropped update from the tracker's own state and tells where the mass
was instead:

- *stopped: silence*: the chosen hypothesis is a track that expected a ridge by now and,
  none told, stopped (`Silence.stopped`). By whether the truth's edge had passed that
  next ridge (*ridge passed, not told*: the detector missed it or told it too late) or
  not (*ridge not reached*: the track runs ahead of the object - a wrong speed or an
  alias), and whether the track's last contact was a truth ridge contact;
- *stopped: step*: a track stopped at a contact told a step; by what made the step (a
  truth ridge contact: a ridge's pulse held up, or not) and its shape verdict;
- *stopped: braked*: a braking track whose own motion brought it to rest;
- *no hypothesis*: P(slip) under a half and no stopped track above "no slip": by
  where the mass was - *no slip* (every contact clutter), tracks *not evident* (two or
  more contacts but no pulse verdict among them, or too few: `EVIDENT_CONTACTS`),
  *one contact* (a slip just started or reversed), or *restart held* (a restart whose
  contact was told a step); *last ridge undecided* when the truth's last ridge contact
  is more recent than the detector's longest delay (`_silence_latency`): no decoder
  could have linked it yet.

Each dropped update also notes whether the sensor sat on its rail (saturation) since the
chosen track's contact. Then per kind, and (`--stops`) the same state read at the update
that held each late stop up (`stop_causes.classify`). `--kinds`, `--seeds N` (the full
plan's first N, default 2), `--try NAME=VALUE[,...]` as in `tune_tracker_kinds.py`.

Run: `.venv/bin/python benchmarks/dropped_causes.py --seeds 1`.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections import Counter, defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plan_cases
import stop_causes
from stop_causes import pct

from grasplink.decoding.detector import step_shape
from grasplink.decoding.kernels import posterior as pk
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

MOVING_KINDS = tuple(k for k in sr.KINDS if k in sr.MOVING)
RIDGE_MATCH_S = stop_causes.RIDGE_MATCH_S
SHAPES = {step_shape.STOP_LIKE: "stop-like", step_shape.RIDGE_LIKE: "ridge-like",
          step_shape.UNTOLD: "untold", step_shape.AMBIGUOUS: "ambiguous"}  # fmt: skip


class _State(stop_causes._Watch):
    """The watching decoder (`stop_causes._Watch`), also keeping at every update the
    posterior's decomposition (`decompose`)."""

    def _report(self, g: float):  # type: ignore[override]
        out = super()._report(g)
        # read only where the flag is down (the rest is never classified)
        if out.slip:
            self.states.append({})
        else:
            self.states.append(decompose(self, g) if len(self._tracks) else None)
        return out


def decompose(dec: _State, g: float) -> dict:
    """The posterior at g as the kernel computes it (`kernels.posterior.posterior`), per
    track: its total log weight and which way it counts (slip, stopped by silence, at a
    step, braked; evident or not; waiting for its speed)."""
    B = dec._tracks
    due, adj_t, stop_t, _ = dec._schedule(B)
    blind = dec._blind(B.t, g)
    K = dec._K
    R = dec.count
    evident, bonus = pk._evidence(B.ids, B.n, B.run, dec._ring, dec._ring_id,
                                  *dec._evidence_tables, B.X[:, 1], B.before,
                                  K[pk.RESTART_AGREE_REL])  # fmt: skip
    best = float(B.score.max())
    rows = []
    for i in range(len(B)):
        live = B.score[i] >= best - K[pk.NEGLIGIBLE]
        seen = g - (blind[i] if blind is not None else 0.0)
        j = int(np.sum(due[i] <= seen)) - 1
        adj = adj_t[i, j]
        running = bool(np.isnan(B.stop[i]))
        braked = (
            running
            and B.run[i] >= 2
            and _braked(dec, float(B.X[i, 1]), float(B.X[i, 2]), float(B.P[i, 2, 2]),
                        int(B.ridge[i]), float(B.t[i]), g)
        )  # fmt: skip
        waiting = running and B.run[i] == 1
        if waiting and live:
            elapsed = g - B.t[i] - (blind[i] if blind is not None else 0.0)
            row = (1 - B.dirn[i]) // 2 * R + min(int(B.ridge[i]), R - 1)
            adj = pk.log_waiting(elapsed - K[pk.MAX_LATENCY], row, dec._waiting, K)
        total = B.score[i] + adj + bonus[i] if live else -math.inf
        if not running:
            how = "step"
        elif braked:
            how = "braked"
        elif stop_t[i, j]:
            how = "silence"
        else:
            how = "slip"
        rows.append((total, how, bool(evident[i]), int(B.n[i]), int(B.run[i]), i))
    return {"null": dec._null, "rows": rows, "blind": blind is not None}


def classify(dec: _State, k: int, t_upd: float, truth, contacts: np.ndarray) -> tuple[str, str]:
    """(cause, detail) of one update whose flag was down (see the module doc)."""
    state = dec.states[k]
    if state is None:
        return ("no hypothesis", "no track")
    rows = state["rows"]
    top = max([state["null"], *(r[0] for r in rows)])
    mass: Counter = Counter({"no slip": math.exp(state["null"] - top)})
    for total, how, evident, n, run, _ in rows:
        if not math.isfinite(total):
            continue
        w = math.exp(total - top)
        if evident:
            mass[f"stopped: {how}" if how != "slip" else "slip"] += w
        elif n == 1:
            mass["one contact"] += w
        elif run == 1 and how == "slip":
            mass["restart held"] += w
        else:
            mass["not evident"] += w
    rail = " (rail)" if state["blind"] else ""
    chosen = dec._cache_rows[k]
    if chosen is None:  # no hypothesis: where the mass was
        del mass["slip"]
        where = max(mass, key=lambda key: mass[key])
        where = where if not where.startswith("stopped") else "stopped, below no slip"
        # the truth's last ridge contact not yet decidable (the detector's delay): no
        # tracker can link it yet
        before = contacts[contacts <= t_upd]
        fresh = len(before) and t_upd - float(before[-1]) <= dec._silence_latency
        return ("no hypothesis", where + rail + (", last ridge undecided" if fresh else ""))
    how, t_last, ridge, dirn, last_id = chosen  # (a step's: its step contact)
    on_ridge = len(contacts) and float(np.min(np.abs(contacts - t_last))) <= RIDGE_MATCH_S
    last = "last on a ridge" if on_ridge else "last no ridge"
    if how == "step":
        shape = SHAPES.get(dec._shapes.get(last_id, step_shape.UNTOLD), "untold")
        sure = "sure" if last_id in dec._sure else shape
        return ("stopped: step", f"step {'on a ridge' if on_ridge else 'no ridge'}, {sure}")
    if how == "silence":
        x_next = _next_ridge_x(dec, ridge, dirn)
        edge = float(np.interp(t_upd, truth.t_s, truth.position_mm))
        passed = (edge >= x_next) if dirn > 0 else (edge <= x_next)
        what = "ridge passed, not told" if passed else "ridge not reached"
        return ("stopped: silence", f"{what}, {last}{rail}")
    return (f"stopped: {how}", last + rail)


def _braked(dec: _State, v: float, a: float, p22: float, ridge: int, t: float, g: float) -> bool:
    """Has a running track braked to rest by g: even braking BRAKE_Z sigma gentler, its own
    motion since its contact at t brought it below the slowest slip (as
    `kernels.posterior.posterior` reads it)."""
    K = dec._K
    a_hi = pk.acceleration(a + K[pk.BRAKE_Z] * math.sqrt(max(p22, 0.0)), p22, ridge, dec.count, K)
    if a_hi >= 0:
        return False
    rest = max(K[pk.V_MIN], K[pk.REST_SHARE] * v)
    return t + (rest - v) / a_hi <= g


def _next_ridge_x(dec: _State, ridge: int, dirn: int) -> float:
    """Skin position of the ridge after travel-order ridge `ridge` going `dirn`."""
    di = (1 - dirn) // 2
    s = float(dec._pos[di, min(ridge + 1, dec.count - 1)])
    return s if dirn > 0 else dec.length - s


def _chosen(dec: _State, g: float):
    """The chosen hypothesis at the update just made: None, or (how it is stopped, its
    last contact's time, ridge, direction, id)."""
    if not len(dec._tracks) or dec._cache is None or dec._cache[1] is None:
        return None
    h, stopped, _ = dec._cache[1]
    if not stopped:
        return ("slip", h.t, h.ridge, h.dirn, -1)
    if not math.isnan(h.stop):  # at a step: its step contact (its last is the ridge before)
        step_id = next((c.id for c, _ in dec.contacts if c.t_s == h.stop), -1)
        return ("step", h.stop, h.ridge, h.dirn, step_id)
    braked = h.run >= 2 and _braked(dec, h.v, h.a, h.p22, h.ridge, h.t, g)
    last_id = next((c.id for c, _ in dec.contacts if c.t_s == h.t), -1)
    return ("braked" if braked else "silence", h.t, h.ridge, h.dirn, last_id)


class _Dropped(_State):
    def _report(self, g: float):  # type: ignore[override]
        out = super()._report(g)
        self._cache_rows.append(_chosen(self, g))
        return out


def job(case: sr.Case, tuning: dict) -> tuple[sr.Case, list[tuple[str, str]], list, int]:
    """(case, per dropped update (cause, detail), per late stop (delay, cause, detail,
    step, the dropped-style cause at the update that held it), updates scored)."""
    rec = case.make()
    config = stop_causes.tune_tracker.config(tuning)
    probe = sr.build_decoder("tracker", rec.truth.layout_mm, rec.fs_hz, config)
    dec = _Dropped(rec.truth.layout_mm, rec.fs_hz, tuning=config["tuning"],
                   detector=probe.detector if "watch" in config else None)  # fmt: skip
    sr.tell_grip_commands(dec, case)
    dec.rows, dec.contacts, dec.checks, dec.arrived = [], [], [], []
    dec.states, dec._cache_rows = [], []
    estimates, _ = ns.feed(dec, rec.t_s, rec.force_n, sr.CHUNK)
    truth = rec.truth
    t = np.array([e.t_s for e in estimates])
    flags = np.array([e.slip for e in estimates])
    v = np.interp(t, truth.t_s, truth.speed_mm_s)
    edge = np.interp(t, truth.t_s, truth.position_mm)
    contacts = np.sort(np.asarray(truth.contact_times_s, dtype=float))
    skin = sr.ridges_mm(truth.layout_mm)
    from2, beyond = np.zeros(len(t), bool), np.zeros(len(t), bool)
    for start, end, sign in ns.motion(truth).runs:  # as `slip_reporting.score`
        mine = contacts[(contacts >= start) & (contacts < end)]
        inside = (t >= start) & (t < end)
        beyond |= inside & ((edge >= skin[-1]) if sign > 0 else (edge <= skin[0]))
        if len(mine) >= 2:
            from2 |= inside & (t >= mine[1])
    scored = from2 & (np.abs(v) >= sr.V_MOVING_MM_S) & ~beyond
    # was the flag up earlier in the same motion run: "dropped after up", else "never up"
    was_up = np.zeros(len(t), bool)
    for start, end, _ in ns.motion(truth).runs:
        inside = (t >= start) & (t < end)
        was_up[inside] = np.maximum.accumulate(flags[inside]) if inside.any() else False
    dropped = [(*classify(dec, k, t[k], truth, contacts), bool(was_up[k]))
               for k in np.flatnonzero(scored & ~flags)]  # fmt: skip
    late = []
    for stop in sr.score(estimates, truth).stops:
        if not stop.judged or stop.observable_s is None or stop.delay_s <= sr.CLEAR_WITHIN_S:
            continue
        due = stop.observable_s + sr.CLEAR_WITHIN_S
        late.append((stop.delay_s, *stop_causes.classify(dec, t, stop, due, contacts)))
    return case, dropped, late, int(scored.sum())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    plan_cases.add_plan_arguments(parser, ",".join(MOVING_KINDS), 2)
    parser.add_argument("--detail", action="store_true", help="per kind, each cause's details")
    args = parser.parse_args(argv)
    todo = plan_cases.full_plan_cases(parser, args.kinds, args.seeds, first_seed=args.first_seed)
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(job, todo, [args.tuning] * len(todo), chunksize=2))
    print(f"{len(todo)} cases ({args.kinds}, full plan, {args.seeds} seed(s)), {args.tuning}")
    scored = sum(r[3] for r in results)
    drops = [(case.kind, c[:2]) for case, out, _, _ in results for c in out]
    ups = [(case.kind, c[2]) for case, out, _, _ in results for c in out]
    print(f"\nslip dropped: {len(drops)} of {scored} updates ({pct(len(drops), scored)})")
    causes = Counter(c for _, c in drops)
    for (cause, detail), count in causes.most_common():
        print(f"  {cause:18s} {detail:48s} {count:6d} {pct(count, len(drops)):>7s}")
    print("\nnever up (the flag not up yet in that motion run) / dropped after it was up")
    split = Counter((c[0], c[2]) for _, out, _, _ in results for c in out)
    for cause in sorted({c for c, _ in split}, key=lambda c: -split[c, False] - split[c, True]):
        print(f"  {cause:18s} never up {pct(split[cause, False], scored):>7s} of scored, "
              f"after up {pct(split[cause, True], scored):>7s}")  # fmt: skip
    kind_split: dict[str, Counter] = defaultdict(Counter)
    for kind, up in ups:
        kind_split[kind][up] += 1
    per_kind: dict[str, Counter] = defaultdict(Counter)
    n_kind: Counter = Counter()
    for case, _, _, n in results:
        n_kind[case.kind] += n
    for kind, (cause, detail) in drops:
        per_kind[kind][cause] += 1
        if args.detail:
            per_kind[kind][f"  {cause}: {detail}"] += 1
    heads = sorted({c for _, (c, _) in drops})
    print("\nper kind: dropped % of its scored updates, then each cause's share of them")
    print(f"  {'kind':12s} {'drop%':>6s} {'never':>6s} {'after':>6s} "
          + " ".join(f"{h[:16]:>16s}" for h in heads))  # fmt: skip
    for kind in args.kinds.split(","):
        row = per_kind[kind]
        total = sum(row[h] for h in heads)
        cells = " ".join(f"{pct(row[h], total):>16s}" for h in heads)
        n = max(n_kind[kind], 1)
        never, after = (100.0 * kind_split[kind][up] / n for up in (False, True))
        print(f"  {kind:12s} {100.0 * total / n:6.1f} {never:6.1f} {after:6.1f} {cells}")
        if args.detail:
            for key, count in row.most_common():
                if key.startswith("  "):
                    print(f"      {key.strip():62s} {count:6d}")
    late = [(case, s) for case, _, out, _ in results for s in out]
    print(f"\nlate stops: {len(late)} (stop_causes.classify at the update holding each up)")
    for (cause, detail), count in Counter((s[1], s[2]) for _, s in late).most_common():
        print(f"  {cause:30s} {detail:30s} {count:5d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

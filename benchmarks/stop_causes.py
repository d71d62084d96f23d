"""Why a stop was cleared late: the default decoder's judged stops by cause.

`slip_reporting.score` judges a stop cleared when, from some update on to its end, every
update has the slip flag down and no speed; the target wants that within
`CLEAR_WITHIN_S` of the moment the stop becomes observable (the next ridge contact due
and absent). This tells, for each judged stop cleared later (or never), what the
default decoder's likeliest hypothesis was at the update that held it up (the first
update after the report was due that still flagged a slip or gave a speed):

- *a contact no ridge made*: a slipping track whose last contact is no truth ridge
  contact (within RIDGE_MATCH_S): the level's step as the object sticks (at the stop,
  within NEAR_STOP_S of its start: the braking takes 30 ms), or noise, taken as a ridge;
  by that contact's pulse verdict at the time (pulse, step, unclear, noise, not told);
- *coasting past the last ridge*: a slipping track on the skin's last ridge (an alias
  that no silence can stop before its coast ends);
- *silence not yet read*: a slipping track still waiting for its next ridge; by its
  contacts (2, 3, 4+).

Each also tells whether the stop's own step (a contact within 0.1 s of the stop) was
detected and its verdict by the report's due time. Then per kind and layout, and the
late stops listed. `--kinds` (default: the kinds with stops), `--seeds N` (the full plan's
first N, default 3), `--try NAME=VALUE[,...]` (a tuning) as in `tune_tracker_kinds.py`.

Run: `.venv/bin/python benchmarks/stop_causes.py --seeds 2`.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter, defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plan_cases
import tune_tracker

from grasplink.decoding.contacts import STEP_IDS, ContactEvent, PulseCheck
from grasplink.decoding.detector import step_shape
from grasplink.decoding.kernels.common import ring_slot
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

STOP_KINDS = ("stick-slip", "stop", "rates-drops", "loop")
# --shapes: the stop kinds and the kinds that slide on (a step there is a ridge or a grip)
SHAPE_KINDS = (*STOP_KINDS, "constant", "accelerating", "decelerating", "reversal", "snr10",
               "saturation")  # fmt: skip
NEAR_STOP_S = 0.1  # a contact this close to a stop's start is its step (or the last ridge)
RIDGE_MATCH_S = 0.03  # a decoder contact this close to a truth ridge contact is that ridge
VERDICTS = {0: "not told", 1: "pulse", 2: "step", 3: "unclear", 4: "noise"}


class _Watch(TrackerDecoder):
    """The default decoder, noting its chosen hypothesis at every update and every contact
    and pulse verdict with the update that first saw it."""

    def _report(self, g: float):  # type: ignore[override]
        out = super()._report(g)
        for item in self.arrived:
            if isinstance(item, ContactEvent):
                self.contacts.append((item, g))
            else:
                self.checks.append((item, g))
        self.arrived.clear()
        row: tuple = ("none",)
        if len(self._tracks) and self._cache is not None and self._cache[1] is not None:
            h, stopped, _ = self._cache[1]
            if stopped:
                row = ("stopped",)
            else:
                slot = ring_slot(self._last_id(h.t), len(self._ring))
                verdict = int(self._ring[slot]) if self._ring_id[slot] >= 0 else 0
                row = ("slipping", h.t, h.ridge, h.n, verdict)
        self.rows.append(row)
        return out

    def _last_id(self, t_s: float) -> int:
        for c in self._contacts:
            if c.t_s == t_s:
                return c.id
        return -1

    def _add_contact(self, ev: ContactEvent) -> None:
        self.arrived.append(ev)
        super()._add_contact(ev)

    def _add_check(self, check: PulseCheck) -> None:
        self.arrived.append(check)
        super()._add_check(check)


def _decoder(case: sr.Case, rec: ns.Recorded, tuning: dict) -> _Watch:
    """The watching decoder with a tuning (`tune_tracker.config`: `watch.NAME` and
    `tails.NAME` the detector's), as `slip_reporting.case_job` builds the default one (a
    loop case's grip commands told)."""
    config = tune_tracker.config(tuning)
    probe = sr.build_decoder("tracker", rec.truth.layout_mm, rec.fs_hz, config)
    decoder = _Watch(
        rec.truth.layout_mm, rec.fs_hz, tuning=config["tuning"],
        detector=probe.detector if "watch" in config or "tails" in config else None,
    )  # fmt: skip
    sr.tell_grip_commands(decoder, case)
    return decoder


def classify(
    decoder: _Watch, t_upd: np.ndarray, stop: sr.StopScore, due_s: float, ridges: np.ndarray
) -> tuple:
    """(cause, detail, the stop's step) for one stop cleared late."""
    during = np.flatnonzero((t_upd > due_s) & (t_upd < stop.end_s))
    dirty = [i for i in during if decoder.rows[i][0] == "slipping"]
    if not dirty:  # cleared just after the due time: the last update before that held it
        inside = np.flatnonzero((t_upd >= stop.start_s) & (t_upd <= due_s))
        dirty = [i for i in inside if decoder.rows[i][0] == "slipping"][-1:]
    step = _stop_step(decoder, stop.start_s, due_s)
    if not dirty:  # flagged with no hypothesis slipping: cannot happen, say so if it does
        return ("other", "no slipping hypothesis", step)
    _, t_last, ridge, n, verdict = decoder.rows[dirty[0]]
    if not len(ridges) or np.min(np.abs(ridges - t_last)) > RIDGE_MATCH_S:
        when = (
            "at the stop"
            if abs(t_last - stop.start_s) <= NEAR_STOP_S
            else ("after it" if t_last > stop.start_s else "before it")
        )
        return ("a contact no ridge made", f"{when}, told {VERDICTS[verdict]}", step)
    if ridge == decoder.count - 1:
        return ("coasting past the last ridge", f"{min(n, 4)} contacts", step)
    return ("silence not yet read", f"{min(n, 4)}{'+' if n >= 4 else ''} contacts", step)


def _stop_step(decoder: _Watch, start_s: float, due_s: float) -> str:
    """The contact nearest the stop's start within NEAR_STOP_S, and its last verdict told
    by due_s (or "none")."""
    near = [(abs(c.t_s - start_s), c) for c, _ in decoder.contacts]
    near = [(d, c) for d, c in near if d <= NEAR_STOP_S]
    if not near:
        return "no contact at the stop"
    contact = min(near, key=lambda dc: dc[0])[1]
    told = [(ck, g) for ck, g in decoder.checks if ck.id == contact.id and g <= due_s]
    if not told:
        return "stop contact not told by due"
    check, g = told[-1]
    verdict = {True: "pulse", False: "step", None: "unclear"}[check.pulse]
    return f"stop contact told {verdict} at +{g - start_s:.2f} s"


def late_stops(decoder: _Watch, scored: sr.CaseScore):  # type: ignore[no-untyped-def]
    """Each judged stop cleared late: (stop, the time its report was due, the decoder's
    contact nearest its start within NEAR_STOP_S or None, that contact's verdict by then:
    "pulse", "step", "unclear" or "-" when not told)."""
    for stop in scored.stops:
        if not stop.judged or stop.observable_s is None or stop.delay_s <= sr.CLEAR_WITHIN_S:
            continue
        due = stop.observable_s + sr.CLEAR_WITHIN_S
        near = [c for c, _ in decoder.contacts if abs(c.t_s - stop.start_s) <= NEAR_STOP_S]
        if not near:
            yield stop, due, None, "-"
            continue
        c = min(near, key=lambda c: abs(c.t_s - stop.start_s))
        told = [ck for ck, g in decoder.checks if ck.id == c.id and g <= due]
        yield stop, due, c, VERDICT[told[-1].pulse] if told else "-"


VERDICT = {True: "pulse", False: "step", None: "unclear"}


def job(case: sr.Case, tuning: dict) -> tuple[sr.Case, list[tuple]]:
    """(case, per judged stop: (delay s, cause, detail, step) with cause "" if in time)."""
    rec = case.make()
    decoder = _decoder(case, rec, tuning)
    decoder.rows, decoder.contacts, decoder.checks, decoder.arrived = [], [], [], []
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    scored = sr.score(estimates, rec.truth)
    t_upd = np.array([e.t_s for e in estimates])
    out = []
    for stop in scored.stops:
        if not stop.judged or stop.observable_s is None:
            continue
        if stop.delay_s <= sr.CLEAR_WITHIN_S:
            out.append((stop.delay_s, "", "", ""))
            continue
        due = stop.observable_s + sr.CLEAR_WITHIN_S
        ridges = np.asarray(rec.truth.contact_times_s, dtype=float)
        out.append((stop.delay_s, *classify(decoder, t_upd, stop, due, ridges)))
    return case, out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    plan_cases.add_plan_arguments(parser, ",".join(STOP_KINDS), 3)
    parser.add_argument("--worst", type=int, default=30, help="late stops listed")
    parser.add_argument("--trace", type=int, default=None, help="one case's seed: its timeline")
    parser.add_argument(
        "--shapes", action="store_true",
        help="every contact told a step: its shape (step_shape) by what it was (stop, ridge)",
    )  # fmt: skip
    parser.add_argument("--shapes-out", default=None, help="--shapes: its rows as JSON here")
    args = parser.parse_args(argv)
    if args.shapes and args.kinds == ",".join(STOP_KINDS):
        args.kinds = ",".join(SHAPE_KINDS)
    todo = plan_cases.full_plan_cases(parser, args.kinds, args.seeds, first_seed=args.first_seed)
    if args.trace is not None:
        chosen = [c for c in todo if c.seed == args.trace]
        if not chosen:
            parser.error(f"no case with seed {args.trace} among --kinds and --seeds")
        trace(chosen[0], args.tuning)
        return 0
    if args.shapes:
        return shapes(todo, args.tuning, args.seeds, args.shapes_out)
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(job, todo, [args.tuning] * len(todo), chunksize=2))
    stops = [(case, s) for case, out in results for s in out]
    late = [(case, s) for case, s in stops if s[1]]
    print(f"{len(todo)} cases ({args.kinds}, full plan, {args.seeds} seed(s)), {args.tuning}")
    print(f"{len(stops)} judged stops, {len(late)} cleared late ({pct(len(late), len(stops))})")
    causes = Counter((s[1], s[2]) for _, s in late)
    for (cause, detail), count in causes.most_common():
        print(f"  {cause:30s} {detail:22s} {count:5d} {pct(count, len(late)):>7s}")
    print("\nthe stop's own step, in the late stops")
    for what, count in Counter(_bucket(s[3]) for _, s in late).most_common():
        print(f"  {what:40s} {count:5d}")
    for title, key in (("kind", "kind"), ("layout", "layout")):
        print(f"\nper {title}: judged, late, causes")
        rows: dict[str, Counter] = defaultdict(Counter)
        for case, s in stops:
            rows[getattr(case, key)]["judged"] += 1
            if s[1]:
                rows[getattr(case, key)][s[1]] += 1
        for name, row in sorted(rows.items()):
            n = row.pop("judged")
            parts = ", ".join(f"{k} {c}" for k, c in row.most_common())
            print(f"  {name:12s} {n:5d} {sum(row.values()):5d}  {parts}")
    print("\nlate stops (delay s: inf = never)")
    late.sort(key=lambda cs: -cs[1][0])
    for case, (delay, cause, detail, step) in late[: args.worst]:
        way = "r" if case.reverse else "f"
        print(
            f"  {case.kind:11s} {case.layout:10s} {case.variant:12s} {way} {case.seed} "
            f"{delay:6.2f} {cause} ({detail}); {step}"
        )
    return 0


def trace(case: sr.Case, tuning: dict) -> None:
    """One case's timeline around each stop: the truth's ridge contacts, the decoder's
    contacts and verdicts (with the update that saw them) and its chosen hypothesis."""
    rec = case.make()
    decoder = _decoder(case, rec, tuning)
    decoder.rows, decoder.contacts, decoder.checks, decoder.arrived = [], [], [], []
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    scored = sr.score(estimates, rec.truth)
    print(case)
    truth = np.round(np.sort(np.asarray(rec.truth.contact_times_s, dtype=float)), 3)
    print(f"truth ridge contacts: {truth.tolist()}")
    for c, g in decoder.contacts:
        told = [(ck.pulse, round(gg, 3)) for ck, gg in decoder.checks if ck.id == c.id]
        print(f"  contact {c.id} at {c.t_s:.3f} s (z {c.z:.1f}), seen {g:.3f}: {told}")
    for stop in scored.stops:
        print(
            f"stop {stop.start_s:.3f}-{stop.end_s:.3f} observable {stop.observable_s} "
            f"delay {stop.delay_s:.3f}"
        )
        for e, row in zip(estimates, decoder.rows, strict=True):
            if stop.start_s - 0.3 <= e.t_s <= min(stop.end_s, stop.start_s + 1.5):
                print(f"  {e.t_s:.3f} slip {e.slip:d} speed {e.speed_mm_s} {row}")


def _label(t_c: float, stops: list[tuple[float, float]], ridges: np.ndarray) -> str:
    """What made a contact at t_c: a stop's step (a stop starts within NEAR_STOP_S of it),
    a ridge the slip went on from (a truth ridge contact within RIDGE_MATCH_S, no stop
    near), or something else (a grip change, noise, a contact at rest)."""
    if any(abs(t_c - start) <= NEAR_STOP_S for start, _ in stops):
        return "stop"
    near_ridge = len(ridges) and float(np.min(np.abs(ridges - t_c))) <= RIDGE_MATCH_S
    if near_ridge and not any(start - NEAR_STOP_S <= t_c <= end for start, end in stops):
        return "ridge"
    return "other"


def shapes_job(case: sr.Case, tuning: dict) -> list[dict]:
    """Every contact the default decoder was told a step (its first such verdict): what
    made it (`_label`) and its shape (`step_shape.measure`, the samples up to the
    verdict)."""
    rec = case.make()
    decoder = _decoder(case, rec, tuning)
    decoder.rows, decoder.contacts, decoder.checks, decoder.arrived = [], [], [], []
    ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    stops = ns.motion(rec.truth).stops
    ridges = np.asarray(rec.truth.contact_times_s, dtype=float)
    contacts = {c.id: c for c, _ in decoder.contacts}
    x = np.asarray(rec.force_n, dtype=float)
    out, seen = [], set()
    for check, _ in decoder.checks:
        if check.pulse is not False or check.id in seen or check.id not in contacts:
            continue
        seen.add(check.id)
        c = contacts[check.id]
        # as the tracker reads it (`step_shape.Recent.verdict`): at most HELD_S after the onset
        told = min(check.emit_index, c.index + round(step_shape.HELD_S * rec.fs_hz))
        shape = step_shape.measure(x, c.index, told, rec.fs_hz)
        out.append({
            "kind": case.kind, "layout": case.layout, "variant": case.variant,
            "seed": case.seed, "fs_hz": rec.fs_hz, "t_s": c.t_s, "sure": check.sure,
            "probe": c.id >= STEP_IDS, "label": _label(c.t_s, stops, ridges),
            "shape": None if shape is None else shape._asdict(),
        })  # fmt: skip
    return out


# the shape's cues, each in noise units or a ratio (`shapes`)
CUES = {
    "height/noise": lambda s: s["height_n"] / s["noise_n"],
    "overshoot/noise": lambda s: s["overshoot_n"] / s["noise_n"],
    "overshoot/height": lambda s: s["overshoot_n"] / max(s["height_n"], 1e-9),
    "rise ms": lambda s: 1e3 * s["rise_s"],
    "pre slope/noise per 60ms": lambda s: s["pre_slope_n_s"] * 0.06 / s["noise_n"],
    "post slope/noise per 30ms": lambda s: s["post_slope_n_s"] * 0.03 / s["noise_n"],
    "post slope/height per 30ms": lambda s: s["post_slope_n_s"] * 0.03 / max(s["height_n"], 1e-9),
    "post rough/noise": lambda s: s["post_rough_snr"],
}


_SHAPE_VERDICTS = {step_shape.STOP_LIKE: "stop-like", step_shape.RIDGE_LIKE: "ridge-like",
                   step_shape.UNTOLD: "untold", step_shape.AMBIGUOUS: "ambiguous"}  # fmt: skip


def _shape(row: dict) -> step_shape.StepShape | None:
    return None if row["shape"] is None else step_shape.StepShape(**row["shape"])


def shapes(todo: list[sr.Case], tuning: dict, seeds: int, out_path: str | None) -> int:
    """The table of step shapes: per label (stop, ridge, other) the quartiles of each cue,
    over all kinds and per group of kinds (stop kinds, loop, sliding kinds)."""
    with ProcessPoolExecutor(2) as pool:
        rows = [r for out in pool.map(shapes_job, todo, [tuning] * len(todo), chunksize=2)
                for r in out]  # fmt: skip
    if out_path:
        Path(out_path).write_text(json.dumps(rows))
    print(f"{len(todo)} cases (full plan, {seeds} seed(s)), {tuning}: {len(rows)} steps told")
    groups = {
        "all": lambda r: True,
        "loop": lambda r: r["kind"] == "loop",
        "stop kinds but loop": lambda r: r["kind"] in STOP_KINDS and r["kind"] != "loop",
        "sliding kinds": lambda r: r["kind"] not in STOP_KINDS,
    }
    for gname, pick in groups.items():
        chosen = [r for r in rows if pick(r)]
        print(f"\n{gname}: steps by label (unmeasured: no samples held)")
        for label in ("stop", "ridge", "other"):
            mine = [r for r in chosen if r["label"] == label]
            ok = [r["shape"] for r in mine if r["shape"] is not None]
            sure = sum(r["sure"] for r in mine)
            print(
                f"  {label:6s} {len(mine):5d} told, {sure} sure, {len(mine) - len(ok)} unmeasured"
            )
            for sure_too in (True, False):
                told = Counter(
                    _SHAPE_VERDICTS[step_shape.classify(_shape(r), r["fs_hz"])]
                    for r in mine
                    if r["sure"] == sure_too
                )
                what = "sure" if sure_too else "not sure"
                print(f"    classified ({what}): " + ", ".join(f"{k} {c}" for k, c in told.items()))
            for cue, f in CUES.items():
                v = np.array([f(s) for s in ok], dtype=float)
                v = v[np.isfinite(v)]
                if not len(v):
                    continue
                q = np.percentile(v, [10, 25, 50, 75, 90])
                print(f"    {cue:28s} " + " ".join(f"{x:8.2f}" for x in q))
    return 0


def _bucket(step: str) -> str:
    """A stop-step note without its time (`_stop_step`)."""
    return step.split(" at +")[0]


def pct(part: float, whole: float) -> str:
    """part of whole as "12.3 %" ("-" for a part that is no number): the causes scripts' cells."""
    return f"{100.0 * part / max(whole, 1):.1f} %" if math.isfinite(part) else "-"


if __name__ == "__main__":
    sys.exit(main())

"""The silence bound on "slip dropped" (issue 22): the share of the scored sliding updates
where any decoder that reads stops from silence and clears every stop within 0.15 s of
observable must have the flag down (`evaluation/silence_bound.py`), per moving kind,
beside the default decoder's own slip dropped on the same updates (one run).

Per case: the default decoder (3-sample chunks; a loop case with its gateway's grip
commands, as `slip_reporting.case_job`) gives the update times and its flags. The silence
decoder places a stop just after the last contact known by each update; its flag is down
from the last update at or before that stop's observable moment + 0.15 s (+ a wait) until
the next contact is known. Counted through `slip_reporting.score` (its denominator).

- contacts: the truth's, each known at its time (a perfect detector), or `--latency` s
  later; on snr10 also the oracle's told contacts (`detection_bound`'s matched filter on
  the signal less the other pulses at or above 4.75, known when the filter is decided)
  and today's detector's found ones (within 20 ms of a true contact, at the true time);
- level: silent updates where the noise-free FSR level moved by more than 3 white-noise
  sigmas (the recording's, before the motion) over the 0.25 s before, from the object's
  own motion (`motion_level_move_n`): a decoder reading the level could keep those;
- the trade: waiting w s past due before dropping, the bound and the share of judged
  stops the silence decoder still clears within 0.15 s.

Run: `.venv/bin/python benchmarks/dropped_silence_bound.py --seeds 3 --workers 1
[--kinds a,b] [--found]` (the full plan's moving kinds).
"""

from __future__ import annotations

import argparse
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor

import numpy as np
import plan_cases
from plan_cases import pct_cell

from grasplink.decoding.registry import DEFAULT_DECODER
from grasplink.evaluation import contact_truth as ct
from grasplink.evaluation import detection_bound as db
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import silence_bound as sb
from grasplink.evaluation import slip_reporting as sr

ORACLE_LEVEL = 4.75  # detection_bound's clean level (docs/decoding.md, the information bound)
WAITS_S = (0.0, 0.05, 0.1, 0.2, 0.5)
LEVEL_SIGMAS_SHOWN = (3.0, 10.0, 30.0)  # the level criterion, stricter (drift: not in it)
OBJECT_MM = {"reversal": ns.SHORT_OBJECT_MM, "loop": ct.LOOP_OBJECT_MM}  # else the thesis'


def _white_before_motion(rec: ns.Recorded) -> float:
    """The white noise of the recording where the object has not moved yet (all of it
    when that is too short)."""
    runs = ns.motion(rec.truth).runs
    first = runs[0][0] if runs else np.inf
    quiet = np.asarray(rec.t_s) < first
    x = np.asarray(rec.force_n)[quiet] if quiet.sum() >= 50 else np.asarray(rec.force_n)
    return sb.white_noise_n(x)


def _oracle_contacts(rec: ns.Recorded, case: sr.Case) -> tuple[np.ndarray, np.ndarray]:
    """snr10: the contacts the oracle tells at ORACLE_LEVEL (clean) and when it decides."""
    truth, fs = rec.truth, rec.fs_hz
    train = ct.pulse_train(truth, case.seed)
    rest = np.asarray(rec.force_n, dtype=float) - train.pulses_n
    white = ns.pulse_height_n(truth.layout_mm) / 10 ** (ns.SNR_DB / 20)
    tmpls = [db.template(train, i, fs) for i in range(len(train.times_s))]
    onsets = np.ceil(train.times_s * fs).astype(int)
    clean = np.array(
        [
            db.statistic(rest, a, t, white) + t.norm_n / white
            for a, t in zip(onsets, tmpls, strict=True)
        ]
    )
    decided = (onsets + np.array([t.after for t in tmpls])) / fs
    told = np.nan_to_num(clean, nan=-np.inf) >= ORACLE_LEVEL
    return train.times_s[told], decided[told]


def job(case: sr.Case, latency_s: float, found_all: bool = False) -> dict:
    """One case: the decoder's flags, the silence decoder's, their counts via `score`."""
    rec = case.make()
    truth = rec.truth
    decoder = sr.build_decoder(DEFAULT_DECODER, truth.layout_mm, rec.fs_hz, {})
    sr.tell_grip_commands(decoder, case)
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    t = np.array([e.t_s for e in estimates])
    flag = np.array([e.slip for e in estimates])
    mine = sr.score(estimates, truth)
    contacts = np.sort(np.asarray(truth.contact_times_s, dtype=float))
    due = sb.stop_due_s(truth, contacts)

    def down(known: np.ndarray, wait: float = 0.0, which: np.ndarray | None = None):
        c, d = (contacts, due) if which is None else (contacts[which], due[which])
        return sb.silent_down(t, c, known, d, wait)

    def count(mask: np.ndarray) -> int:
        return sb.dropped_where(t, mask, truth)[0]

    silent = down(contacts)
    level = sb.motion_level_move_n(truth, t, OBJECT_MM.get(case.kind, ns.THESIS_OBJECT_MM))
    sigma = _white_before_motion(rec)
    out = {
        "kind": case.kind,
        "scored": mine.moving_from2,
        "decoder": mine.dropped_from2,
        "bound": count(silent),
        "latency": count(down(contacts + latency_s)),
        "no_level": count(silent & (level <= sb.LEVEL_SIGMAS * sigma)),
        "no_level_by": [count(silent & (level <= k * sigma)) for k in LEVEL_SIGMAS_SHOWN],
        "decoder_in_silent": count(silent & ~flag),
        "decoder_outside": count(~silent & ~flag),
        "decoder_stops": [
            sum(1 for s in mine.stops if s.judged and s.delay_s <= sr.CLEAR_WITHIN_S + 1e-9),
            sum(1 for s in mine.stops if s.judged),
        ],
        "waits": [],
    }
    for w in WAITS_S:
        mask = down(contacts, w)
        out["waits"].append([count(mask), *sb.stops_cleared(t, mask, truth)])
    if case.kind == "snr10":
        told_s, decided_s = _oracle_contacts(rec, case)
        told_due = sb.stop_due_s(truth, told_s)
        oracle = sb.silent_down(t, told_s, decided_s, told_due)
        out["oracle"] = count(oracle)
        out["oracle_no_level"] = count(oracle & (level <= sb.LEVEL_SIGMAS * sigma))
        out["oracle_decoder_in_silent"] = count(oracle & ~flag)
        out["oracle_waits"] = [
            count(sb.silent_down(t, told_s, decided_s, told_due, w)) for w in WAITS_S
        ]
    if found_all or case.kind == "snr10":
        found = np.asarray(ct.by_contact(truth, rec.t_s, rec.force_n, rec.fs_hz).found, bool)
        if len(found) == len(contacts):
            quiet = down(contacts[found], which=found)
            out["found"] = count(quiet)
            out["found_decoder_in_silent"] = count(quiet & ~flag)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=3, help="seeds of the full plan (1-3)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--kinds", default="", help="comma-separated moving kinds (default all)")
    parser.add_argument("--latency", type=float, default=0.05, help="a detector's latency (s)")
    parser.add_argument(
        "--found", action="store_true", help="every kind's bound on today's detector's contacts"
    )
    args = parser.parse_args(argv)
    kinds_text = args.kinds or ",".join(sr.MOVING)
    todo = plan_cases.full_plan_cases(parser, kinds_text, args.seeds, allowed=sr.MOVING)
    started = time.monotonic()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(
            pool.map(job, todo, [args.latency] * len(todo), [args.found] * len(todo), chunksize=2)
        )
    print(
        plan_cases.run_title(
            todo, args.seeds, kinds_text.split(","), args.workers, time.monotonic() - started
        )
    )
    report(rows, args.latency)
    return 0


def report(rows: list[dict], latency_s: float) -> None:
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[r["kind"]].append(r)
        groups["every moving kind"].append(r)
        if r["kind"] != "snr10":
            groups["moving, snr10 apart"].append(r)

    def total(rs: list[dict], key: str) -> float:
        return float(sum(r[key] for r in rs))

    print()
    print(
        "| kind | cases | scored updates | decoder slip dropped % | bound: perfect detector %"
        f" | contacts known {latency_s:g} s late % | bound less level-evidence updates % |"
        " decoder down in the silent updates % of them | decoder dropped outside them % |"
        " stops cleared: decoder / silence decoder % |"
    )
    print("|---|" + "---:|" * 9)
    for key, rs in groups.items():
        scored = total(rs, "scored")
        bound = total(rs, "bound")
        dec_stops = np.sum([r["decoder_stops"] for r in rs], axis=0)
        sil_stops = np.sum([r["waits"][0][1:] for r in rs], axis=0)
        cells = [
            key,
            str(len(rs)),
            str(int(scored)),
            pct_cell(total(rs, "decoder"), scored),
            pct_cell(bound, scored),
            pct_cell(total(rs, "latency"), scored),
            pct_cell(total(rs, "no_level"), scored),
            pct_cell(total(rs, "decoder_in_silent"), bound),
            pct_cell(total(rs, "decoder_outside"), scored),
            f"{pct_cell(dec_stops[0], dec_stops[1])} / {pct_cell(sil_stops[0], sil_stops[1])}"
            f" ({int(dec_stops[1])})",
        ]
        print("| " + " | ".join(cells) + " |")
    if any("found" in r for r in rows if r["kind"] != "snr10"):
        print()
        print(
            "On today's detector's found contacts (within 20 ms of a true one, taken at the true"
            " time; its false contacts left out): a perfect tracker behind today's detector"
        )
        print("| kind | bound % | decoder slip dropped % | decoder down in those silent % |")
        print("|---|---:|---:|---:|")
        for key, rs in groups.items():
            got = [r for r in rs if "found" in r]
            scored = total(got, "scored")
            print(
                f"| {key} | {pct_cell(total(got, 'found'), scored)} |"
                f" {pct_cell(total(got, 'decoder'), scored)} |"
                f" {pct_cell(total(got, 'found_decoder_in_silent'), total(got, 'found'))} |"
            )
    snr = groups.get("snr10", [])
    if snr:
        scored = total(snr, "scored")
        print()
        print(
            f"snr10, the bound on other contacts ({int(scored)} scored updates): perfect"
            f" detector {pct_cell(total(snr, 'bound'), scored)} %, the oracle's told"
            f" (clean >= {ORACLE_LEVEL:g}, known when decided)"
            f" {pct_cell(total(snr, 'oracle'), scored)} %, today's detector's found (at the"
            f" true times) {pct_cell(sum(r.get('found', 0) for r in snr), scored)} %; the decoder"
            f" {pct_cell(total(snr, 'decoder'), scored)} %"
        )
        oracle = total(snr, "oracle")
        print(
            f"  the oracle's bound less level-evidence updates"
            f" {pct_cell(total(snr, 'oracle_no_level'), scored)} %; the decoder is down in"
            f" {pct_cell(total(snr, 'oracle_decoder_in_silent'), oracle)} % of the oracle's"
            " silent updates; waiting w past due ("
            + ", ".join(f"{w:g}" for w in WAITS_S)
            + " s): "
            + " / ".join(
                pct_cell(g, scored) for g in np.sum([r["oracle_waits"] for r in snr], axis=0)
            )
            + " %"
        )
        every = groups["every moving kind"]
        pooled = total(every, "bound") - total(snr, "bound") + oracle
        print(
            f"Every moving kind with snr10 at the oracle's contacts:"
            f" {pct_cell(pooled, total(every, 'scored'))} % (the decoder"
            f" {pct_cell(total(every, 'decoder'), total(every, 'scored'))} %)"
        )
    print()
    print("The trade: the silence decoder waits w past due before dropping (perfect detector)")
    print(
        "| wait w s | bound: every moving kind % | snr10 apart % | stops cleared"
        " <= 0.15 s: every moving kind % | snr10 apart % |"
    )
    print("|---:|---:|---:|---:|---:|")
    every, apart = groups["every moving kind"], groups.get("moving, snr10 apart", [])
    for i, w in enumerate(WAITS_S):
        cells = [f"{w:g}"]
        pooled = []
        for rs in (every, apart):
            got = np.sum([r["waits"][i] for r in rs], axis=0) if rs else np.zeros(3)
            cells.append(pct_cell(got[0], total(rs, "scored")))
            pooled.append(pct_cell(got[1], got[2]))
        print("| " + " | ".join(cells + pooled) + " |")
    print()
    print(
        "Bound less the updates whose level moved by more than k white-noise sigmas (k = "
        + ", ".join(f"{k:g}" for k in LEVEL_SIGMAS_SHOWN)
        + "; the drift is no part of the criterion):"
    )
    for key, rs in groups.items():
        got = np.sum([r["no_level_by"] for r in rs], axis=0)
        print(f"  {key}: " + " / ".join(pct_cell(g, total(rs, "scored")) for g in got) + " %")
    print()
    print("By kind, bound % at each wait (" + ", ".join(f"{w:g}" for w in WAITS_S) + " s):")
    for key, rs in groups.items():
        scored = total(rs, "scored")
        got = np.sum([r["waits"] for r in rs], axis=0)
        cells = [pct_cell(g[0], scored) for g in got]
        stops = [pct_cell(g[1], g[2]) for g in got]
        print(f"  {key}: {' / '.join(cells)}; stops cleared {' / '.join(stops)} %")


if __name__ == "__main__":
    raise SystemExit(main())

"""Which ridge contacts today's detector misses at the plan's noise, why, and what each
miss costs in "slip dropped" (issue 22).

Why: the silence bound (`evaluation/silence_bound.py`, docs/decoding.md "The silence
bound on slip dropped") says a decoder that clears stops within 0.15 s must drop 1.0 %
with every ridge told, but 11.3 % on today's detector's contacts: the gap to <= 1 % is
mostly contacts the detector does not tell. This finds them, kind by kind.

Per case (the full plan's moving kinds, snr10 apart - it has its own bound):

- every true ridge contact (`contact_truth.by_contact`: found within 20 ms or not, and
  the detector's own why - `AGAIN`, `UNDER`, `NO_KINK`) and, when found, how late it was
  told (the deciding sample of the nearest contact, `contact_truth.detect`);
- each miss's cause, the first rule that holds, in this order: *told off* a told
  contact nearer to it than to any other true contact lies 20-50 ms off (`OFF_S`: told,
  but placed outside the match - its silence is mostly the match's, not the decoder's);
  *rail* the noise-free force touches the FSR's full scale within [-10, +50] ms of the
  contact (saturation); *samples lost* a sample dropped in that window (rates-drops);
  *grip change* the grip moved by more than `GRIP_MOVE_N` over +-0.1 s; *first ridge*
  the run's first contact (the object arriving, no pulse before it); *hysteresis-held*
  the noise-free force stays flat for more than 10 ms from the contact (the loop's FSR
  hysteresis, a play operator 0.2 N wide, holds the level until the new pulse has risen
  through the band: its kink comes late or never); *merged* the time
  since the previous true contact (spacing / speed) under `MERGE_S`, the kink bank's
  longest scale (80 ms: the two onsets share a hinge's reach, and a candidate within its
  reach of an earlier contact is that contact again); *weak* the pulse's own
  matched-filter SNR (`pulse_snr`) under `contact_truth.DETECTABLE_SNR` (5); *blunt
  kink* a pulse that strong whose kink on the noise-free signal (`clean_kink_z`) stays
  under the kink bank's threshold (a slow rise, longer than its scales, or a pulse on
  a bend); else *other* (a clean kink over the threshold, yet missed: the detector's
  own rules), by the detector's why;
- its cost, by the silence bound's logic: the updates silent past due with the found
  contacts (known at their true times) that are not with all of them; each is charged to
  the latest true contact by then (a miss: telling it alone keeps the flag there). Of
  those, the ones the default decoder (3-sample chunks; a loop case with its grip
  commands) had the flag down in. Counted through `slip_reporting.score` (slip dropped's
  own scored updates), so the pooled line reads in points of the dropped figure.
  *told late*: updates silent when the found contacts are known only when told.

`clean_kink_z`: the noise-free recorded signal (the recording less its white noise and
drift, rebuilt from the case's seed: `noise.WhiteNoise` and `noise.Drift` draw from their
own streams) through a hinge - least-squares slope over the w after minus over the w
before, each of the kink bank's scales - divided by that hinge's white-noise std; the
largest within 20 ms of the contact. What the kink bank's z would read without noise:
the pulse's size in noise units after hysteresis, merging and the level's own bends.

Run: `.venv/bin/python benchmarks/missed_ridges.py --seeds 2 --workers 1 [--kinds a,b]`.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import plan_cases
from plan_cases import pct_cell

from grasplink.decoding.contacts import DEFAULT_SCALES_S, HingeSettings
from grasplink.decoding.detector.hinges import hinge_widths
from grasplink.decoding.registry import DEFAULT_DECODER
from grasplink.evaluation import contact_truth as ct
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import silence_bound as sb
from grasplink.evaluation import slip_reporting as sr
from grasplink.simulators import harness, synth
from grasplink.simulators.effects import noise

OFF_S = 0.05  # a miss told this near (but over MATCH_S off) was told, misplaced
WINDOW_S = (-0.01, 0.05)  # around a contact: where its pulse rises (rail, lost samples)
GRIP_MOVE_N = 0.1  # a grip change: the grip moved more than this over +-GRIP_SPAN_S
GRIP_SPAN_S = 0.1
MERGE_S = max(DEFAULT_SCALES_S)  # a pulse this soon after the previous one: within its reach
HELD_MIN_S = 0.01  # ... for longer than this: a kink that shows late if at all
HELD_N = 1e-6  # the noise-free force held (hysteresis' play operator) while it moves less
RISE_LOOK_S = 0.3  # a pulse's rise: the noise-free force's highest over this (or until the next)
OFF = "told off"
RAIL = "rail"
LOST = "samples lost"
GRIP = "grip change"
FIRST = "first ridge"
HELD = "hysteresis-held"
MERGED = "merged"
WEAK = "weak"
BLUNT = "blunt kink"
OTHER = "other"
LATE = "told late"
CAUSES = (OFF, RAIL, LOST, GRIP, FIRST, HELD, MERGED, WEAK, BLUNT, OTHER)
KINDS = tuple(k for k in sr.MOVING if k != "snr10")


def added_noise_n(case: sr.Case, truth: synth.SkinRecording) -> np.ndarray:
    """The white noise and drift the case's recording added (every sample), rebuilt from
    its seed: both draw from their own stream (`Context.rng`), whatever else runs. Every
    kind but snr10 adds the thesis-like 0.02 N white noise and 0.05 N drift at 0.3 Hz
    (`synth` defaults; the loop's `contact_truth.loop_recording` the same)."""
    if case.kind in ("snr10", "held-noise"):
        raise ValueError("missed_ridges: snr10's noise is not rebuilt here")
    ctx = harness.context(seed=case.seed, rate_hz=truth.fs_hz, layout_mm=tuple(truth.layout_mm))
    effects = [
        harness.make(noise.WhiteNoise, ctx, std=synth.NOISE_WHITE_N),
        harness.make(noise.Drift, ctx, std=synth.NOISE_DRIFT_N, corner_hz=synth.DRIFT_CORNER_HZ),
    ]
    times_us = harness.sample_times_us(truth.fs_hz, len(truth.t_s) / truth.fs_hz)
    out = harness.run(effects, times_us, {"skin.force_n": np.zeros(len(times_us))}, chunk=4096)
    return np.asarray(out["skin.force_n"], dtype=float)


def hinge_taps(width: int, fs_hz: float) -> np.ndarray:
    """The hinge at `width` samples as FIR taps over the 2 w + 1 samples around a centre:
    least-squares slope (N/s) over the w + 1 after minus over the w + 1 before."""
    k = np.arange(width + 1) - width / 2.0
    slope = k / np.sum(k**2) * fs_hz  # taps of the slope over w + 1 samples
    taps = np.zeros(2 * width + 1)
    taps[width:] += slope
    taps[: width + 1] -= slope
    return taps


def clean_kink_z(
    clean_n: np.ndarray, fs_hz: float, contact_s: np.ndarray, white_n: float
) -> np.ndarray:
    """Per contact: the largest hinge on the noise-free signal within `MATCH_S` of it, in
    that hinge's white-noise std, over the kink bank's scales (module doc)."""
    n = len(clean_n)
    best = np.zeros(len(contact_s))
    reach = round(ct.MATCH_S * fs_hz)
    for width in hinge_widths(fs_hz, HingeSettings()):
        if 2 * width + 1 > n:
            continue
        taps = hinge_taps(width, fs_hz)
        h = np.convolve(clean_n, taps[::-1], mode="valid")  # h[i]: centre i + width
        z = h / (white_n * np.linalg.norm(taps))
        for i, c in enumerate(contact_s):
            centre = round(c * fs_hz)
            lo, hi = max(0, centre - reach - width), min(len(z), centre + reach - width + 1)
            if hi > lo:
                best[i] = max(best[i], float(z[lo:hi].max()))
    return best


def pulse_snr(case: sr.Case, truth: synth.SkinRecording) -> np.ndarray:
    """Per true contact: its pulse's own matched-filter SNR against the white noise, a
    previous tail's bend unknown (`contact_truth.ideal_snr`, background 2) - the pulse's
    size in noise units before hysteresis and the rail; nan where the case's pulses are
    not rebuilt (`contact_truth.pulse_train`)."""
    try:
        train = ct.pulse_train(truth, case.seed)
    except ValueError:
        return np.full(len(truth.contact_times_s), np.nan)
    return ct.ideal_snr(train, truth.t_s, synth.NOISE_WHITE_N, background=2)


def own_told_offset_s(contact_s: np.ndarray, told_s: np.ndarray) -> np.ndarray:
    """Per true contact: the signed time to the nearest told contact among those nearer to
    it than to any other true contact (nan: none) - a miss told too far off to match."""
    contact_s, told_s = np.asarray(contact_s, dtype=float), np.asarray(told_s, dtype=float)
    out = np.full(len(contact_s), np.nan)
    if not len(contact_s) or not len(told_s):
        return out
    owner = np.argmin(np.abs(told_s[:, None] - contact_s[None, :]), axis=1)
    for i, c in enumerate(contact_s):
        mine = told_s[owner == i] - c
        if len(mine):
            out[i] = mine[np.argmin(np.abs(mine))]
    return out


def contact_facts(
    case: sr.Case, rec: ns.Recorded, z: np.ndarray, clean_n: np.ndarray
) -> list[dict]:
    """Per true contact what `cause` reads: the noise-free force on the rail in `WINDOW_S`
    (saturation), a sample lost there, the grip's move over +-`GRIP_SPAN_S`, the time
    since the previous contact of its motion run (None: the run's first), the clean z."""
    truth = rec.truth
    t = truth.t_s
    contacts = np.asarray(truth.contact_times_s, dtype=float)
    runs = ns.motion(truth).runs
    kept = np.zeros(len(t), bool)
    kept[np.clip(np.round(np.asarray(rec.t_s) * truth.fs_hz).astype(int), 0, len(t) - 1)] = True
    saturates = case.kind == "saturation"
    out = []
    for i, c in enumerate(contacts):
        w = (t >= c + WINDOW_S[0]) & (t <= c + WINDOW_S[1])
        grip = np.interp([c - GRIP_SPAN_S, c + GRIP_SPAN_S], t, truth.grip_n)
        run = next(((a, b) for a, b, _ in runs if a <= c < b), None)
        previous = contacts[:i][contacts[:i] >= run[0]] if run else contacts[:i]
        k = int(np.searchsorted(t, c))
        end = len(t) if i + 1 == len(contacts) else int(np.searchsorted(t, contacts[i + 1]))
        end = min(end, k + round(RISE_LOOK_S * truth.fs_hz))
        after = clean_n[k:end] - clean_n[k] if end > k else np.zeros(1)
        moved = np.flatnonzero(np.abs(after) > HELD_N)
        out.append(
            {
                "held_s": float(moved[0] if len(moved) else len(after)) / truth.fs_hz,
                "rise_n": float(after.max()),
                "speed_mm_s": float(np.abs(np.interp(c, t, truth.speed_mm_s))),
                "rail": bool(saturates and (truth.force_n[w] >= ns.FULL_SCALE_N - 1e-9).any()),
                "lost": bool(not kept[w].all()),
                "grip_n": float(abs(grip[1] - grip[0])),
                "gap_s": float(c - previous[-1]) if len(previous) else None,
                "z": float(z[i]),
            }
        )
    return out


def cause(facts: dict, threshold: float) -> str:
    """A missed contact's cause: the first rule of the module doc that holds."""
    if abs(facts["off_s"]) <= OFF_S:
        return OFF
    if facts["rail"]:
        return RAIL
    if facts["lost"]:
        return LOST
    if facts["grip_n"] > GRIP_MOVE_N:
        return GRIP
    if facts["gap_s"] is None:
        return FIRST
    if facts["held_s"] > HELD_MIN_S:
        return HELD
    if facts["gap_s"] < MERGE_S:
        return MERGED
    if facts["snr"] < ct.DETECTABLE_SNR:
        return WEAK
    return BLUNT if facts["z"] < threshold else OTHER


def job(case: sr.Case) -> dict:
    """One case: per true contact found or not, how late, its facts and - a miss - the
    silent-past-due updates charged to it (and of those the decoder dropped)."""
    rec = case.make()
    truth = rec.truth
    fs = rec.fs_hz
    contacts = np.asarray(truth.contact_times_s, dtype=float)
    by = ct.by_contact(truth, rec.t_s, rec.force_n, fs)
    found = np.asarray(by.found, bool)
    told = ct.detect(np.asarray(rec.t_s), np.asarray(rec.force_n), fs)
    told_s = np.array([e.t_s for e in told.contacts])
    emit_s = np.array([rec.t_s[e.emit_index] for e in told.contacts])
    known_s = contacts.copy()  # found: when the nearest contact was told
    for i in np.flatnonzero(found):
        known_s[i] = max(contacts[i], emit_s[int(np.argmin(np.abs(told_s - contacts[i])))])
    clean = truth.force_n - added_noise_n(case, truth)
    z = clean_kink_z(clean, fs, contacts, synth.NOISE_WHITE_N)
    facts = contact_facts(case, rec, z, clean)
    offsets = own_told_offset_s(contacts, told_s)
    for f, snr, off in zip(facts, pulse_snr(case, truth), offsets, strict=True):
        f["snr"] = float(snr)
        f["off_s"] = float(off)

    decoder = sr.build_decoder(DEFAULT_DECODER, truth.layout_mm, fs, {})
    sr.tell_grip_commands(decoder, case)
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    t = np.array([e.t_s for e in estimates])
    flag = np.array([e.slip for e in estimates])
    mine = sr.score(estimates, truth)
    due = sb.stop_due_s(truth, contacts)

    def count(mask: np.ndarray) -> int:
        return sb.dropped_where(t, mask, truth)[0] if mask.any() else 0

    every = sb.silent_down(t, contacts, contacts, due)
    on_found = sb.silent_down(t, contacts[found], contacts[found], due[found])
    when_told = sb.silent_down(t, contacts[found], known_s[found], due[found])
    by_miss = on_found & ~every
    late = when_told & ~on_found
    j = sb.last_known(t, contacts, contacts)
    for i, f in enumerate(facts):
        mask = by_miss & (j == i)
        f.update(
            found=bool(found[i]),
            late_s=float(known_s[i] - contacts[i]) if found[i] else None,
            why=by.why[i],
            cost=[count(mask), count(mask & ~flag)],
        )
    return {
        "kind": case.kind,
        "case": f"{case.variant} {case.layout}{' rev' if case.reverse else ''} {case.seed}",
        "scored": mine.moving_from2,
        "decoder": mine.dropped_from2,
        "every": count(every),
        "found_bound": count(on_found),
        "told_bound": count(when_told),
        "decoder_in_bound": count(when_told & ~flag),
        "late": [count(late), count(late & ~flag)],
        "contacts": facts,
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2, help="seeds of the full plan (1-3)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--kinds", default="", help="comma-separated moving kinds (no snr10)")
    parser.add_argument("--save", default="", help="write the per-contact rows (JSON) here")
    parser.add_argument("--load", default="", help="report rows saved by --save (no run)")
    args = parser.parse_args(argv)
    if args.load:
        saved = json.loads(Path(args.load).read_text())
        print(saved["title"])
        report(saved["rows"])
        return 0
    kinds_text = args.kinds or ",".join(KINDS)
    todo = plan_cases.full_plan_cases(parser, kinds_text, args.seeds, allowed=KINDS)
    started = time.monotonic()
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(job, todo, chunksize=2))
    title = plan_cases.run_title(
        todo, args.seeds, kinds_text.split(","), args.workers, time.monotonic() - started
    )
    if args.save:
        Path(args.save).write_text(json.dumps({"title": title, "rows": rows}))
    print(title)
    report(rows)
    return 0


def report(rows: list[dict]) -> None:
    threshold = HingeSettings().threshold
    groups: dict[str, list[dict]] = {k: [] for k in KINDS}
    for r in rows:
        for f in r["contacts"]:
            f["cause"] = None if f["found"] else cause(f, threshold)
        groups[r["kind"]].append(r)
    groups = {k: rs for k, rs in groups.items() if rs}
    groups["pooled"] = list(rows)

    def total(rs: list[dict], key: str) -> int:
        return sum(r[key] for r in rs)

    print()
    print(
        "| kind | scored updates | decoder dropped % | bound: all told % | found, at true"
        " times % | found, when told % | decoder down in that % of it | contacts | missed %"
        " | told late median / p90 ms |"
    )
    print("|---|" + "---:|" * 9)
    for key, rs in groups.items():
        scored = total(rs, "scored")
        told = total(rs, "told_bound")
        facts = [f for r in rs for f in r["contacts"]]
        lates = np.array([f["late_s"] for f in facts if f["found"]]) * 1e3
        missed = sum(1 for f in facts if not f["found"])
        late = f"{np.median(lates):.0f} / {np.percentile(lates, 90):.0f}" if len(lates) else "-"
        cells = [
            key,
            str(scored),
            pct_cell(total(rs, "decoder"), scored),
            pct_cell(total(rs, "every"), scored),
            pct_cell(total(rs, "found_bound"), scored),
            pct_cell(told, scored),
            pct_cell(total(rs, "decoder_in_bound"), told),
            str(len(facts)),
            pct_cell(missed, len(facts)),
            late,
        ]
        print("| " + " | ".join(cells) + " |")
    print()
    print(
        "Per kind x cause: missed contacts, speed, pulse SNR, clean kink z, the detector why,"
        " the silent-past-due updates charged to them and of those the decoder dropped (both"
        " % of the kind's scored updates: points of its slip dropped)"
    )
    print(
        "| kind | cause | missed | speed median mm/s | pulse SNR median | clean z median |"
        " detector why | silent % | decoder dropped % |"
    )
    print("|---|---|---:|---:|---:|---:|---|---:|---:|")
    for key, rs in groups.items():
        scored = total(rs, "scored")
        facts = [f for r in rs for f in r["contacts"]]
        for c in CAUSES:
            mine = [f for f in facts if f["cause"] == c]
            if not mine:
                continue
            whys: dict[str, int] = defaultdict(int)
            for f in mine:
                whys[f["why"]] += 1
            cells = [
                key,
                c,
                str(len(mine)),
                f"{np.median([f['speed_mm_s'] for f in mine]):.0f}",
                f"{np.nanmedian([f['snr'] for f in mine]):.1f}",
                f"{np.median([f['z'] for f in mine]):.1f}",
                ", ".join(f"{k} {v}" for k, v in sorted(whys.items())),
                pct_cell(sum(f["cost"][0] for f in mine), scored),
                pct_cell(sum(f["cost"][1] for f in mine), scored),
            ]
            print("| " + " | ".join(cells) + " |")
        late = np.sum([r["late"] for r in rs], axis=0)
        print(
            f"| {key} | {LATE} | - | - | - | - | - | {pct_cell(late[0], scored)} |"
            f" {pct_cell(late[1], scored)} |"
        )
    print()
    print(
        "Compact (docs/decoding.md): per kind x cause, missed contacts / silent % / decoder"
        " dropped % (both of the kind's scored updates)"
    )
    print("| kind | " + " | ".join((*CAUSES, LATE)) + " |")
    print("|---|" + "---:|" * (len(CAUSES) + 1))
    for key, rs in groups.items():
        scored = total(rs, "scored")
        facts = [f for r in rs for f in r["contacts"]]
        cells = [key]
        for c in CAUSES:
            mine = [f for f in facts if f["cause"] == c]
            silent = sum(f["cost"][0] for f in mine)
            dropped = sum(f["cost"][1] for f in mine)
            cells.append(
                f"{len(mine)} / {pct_cell(silent, scored)} / {pct_cell(dropped, scored)}"
                if mine
                else "-"
            )
        late = np.sum([r["late"] for r in rs], axis=0)
        cells.append(f"{pct_cell(late[0], scored)} / {pct_cell(late[1], scored)}")
        print("| " + " | ".join(cells) + " |")
    facts = [f for r in rows for f in r["contacts"]]
    held = [f for f in facts if f["cause"] == HELD]
    if held:
        white = synth.NOISE_WHITE_N
        shows = sum(1 for f in held if f["rise_n"] >= threshold * white)
        print()
        flat_ms = np.median([f["held_s"] for f in held]) * 1e3
        print(
            f"{HELD}: {len(held)} misses, held flat {flat_ms:.0f}"
            f" ms (median); their pulse rises through the band by >= {threshold:g} white-noise"
            f" units later in {shows} ({pct_cell(shows, len(held))} %), median rise"
            f" {np.median([f['rise_n'] for f in held]) / white:.1f} units"
        )
    zs = np.array([f["z"] for f in facts if f["found"]])
    zm = np.array([f["z"] for f in facts if not f["found"]])
    if len(zs) and len(zm):
        print()
        print(
            f"Clean kink z (threshold {threshold:g}): found contacts median"
            f" {np.median(zs):.1f} (under the threshold {pct_cell((zs < threshold).sum(), len(zs))}"
            f" %), missed median {np.median(zm):.1f} (under"
            f" {pct_cell((zm < threshold).sum(), len(zm))} %)"
        )
    snr_found = np.array([f["snr"] for f in facts if f["found"]])
    snr_missed = np.array([f["snr"] for f in facts if not f["found"]])
    if len(snr_found) and len(snr_missed):
        level = ct.DETECTABLE_SNR
        print(
            f"Pulse SNR (detectable from {level:g}): found median {np.nanmedian(snr_found):.1f}"
            f" (under {pct_cell((snr_found < level).sum(), len(snr_found))} %), missed median"
            f" {np.nanmedian(snr_missed):.1f} (under"
            f" {pct_cell((snr_missed < level).sum(), len(snr_missed))} %)"
        )
    cost = [(sum(f["cost"][0] for f in r["contacts"]), r) for r in rows]
    print("Costliest cases (silent updates charged to misses / of those decoder-dropped):")
    for n, r in sorted(cost, key=lambda x: -x[0])[:12]:
        print(
            f"  {r['kind']} {r['case']}: {n} / {sum(f['cost'][1] for f in r['contacts'])}; "
            + ", ".join(
                f"{f['cause']} snr {f['snr']:.1f} z {f['z']:.1f} {f['cost'][0]}"
                for f in r["contacts"]
                if f["cost"][0]
            )
        )


if __name__ == "__main__":
    raise SystemExit(main())

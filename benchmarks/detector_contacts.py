"""The contact detector against the simulator's truth (issue 22): first verdicts on the
headline loop's rising level, detection at 10 dB SNR, and the detector's cost.

1. Headline (`contact_truth.headline_replica`, seeds 1-12): the ridge contacts found
   mid-slip (after the first, 0.15 s or more before the stop) and how many are told a
   pulse at their first verdict; the stop's first verdict.
2. 10 dB SNR (`nonstationary` category "snr10", every signal: all layouts, both
   directions, both seeds): true ridge crossings found within +-20 ms, false contacts,
   timing error, per variant and in all.
3. Cost: µs per sample over 60 s fed 3 samples at a time, with and without the pulse
   probe, of a clean slip and rest and of a 10 dB SNR slip (wall time, best of 3: figures
   to compare within one run, not a target).

4. By spacing (`--spacings`): true ridge contacts found within +-20 ms by the spacing
   crossed BEFORE the contact and by speed band, and why the others were missed (the
   same contact again, under the threshold, no kink: `contact_truth.by_contact`), on
   constant-speed slips (`synth.slip_recording`: every layout, 8-120 mm/s, both
   directions, seeds 1-2, thesis-like noise) and on slip_reporting's constant, stop and
   stick-slip cases (every layout, both directions, one seed). The tracker's P_DETECT
   model reads this table.

5. With `--decoder`: the default decoder's speed missing (from each run's 3rd contact,
   `slip_reporting.score`) on the snr10 signals, with and without the pulse probe.

6. The ceiling at 10 dB SNR (`--snr-ceiling`, alone): on slip_reporting's snr10 cases
   (the full plan's: every layout, both directions, 3 seeds) each true ridge contact's own
   rise (the simulator's pulse rebuilt, `contact_truth.pulse_train`: from the previous
   pulse's tail to its alpha) in white-noise units, and its matched-filter SNR with the
   pulse's shape and time known and a linear (or quadratic) background unknown
   (`contact_truth.ideal_snr`) - detectable at `DETECTABLE_SNR` or more - by layout and by
   the spacing before, beside what the detector finds now; and of the slipping updates
   from each run's 3rd contact, the share with 2 detectable contacts before them in the
   run (an upper bound for "speed given") and among the run's last 3 contacts.
   `--ceiling KIND` does the same on another kind's cases (their own white noise; the
   loop kind's hysteresis is not in the rebuilt pulses, so its ceiling is an upper bound),
   with the default decoder's speed missing beside it: over all those updates, and over
   those with 2 detectable contacts among the run's last 3 (what the contacts determine).

Run: `.venv/bin/python benchmarks/detector_contacts.py [--skip-snr] [--decoder]
[--spacings [--only-spacings] [--json FILE]] [--snr-ceiling | --ceiling KIND]`.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from grasplink.decoding.contacts import (
    PULSE_SCALES_S,
    ContactDetector,
    DetectorSettings,
    PulseProbeSettings,
)
from grasplink.decoding.registry import DEFAULT_DECODER
from grasplink.evaluation import contact_truth as ct
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
from grasplink.evaluation.contact_truth import (
    HEADLINE_STOP_S,
    LOOP_WHITE_N,
    MATCH_S,
    detect,
    headline_replica,
    match,
)
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth


def _pulse_scales(scales: tuple[float, ...]) -> DetectorSettings:
    """The shipped detector with the pulse probe's windows `scales` (none: off)."""
    return DetectorSettings(pulses=PulseProbeSettings(scales_s=scales))


def headline() -> None:
    found = pulses = steps = stop_steps = 0
    for seed in range(1, 13):
        rec = headline_replica(seed)
        told = detect(rec.t_s, rec.force_n, rec.fs_hz)
        for crossing in rec.contact_times_s:
            if not 1.3 < crossing < HEADLINE_STOP_S - 0.15:
                continue
            near = [e for e in told.contacts if abs(e.t_s - crossing) <= MATCH_S]
            if near:
                found += 1
                verdict = told.first_verdict.get(near[0].id)
                pulses += verdict is not None and verdict.pulse is True
                steps += verdict is not None and verdict.pulse is False
        stop = [e for e in told.contacts if abs(e.t_s - HEADLINE_STOP_S) <= 0.01]
        if stop:
            verdict = told.first_verdict.get(stop[0].id)
            stop_steps += verdict is not None and verdict.pulse is False
    print("headline replica, 12 seeds:")
    print(f"  mid-slip ridge contacts found {found}: first verdict pulse {pulses}, step {steps}")
    print(f"  stop told a step at its first verdict: {stop_steps} of 12")


def snr10() -> None:
    by_variant: dict[str, list] = defaultdict(lambda: [0, 0, 0, []])
    for signal in ns.signals(False):
        if signal.category != "snr10":
            continue
        rec = signal.make()
        told = detect(rec.t_s, rec.force_n, rec.fs_hz, chunk=256)  # (chunking changes nothing)
        m = match(rec.truth.contact_times_s, told)
        for key in (f"{signal.variant} {signal.layout}", f"every speed {signal.layout}", "all"):
            row = by_variant[key]
            row[0] += m.true_count
            row[1] += m.found
            row[2] += m.false
            row[3] += list(m.errors_s)
    print(f"10 dB SNR (snr10, every signal), found within +-{MATCH_S * 1e3:.0f} ms:")
    for key, (true, found, false, errors) in by_variant.items():
        err = np.abs(np.array(errors)) * 1e3
        timing = f"|error| median {np.median(err):.1f} ms, p90 {np.percentile(err, 90):.1f}"
        print(
            f"  {key:28s} true {true:4d}  found {found:4d} ({found / true:5.1%})  "
            f"false {false:3d}  {timing if len(err) else ''}"
        )


SPACING_SPEEDS_MM_S = (8, 12, 20, 35, 60, 90, 120)
SPACING_SEEDS = (1, 2)
REASONS = (ct.AGAIN, ct.UNDER, ct.NO_KINK)


def spacing_signals() -> list[tuple[str, ns.Recorded]]:
    """(set name, signal): constant slips of every layout 8-120 mm/s both ways, seeds 1-2;
    slip_reporting's constant, stop and stick-slip cases (every layout, both ways, 1 seed)."""
    out = []
    for layout in LAYOUTS_MM.values():
        for v in SPACING_SPEEDS_MM_S:
            for reverse in (False, True):
                for seed in SPACING_SEEDS:
                    rec = synth.slip_recording(layout, float(v), reverse=reverse, seed=seed)
                    out.append(("constant 8-120", ns.Recorded(rec, rec.t_s, rec.force_n, 400)))
    plan = sr.Plan(
        name="spacings",
        layouts=tuple(LAYOUTS_MM),
        seeds=1,
        variants={k: tuple(range(len(sr.VARIANTS[k]))) for k in ("constant", "stop", "stick-slip")},
        sweep_layouts=(),
        sweep_variants={},
        sweeps=(),
        sweep_values=None,
        cost_cases=0,
        headline=False,
    )
    out += [(f"slip_reporting {case.kind}", case.make()) for case in sr.cases(plan)]
    return out


def spacings(json_path: str | None = None) -> dict:
    """Found share by the spacing before each true ridge contact (see the module doc)."""
    rows: dict[str, dict[str, list[int]]] = defaultdict(lambda: defaultdict(lambda: [0, 0]))
    why: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    false: dict[str, int] = defaultdict(int)
    kinks: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    for set_name, rec in spacing_signals():
        told = ct.by_contact(rec.truth, rec.t_s, rec.force_n, rec.fs_hz)
        false[set_name] += told.false
        for kink, hit in zip(ct.onset_kinks_met(rec.truth), told.found, strict=True):
            cell = kinks[kink_label(kink)]
            cell[0] += 1
            cell[1] += hit
        for d, band, hit, reason in zip(told.spacing, told.band, told.found, told.why, strict=True):
            for key in ("all", set_name, band):
                rows[d][key][0] += 1
                rows[d][key][1] += hit
            if reason is not None:
                why[d][reason] += 1
    order = sorted(
        rows, key=lambda d: (d == ct.FIRST, float(d.rstrip("+")) if d != ct.FIRST else 0.0)
    )
    bands = [ct.speed_band(lo) for lo, _ in ct.SPEED_BANDS_MM_S]
    sets = sorted({k for d in rows for k in rows[d] if k != "all" and k not in bands})
    print("Ridge contacts found within +-20 ms by the spacing before them (mm):")
    head = ["spacing", "true", "found", *bands, *sets, *REASONS]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))

    def share(cell: list[int]) -> str:
        return f"{cell[1] / cell[0]:.0%} ({cell[0]})" if cell[0] else "-"

    for d in order:
        cells = rows[d]
        total, hit = cells["all"]
        line = [d, str(total), f"{hit / total:.1%}"]
        line += [share(cells[b]) for b in bands] + [share(cells[k]) for k in sets]
        line += [str(why[d][r]) for r in REASONS]
        print("| " + " | ".join(line) + " |")
    told = ", ".join(f"{k} {v}" for k, v in sorted(false.items()))
    print(f"False contacts (within +-20 ms of no true ridge contact): {told}")
    print("\nThe same contacts by the kink at their onset (`ridge_pulses.onset_kinks`, the")
    print("tracker's detection model `DETECT_KINKS`; the first ridge met: kink 1):")
    print("| kink | true | found |")
    print("|---|---:|---:|")
    for label in sorted(kinks, key=lambda k: float(k.split(" ")[0])):
        total, hit = kinks[label]
        print(f"| {label} | {total} | {hit / total:.1%} |")
    figures = {d: {k: list(v) for k, v in rows[d].items()} for d in order}
    result = {
        "found": figures,
        "why": {d: dict(why[d]) for d in order},
        "false": dict(false),
        "kinks": {k: list(v) for k, v in kinks.items()},
    }
    if json_path:
        Path(json_path).write_text(json.dumps(result, indent=1))
    return result


KINK_EDGES = (0.0, 0.03, 0.08, 0.13, 0.2, 0.27, 0.35, 0.5, 0.75, 0.999)


def kink_label(kink: float) -> str:
    """A kink's row label: the band of `KINK_EDGES` it falls in ("0.08 - 0.13")."""
    edges = (-math.inf, *KINK_EDGES, math.inf)
    i = int(np.searchsorted(edges, kink, side="right")) - 1
    lo, hi = edges[i], edges[i + 1]
    return f"{lo:.3g} - {hi:.3g}"


def decoder_snr10() -> None:
    """The default decoder on the same snr10 signals, with and without the pulse probe:
    speed missing from each run's 3rd ridge contact (`slip_reporting.score`)."""
    from grasplink.evaluation import slip_reporting as sr

    rows: dict[tuple[str, str], list[int]] = defaultdict(lambda: [0, 0])
    for signal in ns.signals(False):
        if signal.category != "snr10":
            continue
        rec = signal.make()
        for label, scales in (("pulse probe", PULSE_SCALES_S), ("without", ())):
            detector = ContactDetector(rec.fs_hz, _pulse_scales(scales))
            decoding = sr.build_decoder(
                DEFAULT_DECODER, rec.truth.layout_mm, rec.fs_hz, {"detector": detector}
            )
            estimates, _ = ns.feed(decoding, rec.t_s, rec.force_n, sr.CHUNK)
            scored = sr.score(estimates, rec.truth)
            for key in (signal.layout, "all"):
                rows[(key, label)][0] += scored.moving_from3
                rows[(key, label)][1] += scored.missing_from3
    print(f"10 dB SNR, {DEFAULT_DECODER} decoder: speed missing from the 3rd contact")
    for (key, label), (moving, missing) in sorted(rows.items()):
        print(f"  {key:10s} {label:12s} {missing:5d} of {moving:5d} ({missing / moving:5.1%})")


def ceiling_cases(kind: str = "snr10") -> list:
    """slip_reporting's cases of one kind in the full plan (the targets are judged on)."""
    return [c for c in sr.cases(sr.FULL) if c.kind == kind]


def white_noise_n(kind: str, layout_mm) -> float:
    """The white noise of a kind's signals (N): 10 dB under the median pulse for snr10,
    the closed-loop scenes' 0.02 N for loop, `synth.NOISE_WHITE_N` for the others."""
    if kind == "snr10":
        return ns.pulse_height_n(layout_mm) / 10 ** (ns.SNR_DB / 20)
    return LOOP_WHITE_N if kind == "loop" else synth.NOISE_WHITE_N


def snr_ceiling(kind: str = "snr10") -> None:
    """The detection ceiling on one kind's signals (see the module doc, 6)."""
    rows: dict[str, list[list[float]]] = defaultdict(list)
    updates: dict[str, list[int]] = defaultdict(lambda: [0, 0, 0, 0, 0, 0])
    todo = ceiling_cases(kind)
    for case in todo:
        rec = case.make()
        truth = rec.truth
        white = white_noise_n(kind, truth.layout_mm)
        train = ct.pulse_train(truth, case.seed)
        snr = ct.ideal_snr(train, truth.t_s, white)
        snr2 = ct.ideal_snr(train, truth.t_s, white, background=2)
        found = ct.by_contact(truth, rec.t_s, rec.force_n, rec.fs_hz).found
        spacing = [ct.spacing_label(d) for d in ct.spacings_before_mm(truth)]
        for i in range(len(train.times_s)):
            cell = [train.step_n[i] / white, snr[i], snr2[i], float(found[i])]
            for key in (case.layout, f"spacing {spacing[i]}", "all"):
                rows[key].append(cell)
        # the default decoder's updates, scored as slip_reporting scores them
        decoder = sr.build_decoder(DEFAULT_DECODER, truth.layout_mm, rec.fs_hz, {})
        estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
        t_upd = np.array([e.t_s for e in estimates])
        speed = np.array([0.0 if e.speed_mm_s is None else abs(e.speed_mm_s) for e in estimates])
        moving = np.abs(np.interp(t_upd, truth.t_s, truth.speed_mm_s)) >= sr.V_MOVING_MM_S
        edge = np.interp(t_upd, truth.t_s, truth.position_mm)
        skin = sr.ridges_mm(truth.layout_mm)
        ok = (snr >= ct.DETECTABLE_SNR) & (train.step_n > 0)  # it rises, and clearly
        for start, end, sign in ns.motion(truth).runs:
            mine = np.flatnonzero((train.times_s >= start) & (train.times_s < end))
            if len(mine) < 3:
                continue
            beyond = (edge >= skin[-1]) if sign > 0 else (edge <= skin[0])
            scored = moving & ~beyond & (t_upd >= train.times_s[mine[2]]) & (t_upd < end)
            for t, v in zip(t_upd[scored], speed[scored], strict=True):
                before = mine[train.times_s[mine] <= t]
                any2 = int(ok[before].sum()) >= 2
                last2 = int(ok[before[-3:]].sum()) >= 2
                now = int(np.asarray(found)[before].sum()) >= 2
                for key in (case.layout, "all"):
                    cell = updates[key]
                    cell[0] += 1
                    cell[1] += any2
                    cell[2] += last2
                    cell[3] += now
                    cell[4] += v <= 0  # speed missing (slip_reporting's missing from 3rd)
                    cell[5] += last2 and v <= 0
    print(
        f"Detection ceiling, slip_reporting's {kind} cases ({len(todo)}, white noise "
        f"{'10 dB under the pulse' if kind == 'snr10' else f'{white_noise_n(kind, ()):g} N'}): "
        f"detectable = matched-filter SNR >= {ct.DETECTABLE_SNR:g}"
        + (" (hysteresis not modelled: an upper bound)" if kind == "loop" else "")
    )
    head = [
        "set",
        "contacts",
        "rise/sigma median",
        "SNR median",
        "SNR >= 4",
        "SNR >= 5",
        "SNR >= 5 (quadratic bg)",
        "rises, SNR >= 5",
        "found now",
    ]
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    order = sorted(rows, key=lambda k: (k == "all", k.startswith("spacing"), _spacing_key(k)))
    for key in order:
        a = np.array(rows[key])
        line = [
            key,
            str(len(a)),
            f"{np.median(a[:, 0]):.1f}",
            f"{np.median(a[:, 1]):.1f}",
            f"{np.mean(a[:, 1] >= 4):.0%}",
            f"{np.mean(a[:, 1] >= 5):.0%}",
            f"{np.mean(a[:, 2] >= 5):.0%}",
            f"{np.mean((a[:, 1] >= 5) & (a[:, 0] > 0)):.0%}",
            f"{np.mean(a[:, 3]):.0%}",
        ]
        print("| " + " | ".join(line) + " |")
    print(
        "Scored slipping updates (from each run's 3rd contact, before the last ridge) with 2"
        " contacts detectable (rising, SNR >= 5) before them, and the default decoder's"
        " speed missing:"
    )
    print(
        "| set | updates | 2 detectable in the run | among its last 3 | 2 found now |"
        " speed missing | missing where 2 of the last 3 are detectable |"
    )
    print("|---|---|---|---|---|---|---|")
    for key in sorted(updates, key=lambda k: k == "all"):
        n, in_run, in_last3, found_now, missing, missing_det = updates[key]
        print(
            f"| {key} | {n} | {in_run / n:.0%} | {in_last3 / n:.0%} | {found_now / n:.0%} |"
            f" {missing / n:.1%} | {missing_det / max(in_last3, 1):.1%} |"
        )


def _spacing_key(key: str) -> tuple[int, float, str]:
    label = key.removeprefix("spacing ")
    if label == ct.FIRST:
        return (0, 0.0, key)
    try:
        return (1, float(label.rstrip("+")), key)
    except ValueError:
        return (2, 0.0, key)


def cost() -> None:
    """The detector with and without the pulse probe, in one run: a clean slip and rest (the
    probe's gate stays shut) and a 10 dB SNR slip (it opens)."""
    layout = LAYOUTS_MM["alpha0.1"]
    slip = synth.slip_recording(layout, 40.0, seed=3).force_n
    rest = synth.static_recording(layout, [[0.0, 5.0]], duration_s=6.0, seed=4).force_n
    noisy = next(s for s in ns.signals(True) if s.category == "snr10").make().force_n
    inputs = {
        "clean": np.resize(np.concatenate([slip, rest]), 60 * 400),
        "10 dB": np.resize(noisy, 60 * 400),
    }
    for name, x in inputs.items():
        t = np.arange(len(x)) / 400.0
        best = {"pulse probe": np.inf, "without": np.inf}
        for _ in range(3):
            for label, scales in (("pulse probe", PULSE_SCALES_S), ("without", ())):
                detector = ContactDetector(400.0, _pulse_scales(scales))
                start = time.perf_counter()
                for i in range(0, len(x), 3):
                    detector.feed(t[i : i + 3], x[i : i + 3])
                best[label] = min(best[label], time.perf_counter() - start)
        figures = ", ".join(f"{k} {1e6 * v / len(x):.1f}" for k, v in best.items())
        print(f"cost, {name}: {figures} µs/sample (60 s at 400 Hz, 3-sample chunks)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--skip-snr", action="store_true", help="no 10 dB SNR figures")
    parser.add_argument("--spacings", action="store_true", help="found by spacing before")
    parser.add_argument("--only-spacings", action="store_true", help="only that table")
    parser.add_argument("--json", help="write the spacing table's figures here")
    parser.add_argument(
        "--decoder", action="store_true", help="and the decoder's speed missing at 10 dB"
    )
    parser.add_argument(
        "--snr-ceiling", action="store_true", help="only the detection ceiling at 10 dB SNR"
    )
    parser.add_argument(
        "--ceiling",
        choices=[k for k in sr.KINDS if not k.startswith("held")],
        help="only the detection ceiling on another kind's cases",
    )
    args = parser.parse_args(argv)
    if args.snr_ceiling or args.ceiling:
        snr_ceiling(args.ceiling or "snr10")
        return 0
    if args.spacings or args.only_spacings:
        spacings(args.json)
        if args.only_spacings:
            return 0
    headline()
    if not args.skip_snr:
        snr10()
        if args.decoder:
            decoder_snr10()
    cost()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

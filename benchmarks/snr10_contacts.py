"""What the contact detector hands the tracker at 10 dB SNR (issue 22, the snr10 figure).

On slip_reporting's snr10 cases (full plan, the first `--seeds` seeds): the true ridge
crossings found within +-20 ms (`contact_truth.match`), by the part that told them (kink
bank or probes, `ContactEvent.id`: the probes' ids start at 10^9), and the contacts
near no crossing while the object slides (per s of slip) and at rest after it (per
min); on the held-noise cases (no slip at 10 dB) the contacts per held minute. The rate
of false contacts is the tracker's clutter density; the found share its detection
probability at this noise (`TrackerDecoder.DETECT_P`, `CLUTTER_PER_S`).

Run: `.venv/bin/python benchmarks/snr10_contacts.py [--seeds N] [--weak-slip-share S]`.
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from grasplink.decoding.contacts import DetectorSettings
from grasplink.decoding.detector.noise_floor import NoiseSettings
from grasplink.evaluation import contact_truth as ct
from grasplink.evaluation import slip_reporting as sr

PROBE_ID = 10**9  # the probes' contact ids start here (`detector.events.Ledger`)


def job(case: sr.Case, settings: DetectorSettings) -> dict:
    """One case's counts: true, found, false while sliding / at rest, by source."""
    rec = case.make()
    told = ct.detect(rec.t_s, rec.force_n, rec.fs_hz, settings=settings)
    truth = rec.truth
    crossings = np.asarray(truth.contact_times_s, dtype=float)
    times = np.array([e.t_s for e in told.contacts])
    probe = np.array([e.id >= PROBE_ID for e in told.contacts], dtype=bool)
    sliding = np.flatnonzero(np.asarray(truth.slipping) > 0)
    t_truth = np.asarray(truth.t_s)
    slip_from = float(t_truth[sliding[0]]) if len(sliding) else np.inf
    slip_to = float(t_truth[sliding[-1]]) if len(sliding) else np.inf
    out: dict = defaultdict(float)
    out["kind"] = case.kind
    out["layout"] = case.layout
    out["true"] = len(crossings)
    out["slide_s"] = max(0.0, slip_to - slip_from) if len(sliding) else 0.0
    out["rest_s"] = float(t_truth[-1] - t_truth[0]) - out["slide_s"]
    near = ct.near_truth(times, crossings)
    for c in crossings:
        if not len(times):
            break
        close = np.abs(times - c) <= ct.MATCH_S
        if np.any(close):
            out["found"] += 1
            j = int(np.flatnonzero(close)[np.argmin(np.abs(times[close] - c))])
            out["found_probe" if probe[j] else "found_kink"] += 1
    for t, is_near, is_probe in zip(times, near, probe, strict=True):
        if is_near:
            continue
        where = "slide" if slip_from <= t <= slip_to + ct.MATCH_S else "rest"
        out[f"false_{where}"] += 1
        out[f"false_{where}_{'probe' if is_probe else 'kink'}"] += 1
    return dict(out)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument(
        "--weak-slip-share", type=float, default=None, help="NoiseSettings.weak_slip_share"
    )
    args = parser.parse_args(argv)
    noise = NoiseSettings()
    if args.weak_slip_share is not None:
        noise = replace(noise, weak_slip_share=args.weak_slip_share)
    settings = DetectorSettings(noise=noise)
    plan = replace(sr.FULL, seeds=args.seeds)
    plan = replace(
        plan, variants={k: v for k, v in plan.variants.items() if k in ("snr10", "held-noise")}
    )
    todo = sr.cases(plan)
    with ProcessPoolExecutor(2) as pool:
        rows = list(pool.map(job, todo, [settings] * len(todo), chunksize=2))
    print(f"{len(todo)} cases (snr10 and held-noise, full plan, {args.seeds} seed(s)), {noise}")
    print(
        "| set | crossings | found % | by kink bank / probes % | false while sliding per s "
        "(kink / probe) | false at rest per min | held min |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[r["kind"] if r["kind"] == "held-noise" else f"snr10 {r['layout']}"].append(r)
        if r["kind"] == "snr10":
            groups["snr10 all"].append(r)
    for name in sorted(groups):
        g = groups[name]

        def total(key: str, g: list[dict] = g) -> float:
            return float(sum(r.get(key, 0.0) for r in g))

        true = total("true")
        slide_s, rest_min = total("slide_s"), total("rest_s") / 60.0
        found = f"{100 * total('found') / true:.0f}" if true else "-"
        split = (
            f"{100 * total('found_kink') / true:.0f} / {100 * total('found_probe') / true:.0f}"
            if true
            else "-"
        )
        slide = (
            f"{total('false_slide') / slide_s:.2f} ({total('false_slide_kink') / slide_s:.2f} / "
            f"{total('false_slide_probe') / slide_s:.2f})"
            if slide_s
            else "-"
        )
        rest = f"{total('false_rest') / rest_min:.2f}" if rest_min else "-"
        print(f"| {name} | {int(true)} | {found} | {split} | {slide} | {rest} | {rest_min:.1f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

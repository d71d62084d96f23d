"""The gated pulse probe's contacts on the snr10 signals (issue 22, 10 dB detection).

Per speed, of the forward snr10 signals' ridge crossings: how many the detector finds
(within `contact_truth.MATCH_S`) and how many contacts it tells near none, under
* `plain`: today's detector;
* `everywhere`: the gated probe open over the whole signal (a wide window everywhere:
  what s27's 50 ms window did, the gate's upper bound);
* `slide`: open from 0.2 s before the first crossing to 0.2 s after the last (an oracle
  gate: the slip's own span);
* `tracker`: open where the tracker expects contacts (`TrackerDecoder.GATE_*`, the
  shipped path): the contacts the tracker was handed.
Run: `.venv/bin/python benchmarks/snr10_gate_contacts.py --scale 0.06 [--threshold 4.5]`.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from grasplink.decoding.contacts import ContactDetector, DetectorSettings
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation.contact_truth import MATCH_S

MODES = ("plain", "everywhere", "slide", "tracker")
CHUNK = 3  # samples per feed of the tracker (as slip_reporting feeds it)


def _settings(scale: float, threshold: float) -> DetectorSettings:
    base = DetectorSettings()
    return replace(
        base, pulses=replace(base.pulses, gated_scale_s=scale, gated_threshold=threshold)
    )


def _events(signal: ns.Signal, mode: str, scale: float, threshold: float, tuning: dict):
    rec = signal.make()
    t, x = rec.t_s, rec.force_n
    if mode == "plain":
        return rec, ContactDetector(rec.fs_hz).feed(t, x)[0]
    det = ContactDetector(rec.fs_hz, _settings(scale, threshold))
    if mode == "everywhere":
        det.expect(0, len(t))
        return rec, det.feed(t, x)[0]
    if mode == "slide":
        times = rec.truth.contact_times_s
        first, last = np.searchsorted(t, [times[0] - 0.2, times[-1] + 0.2])
        det.expect(int(first), int(last))
        return rec, det.feed(t, x)[0]
    told: list = []
    feed = det.feed

    def recording(tt: np.ndarray, xx: np.ndarray):
        events, checks = feed(tt, xx)
        told.extend(events)
        return events, checks

    det.feed = recording  # type: ignore[method-assign]
    decoder = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz, detector=det, tuning=tuning)
    for i in range(0, len(t), CHUNK):
        decoder.feed(t[i : i + CHUNK], x[i : i + CHUNK])
    return rec, told


def job(args: tuple) -> tuple[str, str, int, int, int]:
    signal, mode, scale, threshold, tuning = args
    rec, events = _events(signal, mode, scale, threshold, tuning)
    times = rec.truth.contact_times_s
    onsets = np.array([e.t_s for e in events])
    found = sum(bool(np.any(np.abs(onsets - c) <= MATCH_S)) for c in times) if len(onsets) else 0
    false = sum(not np.any(np.abs(times - o) <= MATCH_S) for o in onsets)
    return signal.variant, mode, len(times), found, false


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=0.06, help="the gated window, s")
    parser.add_argument("--threshold", type=float, default=4.5, help="its threshold")
    parser.add_argument("--back", type=float, default=None, help="TrackerDecoder.GATE_BACK_S")
    parser.add_argument("--ahead", type=float, default=None, help="... GATE_AHEAD_S")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--modes", default=",".join(MODES), help="comma-separated modes")
    args = parser.parse_args(argv)
    tuning = {}
    if args.back is not None:
        tuning["GATE_BACK_S"] = args.back
    if args.ahead is not None:
        tuning["GATE_AHEAD_S"] = args.ahead
    signals = [s for s in ns.signals(False) if s.category == "snr10" and not s.reverse]
    modes = args.modes.split(",")
    unknown = set(modes) - set(MODES)
    if unknown:
        parser.error(f"unknown modes {sorted(unknown)}; known: {', '.join(MODES)}")
    todo = [(s, m, args.scale, args.threshold, tuning) for s in signals for m in modes]
    with ProcessPoolExecutor(args.workers) as pool:
        rows = list(pool.map(job, todo, chunksize=2))
    table: dict = defaultdict(lambda: [0, 0, 0])
    for variant, mode, n, found, false in rows:
        for key in ((variant, mode), ("all", mode)):
            cell = table[key]
            cell[0] += n
            cell[1] += found
            cell[2] += false
    print(f"{len(signals)} forward snr10 signals; gated window {args.scale} s at {args.threshold}")
    print("| speed | crossings | " + " | ".join(f"{m}: found / false" for m in modes) + " |")
    print("|---|---:|" + "---:|" * len(modes))
    for variant in [*dict.fromkeys(s.variant for s in signals), "all"]:
        n = table[(variant, modes[0])][0]
        cells = " | ".join(f"{table[(variant, m)][1]} / {table[(variant, m)][2]}" for m in modes)
        print(f"| {variant} | {n} | {cells} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

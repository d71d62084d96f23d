"""Tail kinks on and off, side by side in one run (issue 22: constant speed missing).

`detector.tail_kinks` gives back the kink bank's candidates its rise check dropped when
they sit on a pulse's falling tail (a ridge after a short spacing). This compares the
shipped detector with the same detector with the test off (`residual_z` 0: the rise check
alone, as before), on the same signals:

1. True ridge contacts found within +-20 ms by the kink at their onset
   (`ridge_pulses.onset_kinks`; `detector_contacts.py --spacings`' signals: constant slips
   of every layout 8-120 mm/s both ways seeds 1-2, slip_reporting's constant, stop and
   stick-slip cases), and the false contacts (no true one within 20 ms) per set.
2. Held objects: every contact and every told pulse (the tracker's slip evidence) on
   slip_reporting's held-grip and held-noise cases (full plan, 2 seeds), per held minute.

Run: `.venv/bin/python benchmarks/tail_kinks.py [--residual-z Z]`.
"""

from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from detector_contacts import kink_label, spacing_signals

from grasplink.decoding.contacts import ContactDetector, DetectorSettings, HingeSettings
from grasplink.decoding.detector.tail_kinks import ON_RESIDUAL_Z, TailKinkSettings
from grasplink.evaluation import contact_truth as ct
from grasplink.evaluation import slip_reporting as sr

HELD_SEEDS = 2


def settings(residual_z: float) -> DetectorSettings:
    return DetectorSettings(
        hinges=HingeSettings(tails=replace(TailKinkSettings(), residual_z=residual_z))
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--residual-z", type=float, default=ON_RESIDUAL_Z)
    args = parser.parse_args(argv)
    trials = {
        "off": settings(0.0),
        f"on (residual_z {args.residual_z:g})": settings(args.residual_z),
    }
    found = {k: defaultdict(lambda: [0, 0]) for k in trials}
    false = {k: defaultdict(int) for k in trials}
    for set_name, rec in spacing_signals():
        truth = rec.truth.contact_times_s
        labels = [kink_label(k) for k in ct.onset_kinks_met(rec.truth)]
        for key, chosen in trials.items():
            events, _ = ContactDetector(rec.fs_hz, chosen).feed(rec.t_s, rec.force_n)
            told = np.array([e.t_s for e in events])
            for c, label in zip(truth, labels, strict=True):
                cell = found[key][label]
                cell[0] += 1
                cell[1] += bool(len(told)) and bool(np.min(np.abs(told - c)) <= ct.MATCH_S)
            false[key][set_name] += sum(
                1 for t in told if not np.any(np.abs(truth - t) <= ct.MATCH_S)
            )
    held = {k: defaultdict(lambda: [0, 0]) for k in trials}
    minutes: dict[str, float] = defaultdict(float)
    plan = replace(
        sr.FULL,
        seeds=HELD_SEEDS,
        variants={k: v for k, v in sr.FULL.variants.items() if k in sr.HELD},
    )
    for case in sr.cases(plan):
        rec = case.make()
        minutes[case.kind] += (rec.t_s[-1] - rec.t_s[0]) / 60.0
        for key, chosen in trials.items():
            events, checks = ContactDetector(rec.fs_hz, chosen).feed(rec.t_s, rec.force_n)
            pulses = {c.id for c in checks if c.pulse is True}
            held[key][case.kind][0] += len(events)
            held[key][case.kind][1] += sum(e.id in pulses for e in events)
    labels = sorted(found["off"], key=lambda k: float(k.split(" ")[0]))
    print("True ridge contacts found within +-20 ms by the kink at their onset:")
    print("| kink | true | " + " | ".join(f"found, tails {k}" for k in trials) + " |")
    print("|---|---:|" + "---:|" * len(trials))
    for label in labels:
        total = found["off"][label][0]
        cells = " | ".join(f"{found[k][label][1] / total:.1%}" for k in trials)
        print(f"| {label} | {total} | {cells} |")
    print("\nFalse contacts (no true ridge contact within 20 ms):")
    for key in trials:
        print(f"  tails {key}: " + ", ".join(f"{s} {n}" for s, n in sorted(false[key].items())))
    print("\nHeld objects (slip_reporting's held cases, full plan, 2 seeds): per held minute")
    for key in trials:
        cells = ", ".join(
            f"{kind} ({minutes[kind]:.1f} min) contacts {c / minutes[kind]:.2f}, "
            f"told pulses {p / minutes[kind]:.2f}"
            for kind, (c, p) in sorted(held[key].items())
        )
        print(f"  tails {key}: {cells}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""One slip_reporting case under tracker settings: what each setting tells, and when.

For the full plan's case with `--seed` (the first of the plan with it), prints the
contacts the shipped detector tells (time, scale, z, near a true ridge crossing or not,
the truth's speed), then per setting (`--try` as `tune_tracker.py` takes it; the shipped
settings first) the updates with the wrong direction, the missing speeds from the 3rd
contact, and every change of the direction told. Used to trace a case a tuning run
flags (`tune_tracker_kinds.py`: rates-drops wrong direction).

Run: `.venv/bin/python benchmarks/case_direction.py --seed 130101 --try OVERDUE_LATCH=1`.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import tune_tracker

from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
from grasplink.evaluation.contact_truth import detect, near_truth


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--try", dest="tries", action="append", default=[], type=tune_tracker.parse)
    args = parser.parse_args(argv)
    found = [c for c in sr.cases(replace(sr.FULL, seeds=3)) if c.seed == args.seed]
    if not found:
        parser.error(f"no case of the full plan (3 seeds) has seed {args.seed}")
    case = found[0]
    rec = case.make()
    truth = rec.truth
    print(case)
    told = detect(rec.t_s, rec.force_n, rec.fs_hz)
    near = near_truth(np.array([e.t_s for e in told.contacts]), truth.contact_times_s)
    print("true ridge crossings (s):", np.round(truth.contact_times_s, 3).tolist())
    for event, is_near in zip(told.contacts, near.tolist(), strict=True):
        v = float(np.interp(event.t_s, truth.t_s, truth.speed_mm_s))
        print(
            f"  {event.t_s:.3f} s id {event.id} scale {event.scale_s * 1e3:.0f} ms "
            f"z {event.z:.1f} {'true' if is_near else 'false'} (truth {v:.1f} mm/s)"
        )
    for tuning in [{}, *args.tries]:
        decoder = sr.build_decoder(
            "tracker", truth.layout_mm, rec.fs_hz, tune_tracker.config(tuning)
        )
        sr.tell_grip_commands(decoder, case)
        estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
        s = sr.score(estimates, truth)
        name = ",".join(f"{k}={v}" for k, v in tuning.items()) or "shipped"
        print(
            f"{name}: wrong direction {s.wrong_direction} of {s.directed} told, "
            f"missing {s.missing_from3} of {s.moving_from3}"
        )
        before: int | None = None
        for e in estimates:
            if e.direction != before:
                v = float(np.interp(e.t_s, truth.t_s, truth.speed_mm_s))
                print(
                    f"    {e.t_s:.3f} s direction {e.direction} speed "
                    f"{'-' if e.speed_mm_s is None else f'{e.speed_mm_s:.1f}'} (truth {v:.1f})"
                )
                before = e.direction
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

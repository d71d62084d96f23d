"""Try tracker settings on the slip-reporting sets: one line of issue 22's figures each.

`slip_reporting`'s full benchmark runs every figure on every set (~4 min); this runs
its quick set (or the full one, one seed) with the shipped tracker and with each
`--try NAME=VALUE[,NAME=VALUE]` setting (`TrackerDecoder(tuning=...)`; `watch.NAME`: the
detector's `WatchSettings` field) in the same
worker pool, so a change's cost and gain are read side by side in one run.

Run: `.venv/bin/python benchmarks/tune_tracker.py --try LOG_STOP=-0.69 [--full]`.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

from grasplink.evaluation import slip_reporting as sr

COLUMNS = (
    ("missing_from3_pct", "miss%"),
    ("dropped_from2_pct", "drop%"),
    ("speed_err_median_pct", "med%"),
    ("speed_err_p90_pct", "p90%"),
    ("first_good_by_third_pct", "by3rd%"),
    ("wrong_direction_pct", "wrongdir%"),
    ("direction_told_pct", "told%"),
    ("stops_cleared_pct", "stops%"),
    ("speed_after_observable_pct", "afterobs%"),
    ("flagged_at_rest_pct", "rest%"),
)


def job(case: sr.Case, configs: dict[str, dict]) -> dict[str, sr.CaseScore]:
    """One case, made once, decoded under every setting (`slip_reporting.case_job`)."""
    return sr.case_job(case, "tracker", configs, baseline=False)["scores"]


def config(tuning: dict) -> dict:
    """A `slip_reporting.build_decoder` config from a parsed setting: tracker constants as
    the tuning, `watch.NAME` as the detector's `WatchSettings` field NAME, `tails.NAME` as
    its kink bank's `TailKinkSettings` field NAME (`detector.tail_kinks`), `pulses.NAME` as
    its pulse probe's `PulseProbeSettings` field NAME (`detector.pulse_probe`),
    `hinges.threshold` as its kink bank's threshold (noise units), `hinges.NAME` as its
    other `HingeSettings` field NAME (e.g. `merge_widths`), `noise.NAME` as its
    noise floor's `NoiseSettings` field NAME (`detector.noise_floor`), `grip_commands` 0 the
    loop cases without the grip commands their gateway would have sent."""
    watch = {k.removeprefix("watch."): v for k, v in tuning.items() if k.startswith("watch.")}
    tails = {k.removeprefix("tails."): v for k, v in tuning.items() if k.startswith("tails.")}
    pulses = {k.removeprefix("pulses."): v for k, v in tuning.items() if k.startswith("pulses.")}
    noise = {k.removeprefix("noise."): v for k, v in tuning.items() if k.startswith("noise.")}
    parts = ("watch.", "tails.", "pulses.", "hinges.", "noise.")
    tracker = {k: v for k, v in tuning.items() if not k.startswith(parts) and k != "grip_commands"}
    out: dict = {"tuning": tracker}
    if "grip_commands" in tuning:  # 0: the loop cases decoded without their grip commands
        out["grip_commands"] = bool(tuning["grip_commands"])
    if "hinges.threshold" in tuning:
        out["detector_threshold"] = tuning["hinges.threshold"]
    kinks = {
        k.removeprefix("hinges."): v
        for k, v in tuning.items()
        if k.startswith("hinges.") and k != "hinges.threshold"
    }
    if kinks:
        out["hinges"] = kinks
    if pulses:
        out["pulses"] = pulses
    if noise:
        out["noise"] = noise
    if watch:
        out["watch"] = watch
    if tails:
        out["tails"] = tails
    return out


def parse(text: str) -> dict:
    """NAME=VALUE[,NAME=VALUE]; a table as NAME=V1/V2/V3 (e.g. DETECT_P=0.5/0.6/0.7)."""
    out: dict = {}
    for item in text.split(","):
        name, _, value = item.partition("=")
        numbers = tuple(float(v) for v in value.split("/"))
        out[name.strip()] = numbers if len(numbers) > 1 else numbers[0]
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--try", dest="tries", action="append", default=[], type=parse)
    parser.add_argument("--full", action="store_true", help="the full plan's cases, one seed")
    args = parser.parse_args(argv)
    plan = replace(sr.FULL if args.full else sr.QUICK, seeds=1)
    todo = sr.cases(plan)
    tunings = [{}, *args.tries]
    configs = {str(k): config(t) for k, t in enumerate(tunings)}
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(job, todo, [configs] * len(todo), chunksize=4))
    n = len(todo)
    print(f"{n} cases ({plan.name} plan, one seed)")
    header = "setting".ljust(28) + " ".join(f"{label:>9s}" for _, label in COLUMNS)
    groups = ((sr.MOVING, "moving"), (("constant",), "constant"), (("loop",), "loop"))
    for kinds, title in (*groups, (sr.HELD, "held")):
        print(f"-- {title}\n{header}")
        for k, tuning in enumerate(tunings):
            scores = [r[str(k)] for r in results if r[str(k)].kind in kinds]
            fig = sr.summarise(scores)
            name = ",".join(f"{a}={b}" for a, b in tuning.items()) or "shipped"
            cells = " ".join(
                f"{fig[key]:9.1f}" if fig[key] is not None else f"{'-':>9s}" for key, _ in COLUMNS
            )
            print(f"{name[:28]:28s}{cells}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

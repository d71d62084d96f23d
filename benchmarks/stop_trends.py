"""The trend a stop's step is judged on, with and without the pulse before it.

A watch (`detector.watch.PulseWatcher.start`) takes out the rising trend of the `trend_s`
before its onset: the level's change from `trend_s` before its base to its base. A ridge
pulse whose onset lies in that window swells the change (`detector.prior_trend`). For each
judged stop cleared late (`stop_causes.job`, the default decoder or a `--try` tuning) this
prints the stop's own step (the contact nearest the stop's start, within
`stop_causes.NEAR_STOP_S`) and its watch: the trend the window gave (own), the trend the
previous contact measured before *its* onset (past pulse, when that onset lies in the
window), the trend the watch used, the base-to-base trend (`_long_trend`), the gap to the
previous contact and the verdict told by the report's due time. `--headline` does the same
for the headline loop's contacts after its onset (`scenes/loop_headline.toml`).

Run: `.venv/bin/python benchmarks/stop_trends.py --seeds 2` (`--cases SEED,...`: only those).
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plan_cases
import stop_causes

from grasplink.decoding.detector import watch as watch_mod
from grasplink.decoding.detector.prior_trend import trend_past_pulse
from grasplink.evaluation import slip_reporting as sr

# per decoded case (one worker process): onset sample -> the watch's trends (N/s) and gap
SEEN: dict[int, dict] = {}
_start = watch_mod.PulseWatcher.start


def _noting_start(self, cid, index, emit=None):  # type: ignore[no-untyped-def]
    """`PulseWatcher.start`, noting a kink contact's trends (module doc)."""
    w = _start(self, cid, index, emit)
    if w is None or emit is None:
        return w
    before = index - 2 * self.level_half - 1
    base, earlier = self.level_at(before), self.level_at(before - self.trend_n)
    own = 0.0 if base is None or earlier is None else max(0.0, (base - earlier) / self.trend_n)
    past = trend_past_pulse(list(self._trends)[:-1], index, emit, before - self.trend_n, own)
    prior = [n for n, e, _ in list(self._bases)[:-1] if e <= emit and n <= index - 2]
    fs = self.fs_hz
    SEEN[index] = {
        "t_s": index / fs, "own": own * fs, "past": past * fs, "used": w.trend * fs,
        "long": w.long * fs, "noise": w.noise, "window_ms": 1e3 * self.trend_n / fs,
        "gap_ms": 1e3 * (index - prior[-1]) / fs if prior else float("nan"),
        "slope": w.slope * fs, "watch": w,
    }  # fmt: skip
    return w


watch_mod.PulseWatcher.start = _noting_start  # type: ignore[method-assign]


def job(case: sr.Case, tuning: dict) -> tuple[sr.Case, list[str]]:
    """The late stops of one case, a line each (module doc)."""
    SEEN.clear()
    rec = case.make()
    decoder = stop_causes._decoder(case, rec, tuning)
    decoder.rows, decoder.contacts, decoder.checks, decoder.arrived = [], [], [], []
    estimates, _ = stop_causes.ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    scored = sr.score(estimates, rec.truth)
    lines = []
    for stop, _, c, verdict in stop_causes.late_stops(decoder, scored):
        if c is None:
            lines.append(f"stop {stop.start_s:.3f}: no contact at the stop")
            continue
        lines.append(f"stop {stop.start_s:.3f} delay {stop.delay_s:.2f}: " + _line(c, verdict))
    return case, lines


def _line(contact, verdict: str) -> str:  # type: ignore[no-untyped-def]
    s = SEEN.get(contact.index)
    if s is None:
        return f"contact {contact.t_s:.3f} told {verdict} (no kink watch)"
    plain = s["watch"].plain / s["noise"]  # level - base by the hold, noise units
    top, end = (float(plain.max()), float(plain[-1])) if len(plain) else (0.0, 0.0)
    return (
        f"contact {contact.t_s:.3f} told {verdict:7s} trend N/s own {s['own']:6.2f} "
        f"past pulse {s['past']:6.2f} used {s['used']:6.2f} long {s['long']:6.2f}; "
        f"previous contact {s['gap_ms']:5.0f} ms before (window {s['window_ms']:.0f} ms); "
        f"slope before {s['slope']:6.2f} N/s; level by the hold top {top:5.1f} end {end:5.1f} "
        "noise units"
    )


def headline() -> None:
    """The headline loop's contacts after the slip's onset and their watches' trends."""
    from grasplink.controllers import build_controllers

    SEEN.clear()
    found = sr.headline_check(Path("scenes/loop_headline.toml"), build_controllers)
    keys = ("stop_s", "first_speed_s", "first_speed", "first_speed_truth", "last_speed_s",
            "speed_at_rest_updates", "speed_after_observable_updates")  # fmt: skip
    print("headline:", {k: found.get(k) for k in keys})
    for _, s in sorted(SEEN.items()):
        print(
            f"  contact {s['t_s']:.3f} trend N/s own {s['own']:6.2f} past pulse "
            f"{s['past']:6.2f} used {s['used']:6.2f} long {s['long']:6.2f}; previous "
            f"{s['gap_ms']:5.0f} ms before"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    plan_cases.add_plan_arguments(parser, ",".join(stop_causes.STOP_KINDS), 2, cases=True)
    parser.add_argument("--headline", action="store_true")
    args = parser.parse_args(argv)
    if args.headline:
        headline()
        return 0
    todo = plan_cases.full_plan_cases(
        parser, args.kinds, args.seeds, args.cases, first_seed=args.first_seed
    )
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(job, todo, [args.tuning] * len(todo), chunksize=2))
    print(f"{len(todo)} cases ({args.kinds}, full plan, {args.seeds} seed(s)), {args.tuning}")
    plan_cases.print_case_lines(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Chosen closed-loop trials of the loop benchmark, one line each (crush, stop, grip).

    .venv/bin/python benchmarks/loop_trial_outcomes.py --speeds 20 --seeds 8 [--modes a,b]
        [--reflex on|off|both] [--workers 2] [--try NAME=VALUE[,...]]

`--try` sets TrackerDecoder constants (the gateway's skin decoder) in the workers, e.g.
`--try ARRIVAL_EMPTY_N=0` for the loop without the arrival rule.

Why: a decoder change that weighs grip commands (the efference copy) can make the reflex
fire at rest and crush the object; `bench_loop.py` finds that in 990 trials but takes an
hour at load. This runs the trials a change is suspected in (`loop.run_trial`, as
bench_loop does; trials are deterministic in virtual time) and prints each outcome.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor

from grasplink.controllers import build_controllers
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import loop


def _numbers(text: str, what: str, kind: type) -> list:
    try:
        return [kind(x) for x in text.split(",") if x]
    except ValueError:
        raise SystemExit(
            f"loop_trial_outcomes: --{what}: comma-separated numbers, got {text!r}"
        ) from None


def _tracker_tuning(text: str) -> dict[str, float]:
    out = {}
    for item in (x for x in text.split(",") if x):
        name, _, value = item.partition("=")
        if not hasattr(TrackerDecoder, name) or name.startswith("_"):
            raise SystemExit(f"loop_trial_outcomes: --try: TrackerDecoder has no constant {name!r}")
        try:
            out[name] = float(value)
        except ValueError:
            what = f"loop_trial_outcomes: --try {name}: a number, got {value!r}"
            raise SystemExit(what) from None
    return out


def _tune(tuning: dict[str, float]) -> None:
    """In each worker: the gateway's decoders are built from these class constants."""
    for name, value in tuning.items():
        setattr(TrackerDecoder, name, value)


def outcome(trial: loop.Trial) -> tuple[loop.Trial, loop.Outcome]:
    return trial, loop.run_trial(trial, build_controllers)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speeds", default="20", help="mm/s, comma-separated")
    parser.add_argument("--seeds", default="8", help="comma-separated")
    parser.add_argument("--modes", default=",".join(loop.MODES), help="comma-separated")
    parser.add_argument("--reflex", choices=("on", "off", "both"), default="on")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--try", dest="tuning", default="", help="TrackerDecoder NAME=VALUE,...")
    args = parser.parse_args(argv)
    modes = [m for m in args.modes.split(",") if m]
    unknown = sorted(set(modes) - set(loop.MODES))
    if unknown or not modes:
        parser.error(f"unknown modes {unknown}; known: {', '.join(loop.MODES)}")
    if args.workers < 1:
        parser.error(f"--workers must be >= 1, got {args.workers}")
    reflexes = {"on": (True,), "off": (False,), "both": (True, False)}[args.reflex]
    trials = [
        loop.Trial(mode, reflex, speed, seed)
        for mode in modes
        for reflex in reflexes
        for speed in _numbers(args.speeds, "speeds", float)
        for seed in _numbers(args.seeds, "seeds", int)
    ]
    tuning = _tracker_tuning(args.tuning)
    crushed = 0
    with ProcessPoolExecutor(args.workers, initializer=_tune, initargs=(tuning,)) as pool:
        for trial, out in pool.map(outcome, trials):
            crushed += out.crushed
            grip = "-" if out.grip_mean_n is None else f"{out.grip_mean_n:.1f}"
            reflex_s = "-" if out.reflex_latency_s is None else f"{out.reflex_latency_s:.2f}"
            belt_s = "-" if out.slip_belt_latency_s is None else f"{out.slip_belt_latency_s:.3f}"
            print(
                f"{trial.mode:16} reflex {'on ' if trial.reflex else 'off'} "
                f"{trial.speed_mm_s:5g} mm/s seed {trial.seed:2d}: crushed {out.crushed!s:5} "
                f"stopped {out.stopped!s:5} dropped {out.dropped!s:5} grip mean {grip} N "
                f"reflex after {reflex_s} s slip belt after {belt_s} s"
            )
    print(f"{len(trials)} trials, {crushed} crushed")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The efference copy on the headline loop, and what it costs (docs/decoding.md, Gaps).

    .venv/bin/python benchmarks/efference.py [--kinks 1,2,4] [--cost ROUNDS]

Runs `scenes/loop_headline.toml` as `grasplink run` does, decodes its can.asc 3 samples at
a time without and with the hand's grip commands (`io.read_grip_commands`), and prints
the speed updates 0.15 s or more into the rest and the last speed; `--kinks` repeats it
with `efference.KINKS_PER_RISE` at each value (the rate's sensitivity). `--cost
ROUNDS`: the tracker's CPU per sample on 8 loop cases of slip_reporting's full plan
without and with their gateway's commands (`loop_grip_commands`), alternating, the least
of ROUNDS runs each, and their ratio.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from grasplink.controllers import build_controllers
from grasplink.decoding import efference, io
from grasplink.decoding.registry import make_decoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import scenes as sc
from grasplink.evaluation import slip_reporting as sr

ROOT = Path(__file__).resolve().parents[1]
REST_FROM_S = 1.768 + sr.REST_SETTLED_S  # the headline's stop (truth) + 0.15 s


def headline(log: Path, layout: tuple[float, ...], commands: bool) -> str:
    t, x, stats = io.read_can_log(log)
    decoder = make_decoder("tracker", layout, stats.rate_hz)
    if commands:
        io.read_grip_commands(log).feed(decoder)
    estimates, _ = ns.feed(decoder, t, x, 3)
    speeds = [(e.t_s, e.speed_mm_s) for e in estimates if e.speed_mm_s]
    at_rest = [(t_s, v) for t_s, v in speeds if t_s >= REST_FROM_S]
    span = f"{at_rest[0][0]:.2f}-{at_rest[-1][0]:.2f} s" if at_rest else "-"
    return f"speed updates at rest {len(at_rest):3d} ({span}), last speed {speeds[-1][0]:.2f} s"


def cost(rounds: int) -> None:
    cases = [c for c in sr.cases(sr.FULL) if c.kind == "loop"][::7][:8]
    made = [(c, c.make()) for c in cases]
    best = {False: float("inf"), True: float("inf")}
    for _ in range(rounds):
        for told in (False, True):
            cpu = samples = 0.0
            for case, rec in made:
                decoder = make_decoder("tracker", rec.truth.layout_mm, rec.fs_hz)
                if told:
                    for t_s, force_n in sr.loop_grip_commands(case):
                        decoder.note_grip_command(t_s, force_n)
                start = time.process_time()
                ns.feed(decoder, rec.t_s, rec.force_n, 3)
                cpu += time.process_time() - start
                samples += len(rec.t_s)
            best[told] = min(best[told], cpu / samples * 1e6)
    print(
        f"loop cases, µs/sample (least of {rounds}): without commands {best[False]:.2f}, "
        f"with {best[True]:.2f}: ratio {best[True] / best[False]:.3f}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--kinks", default="", help="comma-separated KINKS_PER_RISE values (contacts per rise)"
    )
    parser.add_argument("--cost", type=int, default=0, metavar="ROUNDS")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="grasplink-efference-") as folder:
        signals = sc.record_scene(ROOT / sr.HEADLINE_SCENE, build_controllers, folder)
        log = Path(folder) / "can.asc"
        layout = signals.layout_mm
        print(f"without commands:   {headline(log, layout, False)}")
        print(f"with commands:      {headline(log, layout, True)}")
        shipped = efference.KINKS_PER_RISE
        for value in [float(v) for v in args.kinks.split(",") if v]:
            efference.KINKS_PER_RISE = value
            print(f"KINKS_PER_RISE {value:g}: {headline(log, layout, True)}")
        efference.KINKS_PER_RISE = shipped
    if args.cost:
        cost(args.cost)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

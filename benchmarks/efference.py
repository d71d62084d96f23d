"""The efference copy on a loop scene, and what it costs (docs/decoding.md, Gaps).

    .venv/bin/python benchmarks/efference.py [--scene loop_headline] [--kinks 1,2,4]
        [--cost ROUNDS]

Runs the scene (default `scenes/loop_headline.toml`) as `grasplink run` does, decodes its
can.asc 3 samples at a time without and with the hand's grip commands
(`io.read_grip_commands`), and prints the speed updates 0.15 s or more into the rest (the
object's first standstill of 1 s or more), the last speed, and the speeds more than 50 %
off the truth or at rest; `--kinks` repeats it
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

import numpy as np
from shipped_scenes import scene_path

from grasplink.controllers import build_controllers
from grasplink.decoding import efference, io
from grasplink.decoding.registry import make_decoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import scenes as sc
from grasplink.evaluation import slip_reporting as sr
from grasplink.simulators.synth import SkinRecording

FAR_OFF = 0.5  # a speed this far off the truth (relative) counts as wrong


def headline(log: Path, rec: SkinRecording, commands: bool) -> str:
    t, x, stats = io.read_can_log(log)
    decoder = make_decoder("tracker", rec.layout_mm, stats.rate_hz)
    if commands:
        io.read_grip_commands(log).feed(decoder)
    estimates, _ = ns.feed(decoder, t, x, 3)
    speeds = [(e.t_s, e.speed_mm_s) for e in estimates if e.speed_mm_s]
    rests = [s for s in ns.motion(rec).stops if s[1] - s[0] >= 1.0]
    rest_from_s, rest_until_s = (rests[0][0] + sr.REST_SETTLED_S, rests[0][1]) if rests else (0, 0)
    at_rest = [(t_s, v) for t_s, v in speeds if rest_from_s <= t_s < rest_until_s]
    span = f"{at_rest[0][0]:.2f}-{at_rest[-1][0]:.2f} s" if at_rest else "-"
    index = np.minimum(np.searchsorted(rec.t_s, [t_s for t_s, _ in speeds]), len(rec.t_s) - 1)
    truth = np.abs(rec.speed_mm_s[index])
    told = np.array([v for _, v in speeds])
    off = int(np.sum((truth < 1.0) | (np.abs(told / np.maximum(truth, 1.0) - 1) > FAR_OFF)))
    last = f"{speeds[-1][0]:.2f} s" if speeds else "-"
    return (
        f"speed updates at rest {len(at_rest):3d} ({span}), last speed {last}, "
        f"{off} of {len(speeds)} speeds > {FAR_OFF:.0%} off the truth or at rest"
    )


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
                    sr.tell_grip_commands(decoder, case)
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
    parser.add_argument("--scene", default="loop_headline", help="a scene in scenes/")
    parser.add_argument("--cost", type=int, default=0, metavar="ROUNDS")
    args = parser.parse_args(argv)
    scene = scene_path(args.scene)
    with tempfile.TemporaryDirectory(prefix="grasplink-efference-") as folder:
        rec = sc.record_scene(scene, build_controllers, folder).can
        log = Path(folder) / "can.asc"
        print(f"without commands:   {headline(log, rec, False)}")
        print(f"with commands:      {headline(log, rec, True)}")
        shipped = efference.KINKS_PER_RISE
        for value in [float(v) for v in args.kinks.split(",") if v]:
            efference.KINKS_PER_RISE = value
            print(f"KINKS_PER_RISE {value:g}: {headline(log, rec, True)}")
        efference.KINKS_PER_RISE = shipped
    if args.cost:
        cost(args.cost)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

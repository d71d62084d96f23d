"""One closed-loop trial's skin decoding as the live gateway did it: its contacts (time, z,
onto an unloaded sensor or not) and its slip estimates, in order.

    .venv/bin/python benchmarks/loop_trial_trace.py --mode slip_speed --speed 40 --seed 1
        [--reflex] [--from 1.0 --to 2.0] [--try NAME=VALUE[,...]]

Why: `loop_trial_outcomes.py` says when the belt ran; this says which contacts raised the
flag (e.g. the arrival rule's trace in docs/decoding.md: a contact no ridge made, paired
with ridge 0 by an alias the unloaded sensor rules out). `--try` sets TrackerDecoder
constants, as in loop_trial_outcomes.py.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import ClassVar

sys.path.insert(0, str(Path(__file__).resolve().parent))
import loop_trial_outcomes

from grasplink.controllers import build_controllers
from grasplink.decoding.contacts import ContactEvent
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import loop


class _Traced(TrackerDecoder):
    """Notes each contact and whether it came onto an unloaded sensor (`arrival`)."""

    lines: ClassVar[list[tuple[float, str]]] = []

    def _add_contact(self, ev: ContactEvent) -> None:
        super()._add_contact(ev)
        empty = self._onto_empty_skin(ev) if self.ARRIVAL_EMPTY_N > 0 else None
        onto = {True: "onto an unloaded sensor", False: "loaded", None: "arrival off"}[empty]
        self.lines.append((ev.t_s, f"contact id {ev.id} z {ev.z:.1f} ({onto})"))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mode", default="slip_speed", choices=list(loop.MODES))
    parser.add_argument("--speed", type=float, default=40.0, help="mm/s")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--reflex", action="store_true")
    parser.add_argument("--from", dest="t0", type=float, default=1.0, help="s")
    parser.add_argument("--to", dest="t1", type=float, default=2.5, help="s")
    parser.add_argument("--try", dest="tuning", default="", help="TrackerDecoder NAME=VALUE,...")
    args = parser.parse_args(argv)
    loop_trial_outcomes._tune(loop_trial_outcomes._tracker_tuning(args.tuning))

    def controllers(scene):  # type: ignore[no-untyped-def]
        built = list(build_controllers(scene))
        for c in built:
            if isinstance(getattr(c, "decoder", None), TrackerDecoder):
                c.decoder.__class__ = _Traced  # same state, its contacts noted
            if hasattr(c, "estimate_listeners"):
                c.estimate_listeners.append(
                    lambda t_us, e: _Traced.lines.append((e.t_s, _estimate(e)))
                )
        return built

    trial = loop.Trial(args.mode, args.reflex, args.speed, args.seed)
    out = loop.run_trial(trial, controllers)
    last = ""
    for t_s, line in _Traced.lines:
        if args.t0 <= t_s <= args.t1 and line != last:
            print(f"{t_s:7.3f} s  {line}")
        last = line
    print(f"{trial}: slip belt after {out.slip_belt_latency_s} s, stopped {out.stopped}")
    return 0


def _estimate(e) -> str:  # type: ignore[no-untyped-def]
    if not e.slip:
        return "no slip"
    if e.speed_mm_s is not None:
        return f"SLIP speed {e.speed_mm_s:.1f} mm/s"
    low, high = e.speed_low_mm_s, e.speed_high_mm_s
    return "SLIP no speed" + (f" (range {low:.1f}-{high:.1f})" if low is not None else "")


if __name__ == "__main__":
    sys.exit(main())

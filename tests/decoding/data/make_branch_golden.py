"""Record golden children pools of the tracker's branching (`TrackerDecoder._branch`).

Why: the branching was numpy code; it is now one compiled kernel, and this file holds what
the numpy code gave on real contacts, so the kernel is checked against the code it
replaced (tests/decoding/test_branch_kernel.py), not against itself.

Run it with the numpy code's package first on the path (a tree before the kernel, e.g.
commit 0858d90, checked out at <old>):
    PYTHONPATH=<old> python tests/decoding/data/make_branch_golden.py
(it writes branch_golden.npz next to itself). The file here was made so, from main.
It decodes a few signals of the non-stationary set and the gateway benchmark's slip cycle
in 3-sample chunks, captures every `_branch` call (the bank, null score, contact and step
verdict in; the children pool and null score out) and keeps a spread of them, the steps
and step-probe contacts first (the rarer branch kinds).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from grasplink.evaluation import nonstationary
from grasplink.gateway.decoding.contacts import STEP_IDS, ContactEvent
from grasplink.gateway.decoding.tracker import TrackerDecoder
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

OUT = Path(__file__).with_name("branch_golden.npz")
KEEP_STEPS, KEEP_PROBES, KEEP_TOTAL = 40, 20, 120
MAX_ROWS = 60  # banks kept small: the file stays small


def recordings() -> list[tuple[str, np.ndarray, np.ndarray, int]]:
    """(layout name, t, x, fs) of the decoded signals."""
    out = []
    for signal in nonstationary.signals(True):
        rec = signal.make()
        out.append((signal.layout, np.asarray(rec.t_s), np.asarray(rec.force_n), rec.fs_hz))
    rec = synth.slip_recording(LAYOUTS_MM["alpha0.1"], 60.0, fs_hz=400, seed=1)
    rest = np.random.default_rng(1).normal(float(rec.force_n[0]), 0.02, 320)
    x = np.tile(np.concatenate([rec.force_n, rest]), 3)
    out.append(("alpha0.1", np.arange(len(x)) / 400.0, x, 400))
    return out


def capture(layout: str, t: np.ndarray, x: np.ndarray, fs: int) -> list[dict]:
    """Every `_branch` call of one decode."""
    dec = TrackerDecoder(LAYOUTS_MM[layout], fs)
    calls: list[dict] = []
    branch = dec._branch

    def recorded(ev):
        before = dec._tracks
        call = {
            "layout": layout,
            "fs": fs,
            "in_f": before._f.copy(),
            "in_i": before._i.copy(),
            "null_in": dec._null,
            "ev": (ev.id, ev.t_s, ev.sigma_s, ev.z),
            "step": ev.id in dec._steps,
            "trend_on": {None: -1, False: 0, True: 1}[dec._steps.get(ev.id)],
        }
        pool = branch(ev)
        call.update(out_f=pool._f.copy(), out_i=pool._i.copy(), null_out=dec._null)
        calls.append(call)
        return pool

    dec._branch = recorded  # type: ignore[method-assign]
    for start in range(0, len(t), 3):
        dec.process(t[start : start + 3], x[start : start + 3])
    return calls


def edge_cases(calls: list[dict]) -> list[dict]:
    """Inputs the signals seldom or never give, branched by the same code: no tracks (a
    contact and a step probe), one track, and a bank of a real call with a NaN speed, an
    infinite dip variance, a -inf score, a contact at a track's own time and a zero
    timing sigma."""
    from grasplink.gateway.decoding.tracker import _Bank

    model = next(c for c in calls if len(c["in_f"]) >= 8 and not c["step"] and c["fs"] == 400)
    ev_id, _, _, z = model["ev"]
    cases = []

    def case(floats, ints, ev, probe=False):
        call = dict(model, in_f=floats, in_i=ints, step=probe, trend_on=-1)
        if probe:
            ev = (ev[0] + STEP_IDS, *ev[1:])
        call["ev"] = ev
        dec = TrackerDecoder(LAYOUTS_MM[model["layout"]], model["fs"])
        dec._tracks, dec._null = _Bank(floats.copy(), ints.copy()), model["null_in"]
        if probe:
            dec._steps[ev[0]] = None
        event = ContactEvent(ev[0], ev[1], 0, 0, ev[3], 0.0, 0.0, ev[2])
        pool = dec._branch(event)
        call.update(out_f=pool._f.copy(), out_i=pool._i.copy(), null_out=dec._null)
        cases.append(call)

    f, i = model["in_f"], model["in_i"]
    case(f[:0], i[:0], model["ev"])
    case(f[:0], i[:0], model["ev"], probe=True)
    case(f[:1], i[:1], model["ev"])
    odd = f.copy()
    odd[0, 17] = np.nan  # speed
    odd[1, 15] = np.inf  # dip variance
    odd[2, 21] = -np.inf  # score
    case(odd, i, model["ev"])
    case(f, i, (ev_id, float(f[3, 24]), 0.0, z))  # at track 3's own time, exact timing
    case(odd, i, model["ev"], probe=True)
    return cases


def choose(calls: list[dict]) -> list[dict]:
    """The steps and probes (rarer kinds) first, then an even spread of the rest."""
    small = [c for c in calls if len(c["in_f"]) <= MAX_ROWS]
    steps = [c for c in small if c["step"]]
    probes = [c for c in small if c["ev"][0] >= STEP_IDS and not c["step"]]
    rest = [c for c in small if not c["step"] and c["ev"][0] < STEP_IDS]
    picked = steps[:: max(1, len(steps) // KEEP_STEPS)][:KEEP_STEPS]
    picked += probes[:: max(1, len(probes) // KEEP_PROBES)][:KEEP_PROBES]
    room = KEEP_TOTAL - len(picked)
    picked += rest[:: max(1, len(rest) // room)][:room]
    return picked


def save(calls: list[dict]) -> None:
    layouts = sorted({c["layout"] for c in calls})
    ends = lambda key: np.cumsum([0] + [len(c[key]) for c in calls])  # noqa: E731
    np.savez_compressed(
        OUT,
        layouts=np.array(layouts),
        layout=np.array([layouts.index(c["layout"]) for c in calls]),
        fs=np.array([c["fs"] for c in calls]),
        in_f=np.concatenate([c["in_f"] for c in calls]),
        in_i=np.concatenate([c["in_i"] for c in calls]),
        in_at=ends("in_f"),
        out_f=np.concatenate([c["out_f"] for c in calls]),
        out_i=np.concatenate([c["out_i"] for c in calls]),
        out_at=ends("out_f"),
        null=np.array([(c["null_in"], c["null_out"]) for c in calls]),
        ev_id=np.array([c["ev"][0] for c in calls], np.int64),
        ev=np.array([c["ev"][1:] for c in calls]),
        step=np.array([c["step"] for c in calls]),
        trend_on=np.array([c["trend_on"] for c in calls]),
    )


def main() -> None:
    calls = [call for rec in recordings() for call in capture(*rec)]
    picked = choose(calls) + edge_cases(calls)
    save(picked)
    kinds = sum(c["step"] for c in picked), sum(c["ev"][0] >= STEP_IDS for c in picked)
    print(f"{len(calls)} calls, kept {len(picked)} (steps {kinds[0]}, probes {kinds[1]})")
    print(OUT, OUT.stat().st_size, "bytes", file=sys.stderr)


if __name__ == "__main__":
    main()

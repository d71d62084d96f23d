"""Where the clean decoding targets fail with the coast bound on: the scored window.

tests/decoding/test_tracker.py scores every update while the object slips from its 3rd
ridge contact on - past the layout's last ridge too, where no contact can come and the
synthesised slip goes on for 6 mm plus 0.3 s of travel. `decoding.coast_bound`
(`TrackerDecoder.COAST_INTERVALS`) stops showing a speed one interval (the spacing into
the last ridge, at the track's speed) past the last ridge: is the p90 it fails made of
those updates? For the test's grid (both target layouts, 10-120 mm/s, both directions,
dips on half, seeds as there) and its 100 Hz case, per coast setting and window - *all*
(the test's), *to the last ridge* (slip_reporting's: until the edge passes the last
ridge ahead), *one interval past* (until the edge lies one spacing into the last ridge
past it) -: speed error median / p90, missing share, position p90, and the updates the
window leaves out.

Run: `.venv/bin/python benchmarks/coast_scored_window.py` (about a minute; `--coast 0,1`).
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from grasplink.decoding.tracker import TrackerDecoder
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

SPEEDS = (10.0, 30.0, 60.0, 90.0, 120.0)
WINDOWS = ("all", "to the last ridge", "one interval past")


def grid(fs_hz: int) -> list[tuple[str, float, synth.SkinRecording]]:
    """test_tracker's recordings: its `grid` fixture at 400 Hz, `test_other_sample_rates`
    at other rates."""
    out = []
    for name in ("alpha0.1", "fibonacci"):
        layout = LAYOUTS_MM[name]
        if fs_hz == 400:
            for i, speed in enumerate(SPEEDS):
                for reverse in (False, True):
                    dips = (i + reverse) % 2 == 1
                    rec = synth.slip_recording(
                        layout, speed, reverse=reverse, dips=dips, noise_scale=1.0, seed=11 + i
                    )
                    out.append((name, speed, rec))
        else:
            for speed in (20.0, 60.0, 110.0):
                for reverse in (False, True):
                    rec = synth.slip_recording(layout, speed, reverse=reverse, fs_hz=fs_hz, seed=8)
                    out.append((name, speed, rec))
    return out


def windows(rec: synth.SkinRecording, t: np.ndarray) -> dict[str, np.ndarray]:
    """The test's scored updates (slipping, from the 3rd contact) and the two bounded ones."""
    slipping = np.interp(t, rec.t_s, rec.slipping) > 0.5
    base = slipping & (t >= rec.contact_times_s[2])
    edge = np.interp(t, rec.t_s, rec.position_mm)
    layout = np.asarray(rec.layout_mm, dtype=float)
    length = float(layout.sum())
    forward = rec.position_mm[-1] > rec.position_mm[0]
    if forward:
        to_last, past_one = edge < length, edge < length + layout[-1]
    else:
        to_last, past_one = edge > 0.0, edge > -layout[0]
    return {"all": base, WINDOWS[1]: base & to_last, WINDOWS[2]: base & past_one}


def figures(rows: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]) -> str:
    """speed median / p90 %, missing %, position p90 mm over (mask, v, v_true, x err)."""
    rel, pos, scored, missing = [], [], 0, 0
    for mask, v, v_true, x_err in rows:
        answered = mask & np.isfinite(v)
        rel.append(np.abs(v[answered] - np.abs(v_true[answered])) / np.abs(v_true[answered]))
        placed = mask & np.isfinite(x_err)
        pos.append(x_err[placed])
        scored += int(mask.sum())
        missing += int((mask & ~np.isfinite(v)).sum())
    r, p = np.concatenate(rel), np.concatenate(pos)
    return (
        f"{100 * np.median(r):5.1f} / {100 * np.percentile(r, 90):5.1f} | "
        f"{100 * missing / max(scored, 1):4.1f} | {np.percentile(p, 90):5.2f} | {scored}"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--coast", default="0,1", help="COAST_INTERVALS values to compare")
    args = parser.parse_args(argv)
    try:
        coasts = [float(c) for c in args.coast.split(",")]
    except ValueError:
        parser.error(f"--coast: {args.coast!r} is not a comma-separated list of numbers")
    print(
        "| rate | group | coast intervals | window | speed err median / p90 % | "
        "missing % | position p90 mm | scored |"
    )
    print("|---|---|---:|---|---:|---:|---:|---:|")
    for fs in (400, 100):
        recs = grid(fs)
        for coast in coasts:
            per: list[tuple[str, float, dict]] = []
            for name, speed, rec in recs:
                dec = TrackerDecoder(rec.layout_mm, rec.fs_hz, tuning={"COAST_INTERVALS": coast})
                chunk = 64 if fs == 400 else max(1, fs // 40)
                est = []
                for i in range(0, len(rec.t_s), chunk):
                    est += dec.feed(rec.t_s[i : i + chunk], rec.force_n[i : i + chunk])
                t = np.array([e.t_s for e in est])
                v = np.array([np.nan if e.speed_mm_s is None else e.speed_mm_s for e in est])
                x = np.array([np.nan if e.position_mm is None else e.position_mm for e in est])
                v_true = np.interp(t, rec.t_s, rec.speed_mm_s)
                x_err = np.abs(x - np.interp(t, rec.t_s, rec.position_mm))
                per.append((name, speed, {"w": windows(rec, t), "d": (v, v_true, x_err)}))
            groups = {
                "every": lambda n, s: True,
                "alpha0.1": lambda n, s: n == "alpha0.1",
                "fibonacci": lambda n, s: n == "fibonacci",
                "10-30 mm/s": lambda n, s: s <= 30.0,
                "90-120 mm/s": lambda n, s: s >= 90.0,
            }
            for group, keep in groups.items():
                chosen = [p for p in per if keep(p[0], p[1])]
                if not chosen:
                    continue
                for window in WINDOWS:
                    rows = [(p[2]["w"][window], *p[2]["d"]) for p in chosen]
                    print(f"| {fs} Hz | {group} | {coast:g} | {window} | {figures(rows)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Contacts a long stepped grip rise makes on a held object, and where in the rise.

    .venv/bin/python benchmarks/grip_long_rise_contacts.py [--seeds N] [--layouts a,b]

Why: until s25 the efference copy charged 2 contacts over a rising change's whole
window (`KINKS_PER_LONG_RISE`) without a measurement; `grip_ramp_contacts.py` covers
rises of 0.5-6.5 N only. This measured `efference.KINKS_LATE_IN_RISE` and
`LATE_ONSET_S` that replace it. The loop's virtual wearer steps the grip 2.5 N every 50 ms up to
20-28 N (the loop benchmark's 20 mm/s seed-8 crush). Here the object is held (no slip)
over the whole skin or half of it, on every layout; the grip is commanded in steps
(`RISES`: from, to, step N, step interval s, optional pause), the hand node slews its
setpoint at its grip rate and the actuator follows with its first-order lag
(`grip_ramp_contacts.hand_grip`); the skin chain is the loop scenes'
(`contact_truth.loop_recording`). After each rise the grip holds, falls back and holds
again, so every rise starts from a settled level.

Per rise profile: the detector's contacts whose onset falls in the rise's window (first
command .. last command + its step's `HandFollow.window_s`), split into those the
efference copy's onset charges (`GripCommands.rise_at` not None: within
lag + ONSET_TIMING_S of a run of rising commands) and those past it (charged only
within `GripCommands.late_s` of a run's first command, `KINKS_LATE_IN_RISE`); where
the past-onset ones fall (s after the rise's first command and after their run's first
command, commanded grip N at the onset); and
the same signal's contacts per s outside every window (clutter).
"""

from __future__ import annotations

import argparse
from collections import defaultdict
from dataclasses import dataclass

import numpy as np
from grip_ramp_contacts import hand_grip

from grasplink.decoding.efference import (
    HAND_LAG_S,
    KINKS_LATE_IN_RISE,
    LATE_ONSET_S,
    GripCommands,
    HandFollow,
)
from grasplink.evaluation import slip_reporting as sr
from grasplink.evaluation.contact_truth import detect, loop_recording
from grasplink.profiles.layouts import LAYOUTS_MM

HOLD_S = 1.5  # held after a rise, and again after the fall back
FALL_N_S = 50.0  # the fall back to the start grip (commanded at once, the hand's slew)
SETTLE_S = 0.5  # before the first rise (the detector settled)


@dataclass(frozen=True)
class Rise:
    """A stepped rise: from_n to to_n in step_n steps every step_s s; `pause_at_n`: the
    grip held `pause_s` once the commands reach it (the crush trial's 0.24 s at 10.5 N)."""

    name: str
    from_n: float
    to_n: float
    step_n: float
    step_s: float
    pause_at_n: float | None = None
    pause_s: float = 0.0

    def commands(self, t0: float) -> list[tuple[float, float]]:
        out = []
        t, f = t0, self.from_n
        while f < self.to_n - 1e-9:
            f = min(self.to_n, f + self.step_n)
            out.append((t, f))
            t += self.step_s
            if self.pause_at_n is not None and abs(f - self.pause_at_n) < 1e-9:
                t += self.pause_s
        return out

    @property
    def rise_n(self) -> float:
        return self.to_n - self.from_n


RISES = (
    # the wearer's steps (2.5 N / 50 ms: the hand's 50 N/s, the EMG's 20 Hz)
    Rise("0.5->10.5 2.5N/50ms", 0.5, 10.5, 2.5, 0.05),
    Rise("0.5->20.5 2.5N/50ms", 0.5, 20.5, 2.5, 0.05),
    Rise("0.5->28 2.5N/50ms", 0.5, 28.0, 2.5, 0.05),
    Rise("5->10 2.5N/50ms", 5.0, 10.0, 2.5, 0.05),
    Rise("5->20 2.5N/50ms", 5.0, 20.0, 2.5, 0.05),
    Rise("5->28 2.5N/50ms", 5.0, 28.0, 2.5, 0.05),
    # the crush trial's: a run to 10.5 N, 0.24 s held, on to 20.5 N
    Rise("0.5->20.5 crush", 0.5, 20.5, 2.5, 0.05, pause_at_n=10.5, pause_s=0.19),
    # slower contractions: the grip stops between steps
    Rise("5->20 2.5N/100ms", 5.0, 20.0, 2.5, 0.10),
    Rise("5->20 2.5N/200ms", 5.0, 20.0, 2.5, 0.20),
    Rise("5->20 1N/50ms", 5.0, 20.0, 1.0, 0.05),
    Rise("0.5->20.5 2.5N/200ms", 0.5, 20.5, 2.5, 0.20),
    # the gateway's own ramp (0.5 N every 10 ms, its 50 N/s slew), as in the crush trial's
    # CAN log: from a released grip, 0 -> 11 N, 0.2 s held, on to 20 N
    Rise("0->20 0.5N/10ms crush", 0.0, 20.0, 0.5, 0.01, pause_at_n=11.0, pause_s=0.19),
    Rise("5->20 0.5N/10ms", 5.0, 20.0, 0.5, 0.01),
    Rise("5->28 0.5N/10ms", 5.0, 28.0, 0.5, 0.01),
)


def schedule(rises: tuple[Rise, ...]) -> tuple[list, list]:
    """All commands (t_s, N) for the rises in turn (each: rise, hold, fall back, hold), and
    per rise (its commands, the window's end s)."""
    follow = HandFollow.default()
    commands: list[tuple[float, float]] = [(0.0, rises[0].from_n)]
    spans = []
    t = SETTLE_S
    for rise in rises:
        if commands[-1][1] != rise.from_n:  # to this rise's start grip, then settle
            commands.append((t, rise.from_n))
            t += abs(commands[-2][1] - rise.from_n) / FALL_N_S + HOLD_S
        own = rise.commands(t)
        commands += own
        end = own[-1][0] + follow.window_s(rise.step_n)
        spans.append((own, end))
        t = end + HOLD_S
        commands.append((t, rise.from_n))
        t += rise.rise_n / FALL_N_S + HOLD_S
    return commands, spans


def run(seeds: int, layouts: list[str], rises: tuple[Rise, ...]) -> None:
    follow = HandFollow.default()
    commands, spans = schedule(rises)
    end_s = commands[-1][0] + HOLD_S
    grip = hand_grip(commands, follow.rate_n_s, end_s)
    told = {}  # per rise: the efference copy of the commands up to its window's end
    for rise, (own, until) in zip(rises, spans, strict=True):
        copy = GripCommands(follow)  # its own: a copy keeps KEEP_S of commands
        for t, f in commands:
            if own[0][0] - 5.0 <= t <= until or (t < own[0][0] and not len(copy)):
                copy.note(t, f, 1e9)
        told[rise.name] = copy
    onset_n: dict[str, list[int]] = defaultdict(list)
    past_n: dict[str, list[int]] = defaultdict(list)
    past_at: dict[str, list[tuple[float, float, float]]] = defaultdict(list)
    onset_at: dict[str, list[float]] = defaultdict(list)

    def run_starts(rise: Rise, own: list[tuple[float, float]]) -> list[float]:
        """Where the rise's runs of rising commands start (`GripCommands.rise_at`)."""
        found = (told[rise.name].rise_at(t + 1e-9) for t, _ in own)
        return sorted({r.start_s for r in found if r is not None})

    per_layout: dict[tuple[str, str], list[int]] = defaultdict(list)
    clutter = [0, 0.0]
    for layout_name in layouts:
        layout = tuple(LAYOUTS_MM[layout_name])
        skin_mm = float(sum(layout))
        for _cover, edge_mm in (("whole", skin_mm + 10.0), ("half", skin_mm / 2)):
            for seed in range(1, seeds + 1):
                rec = loop_recording(
                    layout, [[0.0, 0.0]], edge_mm, grip.tolist(), seed, end_s, sr.LOOP_FS_HZ
                )
                onsets = np.array([c.t_s for c in detect(rec.t_s, rec.force_n, rec.fs_hz).contacts])
                inside = np.zeros(len(onsets), bool)
                clear = rec.t_s >= SETTLE_S
                for rise, (own, until) in zip(rises, spans, strict=True):
                    start = own[0][0]
                    window = (onsets >= start) & (onsets <= until)
                    inside |= window
                    clear &= ~((rec.t_s >= start) & (rec.t_s <= until))
                    efference = told[rise.name]
                    at_onset = [efference.rise_at(float(x)) is not None for x in onsets[window]]
                    onset_n[rise.name].append(sum(at_onset))
                    past_n[rise.name].append(len(at_onset) - sum(at_onset))
                    per_layout[rise.name, layout_name].append(len(at_onset))
                    for x, charged in zip(onsets[window].tolist(), at_onset, strict=True):
                        if not charged:
                            commanded = max(f for t, f in own if t <= x)
                            run_start = max(t for t in run_starts(rise, own) if t <= x)
                            past_at[rise.name].append((x - start, x - run_start, commanded))
                        else:
                            onset_at[rise.name].append(x - efference.rise_at(x).start_s)
                # falls (commands back down) are clear of rises but are grip moves: skip them
                for k in range(1, len(commands)):
                    if commands[k][1] < commands[k - 1][1]:
                        t0 = commands[k][0]
                        t1 = t0 + follow.window_s(commands[k - 1][1] - commands[k][1])
                        clear &= ~((rec.t_s >= t0) & (rec.t_s <= t1))
                        inside |= (onsets >= t0) & (onsets <= t1)
                clutter[0] += int((~inside & (onsets >= SETTLE_S)).sum())
                clutter[1] += float(clear.sum()) / rec.fs_hz
    runs = len(layouts) * 2 * seeds
    print(
        f"held object, hand slew {follow.rate_n_s:g} N/s, lag {HAND_LAG_S:g} s; layouts "
        f"{','.join(layouts)}, object over the whole skin and half of it, seeds 1-{seeds}: "
        f"{runs} rises of each"
    )
    print(
        f"{'rise':24} {'window s':>8} {'runs':>4} {'per rise':>8} {'onset':>6} {'past':>6} "
        f"{'past/N':>7} {'past/s':>7}  past the onset: s after the first command / its "
        "run's first @ N commanded"
    )
    for rise, (own, until) in zip(rises, spans, strict=True):
        window_s = until - own[0][0]
        onset_c, past_c = np.mean(onset_n[rise.name]), np.mean(past_n[rise.name])
        where = sorted(past_at[rise.name])
        starts = run_starts(rise, own)
        print(
            f"{rise.name:24} {window_s:8.2f} {len(starts):4d} {onset_c + past_c:8.2f} "
            f"{onset_c:6.2f} "
            f"{past_c:6.2f} {past_c / rise.rise_n:7.3f} {past_c / window_s:7.2f}  "
            + " ".join(f"{x:.2f}/{r:.3f}@{f:g}" for x, r, f in where[:12])
            + (" ..." if len(where) > 12 else "")
        )
    late = sorted(r for where in past_at.values() for _, r, _ in where)
    early = np.array(sorted(x for xs in onset_at.values() for x in xs))
    print(
        f"onsets within a run's onset window: {len(early)}, s after the run's first command: "
        f"median {np.median(early):.3f}, p90 {np.quantile(early, 0.9):.3f}, max {early.max():.3f}"
    )
    print(
        f"past it: {len(late)}, s after their run's first command: "
        + " ".join(f"{r:.3f}" for r in late)
    )
    print("contacts per rise by layout (whole and half cover, every seed):")
    print(f"{'rise':24} " + " ".join(f"{name:>9}" for name in layouts))
    for rise in rises:
        print(
            f"{rise.name:24} "
            + " ".join(f"{np.mean(per_layout[rise.name, name]):9.2f}" for name in layouts)
        )
    print(
        f"outside the windows: {clutter[0] / max(clutter[1], 1e-9):.3f} contacts/s over "
        f"{clutter[1]:.0f} s; shipped: KINKS_LATE_IN_RISE {KINKS_LATE_IN_RISE:g} per run "
        f"within {follow.lag_s + LATE_ONSET_S:.2f} s of its first command"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=2)
    parser.add_argument("--layouts", default=",".join(LAYOUTS_MM), help="comma-separated")
    args = parser.parse_args(argv)
    if args.seeds < 1:
        parser.error(f"--seeds must be >= 1, got {args.seeds}")
    layouts = [x for x in args.layouts.split(",") if x]
    unknown = [x for x in layouts if x not in LAYOUTS_MM]
    if unknown or not layouts:
        parser.error(f"unknown layouts {unknown}; known: {', '.join(LAYOUTS_MM)}")
    run(args.seeds, layouts, RISES)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

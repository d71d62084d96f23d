"""Contacts a commanded grip change makes on a held object (issue 22: the efference copy).

    .venv/bin/python benchmarks/grip_ramp_contacts.py [--seeds N] [--rate N_S]

`efference.KINKS_PER_CHANGE` is the number of contacts the contact detector tells per
commanded grip change; the held-grip set's grip steps are instant, so it was never
measured on the level the hand's ramp really makes. Here the object is held (no slip)
over the whole skin or half of it, and the grip is commanded as the gateway commands it
(a target every `sr.LOOP_COMMAND_S`, slewed at the hand's grip rate, 0x2404), the hand
node slews its setpoint at that rate and the actuator follows with its first-order lag
(`efference.HAND_LAG_S`, the `hand.actuator` effect's `FirstOrderLag`); the skin chain
is the loop scenes' (`contact_truth.loop_recording`: FSR model, hysteresis, 0.02 N white
noise, 0.05 N drift). Per change size and sign: the detector's contacts whose onset falls
in the change's window (`HandFollow.window_s`) per change, their first verdicts, and the
contacts per s outside every window (the same signal's clutter).
"""

from __future__ import annotations

import argparse
from collections import defaultdict

import numpy as np

from grasplink.decoding.efference import HAND_LAG_S, HandFollow
from grasplink.evaluation import slip_reporting as sr
from grasplink.evaluation.contact_truth import detect, loop_recording
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators.effects.actuators import FirstOrderLag

LAYOUT = "alpha0.1"
HELD_N = 5.0  # the loop scenes' held grip
CHANGES_N = (0.5, 1.0, 2.0, 3.8, 6.5, -0.5, -1.0, -2.0, -3.8)  # 3.8: the loop kind's rise
SETTLE_S = 1.5  # held between changes (the window plus a clear stretch)
GRID_S = 1e-3  # the grip's script resolution


def hand_grip(commands: list[tuple[float, float]], rate_n_s: float, end_s: float) -> np.ndarray:
    """The grip (rows t_s, N on a GRID_S grid) the hand makes of `commands`: its setpoint
    slewed towards the latest target at rate_n_s, the actuator's first-order lag on it."""
    t = np.arange(0.0, end_s, GRID_S)
    cmd_t = np.array([c[0] for c in commands])
    cmd_f = np.array([c[1] for c in commands])
    target = cmd_f[np.searchsorted(cmd_t, t, side="right") - 1]
    setpoint = np.empty(len(t))
    s = float(target[0])
    step = rate_n_s * GRID_S
    for k, goal in enumerate(target.tolist()):
        s += min(step, max(-step, goal - s))
        setpoint[k] = s
    lag = FirstOrderLag(HAND_LAG_S, float(setpoint[0]))
    grip = lag.step(np.round(t * 1e6).astype(np.int64), setpoint)
    return np.column_stack([t, grip])


def gateway_commands(changes: tuple[float, ...], rate_n_s: float) -> tuple[list, list]:
    """The gateway's commands (a target every LOOP_COMMAND_S, its own slew at rate_n_s, as
    the headline's reflex sent them) for each change in turn from HELD_N, and each change's
    (start s, size N, grip before N)."""
    commands = [(0.0, HELD_N)]
    starts = []
    grip = HELD_N
    t0 = 1.0
    for change in changes:
        goal = grip + change
        n = max(1, int(np.ceil(abs(change) / (rate_n_s * sr.LOOP_COMMAND_S))))
        for k in range(1, n + 1):
            value = grip + change * min(1.0, k * rate_n_s * sr.LOOP_COMMAND_S / abs(change))
            commands.append((t0 + (k - 1) * sr.LOOP_COMMAND_S, value))
        starts.append((t0, change, grip))
        grip = goal
        t0 += SETTLE_S
    return commands, starts


def change_s(change_n: float, ramp_n_s: float, follow: HandFollow) -> float:
    """A change's window as the decoder's efference copy sees it: the gateway's ramp
    commanding it, then the hand's window for its last step."""
    steps = max(
        1, int(np.ceil(abs(change_n) / (min(ramp_n_s, follow.rate_n_s) * sr.LOOP_COMMAND_S)))
    )
    return (steps - 1) * sr.LOOP_COMMAND_S + follow.window_s(change_n / steps)


def run(seeds: int, rate_n_s: float, ramp_n_s: float) -> None:
    layout = tuple(LAYOUTS_MM[LAYOUT])
    skin_mm = float(sum(layout))
    follow = HandFollow(rate_n_s)
    commands, starts = gateway_commands(CHANGES_N, min(ramp_n_s, rate_n_s))
    end_s = starts[-1][0] + SETTLE_S
    grip = hand_grip(commands, rate_n_s, end_s)
    per: dict[tuple[str, float], list[int]] = defaultdict(list)
    verdicts: dict[tuple[str, float], list[str]] = defaultdict(list)
    outside = defaultdict(lambda: [0, 0.0])
    offsets: dict[tuple[str, float], list[float]] = defaultdict(list)
    for cover, edge_mm in (("whole", skin_mm + 10.0), ("half", skin_mm / 2)):
        for seed in range(1, seeds + 1):
            rec = loop_recording(
                layout, [[0.0, 0.0]], edge_mm, grip.tolist(), seed, end_s, sr.LOOP_FS_HZ
            )
            told = detect(rec.t_s, rec.force_n, rec.fs_hz)
            onsets = np.array([c.t_s for c in told.contacts])
            inside = np.zeros(len(onsets), bool)
            for start, change, _ in starts:
                until = start + change_s(change, ramp_n_s, follow)
                window = (onsets >= start) & (onsets <= until)
                inside |= window
                per[cover, change].append(int(window.sum()))
                offsets[cover, change].extend((onsets[window] - start).tolist())
                for c in np.flatnonzero(window):
                    check = told.first_verdict.get(told.contacts[c].id)
                    pulse = None if check is None else check.pulse
                    verdicts[cover, change].append({True: "P", False: "S", None: "?"}[pulse])
            clear = np.ones(len(rec.t_s), bool)
            for start, change, _ in starts:
                until = start + change_s(change, ramp_n_s, follow)
                clear &= ~((rec.t_s >= start) & (rec.t_s <= until))
            clear &= rec.t_s >= 0.5  # the detector settled
            outside[cover][0] += int((~inside & (onsets >= 0.5)).sum())
            outside[cover][1] += float(clear.sum()) / rec.fs_hz
    print(
        f"held object, grip {HELD_N:g} N then changes one at a time, gateway and hand slew "
        f"{rate_n_s:g} N/s, gateway ramp {ramp_n_s:g} N/s, hand lag {HAND_LAG_S:g} s, "
        f"{LAYOUT}, seeds 1-{seeds}"
    )
    print(
        f"{'cover':6} {'change N':>8} {'window s':>8} {'contacts/change':>15}  verdicts"
        "  onsets after the first command (s)"
    )
    for (cover, change), counts in per.items():
        v = verdicts[cover, change]
        tally = " ".join(f"{k}{v.count(k)}" for k in "PS?" if v.count(k))
        print(
            f"{cover:6} {change:8.1f} {change_s(change, ramp_n_s, follow):8.2f} "
            f"{np.mean(counts):15.2f}  {tally:8}  "
            + " ".join(f"{x:.3f}" for x in sorted(offsets[cover, change]))
        )
    for sign, name in ((1, "rise"), (-1, "fall")):
        counts = [n for (_, change), ns in per.items() if change * sign > 0 for n in ns]
        late = [x for (_, change), xs in offsets.items() if change * sign > 0 for x in xs]
        onsets = (
            f", onsets {min(late):.3f}-{max(late):.3f} s after its first command" if late else ""
        )
        print(
            f"per {name}: {np.mean(counts):.2f} contacts ({sum(counts)} in {len(counts)}){onsets}"
        )
    for cover, (count, seconds) in outside.items():
        print(
            f"outside the windows ({cover}): {count / seconds:.3f} contacts/s over {seconds:.0f} s"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=4)
    parser.add_argument(
        "--rate",
        type=float,
        default=HandFollow.default().rate_n_s,
        help="the hand's grip rate (0x2404), N/s",
    )
    parser.add_argument(
        "--ramp",
        type=float,
        default=HandFollow.default().rate_n_s,
        help="the gateway's ramp (its commands slewed at this rate), N/s",
    )
    args = parser.parse_args(argv)
    run(args.seeds, args.rate, args.ramp)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

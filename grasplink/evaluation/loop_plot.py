"""The picture of a closed-loop run: what the gateway decoded and did, against the truth.

A recording of a scene with the gateway in the loop holds the truth
(truth.csv) and every frame on the bus (can.asc). The gateway's decoded
slip speed is what its decoder makes of the skin's TPDOs, so it is decoded
again here from can.asc with the same decoder, layout and grip commands (a
replayed log decodes exactly as live traffic); belt and hand commands are the RPDOs,
unpacked through the nodes' EDS mappings.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import can
import numpy as np

from grasplink.core.frames import RPDO_BASES, Frame, node_cob_ids
from grasplink.decoding.base import SlipEstimate
from grasplink.decoding.io import read_grip_commands
from grasplink.errors import RecordingError
from grasplink.gateway.config import parse_config
from grasplink.gateway.service import Gateway
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import KINDS
from grasplink.profiles.pdo_codec import PdoCodec
from grasplink.simulators import signals as sig
from grasplink.simulators.plots import read_csv, read_summary

MN_PER_N = 1000.0


@dataclass
class LoopTrace:
    """Time series of one closed-loop recording (seconds, physical units)."""

    truth: dict[str, np.ndarray]
    decoded_t_s: np.ndarray
    decoded_speed_mm_s: np.ndarray  # |speed|; NaN where the decoder saw no slip or no speed
    decoded_slip: np.ndarray
    belt_t_s: np.ndarray
    belt_target_mrad_s: np.ndarray
    hand_t_s: np.ndarray
    hand_target_n: np.ndarray
    # the lower bound while the decoder reports slip with a range but no speed (else NaN):
    # what the belt shows and the reflex acts on then
    decoded_speed_low_mm_s: np.ndarray


def read_loop(folder: Path) -> LoopTrace:
    folder = Path(folder)
    summary = read_summary(folder / "summary.json")
    truth = read_csv(folder / "truth.csv", (sig.OBJECT_SPEED_MM_S,), None)
    nodes = summary.get("nodes", {})
    layout = summary.get("layout")
    if "skin" not in nodes or layout is None:
        raise RecordingError(f"{folder}: no skin node in this recording: nothing was decoded")
    layout_text = layout if isinstance(layout, str) else ",".join(f"{x:g}" for x in layout)
    estimates = replay_skin(folder / "can.asc", nodes["skin"], layout_text, nodes.get("hand"))
    decoded_t = np.array([e.t_s for e in estimates])
    # A speed counts only while the decoder says the object slips (what the gateway acts on).
    speed = np.array(
        [e.speed_mm_s if e.slip and e.speed_mm_s is not None else np.nan for e in estimates]
    )
    low = np.array(
        [
            e.speed_low_mm_s
            if e.slip and e.speed_mm_s is None and e.speed_low_mm_s is not None
            else np.nan
            for e in estimates
        ]
    )
    slip = np.array([e.slip for e in estimates], dtype=bool)
    belt_t, belt_v, hand_t, hand_n = _commands(folder / "can.asc", nodes)
    return LoopTrace(truth, decoded_t, speed, slip, belt_t, belt_v, hand_t, hand_n, low)


def replay_skin(
    path: Path, skin: dict, layout: str, hand: dict | None = None
) -> list[SlipEstimate]:
    """The gateway's skin decoder updates, replayed from a CAN log through a `Gateway`.

    Frames reach the gateway at their logged times, as they reached it live, so its
    sample timing and its decoder give the same updates it acted on. Only the skin
    node's own frames: this gateway listens to a recording, it masters nothing, and the
    recorded master's NMT commands and heartbeat would be a second master to it. The
    live decoder was also told every grip command the gateway sent the `hand` (its
    efference copy): those are read back from the hand's RPDOs in the log and told
    first, as `grasplink decode` does - only commands at or before a contact's onset
    weigh it, so the updates are the live ones.
    """
    settings = {"node_id": skin["node_id"], "layout": layout}
    if "sample_rate_hz" in skin:
        settings["sample_rate_hz"] = skin["sample_rate_hz"]
    # every other kind off: a gateway masters each kind its configuration does not disable
    others = {k: {"enabled": False} for k in KINDS if k != "skin"}
    data = {"nodes": {"skin": settings} | others}
    gateway = Gateway(parse_config(data, str(path)))
    if hand is not None and gateway.decoder is not None:
        read_grip_commands(path, node_id=hand["node_id"]).feed(gateway.decoder)
    estimates: list[SlipEstimate] = []
    gateway.estimate_listeners.append(lambda t_us, estimate: estimates.append(estimate))
    skin_cob_ids = frozenset(node_cob_ids(skin["node_id"]))
    started = False
    for msg in can.LogReader(str(path)):
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            continue
        if msg.arbitration_id not in skin_cob_ids:
            continue
        t_us = round(msg.timestamp * 1e6)
        if not started:
            gateway.start(t_us)
            started = True
        gateway.receive(Frame(msg.arbitration_id, bytes(msg.data)), t_us)
    return estimates


def _commands(path: Path, nodes: dict) -> tuple[np.ndarray, ...]:
    """Belt target velocity and hand target grip from their RPDO1s."""
    targets = {}
    for kind, index, scale in (
        ("belt", obj.BELT_TARGET_VELOCITY_MRAD_S, 1.0),
        ("hand", obj.HAND_TARGET_GRIP_MN, 1.0 / MN_PER_N),
    ):
        if kind in nodes:
            node_id = nodes[kind]["node_id"]
            rpdo = PdoCodec(kind, node_id).rpdo(1)
            var = next(v for v in rpdo.map if v.od.index == index)
            targets[RPDO_BASES[0] + node_id] = (kind, rpdo, var, scale)
    series: dict[str, list[tuple[float, float]]] = {"belt": [], "hand": []}
    for msg in can.LogReader(str(path)):
        target = targets.get(msg.arbitration_id)
        if target is None or msg.is_error_frame:
            continue
        kind, rpdo, var, scale = target
        if len(msg.data) != (rpdo.length + 7) // 8:
            continue
        rpdo.data = bytearray(msg.data)
        series[kind].append((float(msg.timestamp), float(var.raw) * scale))
    belt = np.array(series["belt"]).reshape(-1, 2)
    hand = np.array(series["hand"]).reshape(-1, 2)
    return belt[:, 0], belt[:, 1], hand[:, 0], hand[:, 1]


def plot_loop(folder: Path) -> Path:
    """loop.png: true vs decoded slip speed; belt commands; grip commanded and applied."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    folder = Path(folder)
    trace = read_loop(folder)
    truth = trace.truth
    t = truth["t_s"]
    fig, axes = plt.subplots(3, 1, figsize=(10, 9), dpi=110, sharex=True)
    ax = axes[0]
    true_speed = np.abs(truth[sig.OBJECT_SPEED_MM_S])
    ax.plot(t, true_speed, color="0.3", lw=1.2, label="true slip speed (magnitude)")
    ax.plot(
        trace.decoded_t_s,
        trace.decoded_speed_mm_s,
        ".",
        ms=2.5,
        color="tab:red",
        label="decoded by the gateway's decoder (while it reports slip)",
    )
    if np.isfinite(trace.decoded_speed_low_mm_s).any():
        ax.plot(
            trace.decoded_t_s,
            trace.decoded_speed_low_mm_s,
            "^",
            ms=2.5,
            color="tab:orange",
            label="lower bound, while it knows only a range (what the belt shows)",
        )
    slipping = trace.decoded_slip.astype(float)
    ax.fill_between(
        trace.decoded_t_s,
        0,
        slipping * ax.get_ylim()[1] * 0.04,
        step="post",
        color="tab:red",
        alpha=0.3,
        lw=0,
        label="decoder's slip flag",
    )
    ax.set_ylabel("slip speed |v| [mm/s]")
    ax.legend(loc="upper right", fontsize=8)
    ax = axes[1]
    ax.step(
        trace.belt_t_s,
        trace.belt_target_mrad_s / 1000,
        where="post",
        color="tab:blue",
        label="belt RPDO target (+ force belt, − slip belt)",
    )
    if sig.BELT_VELOCITY_MRAD_S in truth:
        ax.plot(
            t, truth[sig.BELT_VELOCITY_MRAD_S] / 1000, color="tab:cyan", lw=1, label="belt motor"
        )
    ax.set_ylabel("belt [rad/s]")
    if sig.WEARER_LEVEL in truth:
        twin = ax.twinx()
        twin.step(t, truth[sig.WEARER_LEVEL], where="post", color="tab:purple", lw=1)
        twin.set_ylabel("wearer level e0..e5", color="tab:purple")
        twin.set_ylim(-0.2, 5.2)
    ax.legend(loc="upper left", fontsize=8)
    ax = axes[2]
    ax.step(
        trace.hand_t_s,
        trace.hand_target_n,
        where="post",
        color="tab:orange",
        label="hand RPDO target grip",
    )
    if sig.HAND_GRIP_N in truth:
        ax.plot(t, truth[sig.HAND_GRIP_N], color="tab:brown", lw=1.2, label="grip applied")
    ax.set_ylabel("grip [N]")
    ax.set_xlabel("time [s]")
    if sig.OBJECT_POSITION_MM in truth:
        twin = ax.twinx()
        twin.plot(t, truth[sig.OBJECT_POSITION_MM], color="0.5", lw=0.8, ls="--")
        twin.set_ylabel("object position [mm]", color="0.4")
    ax.legend(loc="upper left", fontsize=8)
    fig.suptitle(f"{folder.name}: the loop on the bus")
    fig.tight_layout()
    out = folder / "loop.png"
    fig.savefig(out)
    plt.close(fig)
    return out


#: A grip command rises in steps at the hand's slew rate (gateway plausibility limits,
#: a step every 10 ms); no higher value within this long ends the raise.
RAISE_STEP_GAP_S = 0.05


def _end_of_raise(t_s: np.ndarray, grip_n: np.ndarray, first: int) -> int:
    """The RPDO where the ramp that begins at `first` reaches its grip (repeated RPDOs of
    one value, the 100 ms refresh, do not end it; a later raise, the wearer's, is apart)."""
    k = first
    while True:
        higher = np.flatnonzero(
            (t_s > t_s[k]) & (t_s <= t_s[k] + RAISE_STEP_GAP_S) & (grip_n > grip_n[k])
        )
        if not len(higher):
            return k
        k = int(higher[0])


def describe_loop(folder: Path) -> list[str]:
    """What happened in a closed-loop recording, in a few lines a person reads."""
    folder = Path(folder)
    trace = read_loop(folder)
    truth = trace.truth
    t = truth["t_s"]
    slipping = truth[sig.OBJECT_SLIPPING] > 0
    lines = []
    if not slipping.any():
        return ["the object never slipped"]
    onset = float(t[np.argmax(slipping)])
    x = truth[sig.OBJECT_POSITION_MM]
    speed = truth[sig.OBJECT_SPEED_MM_S][np.argmax(slipping)]
    lines.append(f"{onset:.2f} s  the object starts to slip ({abs(speed):.0f} mm/s)")
    slip_flags = trace.decoded_t_s[trace.decoded_slip]
    if len(slip_flags):
        lines.append(f"{slip_flags[0]:.2f} s  the gateway's decoder reports the slip")
    shown = trace.belt_t_s[(trace.belt_target_mrad_s < 0) & (trace.belt_t_s >= onset)]
    if len(shown):
        lines.append(f"{shown[0]:.2f} s  belt RPDO: the slip belt runs")
    before = trace.hand_target_n[trace.hand_t_s < onset]
    grip0 = float(before[-1]) if len(before) else float(truth[sig.HAND_GRIP_N][0])
    raised = np.flatnonzero((trace.hand_t_s >= onset) & (trace.hand_target_n > grip0 + 0.5))
    if len(raised):
        i = raised[0]
        j = _end_of_raise(trace.hand_t_s, trace.hand_target_n, i)
        lines.append(
            f"{trace.hand_t_s[i]:.2f} s  hand RPDO: grip raised {grip0:.1f} -> "
            f"{trace.hand_target_n[j]:.1f} N (reached at {trace.hand_t_s[j]:.2f} s)"
        )
    if sig.WEARER_LEVEL in truth:
        level = truth[sig.WEARER_LEVEL]
        changes = np.flatnonzero(np.diff(level) != 0) + 1
        for i in changes[:3]:
            lines.append(f"{t[i]:.2f} s  the wearer contracts to e{int(level[i])}")
    after = np.flatnonzero(~slipping & (t > onset))
    if len(after):
        stop = after[0]
        lines.append(
            f"{t[stop]:.2f} s  the object is held: {x[stop] - x[np.argmax(slipping)]:.0f} mm "
            f"of slip in {t[stop] - onset:.2f} s"
        )
    else:
        lines.append(f"the object was still slipping at {t[-1]:.2f} s")
    if sig.HAND_CRUSHED in truth and truth[sig.HAND_CRUSHED].max() > 0:
        lines.append("the grip crushed the object")
    return sorted(lines, key=lambda line: float(line.split()[0]) if line[0].isdigit() else 1e9)

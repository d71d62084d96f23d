"""`grasplink plot DIR`: pictures of a recording a person would rather look at than read.

Draws only what the recording holds: the FSR signal with the ridge
contacts and the truth (like thesis fig. 5.7), speed and position against
time and against position with the ridges marked (fig. 5.9), EMG with its
envelope and contraction levels, and the belt and hand commands decoded
from the CAN log.
"""

from __future__ import annotations

import csv
import json
import struct
from pathlib import Path

import can
import numpy as np

from grasplink.core.frames import RPDO_BASES, function_of
from grasplink.errors import GrasplinkError
from grasplink.profiles.layouts import parse_layout
from grasplink.simulators import signals as sig

ENVELOPE_WINDOW_S = 0.1


def read_csv(path: Path) -> dict[str, np.ndarray]:
    with path.open() as handle:
        reader = csv.reader(handle)
        header = next(reader)
        rows = np.array([[float(v) for v in row] for row in reader], dtype=np.float64)
    if rows.size == 0:
        return {name: np.zeros(0) for name in header}
    return {name: rows[:, i] for i, name in enumerate(header)}


def ridge_positions_mm(layout) -> np.ndarray | None:
    if layout is None:
        return None
    spacings = parse_layout(layout) if isinstance(layout, str) else tuple(layout)
    return np.concatenate([[0.0], np.cumsum(spacings)])


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_recording(folder: Path) -> list[Path]:
    folder = Path(folder)
    summary_path = folder / "summary.json"
    if not summary_path.is_file():
        raise GrasplinkError(
            f"{folder}: not a recording (no summary.json); "
            "make one with `grasplink run SCENE --out DIR`"
        )
    summary = json.loads(summary_path.read_text())
    ridges = ridge_positions_mm(summary.get("layout"))
    truth = read_csv(folder / "truth.csv") if (folder / "truth.csv").is_file() else {}
    skin = read_csv(folder / "skin.csv") if (folder / "skin.csv").is_file() else {}
    emg = read_csv(folder / "emg.csv") if (folder / "emg.csv").is_file() else {}
    written = []
    title = summary.get("scene", folder.name)
    plt = _pyplot()
    if sig.SKIN_FORCE_N in skin:
        written.append(_plot_fsr(plt, folder, title, skin, truth, ridges))
    if sig.OBJECT_POSITION_MM in truth:
        written.append(_plot_kinematics(plt, folder, title, truth, ridges))
    if sig.EMG_RAW_UV in emg:
        written.append(_plot_emg(plt, folder, title, emg, truth))
    commands = _commands_from_log(folder / "can.asc", summary)
    if commands:
        written.append(_plot_commands(plt, folder, title, commands, truth))
    if (folder / "can.asc").is_file():
        written.append(_plot_bus(plt, folder, title, summary))
    return written


BUS_BIN_S = 0.1


def _function_of(can_id: int) -> str:
    """The service of a CAN-ID, PDO numbers folded ("TPDO", "RPDO", "SDO", "EMCY/SYNC")."""
    name = function_of(can_id)[0]
    if name in ("EMCY", "SYNC"):
        return "EMCY/SYNC"
    return (
        name.rstrip("1234").removesuffix(" tx").removesuffix(" rx") if name[0] != "0" else "other"
    )


def _plot_bus(plt, folder, title, summary) -> Path:
    """Frames per second by CANopen function, and bus load, over the scene."""
    from grasplink.bus.load import frame_bits_worst_case

    duration_s = float(summary.get("duration_s") or 1.0)
    bins = np.arange(0.0, duration_s + BUS_BIN_S, BUS_BIN_S)
    series: dict[str, list[float]] = {}
    bits, times = [], []
    for msg in can.ASCReader(str(folder / "can.asc")):
        name = "error frame" if msg.is_error_frame else _function_of(msg.arbitration_id)
        series.setdefault(name, []).append(msg.timestamp)
        times.append(msg.timestamp)
        bits.append(
            23 if msg.is_error_frame else frame_bits_worst_case(msg.dlc, msg.is_remote_frame)
        )
    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), dpi=110, sharex=True)
    for name, stamps in sorted(series.items()):
        counts, _ = np.histogram(stamps, bins=bins)
        axes[0].step(bins[:-1], counts / BUS_BIN_S, where="post", label=name)
    axes[0].set_ylabel("frames/s")
    axes[0].legend(fontsize=8, ncol=3)
    load, _ = np.histogram(times, bins=bins, weights=bits)
    axes[1].step(bins[:-1], 100 * load / BUS_BIN_S / 1e6, where="post", color="tab:red")
    axes[1].set_ylabel("bus load [% of 1 Mbit/s]")
    axes[1].set_xlabel("time [s]")
    axes[0].set_title(f"{title}: bus traffic (worst-case stuffing)")
    return _save(plt, fig, folder / "bus.png")


def _contact_times(truth: dict[str, np.ndarray], ridges: np.ndarray | None) -> np.ndarray:
    """Times the leading edge crosses a ridge (linear interpolation between truth samples)."""
    if ridges is None or sig.OBJECT_POSITION_MM not in truth:
        return np.zeros(0)
    t, x = truth["t_s"], truth[sig.OBJECT_POSITION_MM]
    times = []
    for ridge in ridges:
        beyond = x >= ridge
        crossing = np.nonzero(beyond[:-1] != beyond[1:])[0]
        for i in crossing:
            frac = (ridge - x[i]) / (x[i + 1] - x[i])
            times.append(t[i] + frac * (t[i + 1] - t[i]))
    return np.sort(np.array(times))


def _plot_fsr(plt, folder, title, skin, truth, ridges) -> Path:
    fig, ax = plt.subplots(figsize=(10, 4.5), dpi=110)
    ax.plot(skin["t_s"], skin[sig.SKIN_FORCE_N], lw=0.8, color="tab:red", label="FSR signal [N]")
    contacts = _contact_times(truth, ridges)
    for i, t in enumerate(contacts):
        label = "ridge contact" if i == 0 else None
        ax.axvline(t, color="tab:orange", lw=0.7, ls="--", label=label)
    ax.set_xlabel("time [s]")
    ax.set_ylabel("force [N]")
    if sig.OBJECT_POSITION_MM in truth:
        twin = ax.twinx()
        twin.plot(
            truth["t_s"],
            truth[sig.OBJECT_POSITION_MM],
            color="tab:blue",
            lw=1,
            label="leading edge (truth) [mm]",
        )
        twin.set_ylabel("position [mm]", color="tab:blue")
        twin.legend(loc="upper right", fontsize=8)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"{title}: FSR signal, ridge contacts and truth")
    return _save(plt, fig, folder / "fsr.png")


def _plot_kinematics(plt, folder, title, truth, ridges) -> Path:
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2), dpi=110)
    t, x, v = truth["t_s"], truth[sig.OBJECT_POSITION_MM], truth.get(sig.OBJECT_SPEED_MM_S)
    axes[0].plot(t, x, color="tab:blue", label="position [mm]")
    axes[0].set_xlabel("time [s]")
    axes[0].set_ylabel("leading edge [mm]")
    if v is not None:
        twin = axes[0].twinx()
        twin.plot(t, v, color="tab:green", lw=0.8, label="speed [mm/s]")
        twin.set_ylabel("speed [mm/s]", color="tab:green")
        axes[1].plot(x, v, color="tab:green", lw=0.9)
    if ridges is not None:
        for r in ridges:
            axes[1].axvline(r, color="tab:orange", lw=0.8)
    axes[1].set_xlabel("leading edge [mm] (orange: ridges)")
    axes[1].set_ylabel("speed [mm/s]")
    axes[0].set_title("position and speed over time")
    axes[1].set_title("speed along the skin (cf. thesis fig. 5.9)")
    fig.suptitle(title)
    return _save(plt, fig, folder / "kinematics.png")


def _plot_emg(plt, folder, title, emg, truth) -> Path:
    t, raw = emg["t_s"], emg[sig.EMG_RAW_UV]
    rate = 1.0 / np.median(np.diff(t)) if len(t) > 1 else 1.0
    window = max(1, int(ENVELOPE_WINDOW_S * rate))
    envelope = np.convolve(np.abs(raw), np.ones(window) / window, mode="same")
    fig, ax = plt.subplots(figsize=(10, 4.2), dpi=110)
    ax.plot(t, raw, lw=0.3, color="0.6", label="surface EMG [µV]")
    ax.plot(t, envelope, lw=1.2, color="tab:purple", label="envelope (rectified, 100 ms) [µV]")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("µV")
    if sig.WEARER_LEVEL in truth:
        twin = ax.twinx()
        twin.step(
            truth["t_s"],
            truth[sig.WEARER_LEVEL],
            where="post",
            color="tab:orange",
            label="contraction level",
        )
        twin.set_ylabel("level (e0..e5)", color="tab:orange")
        twin.set_ylim(-0.2, 5.5)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title(f"{title}: EMG")
    return _save(plt, fig, folder / "emg.png")


def _commands_from_log(path: Path, summary: dict) -> dict[str, tuple[list, list]]:
    nodes = summary.get("nodes", {})
    targets = {}
    if "belt" in nodes:
        targets[RPDO_BASES[0] + nodes["belt"]["node_id"]] = ("belt command [rad/s]", "<Hi", 1e-3)
    if "hand" in nodes:
        targets[RPDO_BASES[0] + nodes["hand"]["node_id"]] = ("hand grip command [N]", "<HI", 1e-3)
    if not targets or not path.is_file():
        return {}
    series: dict[str, tuple[list, list]] = {}
    for msg in can.ASCReader(str(path)):
        target = targets.get(msg.arbitration_id)
        if target is None or msg.is_error_frame or len(msg.data) < 6:
            continue
        label, fmt, scale = target
        _, value = struct.unpack_from(fmt, msg.data)
        times, values = series.setdefault(label, ([], []))
        times.append(msg.timestamp)
        values.append(value * scale)
    return series


def _plot_commands(plt, folder, title, commands, truth) -> Path:
    fig, ax = plt.subplots(figsize=(10, 4.2), dpi=110)
    for label, (times, values) in commands.items():
        ax.step(times, values, where="post", label=label)
    if sig.BELT_VELOCITY_MRAD_S in truth:
        ax.plot(
            truth["t_s"],
            truth[sig.BELT_VELOCITY_MRAD_S] / 1000,
            lw=1,
            label="belt velocity [rad/s]",
        )
    if sig.HAND_GRIP_N in truth:
        ax.plot(truth["t_s"], truth[sig.HAND_GRIP_N], lw=1, label="grip force [N]")
    ax.axhline(0, color="0.7", lw=0.6)
    ax.set_xlabel("time [s]")
    ax.set_title(f"{title}: commands on the bus (+ force belt, - slip belt)")
    ax.legend(fontsize=8)
    return _save(plt, fig, folder / "commands.png")


def _save(plt, fig, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path

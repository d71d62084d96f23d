"""`grasplink plot DIR`: pictures of a recording a person would rather look at than read.

Draws only what the recording holds: the FSR signal with the ridge
contacts and the truth (like thesis fig. 5.7), speed and position against
time and against position with the ridges marked (fig. 5.9), EMG with its
envelope and contraction levels, and the belt and hand commands decoded
from the CAN log.

Every file is read and checked before anything is drawn (`read_summary`,
`read_csv`, `read_can_log`): a truncated, binary, empty or mis-shaped file is
one `RecordingError` naming the file and its line or key, never a traceback
and never half the pictures. Truncation at a line boundary is caught by
comparing with the counts summary.json keeps (rows per domain, frames).
"""

from __future__ import annotations

import io
import json
import math
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeGuard

import can
import numpy as np

from grasplink.core.frames import RPDO_BASES, function_of
from grasplink.errors import ConfigError, GrasplinkError, RecordingError
from grasplink.profiles.layouts import parse_layout
from grasplink.simulators import signals as sig

ENVELOPE_WINDOW_S = 0.1
BUS_BIN_S = 0.1
ASC_END = "End TriggerBlock"  # python-can's ASCWriter closes every log with this line
DOMAIN_FILES = {"physics": "truth.csv", "skin": "skin.csv", "emg": "emg.csv"}
# Columns a domain file must hold to be what its name says (truth.csv's vary by scene).
REQUIRED_COLUMNS = {"skin.csv": (sig.SKIN_FORCE_N,), "emg.csv": (sig.EMG_RAW_UV,)}
HISTOGRAM_BATCH = 8192  # CAN frames binned at a time: bounded memory for long logs


def plot_recording(folder: Path) -> list[Path]:
    """Draw every picture the recording in `folder` has data for; the PNG paths written."""
    folder = Path(folder)
    summary_path = folder / "summary.json"
    if not summary_path.is_file():
        raise GrasplinkError(
            f"{folder}: not a recording (no summary.json); "
            "make one with `grasplink run SCENE --out DIR`"
        )
    summary = read_summary(summary_path)
    ridges = ridge_positions_mm(summary.get("layout"))
    listed = set(summary.get("files", {}).values())
    samples = summary.get("samples", {})
    tables: dict[str, dict[str, np.ndarray]] = {}
    for domain, name in DOMAIN_FILES.items():
        path = folder / name
        if name in listed or path.exists():
            tables[name] = read_csv(path, REQUIRED_COLUMNS.get(name, ()), samples.get(domain))
    truth, skin, emg = (tables.get(name, {}) for name in ("truth.csv", "skin.csv", "emg.csv"))
    can_path = folder / "can.asc"
    log = read_can_log(can_path, summary) if "can.asc" in listed or can_path.exists() else None
    written = []
    title = summary.get("scene", folder.name)
    plt = _pyplot()
    if sig.SKIN_FORCE_N in skin:
        written.append(_plot_fsr(plt, folder, title, skin, truth, ridges))
    if sig.OBJECT_POSITION_MM in truth:
        written.append(_plot_kinematics(plt, folder, title, truth, ridges))
    if sig.EMG_RAW_UV in emg:
        written.append(_plot_emg(plt, folder, title, emg, truth))
    if log is not None and log.commands:
        written.append(_plot_commands(plt, folder, title, log.commands, truth))
    if log is not None:
        written.append(_plot_bus(plt, folder, title, log))
    return written


# -- reading a recording ----------------------------------------------------------------------
def _read_text(path: Path) -> str:
    """The file as text; RecordingError when it is missing, a folder, unreadable or binary."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file (summary.json lists it)") from None
    except IsADirectoryError:
        raise RecordingError(f"{path}: is a directory, not a file") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror or exc}") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data[: exc.start].count(b"\n") + 1
        raise RecordingError(
            f"{path}:{line}: not a text file (byte 0x{data[exc.start]:02X} is not UTF-8)"
        ) from None


def read_summary(path: Path) -> dict:
    """summary.json, with the keys the plots use checked for type and range."""
    text = _read_text(path)
    if not text.strip():
        raise RecordingError(
            f"{path}: empty file; expected the JSON summary `grasplink run` writes"
        )
    try:
        summary = json.loads(text)
    except json.JSONDecodeError as exc:
        cut = " (the file ends early: truncated?)" if exc.pos >= len(text.rstrip()) else ""
        raise RecordingError(
            f"{path}:{exc.lineno}: not valid JSON: {exc.msg} at column {exc.colno}{cut}"
        ) from None
    if not isinstance(summary, dict):
        raise RecordingError(f"{path}: expected a JSON object, got a {type(summary).__name__}")
    _check_summary(path, summary)
    return summary


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _is_count(value: object) -> TypeGuard[int]:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _check_summary(path: Path, summary: dict) -> None:
    """Type and range of every summary key the plots read; the message names the key."""

    def fail(key: str, value: object, expected: str) -> RecordingError:
        return RecordingError(f"{path}: {key}: expected {expected}, got {value!r}")

    if not isinstance(summary.get("scene", ""), str):
        raise fail("scene", summary["scene"], "a string")
    duration = summary.get("duration_s")
    if duration is not None and not (_is_number(duration) and duration > 0):
        raise fail("duration_s", duration, "a number of seconds > 0")
    layout = summary.get("layout")
    if isinstance(layout, str):
        try:
            parse_layout(layout)
        except ConfigError as exc:
            raise RecordingError(f"{path}: layout: {exc}") from None
    elif layout is not None and not (
        isinstance(layout, list) and layout and all(_is_number(s) and s > 0 for s in layout)
    ):
        raise fail("layout", layout, "a layout name or a list of spacings in mm > 0")
    for key in ("nodes", "files", "samples", "frames"):
        if not isinstance(summary.get(key, {}), dict):
            raise fail(key, summary[key], "an object")
    for kind, node in summary.get("nodes", {}).items():
        node_id = node.get("node_id") if isinstance(node, dict) else node
        if not (_is_count(node_id) and 1 <= node_id <= 127):
            raise fail(f"nodes.{kind}.node_id", node_id, "a node-ID 1..127")
    known = {**DOMAIN_FILES, "can": "can.asc"}
    for domain, name in summary.get("files", {}).items():
        if domain in known and name != known[domain]:
            raise fail(f"files.{domain}", name, repr(known[domain]))
    for key in ("samples", "frames"):
        for name, count in summary.get(key, {}).items():
            if not _is_count(count):
                raise fail(f"{key}.{name}", count, "a count >= 0")
    if not _is_count(summary.get("error_frames", 0)):
        raise fail("error_frames", summary["error_frames"], "a count >= 0")


def read_csv(
    path: Path, required: tuple[str, ...] = (), expected_rows: int | None = None
) -> dict[str, np.ndarray]:
    """A recorded CSV: header t_s,signal...; rows of numbers; t_s finite and never going back.

    `required` columns must be present; `expected_rows` (from summary.json) must match.
    """
    text = _read_text(path)
    if not text.strip():
        raise RecordingError(f"{path}: empty file; expected a header line starting with t_s")
    lines = text.split("\n")
    if lines[-1]:
        raise RecordingError(f"{path}:{len(lines)}: the last line is cut off (truncated?)")
    lines.pop()
    header = [name.strip() for name in lines[0].split(",")]
    if header[0] != "t_s" or not all(header) or len(set(header)) != len(header):
        raise RecordingError(
            f"{path}:1: header must be t_s and distinct signal names, found {lines[0].strip()!r}"
        )
    missing = [name for name in required if name not in header]
    if missing:
        raise RecordingError(
            f"{path}:1: no column {', '.join(missing)} (columns: {', '.join(header)})"
        )
    rows = np.empty((len(lines) - 1, len(header)), dtype=np.float64)
    for k, line in enumerate(lines[1:]):
        number = k + 2
        fields = line.split(",")
        if len(fields) != len(header):
            raise RecordingError(
                f"{path}:{number}: {len(fields)} values, the header names {len(header)} columns"
            )
        try:
            rows[k] = [float(value) for value in fields]
        except ValueError:
            name, value = next(
                (n, v) for n, v in zip(header, fields, strict=True) if not _is_float(v)
            )
            raise RecordingError(
                f"{path}:{number}: {name} {value.strip()!r} is not a number"
            ) from None
        if not math.isfinite(rows[k, 0]):
            raise RecordingError(f"{path}:{number}: t_s {fields[0].strip()!r} is not finite")
        if k and rows[k, 0] < rows[k - 1, 0]:
            raise RecordingError(
                f"{path}:{number}: t_s {fields[0].strip()} is before the previous row's "
                f"{rows[k - 1, 0]:g} (time must not go back)"
            )
    if expected_rows is not None and len(rows) != expected_rows:
        raise RecordingError(
            f"{path}: {len(rows)} rows, summary.json counts {expected_rows} (truncated or edited?)"
        )
    return {name: rows[:, i] for i, name in enumerate(header)}


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


class _NumberedLines(io.StringIO):
    """Text whose iteration counts lines, so a problem python-can meets names its line."""

    line = 0

    # typeshed gives StringIO _IOBase's `__next__ -> bytes` through io.TextIOBase as well as
    # its own `-> str`: any override of it is flagged (typeshed ignores its own misc there).
    def __next__(self) -> str:  # type: ignore[override]
        self.line += 1
        return super().__next__()


@dataclass
class CanLog:
    """What the plots need from can.asc, gathered in one pass."""

    bins_s: np.ndarray  # BUS_BIN_S bin edges over the scene
    counts: dict[str, np.ndarray] = field(default_factory=dict)  # frames per bin, by function
    bits: np.ndarray = field(default_factory=lambda: np.zeros(0))  # bus bits per bin
    commands: dict[str, tuple[list[float], list[float]]] = field(default_factory=dict)
    frames: int = 0
    _batch: list[tuple[str, float, int]] = field(default_factory=list)

    def add(self, name: str, t_s: float, bits: int) -> None:
        self.frames += 1
        self._batch.append((name, t_s, bits))
        if len(self._batch) >= HISTOGRAM_BATCH:
            self.flush()

    def flush(self) -> None:
        """Bin the batch (np.histogram's edges, as before: one frame per bin either way)."""
        if not self._batch:
            return
        names, times, bits = zip(*self._batch, strict=True)
        times_s, names_a = np.asarray(times), np.asarray(names)
        self.bits += np.histogram(times_s, bins=self.bins_s, weights=np.asarray(bits))[0]
        for name in set(names):
            counts = np.histogram(times_s[names_a == name], bins=self.bins_s)[0]
            self.counts[name] = self.counts.get(name, 0) + counts
        self._batch.clear()


def read_can_log(path: Path, summary: dict) -> CanLog:
    """can.asc as python-can reads it, checked: complete, every frame well-formed and counted."""
    from grasplink.bus.load import frame_bits_worst_case

    text = _read_text(path)
    if not text.strip():
        raise RecordingError(f"{path}: empty file; expected a CAN log (Vector ASC)")
    if text.rstrip().rsplit("\n", 1)[-1].strip() != ASC_END:
        raise RecordingError(f"{path}: no '{ASC_END}' line at the end (truncated?)")
    duration_s = float(summary.get("duration_s") or 1.0)
    bins = np.arange(0.0, duration_s + BUS_BIN_S, BUS_BIN_S)
    log = CanLog(bins, bits=np.zeros(len(bins) - 1))
    targets = _command_targets(summary)
    lines = _NumberedLines(text)
    try:
        for msg in can.ASCReader(lines):
            _check_frame(path, lines.line, msg)
            if msg.is_error_frame:
                log.add("error frame", msg.timestamp, 23)
                continue
            bits = frame_bits_worst_case(msg.dlc, msg.is_remote_frame)
            log.add(_function_of(msg.arbitration_id), msg.timestamp, bits)
            target = targets.get(msg.arbitration_id)
            if target is not None and len(msg.data) >= 6:
                label, fmt, scale = target
                _, value = struct.unpack_from(fmt, msg.data)
                times, values = log.commands.setdefault(label, ([], []))
                times.append(msg.timestamp)
                values.append(value * scale)
    except ValueError as exc:  # python-can on a malformed number or frame
        raise RecordingError(f"{path}:{lines.line}: not a CAN log line: {exc}") from None
    log.flush()
    if "frames" in summary:
        expected = sum(summary["frames"].values()) + summary.get("error_frames", 0)
        if log.frames != expected:
            raise RecordingError(
                f"{path}: {log.frames} frames, summary.json counts {expected} "
                "(truncated or edited?)"
            )
    return log


def _check_frame(path: Path, line: int, msg: can.Message) -> None:
    if not (math.isfinite(msg.timestamp) and msg.timestamp >= 0):
        raise RecordingError(f"{path}:{line}: time {msg.timestamp} s is not a time in the run")
    if msg.is_error_frame:
        return
    if msg.is_extended_id or msg.arbitration_id > 0x7FF:
        raise RecordingError(
            f"{path}:{line}: CAN-ID 0x{msg.arbitration_id:X} is not an 11-bit CANopen identifier"
        )
    if not msg.is_remote_frame and len(msg.data) != msg.dlc:
        raise RecordingError(
            f"{path}:{line}: DLC {msg.dlc} but {len(msg.data)} data bytes (cut off?)"
        )


def _command_targets(summary: dict) -> dict[int, tuple[str, str, float]]:
    """RPDO1 CAN-ID -> (label, struct format of controlword + target, scale to SI units)."""
    nodes = summary.get("nodes", {})
    targets = {}
    if "belt" in nodes:
        targets[RPDO_BASES[0] + nodes["belt"]["node_id"]] = ("belt command [rad/s]", "<Hi", 1e-3)
    if "hand" in nodes:
        targets[RPDO_BASES[0] + nodes["hand"]["node_id"]] = ("hand grip command [N]", "<HI", 1e-3)
    return targets


# -- drawing ------------------------------------------------------------------------------------
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


def _function_of(can_id: int) -> str:
    """The service of a CAN-ID, PDO numbers folded ("TPDO", "RPDO", "SDO", "EMCY/SYNC")."""
    name = function_of(can_id)[0]
    if name in ("EMCY", "SYNC"):
        return "EMCY/SYNC"
    return (
        name.rstrip("1234").removesuffix(" tx").removesuffix(" rx") if name[0] != "0" else "other"
    )


def _plot_bus(plt, folder, title, log: CanLog) -> Path:
    """Frames per second by CANopen function, and bus load, over the scene."""
    bins = log.bins_s
    fig, axes = plt.subplots(2, 1, figsize=(10, 5.5), dpi=110, sharex=True)
    for name, counts in sorted(log.counts.items()):
        axes[0].step(bins[:-1], counts / BUS_BIN_S, where="post", label=name)
    axes[0].set_ylabel("frames/s")
    if log.counts:
        axes[0].legend(fontsize=8, ncol=3)
    axes[1].step(bins[:-1], 100 * log.bits / BUS_BIN_S / 1e6, where="post", color="tab:red")
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

"""A folder written by `grasplink run`, made into what the live page is fed: the JSON
tree's messages on the recording's clock, and the truth beside them (docs/view.md,
Recordings).

The page's meaning stays the live one's: can.asc is replayed through a sans-IO `Gateway`
at the logged times, its snapshots become messages through telemetry's `JsonTree`, and
`ViewState` takes them as it takes a broker's. The gateway listens only: what it would
send is dropped, and what the recorded master sent on the bus (NMT commands, its own
heartbeat) is not shown to it, or it would take them for a second master. With the
run's gateway settings (the scene's `[controller]`), the same frames at the same times
make the same decisions, so its belt and hand commands are the run's.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
import numpy as np

from grasplink.core.frames import HEARTBEAT_BASE, NMT_COB_ID, SDO_RX_BASE, Frame
from grasplink.core.params import Params
from grasplink.errors import GrasplinkError, RecordingError
from grasplink.gateway.config import GatewayConfig, scene_config
from grasplink.gateway.service import Gateway
from grasplink.simulators import signals as sig
from grasplink.simulators.plots import read_can_log, read_csv, read_summary
from grasplink.simulators.scene import load_scene
from grasplink.surfaces.telemetry.buffer import Sample
from grasplink.surfaces.telemetry.json_tree import JsonTree
from grasplink.surfaces.telemetry.transport import TelemetryPublisher

TRUTH_PERIOD_S = 0.02  # truth.csv (1 kHz) is shown at 50 Hz: the ridge dips (50 ms) stay
TRUTH_KIND = "truth"  # the points' kind beside the nodes' (`skin`, `belt`, …)
#: the truth the page shows: its field -> (truth.csv column, made absolute)
TRUTH_FIELDS: dict[str, tuple[str, bool]] = {
    "speed_mm_s": (sig.OBJECT_SPEED_MM_S, True),  # beside the decoder's |speed|
    "position_mm": (sig.OBJECT_POSITION_MM, False),
    "slipping": (sig.OBJECT_SLIPPING, False),
    "grip_n": (sig.HAND_GRIP_N, False),
}
_NOT_ID = re.compile(r"[^A-Za-z0-9_.:-]")


@dataclass(frozen=True, slots=True)
class Timed:
    """One JSON-tree message as the page is fed it: when in the run, topic, payload."""

    t_s: float
    topic: str
    payload: bytes
    retained: bool  # state that holds until replaced (fed again after a seek)


@dataclass(frozen=True)
class Recording:
    """A run folder replayed once: every message and truth point, in time order."""

    folder: Path
    gateway_id: str  # the page's gateway: the folder's name, as one topic level
    duration_s: float
    messages: tuple[Timed, ...]
    truth_t_s: np.ndarray
    truth: dict[str, np.ndarray]  # TRUTH_FIELDS' fields truth.csv has, at truth_t_s
    settings: str  # where the gateway's settings came from, said on the page


def load_recording(folder: Path) -> Recording:
    """Check the folder's files and replay it; RecordingError naming the file otherwise."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RecordingError(f"{folder}: not a folder (expected one `grasplink run --out` wrote)")
    summary_path = folder / "summary.json"
    if not summary_path.is_file():
        raise RecordingError(
            f"{summary_path}: missing: {folder} is not a folder `grasplink run` wrote"
        )
    summary = read_summary(summary_path)
    nodes = summary.get("nodes") or {}
    if not nodes:
        raise RecordingError(f"{summary_path}: nodes: no node in this run: nothing to show")
    for name in ("can.asc", "truth.csv"):
        if not (folder / name).is_file():
            raise RecordingError(f"{folder / name}: missing (every run folder has one)")
    # a scene without the object or the hand has fewer columns: the page shows what is there
    truth = read_csv(folder / "truth.csv", (), (summary.get("samples") or {}).get("physics"))
    read_can_log(folder / "can.asc", summary)  # complete and well-formed, else named
    config, settings = _gateway_config(summary, summary_path)
    duration_s = float(summary.get("simulated_s") or summary.get("duration_s") or 0.0)
    gateway_id = _NOT_ID.sub("_", folder.resolve().name)[:64] or "recording"
    messages = replay(folder / "can.asc", config, gateway_id)
    if not messages:
        raise RecordingError(f"{folder / 'can.asc'}: no frames: an empty log")
    duration_s = max(duration_s, messages[-1].t_s)
    t_s, fields = _truth_points(truth)
    return Recording(folder, gateway_id, duration_s, messages, t_s, fields, settings)


def replay(can_log: Path, config: GatewayConfig, gateway_id: str) -> tuple[Timed, ...]:
    """can.asc through a listening `Gateway` at the logged times, its snapshots through a
    `JsonTree`: the messages a broker would have carried (time-ordered)."""
    gateway = Gateway(config)
    tree = JsonTree(gateway_id)
    extra = {"controls": TelemetryPublisher.controls_of(config), "telemetry": {}}
    master_frames = {NMT_COB_ID, HEARTBEAT_BASE + config.node_id}
    out: list[Timed] = []
    last_snapshot = None
    now_us: int | None = None

    def take(t_us: int) -> None:
        nonlocal last_snapshot
        snapshot = gateway.latest
        if snapshot is None or snapshot is last_snapshot:
            return
        last_snapshot = snapshot
        for message in tree.update([Sample(t_us // 1000, snapshot)], extra):
            out.append(Timed(t_us / 1e6, message.topic, message.payload, message.retain))

    def advance_to(t_us: int) -> None:
        """Every deadline before `t_us`, as a runner would call them."""
        nonlocal now_us
        assert now_us is not None
        while (due := gateway.next_deadline_us()) is not None and due < t_us:
            now_us = max(due, now_us + 1)
            gateway.advance(now_us)
            take(now_us)

    for msg in can.LogReader(str(can_log)):
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            continue
        can_id = msg.arbitration_id
        if can_id in master_frames or SDO_RX_BASE < can_id <= SDO_RX_BASE + 0x7F:
            continue  # the recorded master's, not the nodes'
        t_us = max(0, round(msg.timestamp * 1e6))
        if now_us is None:
            now_us = t_us
            gateway.start(t_us)
            first, _ = tree.on_connect(t_us // 1000)
            out += [Timed(t_us / 1e6, m.topic, m.payload, m.retain) for m in first]
        advance_to(t_us)
        now_us = max(now_us, t_us)
        gateway.receive(Frame(can_id, bytes(msg.data)), now_us)
    if now_us is not None:
        advance_to(now_us + 1)
    return tuple(out)


def _gateway_config(summary: dict[str, Any], summary_path: Path) -> tuple[GatewayConfig, str]:
    """The run's gateway settings: the `[controller]` summary.json recorded as run, else
    its scene's when the scene file named in summary.json is there (runs from before the
    record), else the defaults, said so (the belt and hand commands shown are then a
    default gateway's). Node-IDs, skin and sample rates from summary.json."""
    nodes = {
        kind: {"node_id": node["node_id"]} for kind, node in (summary.get("nodes") or {}).items()
    }
    layout = summary.get("layout")
    if "skin" in nodes and layout is not None:
        nodes["skin"]["layout"] = (
            layout if isinstance(layout, str) else ",".join(f"{s:g}" for s in layout)
        )
    source = str(summary_path)
    options = Params({}, source, "controller")
    settings = (
        "default gateway settings (the run's scene file was not found): "
        "the belt and hand commands shown may not be the run's"
    )
    scene_path = summary.get("path")
    recorded = summary.get("controller_options")
    if summary.get("controller") == "gateway" and isinstance(recorded, dict):
        # as run; relative file names in it resolve against the run's scene file
        base = scene_path if isinstance(scene_path, str) else source
        options = Params(dict(recorded), base, "controller")
        settings = f"gateway settings as run ({summary_path.name} controller_options)"
        candidates: list[Path] = []
    else:
        candidates = (
            [Path(scene_path), summary_path.parent / Path(scene_path).name]
            if isinstance(scene_path, str)
            else []
        )
    for kind, node in (summary.get("nodes") or {}).items():
        if kind in nodes and "sample_rate_hz" in node:
            nodes[kind]["sample_rate_hz"] = node["sample_rate_hz"]
    for candidate in candidates:
        if not candidate.is_file():
            continue
        try:
            scene = load_scene(candidate)
        except GrasplinkError:
            break
        if scene.controller.name == "gateway":
            options = scene.controller.params()
            for kind, scene_node in scene.node_settings().items():
                if kind in nodes and "sample_rate_hz" in scene_node:
                    nodes[kind]["sample_rate_hz"] = scene_node["sample_rate_hz"]
            settings = f"gateway settings from {candidate} [controller]"
        else:
            settings = (
                f"default gateway settings ({candidate} has no gateway controller): "
                "the belt and hand commands shown were not the run's"
            )
        break
    try:
        return scene_config(options, nodes), settings
    except GrasplinkError as exc:
        raise RecordingError(f"{summary_path}: the run's gateway settings: {exc}") from None


def _truth_points(truth: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The truth at TRUTH_PERIOD_S: the row at or just before each tick."""
    t = truth["t_s"]
    if not len(t):
        return np.zeros(0), {}
    ticks = np.arange(t[0], t[-1] + TRUTH_PERIOD_S / 2, TRUTH_PERIOD_S)
    rows = np.clip(np.searchsorted(t, ticks, side="right") - 1, 0, len(t) - 1)
    fields = {}
    for name, (column, magnitude) in TRUTH_FIELDS.items():
        if column not in truth:
            continue
        values = truth[column][rows]
        fields[name] = np.abs(values) if magnitude else values
    return ticks, fields

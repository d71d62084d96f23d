"""What an external master did with a scene run on a live bus, judged from its recording.

`grasplink run SCENE --bus URL --master external` records truth.csv and can.asc
like an in-process run, but the loop is closed by whoever masters the bus. The
master is known only by what it sent: NMT commands, SDO requests and RPDOs to the
scene's nodes, its heartbeat. `master_activity` reads that from can.asc;
`judge_recording` hands the same recording to the closed-loop judgement of the
in-process trials (`loop.outcome`: the belt and hand RPDOs, the EMG envelope and the
truth), so a HIL run and an in-silico trial are judged alike.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import can

from grasplink.core.frames import (
    HEARTBEAT_BASE,
    NMT_COB_ID,
    RPDO_BASES,
    SDO_RX_BASE,
    Frame,
)
from grasplink.core.nmt import NmtCommand
from grasplink.errors import RecordingError
from grasplink.evaluation.loop import LOOP_KINDS, BusLog, Outcome
from grasplink.gateway.config import GatewayConfig, scene_config
from grasplink.profiles.layouts import parse_layout
from grasplink.simulators import signals as sig
from grasplink.simulators.plots import read_csv, read_summary
from grasplink.simulators.scene import load_scene

US_PER_S = 1_000_000


@dataclass
class MasterActivity:
    """What the bus carried from a master to the recorded nodes (times in s of scene time)."""

    node_ids: dict[str, int]  # the recorded nodes by kind
    started_s: dict[str, float] = field(default_factory=dict)  # first NMT start per kind
    sdo_requests: dict[str, int] = field(default_factory=dict)
    rpdos: dict[str, int] = field(default_factory=dict)
    rpdo_times_s: dict[str, list[float]] = field(default_factory=dict)
    heartbeats: dict[int, int] = field(default_factory=dict)  # other node-IDs' heartbeats

    @property
    def masters(self) -> list[int]:
        """Node-IDs other than the recorded nodes' that sent a heartbeat."""
        return sorted(self.heartbeats)

    def lines(self) -> list[str]:
        """A few lines a person reads."""
        masters = ", ".join(f"0x{n:02X}" for n in self.masters) or "none"
        lines = [f"heartbeats from other node-IDs (the master's): {masters}"]
        for kind, node_id in self.node_ids.items():
            started = self.started_s.get(kind)
            what = f"NMT start at {started:.2f} s" if started is not None else "never started"
            lines.append(
                f"{kind} 0x{node_id:02X}: {what}; {self.sdo_requests.get(kind, 0)} SDO "
                f"requests, {self.rpdos.get(kind, 0)} RPDOs"
            )
        return lines


def master_activity(can_asc: Path, node_ids: dict[str, int]) -> MasterActivity:
    """Read from a CAN log what a master sent to the nodes `node_ids` (kind -> node-ID)."""
    kind_of = {node_id: kind for kind, node_id in node_ids.items()}
    rpdo_of = {base + node_id: kind for kind, node_id in node_ids.items() for base in RPDO_BASES}
    activity = MasterActivity(dict(node_ids))
    for kind in node_ids:
        activity.rpdo_times_s[kind] = []
    for msg in _frames(can_asc):
        can_id, data, t_s = msg.arbitration_id, bytes(msg.data), float(msg.timestamp)
        if can_id == NMT_COB_ID and len(data) == 2 and data[0] == NmtCommand.START:
            for node_id, kind in kind_of.items():
                if data[1] in (0, node_id):
                    activity.started_s.setdefault(kind, t_s)
        elif can_id - SDO_RX_BASE in kind_of:
            kind = kind_of[can_id - SDO_RX_BASE]
            activity.sdo_requests[kind] = activity.sdo_requests.get(kind, 0) + 1
        elif can_id in rpdo_of:
            kind = rpdo_of[can_id]
            activity.rpdos[kind] = activity.rpdos.get(kind, 0) + 1
            activity.rpdo_times_s[kind].append(t_s)
        elif HEARTBEAT_BASE < can_id <= HEARTBEAT_BASE + 127 and not msg.is_remote_frame:
            node_id = can_id - HEARTBEAT_BASE
            if node_id not in kind_of:
                activity.heartbeats[node_id] = activity.heartbeats.get(node_id, 0) + 1
    return activity


def judge_recording(folder: Path, config: GatewayConfig | None = None) -> Outcome:
    """The closed-loop outcome (`loop.outcome`) of a recorded run with skin, EMG, belt and
    hand nodes, from its truth.csv and can.asc.

    `config` is the master's configuration: its EMG settings (calibration, grip levels) say
    what grip the wearer asked for at each hand RPDO, its bindings how the belt's and hand's
    RPDOs carry the commands (a vendor's drive in its own units); by default the scene's
    own `[controller]` (the scene named in summary.json), which a gateway configured for the
    scene shares.
    """
    folder = Path(folder)
    summary = read_summary(folder / "summary.json")
    nodes = {kind: int(n["node_id"]) for kind, n in summary.get("nodes", {}).items()}
    missing = [kind for kind in LOOP_KINDS if kind not in nodes]
    if missing:
        raise RecordingError(f"{folder}: no {', '.join(missing)} node: not a closed-loop run")
    if config is None:
        scene = load_scene(summary["path"])
        config = scene_config(scene.controller.params(), scene.node_settings())
    bus = BusLog(config)
    for msg in _frames(folder / "can.asc"):
        bus.tap(round(msg.timestamp * US_PER_S), Frame(msg.arbitration_id, bytes(msg.data)), None)
    truth = read_csv(folder / "truth.csv", (sig.OBJECT_POSITION_MM, sig.OBJECT_SLIPPING))
    return bus.outcome(truth, sum(summary_layout_mm(summary)))


def summary_layout_mm(summary: dict) -> tuple[float, ...]:
    """The skin's ridge spacings (mm) of a recording's summary (a layout name or spacings)."""
    layout = summary.get("layout")
    if layout is None:
        return ()
    return tuple(parse_layout(layout) if isinstance(layout, str) else layout)


def _frames(path: Path):
    """The data frames of a CAN log with 11-bit IDs (what CANopen carries)."""
    for msg in can.LogReader(str(path)):
        if not (msg.is_error_frame or msg.is_extended_id):
            yield msg

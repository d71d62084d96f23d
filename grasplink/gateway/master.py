"""NMT master (sans-IO): boots the network, starts the nodes and watches them.

On start it resets communication on every node so nodes already running
boot again, then starts each node when its boot-up arrives - or when a
heartbeat shows a node back in PRE-OPERATIONAL, since a boot-up frame can
be lost like any other. It produces its own heartbeat (the nodes' 1016h
consumers watch it) and tracks every node's state from their heartbeats,
flagging a node as lost when its heartbeat is overdue.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from grasplink.core.frames import HEARTBEAT_BASE, NMT_COB_ID, Frame
from grasplink.core.nmt import NmtCommand, NmtState
from grasplink.profiles import objects as obj

LOST_AFTER_PERIODS = 3


@dataclass(slots=True)
class NodeStatus:
    node_id: int
    state: NmtState | None = None
    boots: int = 0
    last_heartbeat_us: int | None = None
    heartbeat_intervals_us: list[int] = field(default_factory=list)
    lost: bool = False


class NmtMaster:
    def __init__(
        self,
        node_id: int = obj.GATEWAY_NODE_ID,
        *,
        heartbeat_ms: int = 100,
        node_heartbeat_ms: int = 100,
        autostart: bool = True,
        interval_history: int = 1000,
    ):
        self.node_id = node_id
        self.heartbeat_us = heartbeat_ms * 1000
        self.node_heartbeat_us = node_heartbeat_ms * 1000
        self.autostart = autostart
        self.interval_history = interval_history
        self.nodes: dict[int, NodeStatus] = {}
        self._next_beat_us: int | None = None

    # -- SansIoDevice --------------------------------------------------------------
    def start(self, t_us: int) -> list[Frame]:
        self._next_beat_us = t_us + self.heartbeat_us
        return [
            Frame(HEARTBEAT_BASE + self.node_id, bytes([NmtState.INITIALISING])),
            self.command(NmtCommand.RESET_COMMUNICATION, 0),
        ]

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        node_id = frame.can_id - HEARTBEAT_BASE
        if (
            not (1 <= node_id <= 127)
            or frame.rtr
            or len(frame.data) != 1
            or (node_id == self.node_id)
        ):
            return []
        status = self.nodes.setdefault(node_id, NodeStatus(node_id))
        state = frame.data[0]
        if status.last_heartbeat_us is not None and state != NmtState.INITIALISING:
            intervals = status.heartbeat_intervals_us
            intervals.append(t_us - status.last_heartbeat_us)
            del intervals[: -self.interval_history]
        status.last_heartbeat_us = None if state == NmtState.INITIALISING else t_us
        status.lost = False
        if state == NmtState.INITIALISING:
            status.boots += 1
            status.state = NmtState.PRE_OPERATIONAL
            return self._start(node_id) if self.autostart else []
        try:
            status.state = NmtState(state)
        except ValueError:
            status.state = None
        if self.autostart and status.state == NmtState.PRE_OPERATIONAL:
            return self._start(node_id)
        return []

    def _start(self, node_id: int) -> list[Frame]:
        """Start a node that (re)entered PRE-OPERATIONAL."""
        self.on_node_restart(node_id)
        return [self.command(NmtCommand.START, node_id)]

    def on_node_restart(self, node_id: int) -> None:
        """Hook: a node booted or fell back to PRE-OPERATIONAL and is being started."""

    def advance(self, t_us: int) -> list[Frame]:
        frames = []
        if self._next_beat_us is not None and t_us >= self._next_beat_us:
            frames.append(Frame(HEARTBEAT_BASE + self.node_id, bytes([NmtState.OPERATIONAL])))
            self._next_beat_us += self.heartbeat_us * (
                1 + (t_us - self._next_beat_us) // self.heartbeat_us
            )
        limit = self.node_heartbeat_us * LOST_AFTER_PERIODS
        for status in self.nodes.values():
            if status.last_heartbeat_us is not None and t_us - status.last_heartbeat_us > limit:
                status.lost = True
        return frames

    def next_deadline_us(self) -> int | None:
        return self._next_beat_us

    # -- commands ------------------------------------------------------------------
    @staticmethod
    def command(command: NmtCommand, node_id: int = 0) -> Frame:
        return Frame(NMT_COB_ID, bytes([command, node_id]))

"""NMT master (sans-IO): boots the network, starts the nodes and watches them.

On start it resets communication on every node so nodes already running
boot again, then starts each node when its boot-up arrives - or when a
heartbeat shows a node back in PRE-OPERATIONAL, since a boot-up frame can
be lost like any other. It produces its own heartbeat (the nodes' 1016h
consumers watch it: `HeartbeatProducer`, which a live edge may take over
and serve on a schedule of its own, `detach_heartbeat`) and consumes every
node's heartbeat and EMCY.

Two rules keep a node's safe state from being undone by the master:

- **Consumer fault**: a node whose heartbeat consumer timed out (EMCY 8130h)
  has quick-stopped and, by its 1029h, usually dropped to PRE-OPERATIONAL.
  While that EMCY is active the master does not start it again (nor does a
  controller command it); when the node's error-reset EMCY (0000h) or an
  error register without the communication bit says the fault is gone, the
  master starts it, and the drive walks its enable sequence afresh.
- **Lost node**: a node whose heartbeat is overdue (`LOST_AFTER_PERIODS`
  periods and the scheduling allowance since it was last heard) is lost and
  gets no commands until it boots again. A lost node that reappears without
  a boot-up is in an unknown state: it is sent NMT reset communication (as a CiA 302 master boots a
  slave that comes back) and counts as booted once its boot-up - or, if that
  is lost, a PRE-OPERATIONAL heartbeat - arrives. A lost node in a consumer
  fault is reset only once the fault clears: the reset would wipe the fault.
"""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from grasplink.core.frames import EMCY_BASE, HEARTBEAT_BASE, NMT_COB_ID, NODE_ID_MASK, Frame
from grasplink.core.nmt import NmtCommand, NmtState
from grasplink.profiles import objects as obj

logger = logging.getLogger(__name__)

LOST_AFTER_PERIODS = 3
# What the nodes' consumer of the master's heartbeat (1016h) allows beyond a multiple of its
# period: a host's scheduling (a loaded gateway thread, a bus relay) must not fault a node.
CONSUMER_ALLOWANCE_MS = 200
LATE_LOG_EVERY_US = 10_000_000  # late beats after the first are logged at most this often

# CiA 301 EMCY error codes the master acts on.
EMCY_ERROR_RESET = 0x0000  # "error reset or no error"
EMCY_HEARTBEAT_ERROR = 0x8130  # "life guard error or heartbeat error": a consumer timed out
# Errors that hold a node in its safe state: it is not restarted while one is active.
HOLD_CODES = frozenset({EMCY_HEARTBEAT_ERROR})
ACTIVE_EMCY_LIMIT = 16  # distinct active error codes remembered per node

# Error register (1001h) bits, and the bit each class of error code sets (CiA 301 7.5.2.2).
REG_CURRENT, REG_VOLTAGE, REG_TEMPERATURE = 0x02, 0x04, 0x08
REG_COMMUNICATION, REG_MANUFACTURER = 0x10, 0x80


def register_bit_of(code: int) -> int | None:
    """The error-register bit an error code's class sets; None if only the generic bit."""
    if 0x2000 <= code < 0x3000:
        return REG_CURRENT
    if 0x3000 <= code < 0x4000:
        return REG_VOLTAGE
    if 0x4000 <= code < 0x5000:
        return REG_TEMPERATURE
    if 0x8100 <= code < 0x8300:  # communication (81xxh) and protocol (82xxh) errors
        return REG_COMMUNICATION
    if code >= 0xFF00:
        return REG_MANUFACTURER
    return None


@dataclass(frozen=True, slots=True)
class Emcy:
    """One EMCY as CiA 301 frames it: error code, error register, manufacturer bytes."""

    code: int
    register: int
    manufacturer: bytes
    t_us: int

    @classmethod
    def parse(cls, data: bytes, t_us: int) -> Emcy | None:
        """None for a frame that is not an 8-byte EMCY."""
        if len(data) != 8:
            return None
        return cls(int.from_bytes(data[:2], "little"), data[2], bytes(data[3:]), t_us)


@dataclass(slots=True)
class NodeStatus:
    node_id: int
    state: NmtState | None = None
    boots: int = 0
    last_heartbeat_us: int | None = None  # last heartbeat (not boot-up): intervals
    last_seen_us: int | None = None  # last heartbeat or boot-up: loss detection
    heartbeat_intervals_us: list[int] = field(default_factory=list)
    lost: bool = False  # heartbeat overdue: no commands until it boots again
    reset_sent: bool = False  # lost node reappeared: reset communication sent, boot awaited
    error_register: int = 0  # from its latest EMCY
    active_emcy: dict[int, Emcy] = field(default_factory=dict)  # error code -> latest EMCY

    @property
    def in_consumer_fault(self) -> bool:
        """An active EMCY holds the node in its safe state (heartbeat consumer timed out)."""
        return not HOLD_CODES.isdisjoint(self.active_emcy)  # (asked per command sent)

    def on_emcy(self, emcy: Emcy) -> None:
        """Update the active errors from one EMCY (it carries the node's current 1001h)."""
        self.error_register = emcy.register
        if emcy.register == 0:
            self.active_emcy.clear()  # no error left, whatever the code says
        else:
            # A class bit gone from the register means that class's errors are gone,
            # also when the node sent no error reset for each (CiA 301 allows that).
            for code in list(self.active_emcy):
                bit = register_bit_of(code)
                if bit is not None and not emcy.register & bit:
                    del self.active_emcy[code]
        if emcy.code == EMCY_ERROR_RESET:
            return
        self.active_emcy.pop(emcy.code, None)
        self.active_emcy[emcy.code] = emcy
        if len(self.active_emcy) > ACTIVE_EMCY_LIMIT:
            oldest = next(c for c in self.active_emcy if c not in HOLD_CODES)
            del self.active_emcy[oldest]

    def on_boot(self) -> None:
        """A boot resets the node's error state and makes a lost node known again."""
        self.boots += 1
        self.state = NmtState.PRE_OPERATIONAL
        self.lost = self.reset_sent = False
        self.error_register = 0
        self.active_emcy.clear()


class HeartbeatProducer:
    """The master's own heartbeat (sans-IO): a beat every period on a fixed grid, and how
    late each one went out.

    Kept apart from the rest of the master so a live edge can serve it on a schedule of
    its own (a real-time thread, or between two received frames), never behind decoding;
    its state is its own, so serving it from another thread touches nothing else.

    Lateness is time past the beat's grid slot. A beat is *late* when it is more than a
    quarter of the nodes' margin (consumer time - period) behind; an interval longer than
    the nodes' consumer time would have faulted them (EMCY 8130h) and is counted apart.
    The first late beat is logged at once, later ones at most every 10 s, with counts.
    """

    def __init__(self, node_id: int, period_us: int, consumer_us: int, history: int = 1000):
        if period_us <= 0 or consumer_us <= period_us:
            raise ValueError("a heartbeat needs period_us > 0 and consumer_us > period_us")
        self.node_id = node_id
        self.period_us = period_us
        self.consumer_us = consumer_us
        self.late_after_us = (consumer_us - period_us) // 4
        self.frame = Frame(HEARTBEAT_BASE + node_id, bytes([NmtState.OPERATIONAL]))
        self.beats = 0
        self.late = 0
        self.over_consumer = 0  # intervals longer than the nodes' consumer time
        self.max_late_us = 0
        self.max_interval_us = 0
        self.intervals_us: deque[int] = deque(maxlen=history)  # the latest, for percentiles
        self._next_us: int | None = None
        self._last_us: int | None = None
        self._logged_us: int | None = None  # when late beats were last logged
        self._unlogged = 0  # late beats since then

    def start(self, t_us: int) -> list[Frame]:
        """Start the grid at `t_us` (the boot-up heartbeat the master sends then is beat 0)."""
        self._next_us = t_us + self.period_us
        self._last_us = t_us
        return []

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        return []

    def next_deadline_us(self) -> int | None:
        return self._next_us

    def advance(self, t_us: int) -> list[Frame]:
        due = self._next_us
        if due is None or t_us < due:
            return []
        self._next_us = due + self.period_us * (1 + (t_us - due) // self.period_us)
        self._count(t_us, t_us - due)
        return [self.frame]

    def _count(self, t_us: int, late_us: int) -> None:
        self.beats += 1
        self.max_late_us = max(self.max_late_us, late_us)
        if self._last_us is not None:
            interval = t_us - self._last_us
            self.intervals_us.append(interval)
            self.max_interval_us = max(self.max_interval_us, interval)
            if interval > self.consumer_us:
                self.over_consumer += 1
        self._last_us = t_us
        if late_us <= self.late_after_us:
            return
        self.late += 1
        self._unlogged += 1
        if self._logged_us is None or t_us - self._logged_us >= LATE_LOG_EVERY_US:
            logger.warning(
                "own heartbeat 0x%03X went out %.0f ms late (%d late beats of %d so far, "
                "%d since the last report; %d intervals over the nodes' %d ms consumer time)",
                self.frame.can_id,
                late_us / 1000,
                self.late,
                self.beats,
                self._unlogged,
                self.over_consumer,
                self.consumer_us // 1000,
            )
            self._logged_us = t_us
            self._unlogged = 0

    def stats(self) -> dict[str, Any]:
        """For the snapshot: counts, lateness and the recent intervals' p50/p99/max (ms)."""
        recent = sorted(tuple(self.intervals_us))  # a copy first: another thread may beat

        def pick(share: float) -> float | None:
            if not recent:
                return None
            return recent[min(len(recent) - 1, int(share * len(recent)))] / 1000

        return {
            "period_ms": self.period_us / 1000,
            "consumer_ms": self.consumer_us / 1000,
            "beats": self.beats,
            "late": self.late,
            "late_max_ms": self.max_late_us / 1000,
            "over_consumer": self.over_consumer,
            "interval_p50_ms": pick(0.5),
            "interval_p99_ms": pick(0.99),
            "interval_max_ms": self.max_interval_us / 1000,
        }


class NmtMaster:
    def __init__(
        self,
        node_id: int = obj.GATEWAY_NODE_ID,
        *,
        heartbeat_ms: int = 100,
        node_heartbeat_ms: int = 100,
        autostart: bool = True,
        interval_history: int = 1000,
        consumer_ms: int | None = None,
        loss_allowance_ms: int = CONSUMER_ALLOWANCE_MS,
    ):
        self.node_id = node_id
        self.heartbeat_us = heartbeat_ms * 1000
        self.node_heartbeat_us = node_heartbeat_ms * 1000
        # Our own consumer of the nodes' heartbeats keeps the same scheduling allowance we
        # give theirs of ours: a loaded host that reads a heartbeat late has not lost a node.
        self.loss_allowance_us = loss_allowance_ms * 1000
        self.autostart = autostart
        self.interval_history = interval_history
        self.nodes: dict[int, NodeStatus] = {}
        # the nodes' consumer time of our heartbeat (1016h): 3 periods and an allowance
        if consumer_ms is None:
            consumer_ms = LOST_AFTER_PERIODS * heartbeat_ms + CONSUMER_ALLOWANCE_MS
        self.heartbeat = HeartbeatProducer(node_id, self.heartbeat_us, consumer_ms * 1000)
        self._own_heartbeat = True  # False once a live edge serves `heartbeat` itself

    def detach_heartbeat(self) -> HeartbeatProducer:
        """Hand the heartbeat to the caller, who serves it (start, advance) on a schedule of
        its own; `advance` and `next_deadline_us` then leave it out. Before `start`."""
        self._own_heartbeat = False
        return self.heartbeat

    # -- SansIoDevice --------------------------------------------------------------
    def start(self, t_us: int) -> list[Frame]:
        if self._own_heartbeat:
            self.heartbeat.start(t_us)
        return [
            Frame(HEARTBEAT_BASE + self.node_id, bytes([NmtState.INITIALISING])),
            self.command(NmtCommand.RESET_COMMUNICATION, 0),
        ]

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        if frame.rtr:
            return []
        base, node_id = frame.can_id & ~NODE_ID_MASK, frame.can_id & NODE_ID_MASK
        if not (1 <= node_id <= 127) or node_id == self.node_id:
            return []
        if base == HEARTBEAT_BASE and len(frame.data) == 1:
            return self._on_heartbeat(node_id, frame.data[0], t_us)
        if base == EMCY_BASE:
            emcy = Emcy.parse(frame.data, t_us)
            return self._on_emcy(node_id, emcy) if emcy is not None else []
        return []

    def _on_heartbeat(self, node_id: int, state: int, t_us: int) -> list[Frame]:
        status = self.nodes.setdefault(node_id, NodeStatus(node_id))
        status.last_seen_us = t_us
        if state == NmtState.INITIALISING:
            status.last_heartbeat_us = None
            status.on_boot()
            return self._start(node_id) if self.autostart else []
        if status.last_heartbeat_us is not None:
            intervals = status.heartbeat_intervals_us
            intervals.append(t_us - status.last_heartbeat_us)
            del intervals[: -self.interval_history]
        status.last_heartbeat_us = t_us
        try:
            status.state = NmtState(state)
        except ValueError:
            status.state = None
        if status.lost:
            if status.reset_sent and status.state == NmtState.PRE_OPERATIONAL:
                status.on_boot()  # it did reset; its boot-up was lost on the way
            else:
                return self._reboot_lost(node_id)
        if (
            self.autostart
            and status.state == NmtState.PRE_OPERATIONAL
            and not status.in_consumer_fault
        ):
            return self._start(node_id)
        return []

    def _on_emcy(self, node_id: int, emcy: Emcy) -> list[Frame]:
        status = self.nodes.setdefault(node_id, NodeStatus(node_id))
        held = status.in_consumer_fault
        status.on_emcy(emcy)
        if held and not status.in_consumer_fault:
            return self._fault_cleared(node_id)
        return []

    def _fault_cleared(self, node_id: int) -> list[Frame]:
        """The consumer fault is gone: bring the node back the way it left."""
        status = self.nodes[node_id]
        if status.lost:
            return self._reboot_lost(node_id)
        if not self.autostart:
            return []
        if status.state == NmtState.PRE_OPERATIONAL:
            return self._start(node_id)
        if status.state == NmtState.OPERATIONAL:  # 1029h:01 = 1 kept it OPERATIONAL
            self.on_node_restart(node_id)  # its drive quick-stopped: enable it afresh
        return []

    def _reboot_lost(self, node_id: int) -> list[Frame]:
        """A lost node is back without a boot-up: reset it, unless that would wipe a fault.

        Called again at each of its heartbeats until it shows the reset took (the NMT frame
        can be lost like any other).
        """
        status = self.nodes[node_id]
        if status.in_consumer_fault or not self.autostart:
            return []
        status.reset_sent = True
        return [self.command(NmtCommand.RESET_COMMUNICATION, node_id)]

    def _start(self, node_id: int) -> list[Frame]:
        """Start a node that (re)entered PRE-OPERATIONAL."""
        self.on_node_restart(node_id)
        return [self.command(NmtCommand.START, node_id)]

    def on_node_restart(self, node_id: int) -> None:
        """Hook: a node booted, fell back to PRE-OPERATIONAL or left a consumer fault, and
        is being started: whatever it drives must be enabled again."""

    def commandable(self, node_id: int | None) -> bool:
        """Whether a controller may send the node process data (RPDOs) now.

        OPERATIONAL, not lost, and not held in its safe state by a consumer fault.
        """
        status = self.nodes.get(node_id) if node_id is not None else None
        return (
            status is not None
            and status.state == NmtState.OPERATIONAL
            and not status.lost
            and not status.in_consumer_fault
        )

    def advance(self, t_us: int) -> list[Frame]:
        frames = self.heartbeat.advance(t_us) if self._own_heartbeat else []
        for status in self.nodes.values():
            deadline = self._lost_deadline_us(status)
            if deadline is not None and t_us >= deadline:
                status.lost = True
        return frames

    def next_deadline_us(self) -> int | None:
        # asked after every frame: a running minimum (no list, map or generator)
        best = self.heartbeat.next_deadline_us() if self._own_heartbeat else None
        for status in self.nodes.values():
            deadline = self._lost_deadline_us(status)
            if deadline is not None and (best is None or deadline < best):
                best = deadline
        return best

    def _lost_deadline_us(self, status: NodeStatus) -> int | None:
        """When the node counts as lost if nothing is heard from it (None: lost already)."""
        if status.lost or status.last_seen_us is None:
            return None
        return status.last_seen_us + self.node_consumer_us + 1

    @property
    def node_consumer_us(self) -> int:
        """Our consumer time of a node's heartbeat: silent this long, the node is lost."""
        return self.node_heartbeat_us * LOST_AFTER_PERIODS + self.loss_allowance_us

    # -- commands ------------------------------------------------------------------
    @staticmethod
    def command(command: NmtCommand, node_id: int = 0) -> Frame:
        return Frame(NMT_COB_ID, bytes([command, node_id]))

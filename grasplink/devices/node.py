"""A CANopen slave device: NMT, SDO, PDO, SYNC, EMCY and heartbeat around one store.

`DeviceNode` is the firmware of every grasplink node; what differs between
the skin, EMG, belt and hand is the object dictionary (EDS) and the
`DeviceApp` plugged in. Everything is sans-IO (see `protocol.SansIoDevice`).

`node_id` is the *active* node-ID; LSS (`lss.py`) may set a pending one, taken
at the next NMT reset. A node whose node-ID is FFh (`UNCONFIGURED_NODE_ID`)
answers LSS only, and boots once an LSS master has given it a node-ID.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable

import canopen.objectdictionary as cod

from grasplink.core.frames import (
    CAN_ID_MASK,
    HEARTBEAT_BASE,
    LSS_MASTER_COB_ID,
    LSS_SLAVE_COB_ID,
    NMT_COB_ID,
    SDO_RX_BASE,
    SDO_TX_BASE,
    UNCONFIGURED_NODE_ID,
    Frame,
    is_restricted_can_id,
)
from grasplink.core.nmt import (
    EMCY_ALLOWED,
    SDO_ALLOWED,
    SYNC_ALLOWED,
    NmtCommand,
    NmtState,
)
from grasplink.devices import emcy as em
from grasplink.devices.app import DeviceApp
from grasplink.devices.heartbeat import HeartbeatConsumer, HeartbeatProducer
from grasplink.devices.lss import LssSlave
from grasplink.devices.pdo import PdoEngine
from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.devices.sdo_server import SdoServer
from grasplink.devices.store import APPLICATION_AREA, COMMUNICATION_AREA, Key, ObjectStore, Value
from grasplink.errors import ConfigError
from grasplink.profiles import objects as obj

SYNC_GENERATE = 0x40000000
COB_ID_INVALID = 0x80000000
COB_ID_EXTENDED = 0x20000000

# A CAN-ID collision (EMCY 8150h) clears after this long without another foreign frame
# on our heartbeat COB-ID, or three of our own heartbeat periods if longer: a duplicate
# configured like us beats as often as we do.
COLLISION_CLEAR_US = 1_000_000

_LSS_ONLY = frozenset((LSS_MASTER_COB_ID,))

# 1029h:01 communication-error behaviour
ON_ERROR_PRE_OPERATIONAL = 0
ON_ERROR_NO_CHANGE = 1
ON_ERROR_STOPPED = 2


# A span told ahead: per tick (time, application ticks by then), the event-timer TPDOs
# sent (time, number) and the heartbeats (times).
_Told = tuple[list[tuple[int, int]], list[tuple[int, int]], list[int]]


def dummy_usage(od: cod.ObjectDictionary) -> frozenset[int]:
    """Dummy objects the EDS says the device accepts in RPDO mappings."""
    return frozenset(index for index in range(0x0002, 0x0008) if index in od)


class DeviceNode:
    """The behaviour every grasplink device shares; see module docstring."""

    def __init__(
        self,
        od: cod.ObjectDictionary,
        node_id: int,
        app: DeviceApp | None = None,
        *,
        dummies: frozenset[int] | None = None,
        od_node_id: int | None = None,
    ):
        """`od_node_id`: the node-ID `od` was loaded for (default `node_id`; an
        unconfigured node's dictionary needs one to resolve `$NODEID`)."""
        if not (1 <= node_id <= 127 or node_id == UNCONFIGURED_NODE_ID):
            raise ConfigError(f"node-ID {node_id} is outside 1..127 (or 0xFF: unconfigured)")
        if od_node_id is None:
            if node_id == UNCONFIGURED_NODE_ID:
                raise ConfigError("an unconfigured node needs the node-ID its EDS was loaded for")
            od_node_id = node_id
        self.node_id = node_id
        self.store = ObjectStore(od, od_node_id)
        self.lss = LssSlave(self.store, node_id)
        self.emcy = em.EmcyProducer(self.store)
        self.heartbeat = HeartbeatProducer(self.store)
        self.consumer = HeartbeatConsumer(self.store)
        self.pdo = PdoEngine(
            self.store,
            self.emcy,
            dummy_usage(od) if dummies is None else dummies,
            on_rpdo=self._on_rpdo,
        )
        self.sdo = SdoServer(self.store)
        self.app = app or DeviceApp()
        self.state = NmtState.INITIALISING
        self.powered = False
        self._deadline: int | None = None
        self._deadline_stale = True
        # Any change in the dictionary (SDO, RPDO, the application, a simulator
        # pushing an actual value) may move a timer: the deadline is computed again
        # when the store's change count has moved since (a count, not a listener: a
        # sample stream writes its objects hundreds of times a second).
        self._deadline_changes = -1
        # The CAN-IDs a frame may concern one of our services on: an acceptance filter,
        # as a CAN controller has. Nine in ten frames on a loop's bus are other nodes'
        # process data; they stop here instead of going through every service's checks.
        # Built for the node-ID, the SYNC COB-ID, the PDOs' CAN-IDs and the heartbeats
        # 1016h watches it was built with (`_listened_pdo_ids`, `_listened_heartbeats`);
        # a change of either of the first two drops it.
        self._listened: frozenset[int] | None = None
        self._listened_pdo_ids: frozenset[int] | None = None
        self._listened_heartbeats: frozenset[int] | None = None
        # `_listened` and LSS, for a bus's filter (`accepted_can_ids`).
        self._accepted_for: frozenset[int] | None = None
        self._accepted: frozenset[int] = _LSS_ONLY
        # Frames on our own heartbeat COB-ID that we did not send: another node has our ID.
        self.duplicate_frames = 0
        # The last span told ahead and not yet committed (`stream_ahead`).
        self._told: _Told | None = None
        self._collision_clear_us: int | None = None
        # The SYNC COB-ID, read from the store once per change: every frame on the bus
        # asks whether it is the SYNC, and a store lookup per frame is most of that.
        self._sync_cob_id: int | None = None
        if self.store.has(obj.COB_ID_SYNC):
            self._sync_cob_id = int(self.store.get(obj.COB_ID_SYNC)) & CAN_ID_MASK
        self.store.add_listener(self._on_sync_cob_id, (obj.COB_ID_SYNC,))
        self.store.add_validator(obj.COB_ID_SYNC, self._validate_sync_cob_id)
        self.store.add_validator(obj.COB_ID_EMCY, self._validate_emcy_cob_id)
        self.pdo.streamed_tpdos = frozenset(self.app.streamed_tpdos)
        self.pdo.packet_tpdos = frozenset(self.app.packet_tpdos)
        self.pdo.packets_on_sync = self.app.packets_on_sync
        self.app.attach(NodeServices(self))
        # `StreamingDevice.streaming`: whether the application tells its ticks ahead at
        # all (a belt, a hand do not).
        self.streaming = type(self.app).stream_ahead is not DeviceApp.stream_ahead

    # -- SansIoDevice ------------------------------------------------------------
    @property
    def configured(self) -> bool:
        """Whether the node has a node-ID (else it waits for an LSS master)."""
        return self.node_id != UNCONFIGURED_NODE_ID

    def start(self, t_us: int) -> list[Frame]:
        """Power on: initialise the whole dictionary and boot (with the node-ID LSS stored)."""
        self._deadline_stale = True
        self.powered = True
        self.lss.power_on()
        return self._reset(t_us, application=True)

    def power_off(self) -> None:
        """Lose power: silent until `start` is called again (NVM survives)."""
        self.powered = False
        self._deadline_stale = True
        self.state = NmtState.INITIALISING
        self.pdo.set_operational(False, 0)

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        if not self.powered:
            return []
        if frame.can_id == LSS_MASTER_COB_ID and not frame.rtr:
            self._deadline_stale = True
            self._touch(t_us)
            return self._on_lss(frame, t_us)
        if self.state == NmtState.INITIALISING:
            return []
        self._touch(t_us)
        if frame.can_id not in self._listened_can_ids():
            return []  # not for this node: nothing in it changed
        frames = self._dispatch(frame, t_us)
        if frames is None:
            return []
        self._deadline_stale = True
        return frames

    def accepted_can_ids(self) -> frozenset[int]:
        """The CAN-IDs `receive` may act on (`FilteringDevice`): none while off, LSS alone
        while initialising or unconfigured, else those `_dispatch` may handle and LSS.
        A frame on another CAN-ID would only note the time of the call, which matters to
        nothing the bus can see: a bus may leave the node out of it."""
        if not self.powered:
            return frozenset()
        if self.state == NmtState.INITIALISING:
            return _LSS_ONLY
        listened = self._listened_can_ids()
        if self._accepted_for is not listened:
            self._accepted_for = listened
            self._accepted = listened | _LSS_ONLY
        return self._accepted

    def _listened_can_ids(self) -> frozenset[int]:
        """Every CAN-ID `_dispatch` may handle (a superset: it decides by state and
        content); rebuilt after a change of the communication area or the node-ID."""
        pdo_ids = self.pdo.can_ids()
        watched = self.consumer.watched_can_ids
        if (
            self._listened is None
            or pdo_ids is not self._listened_pdo_ids
            or watched is not self._listened_heartbeats
        ):
            self._listened_pdo_ids = pdo_ids
            self._listened_heartbeats = watched
            own = (NMT_COB_ID, HEARTBEAT_BASE + self.node_id, SDO_RX_BASE + self.node_id)
            sync = () if self._sync_cob_id is None else (self._sync_cob_id,)
            self._listened = frozenset((*own, *watched, *sync, *pdo_ids))
        return self._listened

    def _dispatch(self, frame: Frame, t_us: int) -> list[Frame] | None:
        """Handle a frame; None when the frame concerns no service of this node."""
        can_id = frame.can_id
        if can_id == NMT_COB_ID:
            return self._on_nmt(frame, t_us)
        if can_id == HEARTBEAT_BASE + self.node_id:
            # An RTR here is node guarding, which this device does not support (no
            # 100Ch/100Dh in its EDS; it produces heartbeats): ignored, as CiA 301 lets it.
            return None if frame.rtr else self._on_duplicate(can_id, t_us)
        if HEARTBEAT_BASE < can_id <= HEARTBEAT_BASE + 127 and not frame.rtr and frame.data:
            node_id = can_id - HEARTBEAT_BASE
            if not self.consumer.watches(node_id):
                return None
            return self._on_heartbeat(node_id, frame.data[0], t_us)
        if self.state not in SDO_ALLOWED:
            return None
        if can_id == SDO_RX_BASE + self.node_id and not frame.rtr:
            return self._sdo_frames(self.sdo.on_request(bytes(frame.data), t_us))
        if can_id == self._sync_can_id() and len(frame.data) <= 1 and not frame.rtr:
            counter = frame.data[0] if frame.data else None
            return self.pdo.on_sync(counter, t_us) + self._emcy(t_us)
        handled = self.pdo.on_frame(frame, t_us)
        if handled is not None:
            return handled + self._emcy(t_us)
        return None

    def advance(self, t_us: int) -> list[Frame]:
        if not self.powered or self.state == NmtState.INITIALISING:
            return []
        self._deadline_stale = True
        self._touch(t_us)
        frames: list[Frame] = []
        if self._collision_clear_us is not None and t_us >= self._collision_clear_us:
            self._collision_clear_us = None
            self.emcy.clear_error(em.CAN_ID_COLLISION, t_us)
        for node_id in self.consumer.expired(t_us):
            frames += self._on_heartbeat_lost(node_id, t_us)
        if self.state in SDO_ALLOWED:
            frames += self._sdo_frames(self.sdo.advance(t_us))
        frames += self.app.advance(t_us)
        frames += self.pdo.advance(t_us)
        frames += self._emcy(t_us)
        if self.heartbeat.due(t_us):
            frames.append(Frame(HEARTBEAT_BASE + self.node_id, bytes([self.state])))
        return frames

    def stream_until_us(self, t_us: int) -> int | None:
        """`StreamingDevice`: how far a span must reach before the application tells
        anything (None while the node cannot stream: off, not OPERATIONAL)."""
        if not self.streaming or not self.powered or self.state != NmtState.OPERATIONAL:
            return None
        return self.app.stream_until_us(t_us)

    def stream_ahead(self, t_us: int, until_us: int) -> list[tuple[int, list[Frame]]]:
        """`StreamingDevice`: the application's next ticks told ahead, with the event-timer
        TPDOs and heartbeats due among them, while OPERATIONAL and up to any other timer
        (a heartbeat consumer, an SDO timeout, an EMCY held back: each goes through
        `advance` at its time, the span ends before it)."""
        self._told = None
        if not self.streaming or not self.powered or self.state != NmtState.OPERATIONAL:
            return []
        if self.next_deadline_us() != t_us:
            return []  # late: `advance` catches up
        for bound in self._untold_deadlines():
            if bound is not None:
                until_us = min(until_us, bound - 1)
        if until_us < t_us:
            return []
        span = self.app.stream_ahead(t_us, until_us)
        if span is None or not span.times_us:
            return []
        until_us = min(until_us, span.next_us - 1)
        sends = self.pdo.timer_sends(until_us, span.keys)
        if sends is None:
            return []
        beats: list[int] = []
        beat, period = self.heartbeat.next_deadline_us(), self.heartbeat.period_us
        if beat is not None and period:
            beats = list(range(beat, until_us + 1, period))
        if not sends and not beats:
            self._told = ([(t, n) for n, t in enumerate(span.times_us, start=1)], [], [])
            return list(zip(span.times_us, span.frames, strict=True))
        # What the node's own timers send at a time, after the application's frames then.
        extra: dict[int, list[Frame]] = {}
        now = tuple(self.store.get(*key) for key in span.keys)
        for t, frame, _ in sends:
            told = bisect.bisect_right(span.times_us, t)
            values = span.values[told - 1] if told else now
            extra.setdefault(t, []).append(frame(*values))
        heartbeat = Frame(HEARTBEAT_BASE + self.node_id, bytes([self.state]))
        for t in beats:
            extra.setdefault(t, []).append(heartbeat)
        ticks: list[tuple[int, list[Frame]]] = []
        app_ticks: list[tuple[int, int]] = []  # per tick: (time, application ticks by then)
        told = 0
        for t in sorted({*span.times_us, *extra}):
            frames: list[Frame] = []
            if told < len(span.times_us) and span.times_us[told] == t:
                frames = list(span.frames[told])
                told += 1
            frames += extra.get(t, ())
            ticks.append((t, frames))
            app_ticks.append((t, told))
        self._told = (app_ticks, [(t, n) for t, _, n in sends], beats)
        return ticks

    def commit_stream(self, ticks: int) -> None:
        """`StreamingDevice`: the first `ticks` ticks of the last span happened; the
        application, the event timers and the heartbeat are as `advance` there left them."""
        told, self._told = self._told, None
        if told is None:
            return
        app_ticks, sends, beats = told
        if not ticks:
            self.app.commit_stream(0)
            return
        t_us, app_told = app_ticks[ticks - 1]
        self.app.commit_stream(app_told)
        for t, number in sends:
            if t <= t_us:
                self.pdo.timer_sent(number, t)
        done = [t for t in beats if t <= t_us]
        if done:
            self.heartbeat.due(done[-1])
        self._deadline_stale = True
        self._touch(t_us)

    def _untold_deadlines(self) -> tuple[int | None, ...]:
        """The timers a span told ahead does not cover (it ends before the earliest); the
        node's deadline is the earliest of these, the heartbeat's, the PDOs' and the
        application's."""
        deadlines: tuple[int | None, ...] = (
            self.consumer.next_deadline_us(),
            self._collision_clear_us,
        )
        if self.state in SDO_ALLOWED:
            deadlines += (self.sdo.next_deadline_us(), self.emcy.next_deadline_us())
        return deadlines

    def next_deadline_us(self) -> int | None:
        """The earliest timer; cached until a frame, a tick or a store change can move it."""
        changes = self.store.changes
        if self._deadline_stale or changes != self._deadline_changes:
            self._deadline = self._compute_deadline()
            self._deadline_stale = False
            self._deadline_changes = changes
        return self._deadline

    def _compute_deadline(self) -> int | None:
        if not self.powered or self.state == NmtState.INITIALISING:
            return None  # off, or unconfigured: nothing runs until LSS gives a node-ID
        candidates = (
            self.heartbeat.next_deadline_us(),
            self.app.next_deadline_us(),
            self.pdo.next_deadline_us(),
            *self._untold_deadlines(),
        )
        earliest = None
        for candidate in candidates:
            if candidate is not None and (earliest is None or candidate < earliest):
                earliest = candidate
        return earliest

    # -- NMT -------------------------------------------------------------------------
    def _on_nmt(self, frame: Frame, t_us: int) -> list[Frame]:
        if len(frame.data) != 2 or frame.data[1] not in (0, self.node_id):
            return []
        try:
            command = NmtCommand(frame.data[0])
        except ValueError:
            return []
        if command == NmtCommand.RESET_NODE:
            return self._reset(t_us, application=True)
        if command == NmtCommand.RESET_COMMUNICATION:
            return self._reset(t_us, application=False)
        target = {
            NmtCommand.START: NmtState.OPERATIONAL,
            NmtCommand.STOP: NmtState.STOPPED,
            NmtCommand.ENTER_PRE_OPERATIONAL: NmtState.PRE_OPERATIONAL,
        }[command]
        return self._enter(target, t_us)

    def _enter(self, state: NmtState, t_us: int) -> list[Frame]:
        if state == self.state:
            return []
        self.state = state
        if state != NmtState.PRE_OPERATIONAL and state != NmtState.OPERATIONAL:
            self.sdo.reset()
        self.pdo.set_operational(state == NmtState.OPERATIONAL, t_us)
        self.app.on_state(state, t_us)
        # Entering OPERATIONAL publishes the event-driven TPDOs at once.
        return self.pdo.advance(t_us) if state == NmtState.OPERATIONAL else []

    def _reset(self, t_us: int, *, application: bool) -> list[Frame]:
        """Reset node (application=True) or reset communication, then boot again.

        The pending node-ID becomes the active one (CiA 305); without one the node
        stays in initialisation, silent but for LSS.
        """
        self.state = NmtState.INITIALISING
        self.node_id = self.lss.pending_node_id
        self._listened = None
        if self.configured:
            self.store.node_id = self.node_id  # $NODEID defaults follow it
        self.lss.reset()
        self.pdo.set_operational(False, t_us)
        self.sdo.reset()
        if application:
            self.store.load_defaults(APPLICATION_AREA)
        self.store.load_defaults(COMMUNICATION_AREA)
        self.emcy.reset()
        self._collision_clear_us = None
        self.pdo.reload()
        self.consumer.reset()
        if application:
            self.app.on_reset(t_us)
        if not self.configured:
            return []
        self.heartbeat.restart(t_us)
        self.state = NmtState.PRE_OPERATIONAL
        self.app.on_state(self.state, t_us)
        return [Frame(HEARTBEAT_BASE + self.node_id, bytes([NmtState.INITIALISING]))]

    # -- LSS -------------------------------------------------------------------------------
    def _on_lss(self, frame: Frame, t_us: int) -> list[Frame]:
        outcome = self.lss.on_request(bytes(frame.data), self.node_id)
        frames = [] if outcome.reply is None else [Frame(LSS_SLAVE_COB_ID, outcome.reply)]
        if outcome.boot:
            # An unconfigured node never booted: with its first node-ID it boots in full.
            frames += self._reset(t_us, application=True)
        return frames

    # -- heartbeat consumer --------------------------------------------------------------
    def _on_heartbeat(self, node_id: int, state: int, t_us: int) -> list[Frame]:
        if self.consumer.on_heartbeat(node_id, state, t_us):
            if not self.consumer.any_timed_out():
                self.emcy.clear_error(em.HEARTBEAT_TIMEOUT, t_us)
            return self._emcy(t_us)
        return []

    def _on_heartbeat_lost(self, node_id: int, t_us: int) -> list[Frame]:
        """CiA 301 heartbeat event: EMCY 8130h, 1029h behaviour, device safe state."""
        self.emcy.raise_error(em.HEARTBEAT_TIMEOUT, em.REG_COMMUNICATION, t_us, bytes([node_id]))
        self.app.enter_safe_state(t_us, f"heartbeat of node 0x{node_id:02X} lost")
        frames = self._emcy(t_us)
        behaviour = int(self.store.get(obj.ERROR_BEHAVIOUR, 1))
        if behaviour == ON_ERROR_PRE_OPERATIONAL and self.state == NmtState.OPERATIONAL:
            frames += self._enter(NmtState.PRE_OPERATIONAL, t_us)
        elif behaviour == ON_ERROR_STOPPED:
            frames += self._enter(NmtState.STOPPED, t_us)
        return frames

    # -- duplicate node-ID -----------------------------------------------------------------
    @property
    def collision_active(self) -> bool:
        """Whether another node is transmitting on our heartbeat COB-ID (EMCY 8150h active)."""
        return self.emcy.is_active(em.CAN_ID_COLLISION)

    def _on_duplicate(self, can_id: int, t_us: int) -> list[Frame]:
        """A heartbeat or boot-up with our node-ID that we did not send: EMCY 8150h
        (CAN-ID collision) once per episode; the node keeps running."""
        self.duplicate_frames += 1
        self._collision_clear_us = t_us + max(COLLISION_CLEAR_US, 3 * self.heartbeat.period_us)
        if self.emcy.is_active(em.CAN_ID_COLLISION):
            return []
        self.emcy.raise_error(
            em.CAN_ID_COLLISION, em.REG_COMMUNICATION, t_us, can_id.to_bytes(2, "little")
        )
        return self._emcy(t_us)

    # -- helpers ------------------------------------------------------------------------
    def _on_rpdo(self, number: int, t_us: int) -> None:
        self.app.on_rpdo(number, t_us)

    def _emcy(self, t_us: int) -> list[Frame]:
        return self.emcy.poll(t_us) if self.state in EMCY_ALLOWED else []

    def _sdo_frames(self, payloads: list[bytes]) -> list[Frame]:
        if not payloads:
            return []
        return [Frame(SDO_TX_BASE + self.node_id, p) for p in payloads]

    def _sync_can_id(self) -> int | None:
        if self.state not in SYNC_ALLOWED:
            return None
        return self._sync_cob_id

    def _on_sync_cob_id(self, index: int, subindex: int, value: Value) -> None:
        self._sync_cob_id = int(value) & CAN_ID_MASK
        self._listened = None

    def _touch(self, t_us: int) -> None:
        self.heartbeat.now_us = t_us
        self.pdo.now_us = t_us

    def _validate_sync_cob_id(self, index: int, subindex: int, value: Value) -> None:
        value = int(value)
        if value & SYNC_GENERATE:
            raise SdoAbort(
                AbortCode.INVALID_VALUE, "this device consumes SYNC; it cannot produce it"
            )
        self._check_service_cob_id(value)

    def _validate_emcy_cob_id(self, index: int, subindex: int, value: Value) -> None:
        value = int(value)
        current = int(self.store.get(obj.COB_ID_EMCY))
        if not (current & COB_ID_INVALID or value & COB_ID_INVALID) and (
            (value ^ current) & CAN_ID_MASK
        ):
            raise SdoAbort(AbortCode.INVALID_VALUE, "set bit 31 before changing the EMCY CAN-ID")
        if not value & COB_ID_INVALID:
            self._check_service_cob_id(value)

    @staticmethod
    def _check_service_cob_id(value: int) -> None:
        if value & COB_ID_EXTENDED:
            raise SdoAbort(AbortCode.INVALID_VALUE, "29-bit CAN-IDs are not supported")
        can_id = value & CAN_ID_MASK
        if is_restricted_can_id(can_id):
            raise SdoAbort(AbortCode.INVALID_VALUE, f"CAN-ID 0x{can_id:03X} is restricted")


class NodeServices:
    """`AppServices` of one node: the narrow view its application gets."""

    def __init__(self, node: DeviceNode):
        self._node = node
        self.store = node.store

    @property
    def nmt_state(self) -> NmtState:
        return self._node.state

    def now_us(self) -> int:
        return self._node.pdo.now_us

    def transmit_tpdo(self, number: int, t_us: int) -> list[Frame]:
        return self._node.pdo.trigger(number, t_us)

    def tpdo_enabled(self, number: int) -> bool:
        tpdos = self._node.pdo.tpdos
        return 1 <= number <= len(tpdos) and self._node.pdo.is_valid(tpdos[number - 1])

    def raise_error(self, code: int, register_bit: int, t_us: int, data: bytes = b"") -> None:
        self._node.emcy.raise_error(code, register_bit, t_us, data)

    def clear_error(self, code: int, t_us: int) -> None:
        self._node.emcy.clear_error(code, t_us)

    def error_active(self, code: int) -> bool:
        return self._node.emcy.is_active(code)

    def direct_tpdo(
        self, number: int, given: tuple[Key, ...], unmapped: tuple[Key, ...] = ()
    ) -> Callable[..., Frame] | None:
        return self._node.pdo.direct_tpdo(number, given, unmapped)

    def sent_directly(self, number: int, t_us: int) -> None:
        self._node.pdo.sent_directly(number, t_us)

"""The gateway as one sans-IO participant: master the network, decode, close the loop.

`Gateway` is what an integrator deploys, and what a scene puts in the loop
(`[controller] type = "gateway"`): the same object runs on a live bus
(`grasplink gateway`: a real-time runner drives it through its live edge,
`edge.GatewayEdge`, which holds the cross-thread command mailbox and the
wall clock) and in virtual time. What it knows goes out as a typed
`snapshot.Snapshot`.

- **Network master**: NMT master and heartbeat producer (`NmtMaster`); each
  configured node that boots is provisioned over SDO (`provisioning.py`,
  one sans-IO `SdoClient` per node, never inside a frame callback's return
  path blocking anything) and started when every write succeeded; a node
  that reboots is provisioned again.
- **Decoding**: TPDOs are unpacked through the node's EDS mapping
  (`PdoCodec`); frames that do not fit are dropped and counted. Skin samples
  get their node-clock times from the packet sequence (`decoding.skin_frames`,
  the front end offline decoding shares) and feed the configured skin decoder;
  EMG envelopes become intent (`EmgIntentDecoder`).
- **SYNC cycles**: with a SYNC producer, the skin and EMG TPDOs the description
  makes synchronous are gathered as they arrive and handled together at the next
  `advance` (after every frame that came with them): one decoder call, one control
  step, one set of RPDOs per cycle instead of per frame.
- **Control**: every skin decoder update drives the feedback controller
  (belt) and the hybrid reflex, whose grip joins the wearer's EMG grip in
  the arbiter (hand). Commands go out as RPDOs packed through the mapping,
  clamped to the profile's limits with an alarm.
- **Degraded states**: a node whose heartbeat is lost (one consumer time),
  or that leaves OPERATIONAL, puts the loop in a defined state: belt stopped,
  hand holding its last grip, an alarm raised; it recovers when the node
  is back.
"""

from __future__ import annotations

import logging
import math
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from grasplink.core.frames import (
    CAN_ID_MASK,
    EMCY_BASE,
    HEARTBEAT_BASE,
    NMT_COB_ID,
    Frame,
    function_of,
)
from grasplink.core.nmt import NmtCommand, NmtState
from grasplink.core.params import Params
from grasplink.decoding.base import SlipEstimate
from grasplink.decoding.packets import LIVE_SETTLE_US
from grasplink.decoding.registry import make_decoder
from grasplink.decoding.skin_frames import SkinCalibration, SkinFrames
from grasplink.errors import ConfigError, PdoError
from grasplink.gateway import roles
from grasplink.gateway.commands import Command, CommandError, CommandResult, parse_value, shown
from grasplink.gateway.config import (
    DEVICE_ROLE,
    EmgConfig,
    GatewayConfig,
    HandConfig,
    NodeConfig,
    SkinConfig,
    scene_config,
    synchronous_tpdos,
)
from grasplink.gateway.description import SdoWrite
from grasplink.gateway.drives import DriveHandshake
from grasplink.gateway.emg import (
    ENVELOPE_FULL_SCALE_UV,
    CalibrationRecorder,
    EmgCalibration,
    EmgIntent,
    EmgIntentDecoder,
)
from grasplink.gateway.feedback import FeedbackController, FeedbackOutput
from grasplink.gateway.levels import Belt
from grasplink.gateway.master import NmtMaster
from grasplink.gateway.percept import Percept
from grasplink.gateway.plausibility import (
    CommandRamp,
    EnvelopeCheck,
    GripCheck,
    Rejections,
    judge_emcy,
)
from grasplink.gateway.provisioning import Provisioner
from grasplink.gateway.reflex import GripArbiter, GripCommand, ReflexState
from grasplink.gateway.sdo_client import SdoClient, Transfer
from grasplink.gateway.snapshot import (
    BeltSnapshot,
    DeviceObject,
    DeviceValues,
    EmgSnapshot,
    HandSnapshot,
    HeartbeatStats,
    LoopSnapshot,
    NodePhase,
    NodeSnapshot,
    Rejected,
    SkinSnapshot,
    Snapshot,
    device_objects,
    device_value,
)
from grasplink.gateway.sync import SyncNumbers, SyncProducer
from grasplink.profiles import object_key, object_limits, variable_limits
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import KINDS
from grasplink.profiles.pdo_codec import INTEGER_TYPES, Key, PdoCodec

log = logging.getLogger(__name__)

LATENCY_HISTORY = 2000
SECOND_MASTER_CLEAR_US = 5_000_000  # the second-master alarm clears after this long unheard
COMMAND_REFRESH_US = 100_000  # RPDOs repeat at least this often (drive handshake, deadlines)
SNAPSHOT_PERIOD_US = 50_000  # 20 Hz, the default telemetry rate
PROVISION_RETRY_US = 2_000_000
NETWORK_HELD = "network.held"  # the alarm while a mandatory node keeps the others waiting
STARTED_OR_READY = (NodePhase.READY, NodePhase.STARTING, NodePhase.OPERATIONAL)
MN_PER_N = 1000.0

STATIC_FORCE_KEY = (obj.SKIN_STATIC_FORCE_MN, 0)
STATUSWORD_KEY = (obj.STATUSWORD, 0)
CONTROLWORD_KEY = (obj.CONTROLWORD, 0)


@dataclass
class NodeLink:
    """What the gateway keeps per configured node."""

    config: NodeConfig
    codec: PdoCodec
    sdo: SdoClient
    phase: NodePhase = NodePhase.ABSENT
    provisioning: list[tuple[SdoWrite, Transfer]] = field(default_factory=list)
    identity_reads: list[tuple[int, Transfer]] = field(default_factory=list)  # 1018h sub-index
    writes: tuple[SdoWrite, ...] = ()  # built with the gateway: a boot never parses an EDS
    retry_at_us: int | None = None
    boots_seen: int = -1  # the master's boot count when provisioning last began
    failure: str = ""
    pdos_rx: int = 0
    pdos_dropped: Counter[str] = field(default_factory=Counter)
    emcy: list[tuple[int, int]] = field(default_factory=list)  # (t_us, error code), bounded
    values: dict[Key, int | float] = field(default_factory=dict)
    # RPDO values last sent to a device at a client's request (write_object); replaced
    # whole, as the Modbus thread reads it back
    written: dict[Key, int | float] = field(default_factory=dict)

    @property
    def kind(self) -> str:
        return self.config.kind

    @property
    def name(self) -> str:
        """The description's name (a loop node's is its kind): alarms and snapshots use it."""
        return self.config.name

    def codec_od_entry(self, index: int, subindex: int = 0) -> Any:
        """The node's object-dictionary entry (types for SDO values)."""
        return self.codec.od_entry(index, subindex)

    @property
    def node_id(self) -> int:
        return self.config.node_id


@dataclass(frozen=True, slots=True)
class TpdoRoute:
    """What a node's TPDO asks of the gateway, worked out once from the configuration:
    the frame path looks this up by CAN-ID instead of parsing the CAN-ID, the node's kind
    and each mapped object's EDS limits per frame."""

    link: NodeLink
    kind: str  # the node's (link.kind, looked up per frame otherwise)
    limits: tuple[tuple[Key, float, float], ...]  # mapped objects the EDS bounds
    sample_keys: tuple[Key, ...]  # the skin's sample slots it maps (their sensor's range)
    batched: bool = False  # a skin's or EMG's synchronous TPDO: handled once per SYNC cycle


class Gateway(NmtMaster):
    """See module docstring."""

    def __init__(self, config: GatewayConfig):
        skin_hb = [n.heartbeat_ms for n in config.nodes.values()] or [100]
        super().__init__(
            config.node_id,
            heartbeat_ms=config.heartbeat_ms,
            node_heartbeat_ms=max(skin_hb),
            consumer_ms=config.consumer_ms,
            loss_allowance_ms=config.consumer_allowance_ms,
        )
        self.config = config
        self.links: dict[int, NodeLink] = {}
        self.by_kind: dict[str, NodeLink] = {}  # the loop's nodes, by role
        for node in config.nodes.values():
            link = NodeLink(
                node,
                PdoCodec.from_od(node.dictionary(), node.node_id),
                SdoClient(node.node_id, timeout_us=config.sdo_timeout_ms * 1000),
                writes=tuple(Provisioner(node, config).writes()),
            )
            self.links[node.node_id] = link
            if node.kind in KINDS:
                self.by_kind[node.kind] = link
        self.alarms: dict[str, str] = {}
        # device nodes: what their TPDOs map, described once for every snapshot
        self._device_objects: dict[str, tuple[NodeLink, tuple[DeviceObject, ...]]] = {
            link.name: (link, device_objects(link.codec))
            for link in self.links.values()
            if link.kind == DEVICE_ROLE
        }
        self.frames_dropped: Counter[str] = Counter()
        # the SYNC producer (sync.py), when the configuration asks for one
        self.sync = (
            SyncProducer(config.sync_period_us, config.sync_counter_overflow)
            if config.sync_period_us
            else None
        )
        # the skin's and EMG's synchronous TPDOs (CAN-IDs), handled once per SYNC cycle
        self._batched = self._synchronous_can_ids() if self.sync is not None else frozenset()
        # (arrival, role, values, the number of the SYNC a vendor's sample answered)
        self._cycle: list[tuple[int, str, dict[Key, int | float], int | None]] = []
        self._cycle_due_us: int | None = None
        # the earliest deadline besides the SYNC and the cycle, when nothing happened since
        # it was computed (None: unknown, advance runs in full)
        self._rest_due_us: int | None = None
        # The network side's earliest deadline (heartbeats, lost nodes, SDO, provisioning
        # retries, command refresh, snapshot), kept until a call that can move it: a
        # TPDO moves only the control's deadlines, and most frames are TPDOs.
        self._network_due_us: int | None = None
        self._network_stale = True
        # The control's earliest deadline (feedback, reflex, command ramps), likewise kept
        # until the control or a command moves: most TPDOs move neither.
        self._control_due_us: int | None = None
        self._control_stale = True
        self.cycles = 0  # SYNC cycles handled
        self._skin_setup()
        self._emg_setup()
        self._bindings_setup()
        self.feedback = FeedbackController(config.feedback.controller, mode=config.feedback.mode)
        self.arbiter = GripArbiter(config.reflex)
        self.drives = {k: DriveHandshake() for k in ("belt", "hand") if k in self.by_kind}
        self.belt_output: FeedbackOutput | None = None
        self.grip_command: GripCommand | None = None
        self.hand_grip_n: float | None = None  # actual, from the hand's TPDO
        self.last_estimate: SlipEstimate | None = None
        self.last_intent: EmgIntent | None = None
        self.counters: Counter[str] = Counter()
        self._plausibility_setup()
        self._routes = self._tpdo_routes()
        self.calibration = CalibrationRecorder()
        # Called with (t_us, estimate) for every skin decoder update (telemetry, replays).
        self.estimate_listeners: list[Callable[[int, SlipEstimate], None]] = []
        # Processing time from a skin TPDO to the RPDOs it causes, recent history only:
        # measured by the live edge (`edge.GatewayEdge`), which has a clock; none in virtual time.
        self.loop_latency_us: deque[float] = deque(maxlen=LATENCY_HISTORY)
        self._next_refresh_us: int | None = None
        # The latest snapshot, replaced whole every SNAPSHOT_PERIOD_US on the gateway's own
        # thread, so other threads (status line, telemetry) read it without locks.
        self.latest: Snapshot | None = None
        self._next_snapshot_us: int | None = None
        self._started_us = 0
        self._sent: dict[int, bytes] = {}
        self._packed: dict[str, tuple[tuple[int, Key, int], tuple[int, bytes]]] = {}  # last RPDO
        self._held_grip_mn: int | None = None
        # Until the wearer's grip is known (EMG, or without EMG the hand's own grip) the
        # hand is only commanded by the reflex: it keeps what it holds.
        self._voluntary_known = False
        self.now_us = 0

    @classmethod
    def from_scene(cls, options: Params, nodes: Mapping[str, Mapping[str, Any]]) -> Gateway:
        """A scene's `[controller] type = "gateway"` (see `scene_config`)."""
        return cls(scene_config(options, nodes))

    # -- construction helpers --------------------------------------------------------------
    def _synchronous_can_ids(self) -> frozenset[int]:
        """CAN-IDs of the skin's and the EMG's TPDOs their `[sdo]` tables make synchronous."""
        can_ids = set()
        for role in ("skin", "emg"):
            link = self.by_kind.get(role)
            if link is None:
                continue
            written = {(w.index, w.subindex): w.data for w in link.config.sdo}
            for comm in synchronous_tpdos(link.config):
                data = written.get((comm, 1))
                cob_id = (
                    link.codec_od_entry(comm, 1).default
                    if data is None
                    else int.from_bytes(data, "little")
                )
                can_ids.add(int(cob_id) & CAN_ID_MASK)
        return frozenset(can_ids)

    def _tpdo_routes(self) -> dict[int, TpdoRoute]:
        """Each configured node's TPDOs by CAN-ID: only those whose CAN-ID names the node
        itself (the predefined connection set), as `receive` finds the node by it."""
        routes = {}
        for link in self.links.values():
            for can_id in link.codec.tpdo_can_ids():
                function, node_id = function_of(can_id)
                if node_id != link.node_id or not function.startswith("TPDO"):
                    continue
                keys = link.codec.tpdo_keys(can_id)
                limits = []
                for key in dict.fromkeys(keys):
                    bounds = self._eds_limit(link, key)
                    if bounds is not None:
                        limits.append((key, *bounds))
                routes[can_id] = TpdoRoute(
                    link,
                    link.kind,
                    tuple(limits),
                    tuple(k for k in dict.fromkeys(keys) if k[0] == obj.SKIN_SAMPLE_SLOTS),
                    can_id in self._batched and link.kind in ("skin", "emg"),
                )
        return routes

    def stream_can_ids(self) -> frozenset[int]:
        """The TPDOs that carry the skin's samples (`StreamConsumer`): a runner behind the
        bus delivers every one of them, as each packet holds samples no later one does."""
        if self.skin_binding is None:
            return frozenset()
        samples = set(self.skin_binding.objects.samples)
        return frozenset(
            can_id
            for can_id, route in self._routes.items()
            if route.kind == "skin" and samples.intersection(route.link.codec.tpdo_keys(can_id))
        )

    def _skin_setup(self) -> None:
        link = self.by_kind.get("skin")
        self.skin_frames: SkinFrames | None = None
        self.decoder = None
        self.skin_binding: roles.SkinBinding | None = None  # its objects, what it can read
        self._noted_grip_mn: int | None = None  # the last grip command the decoder was told
        # a vendor's samples on SYNC are numbered by the SYNC they answer (roles.py)
        self._skin_sync_numbers: SyncNumbers | None = None
        if link is None:
            return
        skin = link.config
        assert isinstance(skin, SkinConfig)
        binding = skin.binding
        if binding is None:  # our skin node: its calibration from its EDS
            calibration = SkinCalibration.from_od(skin.dictionary())
            binding = roles.own_skin(calibration, skin.samples_per_pdo)
        assert isinstance(binding, roles.SkinBinding)
        self.skin_binding = binding
        # Sample times come from the packet sequence; a packet may arrive as late as the
        # heartbeat consumer time (a stalled host, the burst after it) without a reset.
        self.skin_frames = SkinFrames(
            binding.objects,
            skin.sample_rate_hz,
            late_us=self.node_consumer_us,
            settle_us=LIVE_SETTLE_US,
        )
        self.decoder = make_decoder(skin.decoder, skin.layout_mm, skin.sample_rate_hz)
        hand = self.by_kind.get("hand")
        if hand is not None and isinstance(hand.config, HandConfig):
            # the efference copy (`_commands`): how fast the hand follows a grip command
            self.decoder.set_hand_follow(hand.config.grip_rate_n_s)
        if binding.sync_every:
            self._skin_sync_numbers = SyncNumbers(binding.sync_every)

    def _plausibility_setup(self) -> None:
        """What the loop refuses to follow, and how fast its commands may move
        (plausibility.py; limits from `[plausibility]` and the nodes' EDS)."""
        plaus = self.config.plausibility
        self.rejected = Rejections()
        self.grip_ramp = CommandRamp(plaus.grip_slew_n_s * MN_PER_N, plaus.command_interval_us)
        self.belt_ramp = CommandRamp(plaus.belt_slew_mrad_s2, plaus.command_interval_us)
        self._second_master_us: int | None = None
        self._eds_limits: dict[tuple[str, Key], tuple[float, float] | None] = {}
        emg, hand = self.by_kind.get("emg"), self.by_kind.get("hand")
        self._envelope_check = None
        if emg is not None and isinstance(emg.config, EmgConfig):
            self._envelope_check = EnvelopeCheck(
                plaus.emg_max_amplitude_uv,
                emg.config.window_ms,
                emg.config.envelope_period_ms,
                ENVELOPE_FULL_SCALE_UV,
            )
        self._grip_check = None
        if hand is not None and isinstance(hand.config, HandConfig):
            self._grip_check = GripCheck(
                hand.config.crush_limit_n,
                hand.config.grip_rate_n_s,
                plaus.hand_grip_margin_n,
                plaus.hand_slew_factor,
            )

    def _bindings_setup(self) -> None:
        """Which objects the loop reads and writes on each role's node (roles.py): our own
        nodes' from their EDS, a vendor's from the description."""
        self.drive_bindings: dict[str, roles.DriveBinding] = {}
        for role in ("belt", "hand"):
            link = self.by_kind.get(role)
            if link is not None:
                binding = link.config.binding or roles.own_drive(role, link.codec)
                assert isinstance(binding, roles.DriveBinding)
                self.drive_bindings[role] = binding
        emg = self.by_kind.get("emg")
        envelope = (emg.config.binding if emg is not None else None) or roles.OWN_EMG
        assert isinstance(envelope, roles.EmgBinding)
        self._envelope_key = envelope.envelope
        self._uv_per_unit = envelope.uv_per_unit
        self._command_limits: dict[str, tuple[int, int]] = {}
        for role, binding in self.drive_bindings.items():
            link = self.by_kind[role]
            if link.config.eds is None:
                limits = object_limits(role, *binding.target)
            else:
                low, high = variable_limits(link.codec_od_entry(*binding.target))
                limits = (math.ceil(low), math.floor(high))
            self._command_limits[role] = limits

    def _envelope_uv(self, values: Mapping[Key, int | float]) -> float:
        return float(values[self._envelope_key]) * self._uv_per_unit

    def _actual_grip_n(self, kind: str, values: Mapping[Key, int | float]) -> float | None:
        """The grip the hand reports, in N (None: this frame is not the hand's or does not
        carry it); `kind`: the sending node's."""
        if kind != "hand":
            return None
        binding = self.drive_bindings["hand"]
        if binding.actual is None or binding.actual not in values:
            return None
        return float(values[binding.actual]) / binding.units_per_command / MN_PER_N

    def _emg_setup(self) -> None:
        link = self.by_kind.get("emg")
        self.emg_decoder: EmgIntentDecoder | None = None
        if link is None:
            return
        emg = link.config
        assert isinstance(emg, EmgConfig)
        self.emg_decoder = EmgIntentDecoder(
            EmgCalibration(emg.e_min_uv, emg.e_max_uv),
            mode=emg.grip_mode,
            grip_levels_n=emg.grip_levels_n,
            grip_max_n=emg.grip_max_n,
        )

    # -- SansIoDevice ----------------------------------------------------------------------
    def start(self, t_us: int) -> list[Frame]:
        self.now_us = t_us
        self._network_stale = self._control_stale = True
        self._next_refresh_us = t_us + COMMAND_REFRESH_US
        self._next_snapshot_us = t_us
        self._started_us = t_us
        if self.sync is not None:
            self.sync.start(t_us)
            if self._skin_sync_numbers is not None:
                self._skin_sync_numbers = SyncNumbers(self._skin_sync_numbers.every)
        return super().start(t_us)

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        self.now_us = t_us
        self._rest_due_us = None  # a frame may make anything due: advance looks at all
        route = self._routes.get(frame.can_id)
        if route is not None:  # a configured node's TPDO: most frames
            return self._on_tpdo(route, frame, t_us)
        self._network_stale = self._control_stale = True
        if frame.can_id == NMT_COB_ID or frame.can_id == HEARTBEAT_BASE + self.node_id:
            return self._second_master(frame, t_us)
        function, node_id = function_of(frame.can_id)
        link = self.links.get(node_id)
        if function == "heartbeat":
            return super().receive(frame, t_us) + self._after_heartbeat(link, t_us)
        if link is None:
            return []
        if function == "SDO tx":
            return link.sdo.receive(frame, t_us) + self._check_provisioning(link, t_us)
        if function == "EMCY" and frame.can_id == EMCY_BASE + node_id:
            return super().receive(frame, t_us) + self._emcy_alarm(link, frame, t_us)
        if function.startswith("TPDO"):  # one the node's file does not map: dropped
            return self._on_tpdo(TpdoRoute(link, link.kind, (), ()), frame, t_us)
        return []

    def advance(self, t_us: int) -> list[Frame]:
        self.now_us = t_us
        self._network_stale = self._control_stale = True
        # SYNC first: the nodes sample and answer on it, the rest can wait a frame
        frames = self.sync.advance(t_us) if self.sync is not None else []
        if frames and self._skin_sync_numbers is not None:
            assert self.sync is not None
            self._skin_sync_numbers.sent(self.sync.index)
        if self._cycle_due_us is not None and t_us >= self._cycle_due_us:
            frames += self._handle_cycle(t_us)
        rest, self._rest_due_us = self._rest_due_us, None
        if rest is not None and t_us < rest:
            # a SYNC or a cycle alone (twice per cycle): the network master, provisioning
            # and the control's timers had nothing due when last asked, and nothing came
            # since; what the cycle made due is seen at the next deadline
            return frames
        frames += super().advance(t_us)
        for link in self.links.values():
            frames += link.sdo.advance(t_us)
            frames += self._check_provisioning(link, t_us)
            if link.retry_at_us is not None and t_us >= link.retry_at_us:
                link.retry_at_us = None
                frames += self._provision(link, t_us)
            status = self.nodes.get(link.node_id)
            if status is not None and status.lost and link.phase is not NodePhase.LOST:
                frames += self._lose(link, NodePhase.LOST, "heartbeat lost", t_us)
        deadline = self._control_deadline()
        if deadline is not None and t_us >= deadline:
            self._advance_control(t_us)
            frames += self._commands(t_us)
        elif self._ramp_deadline(t_us):
            frames += self._commands(t_us)
        if self._next_refresh_us is not None and t_us >= self._next_refresh_us:
            self._next_refresh_us += COMMAND_REFRESH_US * (
                1 + (t_us - self._next_refresh_us) // COMMAND_REFRESH_US
            )
            frames += self._commands(t_us, refresh=True)
        if self._next_snapshot_us is not None and t_us >= self._next_snapshot_us:
            self._second_master_quiet(t_us)
            self._next_snapshot_us = t_us + SNAPSHOT_PERIOD_US
            self.latest = self.snapshot()
        return frames

    def next_deadline_us(self) -> int | None:
        # The runner asks after every frame: a plain running minimum, no lists (~3x cheaper).
        if self._network_stale:
            self._network_due_us = self._network_deadline_us()
            self._network_stale = False
        if self._control_stale:
            self._control_due_us = None
            for c in (
                self.feedback.next_deadline_us(),
                self.arbiter.next_deadline_us(),
                self._next_ramp_us(),
            ):
                if c is not None and (self._control_due_us is None or c < self._control_due_us):
                    self._control_due_us = c
            self._control_stale = False
        best, control = self._network_due_us, self._control_due_us
        if control is not None and (best is None or control < best):
            best = control
        if self.sync is None:
            return best
        # with SYNC: what is due apart from the SYNC and the cycle, for advance's short path
        self._rest_due_us = best
        for c in (self.sync.next_deadline_us(), self._cycle_due_us):
            if c is not None and (best is None or c < best):
                best = c
        return best

    def _network_deadline_us(self) -> int | None:
        """The network side's earliest deadline (heartbeat loss is noticed when advance()
        runs: the master's deadline)."""
        best = None
        for c in (super().next_deadline_us(), self._next_refresh_us, self._next_snapshot_us):
            if c is not None and (best is None or c < best):
                best = c
        for link in self.links.values():
            for c in (link.sdo.next_deadline_us(), link.retry_at_us):
                if c is not None and (best is None or c < best):
                    best = c
        return best

    # -- network management ------------------------------------------------------------------
    def _start(self, node_id: int) -> list[Frame]:
        """A node booted or is PRE-OPERATIONAL: provision it, then start it.

        A PRE-OPERATIONAL heartbeat while its provisioning runs (or waits for a retry) is
        the node waiting for us; one after START was sent means START was lost.
        """
        link = self.links.get(node_id)
        if link is None:
            return super()._start(node_id)
        boots = self.nodes[node_id].boots
        if boots == link.boots_seen:
            if link.phase in (NodePhase.PROVISIONING, NodePhase.FAILED, NodePhase.READY):
                return []
            if link.phase is NodePhase.STARTING:
                return [self.command_start(node_id)]
        link.boots_seen = boots
        self.on_node_restart(node_id)
        return self._provision(link, self.now_us)

    def on_node_restart(self, node_id: int) -> None:
        link = self.links.get(node_id)
        if link is None:
            return
        link.written = {}  # back to its defaults: what a client wrote is gone
        if link.kind in self.drives:
            self.drives[link.kind].reset()
        if link.kind == "skin" and self.skin_frames is not None:
            self._drop_from_cycle("skin")
            self.skin_frames.restart()

    def _provision(self, link: NodeLink, t_us: int) -> list[Frame]:
        """CiA 302-2 boot, the parts that matter here: the identity read back from 1018h
        (when the description gives one), then the configuration writes, then the start."""
        link.sdo.cancel()
        link.phase = NodePhase.PROVISIONING
        identity = link.config.identity
        if identity is not None:
            link.identity_reads = [
                (sub, link.sdo.upload(obj.IDENTITY, sub)) for sub, _ in identity.expected
            ]
            return link.sdo.advance(t_us)
        return self._configure(link, t_us)

    def _configure(self, link: NodeLink, t_us: int) -> list[Frame]:
        link.provisioning = [
            (w, link.sdo.download(w.index, w.subindex, w.data)) for w in link.writes
        ]
        if not link.provisioning:  # a device with nothing to write
            return self._ready(link, t_us)
        return link.sdo.advance(t_us)

    def _check_provisioning(self, link: NodeLink, t_us: int) -> list[Frame]:
        if link.phase is not NodePhase.PROVISIONING:
            return []
        if link.identity_reads:
            return self._check_identity(link, t_us)
        if not link.provisioning:
            return []
        # The client runs the writes one at a time in the order queued (a cancel fails the
        # rest at once): the first not yet ok is the first to fail, or the one under way.
        # (One pass, from every advance while provisioning runs.)
        for write, transfer in link.provisioning:
            if not transfer.ok:
                if transfer.done:
                    return self._failed(link, f"{write.what}: {transfer.describe()}", t_us)
                return []
        link.provisioning = []
        self.alarms.pop(f"{link.name}.provisioning", None)
        return self._ready(link, t_us)

    def _failed(self, link: NodeLink, why: str, t_us: int, *, retry: bool = True) -> list[Frame]:
        """A configuration step failed: alarmed, and retried later unless `retry` is False
        (a wrong identity stays wrong until the node boots again)."""
        link.sdo.cancel()
        link.provisioning = []
        link.identity_reads = []
        link.phase = NodePhase.FAILED
        link.failure = why
        self.alarms[f"{link.name}.{'provisioning' if retry else 'identity'}"] = why
        link.retry_at_us = t_us + PROVISION_RETRY_US if retry else None
        if link.config.mandatory:  # the nodes it holds say why
            self._missing_mandatory()
        return []

    def _check_identity(self, link: NodeLink, t_us: int) -> list[Frame]:
        reads = link.identity_reads
        if not all(t.done for _, t in reads):
            return []
        failed = next((t for _, t in reads if not t.ok), None)
        if failed is not None:
            return self._failed(link, f"identity: {failed.describe()}", t_us)
        identity = link.config.identity
        assert identity is not None
        read = {sub: int.from_bytes(t.data[:4], "little") for sub, t in reads}
        link.identity_reads = []
        wrong = identity.mismatch(read)
        if wrong is not None:
            return self._failed(link, f"wrong identity: {wrong}; not started", t_us, retry=False)
        self.alarms.pop(f"{link.name}.identity", None)
        self.alarms.pop(f"{link.name}.provisioning", None)
        return self._configure(link, t_us)

    def _ready(self, link: NodeLink, t_us: int) -> list[Frame]:
        """Configured: started now, or held while a mandatory node is not ready (CiA 302:
        the network starts once every mandatory node is); then every held node starts."""
        link.phase = NodePhase.READY
        if self._missing_mandatory():
            return []
        frames = []
        for held in self.links.values():
            if held.phase is NodePhase.READY:
                held.phase = NodePhase.STARTING
                frames.append(self.command_start(held.node_id))
        return frames

    def _missing_mandatory(self) -> bool:
        """Whether a mandatory node is not ready; while it holds configured nodes back, the
        alarm `network.held` names it and why (a refused write, no answer, not booted)."""
        missing = [
            other
            for other in self.links.values()
            if other.config.mandatory and other.phase not in STARTED_OR_READY
        ]
        held = any(link.phase is NodePhase.READY for link in self.links.values())
        if missing and held:
            self.alarms[NETWORK_HELD] = "waiting for mandatory node " + "; ".join(
                f"{other.name} (0x{other.node_id:02X}): {_why_not_ready(other)}"
                for other in missing
            )
        else:
            self.alarms.pop(NETWORK_HELD, None)
        return bool(missing)

    def command_start(self, node_id: int) -> Frame:
        return self.command(NmtCommand.START, node_id)

    def _after_heartbeat(self, link: NodeLink | None, t_us: int) -> list[Frame]:
        if link is None:
            return []
        status = self.nodes.get(link.node_id)
        if status is None or status.state is None:
            return []
        if status.state == NmtState.OPERATIONAL:
            if link.phase is not NodePhase.OPERATIONAL:
                link.phase = NodePhase.OPERATIONAL
                self.alarms.pop(f"{link.name}.lost", None)
                return self._commands(t_us, refresh=True)
            return []
        if link.phase is NodePhase.OPERATIONAL:
            why = f"left OPERATIONAL ({status.state.name})"
            return self._lose(link, NodePhase.ABSENT, why, t_us)
        return []

    def _lose(self, link: NodeLink, phase: NodePhase, why: str, t_us: int) -> list[Frame]:
        """The degraded state for a node gone (`phase`: lost, its heartbeat stopped; absent,
        it left OPERATIONAL): belt stopped, hand holding, alarm raised."""
        link.phase = phase
        link.sdo.cancel()
        self.alarms[f"{link.name}.lost"] = why
        if link.kind == "skin" and self.skin_frames is not None:
            self._drop_from_cycle("skin")
            self.skin_frames.restart()
        return self._commands(t_us, refresh=True)

    def _emcy_alarm(self, link: NodeLink, frame: Frame, t_us: int) -> list[Frame]:
        if len(frame.data) != 8:
            link.pdos_dropped["emcy length"] += 1
            return []
        code = int.from_bytes(frame.data[:2], "little")
        verdict = judge_emcy(link.kind, code, frame.data[2])
        if not verdict.trusted:  # no CiA 301 error class, or no generic bit: not an EMCY
            self.rejected["emcy_invalid"] += 1
            return []
        if not verdict.known:  # a real class, not a code this node declares: not named
            self.rejected["emcy_unknown_code"] += 1
        link.emcy.append((t_us, code))
        del link.emcy[:-32]
        key = f"{link.name}.emcy"
        if code == 0:
            self.alarms.pop(key, None)
        else:
            self.alarms[key] = verdict.text
        return []

    def _second_master(self, frame: Frame, t_us: int) -> list[Frame]:
        """NMT commands and heartbeats at our node-ID come from the master only, and a bus
        never echoes our own: these are another master's. An alarm, a log line, counted."""
        if frame.rtr:
            return []
        if frame.can_id == NMT_COB_ID:
            self.rejected["foreign_nmt"] += 1
            data = bytes(frame.data).hex(" ")
            what = f"NMT command {data or '(empty)'} we did not send"
        else:
            self.rejected["second_master_heartbeat"] += 1
            what = f"a heartbeat at our node-ID 0x{self.node_id:02X}"
        if self._second_master_us is None:
            log.warning("gateway 0x%02X: another master on the bus: %s", self.node_id, what)
        self._second_master_us = t_us
        self.alarms["gateway.second_master"] = (
            f"another master on the bus: {self.rejected['foreign_nmt']} NMT commands, "
            f"{self.rejected['second_master_heartbeat']} heartbeats at our node-ID; "
            f"last: {what}"
        )
        return []

    def _second_master_quiet(self, t_us: int) -> None:
        """The alarm clears once no other master has been heard for SECOND_MASTER_CLEAR_US."""
        if self._second_master_us is not None and (
            t_us - self._second_master_us >= SECOND_MASTER_CLEAR_US
        ):
            self._second_master_us = None
            self.alarms.pop("gateway.second_master", None)

    # -- process data ----------------------------------------------------------------------
    def _on_tpdo(self, route: TpdoRoute, frame: Frame, t_us: int) -> list[Frame]:
        link, kind = route.link, route.kind
        try:
            values = link.codec.decode(frame.can_id, frame.data)
        except PdoError:
            link.pdos_dropped["does not fit its mapping"] += 1
            return []
        rejected = self._implausible(route, values, t_us)
        if rejected is not None:  # counted; the frame changes nothing
            self.rejected[rejected] += 1
            return []
        link.pdos_rx += 1
        link.values.update(values)
        if route.batched:
            return self._gather(kind, values, t_us)
        if kind == "skin":
            return self._on_skin(values, t_us)
        if kind == "emg" and self._envelope_key in values:
            return self._on_emg(self._envelope_uv(values), t_us)
        if kind in self.drives and STATUSWORD_KEY in values:
            self.drives[kind].on_statusword(int(values[STATUSWORD_KEY]))
            grip_n = self._actual_grip_n(kind, values)
            if grip_n is not None:
                self.hand_grip_n = grip_n
                if self.emg_decoder is None and not self._voluntary_known:
                    # No EMG: the wearer's grip is whatever the hand holds when we start.
                    self._voluntary_known = True
                    self._control_stale = True
                    self.grip_command = self.arbiter.set_voluntary(t_us, self.hand_grip_n)
        return []

    def _implausible(
        self, route: TpdoRoute, values: dict[Key, int | float], t_us: int
    ) -> str | None:
        """Why a decoded TPDO cannot be true (a `REJECTION_KEYS` key), None if it can."""
        for key, low, high in route.limits:
            if not low <= values[key] <= high:
                return "tpdo_out_of_range"
        kind = route.kind
        if kind == "skin" and self.skin_binding is not None:  # what the sensor can report
            top = self.skin_binding.max_units
            if top is not None and any(values[k] > top for k in route.sample_keys):
                return "skin_sample_out_of_range"
            static = self.skin_binding.static_force_range_mn
            if (
                static is not None
                and STATIC_FORCE_KEY in values
                and not static[0] <= values[STATIC_FORCE_KEY] <= static[1]
            ):
                return "skin_sample_out_of_range"
        elif kind == "emg" and self._envelope_key in values and self._envelope_check is not None:
            return self._envelope_check.check(t_us, self._envelope_uv(values))
        elif kind == "hand" and self._grip_check is not None:
            grip_n = self._actual_grip_n(kind, values)
            if grip_n is not None:
                return self._grip_check.check(t_us, grip_n)
        return None

    def _eds_limit(self, link: NodeLink, key: Key) -> tuple[float, float] | None:
        """The EDS LowLimit/HighLimit of a mapped object (None: only its type bounds it)."""
        cache_key = (link.name, key)
        if cache_key not in self._eds_limits:
            entry = link.codec_od_entry(*key)
            low, high = entry.min, entry.max
            self._eds_limits[cache_key] = (
                None
                if low is None and high is None
                else (
                    -math.inf if low is None else float(low),
                    math.inf if high is None else float(high),
                )
            )
        return self._eds_limits[cache_key]

    def _on_skin(self, values: dict[Key, int | float], t_us: int) -> list[Frame]:
        if self.skin_frames is None or self.decoder is None:
            return []
        numbers = self._skin_sync_numbers
        number = numbers.answer() if numbers is not None else None
        t_s, force_n = self.skin_frames.feed(t_us, values, number)
        return self._commands(t_us) if self._decode(t_s, force_n, t_us) else []

    def _decode(self, t_s: np.ndarray, force_n: np.ndarray, t_us: int) -> bool:
        """Samples through the decoder and each update through the control; whether any."""
        if self.decoder is None or not len(t_s):
            return False
        estimates = self.decoder.feed(t_s, force_n)
        if not estimates:
            return False
        self.last_estimate = estimates[-1]
        for estimate in estimates:
            self._control(estimate, t_us)
        return True

    def _on_emg(self, envelope_uv: float, t_us: int) -> list[Frame]:
        return self._commands(t_us) if self._intent(envelope_uv, t_us) else []

    def _intent(self, envelope_uv: float, t_us: int) -> bool:
        """An envelope reading becomes the wearer's grip; whether it did."""
        if self.emg_decoder is None:
            return False
        intent = self.emg_decoder.update(t_us, envelope_uv)
        if intent is None:
            return False
        self.last_intent = intent
        self.calibration.add(envelope_uv)
        self._voluntary_known = True
        self._control_stale = True
        self.grip_command = self.arbiter.set_voluntary(t_us, intent.grip_n)
        return True

    # -- SYNC cycles -------------------------------------------------------------------------
    def _gather(self, role: str, values: dict[Key, int | float], t_us: int) -> list[Frame]:
        """A synchronous TPDO waits for the gateway's next `advance`, which a runner calls
        once it has delivered every frame that arrived with this one: the cycle's."""
        numbers = self._skin_sync_numbers if role == "skin" else None
        self._cycle.append((t_us, role, values, numbers.answer() if numbers else None))
        if self._cycle_due_us is None:
            self._cycle_due_us = t_us
        return []

    def _drop_from_cycle(self, role: str) -> None:
        """A node restarted or lost: what it sent before is not handled after."""
        self._cycle = [entry for entry in self._cycle if entry[1] != role]
        if not self._cycle:
            self._cycle_due_us = None

    def _handle_cycle(self, t_us: int) -> list[Frame]:
        """A cycle's frames at once: the envelopes in order, the skin's packets placed by
        their sequence and decoded in one call, then one set of commands. The control acts
        at `t_us`, the gateway's clock, as it does on a frame's arrival."""
        cycle, self._cycle, self._cycle_due_us = self._cycle, [], None
        self.cycles += 1
        acted = False
        times, forces = [], []
        for arrived_us, role, values, number in cycle:
            if role == "emg":
                if self._envelope_key in values:
                    acted |= self._intent(self._envelope_uv(values), t_us)
            elif self.skin_frames is not None:
                t_s, force_n = self.skin_frames.feed(arrived_us, values, number)
                if len(t_s):
                    times.append(t_s)
                    forces.append(force_n)
        if times:
            acted |= self._decode(np.concatenate(times), np.concatenate(forces), t_us)
        return self._commands(t_us) if acted else []

    # -- what the gateway knows, for status lines, telemetry and registers -------------------
    def snapshot(self) -> Snapshot:
        """Everything a surface wants, typed, with units (see snapshot.py)."""
        nodes = {}
        consumer_ms = self.node_consumer_us // 1000
        for link in self.links.values():
            status = self.nodes.get(link.node_id)
            heard_us = status.last_seen_us if status else None
            lost_packets = None
            if link.kind == "skin" and self.skin_frames is not None:
                lost_packets = self.skin_frames.stats.lost_packets
            nodes[link.name] = NodeSnapshot(
                node_id=link.node_id,
                phase=link.phase,
                nmt_state=status.state if status else None,
                boots=status.boots if status else 0,
                last_emcy=link.emcy[-1][1] if link.emcy else None,
                failure=link.failure or None,
                pdos_dropped=sum(link.pdos_dropped.values()),
                lost_packets=lost_packets,
                heartbeat_consumer_ms=consumer_ms,
                pdos_rx=link.pdos_rx,
                # the gateway's clock, so a replay or a virtual-time run ages like a live one
                heartbeat_age_s=None if heard_us is None else (self.now_us - heard_us) / 1e6,
            )
        est = self.last_estimate
        belt = self.belt_output.belt if self.belt_output else None
        grip = self.grip_command
        intent = self.last_intent
        latencies = sorted(self.loop_latency_us)
        rejected = self.rejected.as_dict()
        rejected["hand_command_slew_limited"] = self.grip_ramp.limited
        rejected["belt_command_slew_limited"] = self.belt_ramp.limited
        return Snapshot(
            uptime_s=(self.now_us - self._started_us) / 1e6,
            nodes=nodes,
            skin=SkinSnapshot(
                grip_force_n=_finite(est.force_n) if est else None,
                slip=est.slip if est else None,
                slip_speed_mm_s=_finite(est.speed_mm_s) if est else None,  # |speed|
                position_mm=_finite(est.position_mm) if est else None,
                confidence=est.confidence if est else None,
                slip_speed_low_mm_s=_finite(est.speed_low_mm_s) if est else None,
                slip_speed_high_mm_s=_finite(est.speed_high_mm_s) if est else None,
                slip_direction=est.direction if est else None,  # +1, -1, None: not told
                slip_direction_confidence=_finite(est.direction_confidence) if est else None,
            ),
            emg=EmgSnapshot(
                envelope_uv=intent.envelope_uv if intent else None,
                level=intent.level if intent else None,
                grip_intent_n=intent.grip_n if intent else None,
                saturated=intent.saturated if intent else None,
            ),
            belt=BeltSnapshot(
                mode=self.feedback.mode,
                belt=belt.belt if belt else Belt.NONE,
                level=belt.level if belt else None,
                velocity_mrad_s=self._belt_velocity(),
                reason=belt.reason if belt else None,
            ),
            hand=HandSnapshot(
                grip_n=self.hand_grip_n,
                setpoint_n=grip.grip_n if grip else None,
                reflex=grip.reflex if grip else ReflexState.IDLE,
                source=grip.source if grip else None,
            ),
            loop=LoopSnapshot(
                latency_p50_us=_percentile(latencies, 0.5),
                latency_p99_us=_percentile(latencies, 0.99),
                percepts=self.counters["percepts"],
            ),
            heartbeat=HeartbeatStats(**self.heartbeat.stats()),  # our own: how late it went
            rejected=Rejected(**rejected),
            alarms=dict(self.alarms),
            devices={
                name: DeviceValues(
                    objects,
                    tuple(device_value(link.values.get((o.index, o.subindex))) for o in objects),
                )
                for name, (link, objects) in self._device_objects.items()
            },
        )

    # -- control ---------------------------------------------------------------------------
    def _control(self, estimate: SlipEstimate, t_us: int) -> None:
        """One decoder update through the feedback controller and the reflex.

        The percept is stamped with the gateway's clock (the time the samples arrived), so
        controller time never runs backwards whatever the decoder's grid does.
        """
        percept = Percept.from_estimate(estimate, t_us=t_us).clean()  # (once for both)
        self._control_stale = True
        self.counters["percepts"] += 1
        for listener in self.estimate_listeners:
            listener(t_us, estimate)
        self.belt_output = self.feedback.update(percept)
        self.grip_command = self.arbiter.update(percept)

    def _control_deadline(self) -> int | None:
        deadlines = (self.feedback.next_deadline_us(), self.arbiter.next_deadline_us())
        return min((d for d in deadlines if d is not None), default=None)

    def _advance_control(self, t_us: int) -> None:
        self.belt_output = self.feedback.advance(t_us)
        self.grip_command = self.arbiter.advance(t_us)

    # -- run-time commands (MQTT, Modbus, through the live edge's mailbox: edge.py) ----------
    def execute(self, command: Command, t_us: int) -> tuple[CommandResult, list[Frame]]:
        """Validate and apply one command now; a refused command changes nothing."""
        t_us = max(t_us, self.now_us)
        self._rest_due_us = None
        self._network_stale = self._control_stale = True
        try:
            value = parse_value(command)
            detail, frames = self._apply(command.name, value, t_us)
        except (CommandError, ConfigError) as exc:
            return CommandResult(command.name, False, str(exc)), []
        self.counters[f"command.{command.name}"] += 1
        return CommandResult(command.name, True, detail), frames

    def _apply(self, name: str, value: Any, t_us: int) -> tuple[str, list[Frame]]:
        if name == "feedback_mode":
            self.belt_output = self.feedback.set_mode(value, t_us)
            return f"feedback mode {value.value}", self._commands(t_us)
        if name == "reflex_enabled":
            self.grip_command = self.arbiter.set_reflex_enabled(value, t_us)
            return f"reflex {'on' if value else 'off'}", self._commands(t_us)
        if name == "reflex_threshold_mm_s":
            reflex = self.arbiter.reflex
            reflex.config = replace(
                reflex.config,
                threshold_mm_s=value,
                hysteresis_mm_s=min(reflex.config.hysteresis_mm_s, value / 2),
            )
            return f"reflex threshold {value:g} mm/s", []
        if name == "emg_calibration":
            return self._calibrate(EmgCalibration(*value), t_us)
        if name == "emg_calibrate":
            return self._calibration_phase(value, t_us)
        if name == "restart_node":  # any node of the description; configured again on boot-up
            node = self.config.nodes.get(value)
            if node is None:
                names = ", ".join(self.config.nodes) or "none"
                raise CommandError(f"restart_node: no node {shown(value)}; nodes: {names}")
            return f"reset node {value}", [self.command(NmtCommand.RESET_NODE, node.node_id)]
        if name == "write_object":
            return self._write_object(*value)
        raise CommandError(f"unknown command {name!r}")

    def _write_object(self, name: str, text: str, value: float) -> tuple[str, list[Frame]]:
        """A client's value for a device's RPDO-mapped object the configuration offers
        (`[[modbus.holding]]`): sent now in its RPDO, whose other objects keep the value
        last sent, else their file's. Never queued: a node not operational refuses it."""
        key = object_key(text)
        offered = {(r.node, (r.index, r.subindex)) for r in self.config.modbus_holding}
        if (name, key) not in offered:
            listed = ", ".join(f"{node} {i:04X}sub{s:X}" for node, (i, s) in sorted(offered))
            raise CommandError(
                f"write_object: {name} {text} is not offered for writing; offered: "
                f"{listed or 'none'} ([[modbus.holding]])"
            )
        link = self.links[self.config.nodes[name].node_id]
        if not self._commandable(link):
            raise CommandError(f"write_object: {name} is {link.phase.value}, not operational")
        codec = link.codec
        number = next(
            n for n in codec.rpdo_numbers() if key in (m.key for m in codec.rpdo_objects(n))
        )
        values = {
            m.key: link.written.get(m.key, _file_value(link, m.key))
            for m in codec.rpdo_objects(number)
        }
        integer = codec.od_entry(*key).data_type in INTEGER_TYPES
        values[key] = int(value) if integer and float(value).is_integer() else value
        try:
            can_id, data = codec.encode(number, values)
        except PdoError as exc:
            raise CommandError(f"write_object: {exc}") from None
        link.written = {**link.written, **values}
        return f"{name} {text} = {value:g} (RPDO{number})", [Frame(can_id, data)]

    def _calibrate(self, calibration: EmgCalibration, t_us: int) -> tuple[str, list[Frame]]:
        """New EMG calibration: used at once, and written to the EMG node (envelope levels)."""
        link = self.by_kind.get("emg")
        if link is None or self.emg_decoder is None:
            raise CommandError("emg_calibration: this gateway has no EMG node")
        old = self.emg_decoder.calibration
        self.emg_decoder.calibration = calibration
        pair = {1: calibration.e_min_uv, 2: calibration.e_max_uv}
        order = (1, 2) if calibration.e_min_uv < old.e_max_uv else (2, 1)
        for sub in order:
            var = link.codec_od_entry(obj.EMG_CALIBRATION, sub)
            link.sdo.download(obj.EMG_CALIBRATION, sub, var.encode_raw(round(pair[sub])))
        detail = f"EMG calibration {calibration.e_min_uv:g}..{calibration.e_max_uv:g} uV"
        return detail, link.sdo.advance(t_us)

    def _calibration_phase(self, phase: str, t_us: int) -> tuple[str, list[Frame]]:
        if self.emg_decoder is None:
            raise CommandError("emg_calibrate: this gateway has no EMG node")
        if phase in ("rest", "maximum"):
            self.calibration.begin(phase)
            return f"recording the {phase} phase", []
        if phase == "cancel":
            self.calibration = CalibrationRecorder()
            return "calibration cancelled", []
        return self._calibrate(self.calibration.result(), t_us)

    def _commands(self, t_us: int, *, refresh: bool = False) -> list[Frame]:
        """RPDOs to the belt and the hand: when a command changed, or as a periodic refresh."""
        self._control_stale = True  # the command ramps may step
        frames = []
        lost = self._sensing_lost()  # (once: each command below asks)
        belt = self.by_kind.get("belt")
        if belt is not None and self._commandable(belt):
            velocity = self._belt_velocity(lost)
            if velocity == 0:  # a stop is never slowed (the belt decelerates at 6084h)
                self.belt_ramp.start_from(0)
            else:  # at most the belt's acceleration, one change per command interval
                velocity = round(self.belt_ramp.output(velocity, t_us))
            frames += self._rpdo(belt, velocity, refresh)
        hand = self.by_kind.get("hand")
        if hand is not None and self._commandable(hand):
            grip_mn = self._hand_grip_mn(lost)
            if grip_mn is not None:
                # held while sensing is lost: where the ramp is, not where it was going;
                # the ramp stops there too, or its next step would stay due for ever
                at = self.grip_ramp.value
                if at is not None and lost:
                    self.grip_ramp.start_from(at)
                    grip_mn = round(at)
                else:
                    grip_mn = round(self.grip_ramp.output(grip_mn, t_us))
                sent = self._rpdo(hand, grip_mn, refresh)
                if sent and grip_mn != self._noted_grip_mn and self.decoder is not None:
                    # the efference copy: the decoder is told the grip it goes on the bus
                    # with, so it can tell the level bending under it from a ridge contact
                    self._noted_grip_mn = grip_mn
                    self.decoder.note_grip_command(t_us / 1e6, grip_mn / MN_PER_N)
                frames += sent
        return frames

    def _next_ramp_us(self) -> int | None:
        """When the next command on its way (slew-limited) takes its next step - only while
        its node takes commands: a ramp towards a node that is lost or held cannot step,
        and its deadline would stand still at the current time. (Asked after every frame:
        the node is looked at only for a ramp under way, no list is built.)"""
        best = None
        for kind, ramp in (("hand", self.grip_ramp), ("belt", self.belt_ramp)):
            due = ramp.next_deadline_us()
            if due is None or (best is not None and due >= best):
                continue
            link = self.by_kind.get(kind)
            if link is not None and self._commandable(link):
                best = due
        return best

    def _ramp_deadline(self, t_us: int) -> bool:
        """Whether a command on its way (slew-limited) is due for its next step."""
        due = self._next_ramp_us()
        return due is not None and t_us >= due

    def _commandable(self, link: NodeLink) -> bool:
        """Operational in our eyes and the master's: not lost, not held by a consumer fault."""
        return link.phase is NodePhase.OPERATIONAL and self.commandable(link.node_id)

    def _sensing_lost(self) -> list[str]:
        return [
            k
            for k in ("skin", "emg")
            if k in self.by_kind and self.by_kind[k].phase is not NodePhase.OPERATIONAL
        ]

    def _belt_velocity(self, sensing_lost: list[str] | None = None) -> int:
        """The belt stops whenever the skin cannot be trusted (lost, not running);
        `sensing_lost`: `_sensing_lost()` when the caller has it."""
        if sensing_lost is None:
            sensing_lost = self._sensing_lost()
        if "skin" in sensing_lost or self.belt_output is None:
            return 0
        return self.belt_output.belt.velocity_mrad_s

    def _hand_grip_mn(self, sensing_lost: list[str]) -> int | None:
        """The grip to command; held (last value sent) while a sensing node is lost."""
        command = self.grip_command
        if command is None or not (self._voluntary_known or command.reflex_active):
            return None
        if sensing_lost:
            return self._held_grip_mn
        self._held_grip_mn = command.target_grip_mn
        return self._held_grip_mn

    def _rpdo(self, link: NodeLink, value: int, refresh: bool) -> list[Frame]:
        """The drive's RPDO with `value` (mN of grip, mrad/s of belt) in its own units."""
        kind = link.kind
        binding = self.drive_bindings[kind]
        target = binding.target
        if binding.units_per_command != 1.0:
            value = round(value * binding.units_per_command)
        low, high = self._command_limits[kind]
        if not low <= value <= high:
            self.alarms[f"{link.name}.clamped"] = f"command {value} clamped to {low}..{high}"
            value = min(high, max(low, value))
        controlword = self.drives[kind].controlword()
        # Most calls repeat the last command (every skin update and EMG intent asks):
        # packing through the mapping costs ~10 µs, the comparison nothing.
        inputs = (controlword, target, value)
        last = self._packed.get(kind)
        if last is not None and last[0] == inputs:
            can_id, data = last[1]
        else:
            can_id, data = link.codec.encode(
                binding.rpdo, {CONTROLWORD_KEY: controlword, target: value}
            )
            self._packed[kind] = (inputs, (can_id, data))
        if not refresh and self._sent.get(can_id) == data:
            return []
        self._sent[can_id] = data
        return [Frame(can_id, data)]


def _file_value(link: NodeLink, key: Key) -> int | float:
    """What the node's file gives an object (a DCF's value, else its default; else 0)."""
    entry = link.codec_od_entry(*key)
    value = entry.value if entry.value is not None else entry.default
    return value if isinstance(value, int | float) else 0


def _why_not_ready(link: NodeLink) -> str:
    if link.phase is NodePhase.FAILED:
        return link.failure
    if link.phase is NodePhase.PROVISIONING:
        return "being configured"
    if link.phase is NodePhase.LOST:
        return "heartbeat lost"
    return "not booted" if link.boots_seen < 0 else "absent"


def _finite(value: float | None) -> float | None:
    return value if value is not None and math.isfinite(value) else None


def _percentile(ordered: list[float], share: float) -> float | None:
    if not ordered:
        return None
    return ordered[min(len(ordered) - 1, int(share * len(ordered)))]

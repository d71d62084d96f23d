"""The gateway's configuration: which nodes it masters and how, validated before the bus is touched.

Every key has a default, so `grasplink gateway` runs with no file; a file
(TOML) overrides what it names, and a mistake is a ConfigError naming the
file and the key (`gw.toml: nodes.emg.window_ms: expected a number 150..250,
got 90`). Values that become node parameters are checked against the node's
EDS limits here, so provisioning never meets an SDO abort for a value the
file could have caught.
"""

from __future__ import annotations

import copy
import itertools
import math
import re
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from canopen.objectdictionary.datatypes import FLOAT_TYPES

from grasplink.core.frames import SYNC_TYPE_MAX
from grasplink.core.params import Params
from grasplink.decoding.registry import DEFAULT_DECODER, check_live_decoder
from grasplink.errors import ConfigError
from grasplink.gateway import description, roles
from grasplink.gateway.description import Identity, SdoWrite
from grasplink.gateway.feedback import FeedbackConfig, FeedbackMode
from grasplink.gateway.levels import (
    DEFAULT_FORCE_ENTRIES,
    DEFAULT_FORCE_HYSTERESIS_N,
    DEFAULT_SLIP_ENTRIES,
    DEFAULT_SLIP_HYSTERESIS_MM_S,
    force_table,
    slip_table,
)
from grasplink.gateway.master import CONSUMER_ALLOWANCE_MS
from grasplink.gateway.plausibility import PlausibilityConfig
from grasplink.gateway.reflex import HAND_MAX_GRIP_N, ReflexConfig
from grasplink.gateway.roles import Binding
from grasplink.profiles import (
    load_profile,
    object_key,
    object_limits,
    shipped_profile,
    variable_limits,
)
from grasplink.profiles import objects as obj
from grasplink.profiles.eds import DATA_TYPES
from grasplink.profiles.field import node_file
from grasplink.profiles.kinds import KINDS, node_kind, per_kind, unknown_kind
from grasplink.profiles.layouts import LAYOUTS_MM, parse_layout
from grasplink.profiles.pdo_codec import PdoCodec

if TYPE_CHECKING:
    import canopen

# The thesis's EMG control window is "rectified and integrated" over 150-250 ms (ch. 2.3).
EMG_WINDOW_MS = (150, 250)
FEEDBACK_MODES = tuple(m.value for m in FeedbackMode)
US_PER_MS = 1000
GRIP_MODES = ("levels", "proportional")
# Where telemetry keeps what must outlive a run (the Sparkplug bdSeq); `~` is expanded.
DEFAULT_STATE_DIR = "~/.local/state/grasplink"
# A Sparkplug host ID is one MQTT topic level (the rule of telemetry.url.check_id, kept here
# so reading a configuration does not import the MQTT stack).
_HOST_ID = re.compile(r"[A-Za-z0-9_.:-]{1,64}")


NODE_NAME = re.compile(r"[a-z][a-z0-9_]{0,31}")  # one topic level, one register-map label
DEVICE_ROLE = "device"  # mastered and published, not in the loop
ROLES = (*KINDS, DEVICE_ROLE)
US_PER_S = 1_000_000


@dataclass
class NodeConfig:
    """One node of the bus description (`[nodes.NAME]`): a loop node is one of our kinds,
    its table named after its role; any other is a `device` built from its EDS/DCF."""

    kind: str  # a node kind (kinds.py), or DEVICE_ROLE
    node_id: int
    heartbeat_ms: int = 100
    options: dict[str, Any] = field(default_factory=dict)
    name: str = ""  # the table's name; a loop node's is its kind
    eds: Path | None = None  # the file its dictionary comes from; None: the kind's own EDS
    identity: Identity | None = None  # what 1018h must read before it is configured
    mandatory: bool = False  # no node is started until every mandatory one is ready
    sdo: tuple[SdoWrite, ...] = ()  # written last before the start, in order
    binding: Binding | None = None  # a vendor's node in a loop role: its objects (roles.py)
    file_warnings: tuple[str, ...] = ()  # what the field loader repaired in its file
    # its dictionary, parsed once when the description is read and shared by every later
    # pass (bindings, codecs, provisioning): read-only
    od: canopen.ObjectDictionary | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self.name = self.name or self.kind

    def dictionary(self) -> canopen.ObjectDictionary:
        """The node's dictionary (read-only): the description's, else its kind's shipped
        profile, parsed once per process."""
        if self.od is None:
            if self.eds is not None:
                self.od = load_profile(self.eds, self.node_id)
            else:
                self.od = shipped_profile(self.kind, self.node_id)
        return self.od

    @property
    def role(self) -> str:
        return self.kind


@dataclass
class SkinConfig(NodeConfig):
    layout: str = "alpha0.1"
    layout_mm: tuple[float, ...] = ()
    sample_rate_hz: int = 400
    samples_per_pdo: int = 3
    decoder: str = "tracker"


@dataclass
class EmgConfig(NodeConfig):
    sample_rate_hz: int = 1500
    window_ms: int = 200
    envelope_period_ms: int = 10
    e_min_uv: float = 50.0
    e_max_uv: float = 500.0
    grip_mode: str = "levels"
    # Grip force [N] the wearer asks for at levels e0..e5 (e5 = crush: the hand's limit caps it).
    grip_levels_n: tuple[float, ...] = (0.0, 2.0, 4.0, 6.0, 8.0, 40.0)
    grip_max_n: float = 20.0  # proportional mode: grip at e_max


@dataclass
class HandConfig(NodeConfig):
    crush_limit_n: float = 40.0
    grip_rate_n_s: float = 50.0


#: Modbus register types a device object may be mapped to -> the CiA 301 data types each
#: carries exactly (float32: REAL64 rounded to the nearest float32, integers up to 24 bits)
MODBUS_TYPES: dict[str, frozenset[str]] = {
    "int16": frozenset({"BOOLEAN", "INTEGER8", "INTEGER16", "UNSIGNED8"}),
    "uint16": frozenset({"BOOLEAN", "UNSIGNED8", "UNSIGNED16"}),
    "int32": frozenset(
        {"BOOLEAN", "INTEGER8", "INTEGER16", "INTEGER24", "INTEGER32"}
        | {"UNSIGNED8", "UNSIGNED16", "UNSIGNED24"}
    ),
    "uint32": frozenset({"BOOLEAN", "UNSIGNED8", "UNSIGNED16", "UNSIGNED24", "UNSIGNED32"}),
    "float32": frozenset(
        {"REAL32", "REAL64", "INTEGER8", "INTEGER16", "INTEGER24"}
        | {"UNSIGNED8", "UNSIGNED16", "UNSIGNED24"}
    ),
}
MODBUS_WORDS = {"int16": 1, "uint16": 1, "int32": 2, "uint32": 2, "float32": 2}
#: Input registers below this are the fixed map's (it stays within one read of 125, and
#: grows only at its end): a configured register starts here or above.
MODBUS_DEVICE_BASE = 256


@dataclass(frozen=True)
class ModbusRegister:
    """One `[[modbus.registers]]` entry (a device object's value at input registers) or
    `[[modbus.holding]]` entry (a device's RPDO-mapped object, written at holding ones)."""

    node: str  # a device node's name
    key: str  # "6401sub1"
    index: int
    subindex: int
    address: int  # PDU address of its first register
    type: str  # a MODBUS_TYPES name
    name: str  # the object's ParameterName in the node's file
    data_type: str  # its CiA 301 data type
    unit: str  # its Unit ("" where the file gives none)
    where: str  # "gw.toml: modbus.registers[0]": what an error about it names
    holding: bool = False  # written by a client, sent in the node's RPDO
    limits: tuple[float, float] = (-math.inf, math.inf)  # what the object accepts (holding)

    @property
    def words(self) -> int:
        return MODBUS_WORDS[self.type]

    @property
    def end(self) -> int:
        """One past its last register."""
        return self.address + self.words


@dataclass
class FeedbackSettings:
    mode: FeedbackMode = FeedbackMode.FORCE_AND_SLIP
    controller: FeedbackConfig = field(default_factory=FeedbackConfig)


@dataclass
class TelemetrySettings:
    """What telemetry needs beyond the broker URL (docs/telemetry.md)."""

    sparkplug_host_id: str = ""  # the primary host application births wait for ("": none)
    state_dir: str = DEFAULT_STATE_DIR  # the Sparkplug bdSeq kept across restarts


@dataclass
class GatewayConfig:
    source: str = "<defaults>"
    node_id: int = obj.GATEWAY_NODE_ID
    heartbeat_ms: int = 100
    # The nodes' consumer time of the gateway's heartbeat (1016h): this many of its periods
    # plus `consumer_allowance_ms` for a host's scheduling (CiA 301 practice: comfortably
    # more than the producer time); 3 x 100 ms + 200 ms = 500 ms by default.
    consumer_factor: float = 3.0
    consumer_allowance_ms: int = CONSUMER_ALLOWANCE_MS
    sdo_timeout_ms: int = 500
    status_period_s: float = 5.0
    lss: bool = False  # assign node-IDs over LSS at start (the description's identities)
    sync_period_us: int = 0  # the SYNC producer's period (1006h), 0: no SYNC
    sync_counter_overflow: int = 0  # 1019h: 2-240, each SYNC carries a counter; 0: none
    nodes: dict[str, NodeConfig] = field(default_factory=dict)
    feedback: FeedbackSettings = field(default_factory=FeedbackSettings)
    reflex: ReflexConfig = field(default_factory=ReflexConfig)
    telemetry: TelemetrySettings = field(default_factory=TelemetrySettings)
    plausibility: PlausibilityConfig = field(default_factory=PlausibilityConfig)
    modbus_registers: tuple[ModbusRegister, ...] = ()  # `[[modbus.registers]]`, by address
    modbus_holding: tuple[ModbusRegister, ...] = ()  # `[[modbus.holding]]`, by address

    def node(self, kind: str) -> NodeConfig | None:
        return self.nodes.get(kind)

    @property
    def consumer_ms(self) -> int:
        """The consumer time the gateway provisions into every node's 1016h:01 for its own
        heartbeat: factor x period + allowance, and always more than one period."""
        return max(
            round(self.heartbeat_ms * self.consumer_factor) + self.consumer_allowance_ms,
            self.heartbeat_ms + 1,
        )


def load_config(path: str | Path | None) -> GatewayConfig:
    """The configuration in `path` over the defaults (defaults alone for None)."""
    if path is None:
        return parse_config({}, "<defaults>")
    source = str(path)
    try:
        with open(path, "rb") as handle:
            data = tomllib.load(handle)
    except FileNotFoundError:
        raise ConfigError(f"{source}: no such configuration file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{source}: not valid TOML: {exc}") from None
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read: {exc.strerror}") from None
    return parse_config(data, source)


def parse_config(data: dict[str, Any], source: str, prefix: str = "") -> GatewayConfig:
    """A configuration from TOML data; `prefix` names where the table sits (a scene's
    `controller`) so errors point at the right key."""
    top = Params(data, source, prefix)
    config = GatewayConfig(source=source)
    gw = top.table_of("gateway", {})
    config.node_id = gw.integer("node_id", obj.GATEWAY_NODE_ID, low=1, high=127)
    config.heartbeat_ms = gw.integer("heartbeat_ms", 100, low=10, high=10_000)
    config.consumer_factor = gw.number("consumer_factor", 3.0, low=1.5, high=20.0)
    config.consumer_allowance_ms = gw.integer(
        "consumer_allowance_ms", CONSUMER_ALLOWANCE_MS, low=0, high=10_000
    )
    config.sdo_timeout_ms = gw.integer("sdo_timeout_ms", 500, low=10, high=10_000)
    config.status_period_s = gw.number("status_period_s", 5.0, low=0.1, high=3600.0)
    config.lss = gw.boolean("lss", False)
    sync_ms = gw.number("sync_period_ms", 0.0, low=0.0, high=1000.0)
    if 0 < sync_ms < 1:
        raise gw.error("sync_period_ms", f"expected 0 (no SYNC) or 1..1000 ms, got {sync_ms:g}")
    config.sync_period_us = round(sync_ms * 1000)
    overflow = gw.integer("sync_counter_overflow", 0, low=0, high=240)
    if overflow == 1:
        raise gw.error("sync_counter_overflow", "expected 0 (no counter) or 2..240, got 1")
    config.sync_counter_overflow = overflow
    gw.finish()
    nodes = top.table_of("nodes", {})
    base = _base_folder(source)
    # Every kind is mastered unless its table says `enabled = false`; then the devices.
    used = {config.node_id: "gateway"}
    for name in (*KINDS, *sorted(set(nodes.table) - set(KINDS))):
        p = nodes.table_of(name, {})
        if not p.boolean("enabled", True):
            p.finish()
            continue
        if not NODE_NAME.fullmatch(name):
            raise nodes.error(name, "a node's name is a-z, 0-9 and _ (1-32, a letter first)")
        node = _PARSERS[name](p, name) if name in KINDS else _device(p, name, base)
        if name in KINDS:
            _describe_loop_node(p, node, base, config.sync_period_us)
        if node.node_id in used:
            raise p.error(
                "node_id", f"0x{node.node_id:02X} is already used by {used[node.node_id]}"
            )
        used[node.node_id] = name
        p.finish()
        config.nodes[name] = node
    if config.lss and not any(
        node.identity is not None and len(node.identity.expected) == len(description.IDENTITY_SUBS)
        for node in config.nodes.values()
    ):
        raise gw.error(
            "lss",
            "no node's identity names vendor_id, product_code, revision and serial: LSS "
            "addresses a node by all four",
        )
    _check_sync(top, config)
    config.feedback = _feedback(top.table_of("feedback", {}))
    hand = config.nodes.get("hand")
    crush_n = hand.crush_limit_n if isinstance(hand, HandConfig) else 40.0
    config.reflex = _reflex(top.table_of("reflex", {}), crush_n)
    config.telemetry = _telemetry(top.table_of("telemetry", {}))
    grip_rate_n_s = hand.grip_rate_n_s if isinstance(hand, HandConfig) else 50.0
    config.plausibility = _plausibility(top.table_of("plausibility", {}), grip_rate_n_s)
    config.modbus_registers, config.modbus_holding = _modbus_registers(
        top.table_of("modbus", {}), config
    )
    top.finish()
    return config


def synchronous_tpdos(node: NodeConfig) -> dict[int, int]:
    """The TPDOs (communication index -> transmission type 0..240) the node's `[sdo]` table
    makes SYNC-synchronous: the last write to each 18xxh:02 counts."""
    types = {
        w.index: int.from_bytes(w.data, "little")
        for w in node.sdo
        if obj.TPDO_COMM <= w.index < obj.TPDO_MAP and w.subindex == 2
    }
    return {index: kind for index, kind in types.items() if kind <= SYNC_TYPE_MAX}


def _check_sync(top: Params, config: GatewayConfig) -> None:
    """A skin or EMG whose samples wait for SYNC needs the gateway to produce it (without,
    its stream would never come); our skin's TPDO1 on SYNC needs 2122h = 1, or it would send
    one of its 133 packets a second per SYNC and drop the rest."""
    for role in ("skin", "emg"):
        node = config.nodes.get(role)
        if node is None:
            continue
        for index, kind in synchronous_tpdos(node).items():
            key = f"nodes.{role}.sdo.{index:04X}sub2"
            if not config.sync_period_us:
                raise top.error(
                    key,
                    f"transmission type {kind} sends the {role}'s TPDO on SYNC, but the "
                    "gateway produces none: set [gateway] sync_period_ms",
                )
            every_packet = {
                (w.index, w.subindex): int.from_bytes(w.data, "little") for w in node.sdo
            }.get((obj.SKIN_PACKETS_ON_SYNC, 0))
            if role == "skin" and node.eds is None and index == obj.TPDO_COMM and not every_packet:
                raise top.error(
                    key,
                    f"transmission type {kind} sends one sample packet per SYNC and drops "
                    'the others: add "2122sub0" = 1 (every packet on SYNC)',
                )


_Built = TypeVar("_Built")


def _checked(p: Params, name: str, build: Callable[[], _Built]) -> _Built:
    """Build a controller part; its own ConfigError is reported at the table's key."""
    try:
        return build()
    except ConfigError as exc:
        raise p.error(name, str(exc)) from None


def _feedback(p: Params) -> FeedbackSettings:
    mode = FeedbackMode(p.string("mode", FeedbackMode.FORCE_AND_SLIP.value, choices=FEEDBACK_MODES))
    defaults = FeedbackConfig()
    force = p.raw("force_table", [list(e) for e in DEFAULT_FORCE_ENTRIES])
    slip = p.raw("slip_table", [list(e) for e in DEFAULT_SLIP_ENTRIES])
    force_h = p.number("force_hysteresis_n", DEFAULT_FORCE_HYSTERESIS_N, low=0.0)
    slip_h = p.number("slip_hysteresis_mm_s", DEFAULT_SLIP_HYSTERESIS_MM_S, low=0.0)
    force_levels = _checked(p, "force_table", lambda: force_table(force, hysteresis_n=force_h))
    slip_levels = _checked(p, "slip_table", lambda: slip_table(slip, hysteresis_mm_s=slip_h))
    timing = {
        f"{name}_us": round(
            p.number(
                f"{name}_ms",
                getattr(defaults, f"{name}_us") / US_PER_MS,
                low=0.0,
                low_open=name in ("slip_off", "stale"),  # zero would drop every slip report
                high=60e3,
            )
            * US_PER_MS
        )
        for name in ("slip_on", "slip_off", "force_return", "level_dwell", "stale")
    }
    occurrence = p.integer(
        "occurrence_velocity_mrad_s",
        defaults.occurrence_velocity_mrad_s,
        low=obj.SLIP_BELT_MIN_MRAD_S,
        high=obj.SLIP_BELT_MAX_MRAD_S,
    )
    confidence = p.number("min_speed_confidence", defaults.min_speed_confidence, low=0, high=1)
    controller = _checked(
        p,
        "mode",
        lambda: FeedbackConfig(
            force_table=force_levels,
            slip_table=slip_levels,
            **timing,
            occurrence_velocity_mrad_s=occurrence,
            min_speed_confidence=confidence,
        ),
    )
    p.finish()
    return FeedbackSettings(mode, controller)


def _reflex(p: Params, crush_limit_n: float) -> ReflexConfig:
    d = ReflexConfig()
    threshold = p.number("threshold_mm_s", d.threshold_mm_s, low=1.0, high=1000.0)
    values: dict[str, Any] = {
        "enabled": p.boolean("enabled", d.enabled),
        "threshold_mm_s": threshold,
        "hysteresis_mm_s": p.number(
            "hysteresis_mm_s", min(d.hysteresis_mm_s, threshold / 2), low=0.0, high=threshold * 0.99
        ),
        "gain_n_per_mm_s": p.number("gain_n_per_mm_s", d.gain_n_per_mm_s, low=0.0, low_open=True),
        "hold_us": round(p.number("hold_ms", d.hold_us / US_PER_MS, low=0.0, high=60e3) * 1000),
        "release_rate_n_s": p.number("release_rate_n_s", d.release_rate_n_s, low=0, low_open=True),
        "min_confidence": p.number("min_confidence", d.min_confidence, low=0.0, high=1.0),
        "open_below_n": p.number("open_below_n", d.open_below_n, low=0.0, high=HAND_MAX_GRIP_N),
        "release_floor_share": p.number(
            "release_floor_share", d.release_floor_share, low=0.0, high=1.0
        ),
        "crush_limit_n": crush_limit_n,
    }
    reflex = _checked(p, "threshold_mm_s", lambda: ReflexConfig(**values))
    p.finish()
    return reflex


def _plausibility(p: Params, grip_rate_n_s: float) -> PlausibilityConfig:
    """Limits on what the loop follows; the grip slew defaults to the hand's own rate."""
    d = PlausibilityConfig()
    config = PlausibilityConfig(
        grip_slew_n_s=p.number("grip_slew_n_s", grip_rate_n_s, low=0.1, high=1000.0),
        belt_slew_mrad_s2=p.number("belt_slew_mrad_s2", d.belt_slew_mrad_s2, low=100.0, high=1e6),
        command_interval_ms=p.number("command_interval_ms", d.command_interval_ms, low=1, high=100),
        emg_max_amplitude_uv=p.number(
            "emg_max_amplitude_uv", d.emg_max_amplitude_uv, low=100.0, high=65535.0
        ),
        hand_grip_margin_n=p.number("hand_grip_margin_n", d.hand_grip_margin_n, low=0.0, high=10.0),
        hand_slew_factor=p.number("hand_slew_factor", d.hand_slew_factor, low=1.0, high=100.0),
    )
    p.finish()
    return config


def _telemetry(p: Params) -> TelemetrySettings:
    host_id = p.string("sparkplug_host_id", "")
    if host_id and not _HOST_ID.fullmatch(host_id):
        raise p.error(
            "sparkplug_host_id",
            f"expected 1..64 of A-Z a-z 0-9 _ . : - (one topic level), got {host_id!r}",
        )
    state_dir = p.string("state_dir", DEFAULT_STATE_DIR)
    if not state_dir.strip():
        raise p.error("state_dir", "expected a directory")
    p.finish()
    return TelemetrySettings(host_id, state_dir)


def _base_folder(source: str) -> Path:
    """Where the files a configuration names are looked up: beside it."""
    path = Path(source)
    return path.parent if path.is_file() else Path.cwd()


def _describe_loop_node(p: Params, node: NodeConfig, base: Path, sync_period_us: int) -> None:
    """The description keys of a loop node. Ours comes with its EDS; a vendor's names its
    file and binds the role to its objects (roles.py)."""
    role = p.string("role", node.kind, choices=ROLES)
    if role != node.kind:
        raise p.error("role", f"[nodes.{node.kind}] is the {node.kind} role's node, got {role!r}")
    path = node_file(p, base)
    if path is None:
        _description(p, node, node.dictionary)
        for table in BINDING_TABLES.values():
            if p.has(table):
                raise p.error(table, "binds a vendor's node: give its file (eds = or dcf =)")
        return
    node.eds = path
    node.od, node.file_warnings = description.dictionary(p, _file_key(path), path, node.node_id)
    codec = PdoCodec.from_od(node.od, node.node_id)
    try:
        if node.kind == "skin":
            node.binding = roles.skin(p, codec)
        elif node.kind == "emg":
            node.binding = roles.emg(p, codec)
        else:
            node.binding = roles.drive(p, codec, node.kind)
    except ConfigError as exc:
        if not p.has(BINDING_TABLES[node.kind]):
            table = BINDING_TABLES[node.kind]
            raise p.error(
                table, f"a vendor's node in the {node.kind} role binds it to its objects here"
            ) from None
        raise exc from None
    _description(p, node, node.dictionary)
    if isinstance(node.binding, roles.SkinBinding) and isinstance(node, SkinConfig):
        node.binding = _synchronous_samples(
            p, node, node.binding, node.dictionary(), sync_period_us
        )


def _synchronous_samples(
    p: Params, node: SkinConfig, binding: roles.SkinBinding, od: Any, sync_period_us: int
) -> roles.SkinBinding:
    """Samples without a packet number in a synchronous TPDO are numbered by the SYNC they
    answer (a transport's jitter and a late host then cannot move them in time): the
    gateway must produce SYNC, at the rate the samples are taken."""
    can_id = binding.tpdo_can_id
    if binding.objects.sequence is not None or can_id is None:
        return binding
    kind = description.tpdo_transmission_type(od, can_id, node.sdo)
    if kind is None or not 1 <= kind <= SYNC_TYPE_MAX:
        return binding
    if not sync_period_us:
        raise p.error(
            "samples",
            f"their TPDO (0x{can_id:03X}) goes on SYNC (type {kind}), and the gateway "
            "produces none: set [gateway] sync_period_ms",
        )
    rate_hz = US_PER_S / (sync_period_us * kind)
    if abs(node.sample_rate_hz - rate_hz) > 1e-9 * rate_hz:
        raise p.error(
            "sample_rate_hz",
            f"{node.sample_rate_hz} Hz, but a sample comes every {kind} SYNC(s) of "
            f"{sync_period_us / 1000:g} ms: {rate_hz:g} Hz",
        )
    return replace(binding, sync_every=kind)


# the table that binds a vendor's node to a loop role (roles.py)
BINDING_TABLES = {"skin": "samples", "emg": "envelope", "belt": "drive", "hand": "drive"}


def _file_key(path: Path) -> str:
    return "dcf" if path.suffix.lower() == ".dcf" else "eds"


def _description(p: Params, node: NodeConfig, od: Callable[[], Any]) -> None:
    node.identity = description.identity(p)
    node.mandatory = p.boolean("mandatory", False)
    node.sdo = description.sdo_writes(p, od) if p.has("sdo") else ()


def _device(p: Params, name: str, base: Path) -> NodeConfig:
    """A node the gateway masters and publishes but does not put in the loop."""
    role = p.string("role", DEVICE_ROLE, choices=ROLES)
    if role != DEVICE_ROLE:
        raise p.error("role", f"the {role} role's node is [nodes.{role}], not [nodes.{name}]")
    path = node_file(p, base)
    if path is None:
        raise p.error(
            "eds",
            f"{unknown_kind(name)}; any other node is a device and needs the EDS or DCF "
            "it is built from (eds = or dcf =)",
        )
    node = NodeConfig(
        kind=DEVICE_ROLE,
        node_id=p.integer("node_id", low=1, high=127),
        heartbeat_ms=p.integer("heartbeat_ms", 100, low=10, high=10_000),
        name=name,
        eds=path,
    )
    node.od, node.file_warnings = description.dictionary(p, _file_key(path), path, node.node_id)
    _description(p, node, node.dictionary)
    return node


def _common(p: Params, kind: str) -> dict[str, Any]:
    return {
        "kind": kind,
        "node_id": p.integer("node_id", node_kind(kind).node_id, low=1, high=127),
        "heartbeat_ms": p.integer("heartbeat_ms", 100, low=10, high=10_000),
    }


def _limits(p: Params, name: str, kind: str, index: int, sub: int = 0, **kw: Any) -> int:
    low, high = object_limits(kind, index, sub)
    return p.integer(name, low=low, high=high, **kw)


def _skin(p: Params, kind: str) -> SkinConfig:
    layout = p.string("layout", "alpha0.1")
    try:
        layout_mm = parse_layout(layout)
    except ConfigError as exc:
        raise p.error("layout", str(exc)) from None
    if layout not in LAYOUTS_MM and len(layout_mm) > 40:
        raise p.error("layout", f"{len(layout_mm)} spacings; the skin node holds at most 40")
    return SkinConfig(
        **_common(p, kind),
        layout=layout,
        layout_mm=tuple(layout_mm),
        sample_rate_hz=_limits(p, "sample_rate_hz", kind, obj.SKIN_SAMPLE_RATE_HZ, default=400),
        samples_per_pdo=_limits(p, "samples_per_pdo", kind, obj.SKIN_SAMPLES_PER_PDO, default=3),
        decoder=_decoder(p),
    )


def _decoder(p: Params) -> str:
    """The skin decoder's name, checked now: a typo must name the file and key, not fail
    at start-up with neither."""
    name = p.string("decoder", DEFAULT_DECODER)
    try:
        return check_live_decoder(name)
    except ConfigError as exc:
        raise p.error("decoder", str(exc)) from None


def _emg(p: Params, kind: str) -> EmgConfig:
    e_min = p.number("e_min_uv", 50.0, low=0.0, high=65535.0)
    e_max = p.number("e_max_uv", 500.0, low=0.0, high=65535.0)
    if not e_max > e_min:
        raise p.error("e_max_uv", f"must be above e_min_uv ({e_min:g} uV), got {e_max:g}")
    levels = p.numbers("grip_levels_n", [0.0, 2.0, 4.0, 6.0, 8.0, 40.0], low=0.0, high=100.0)
    if len(levels) != 6 or any(b < a for a, b in itertools.pairwise(levels)):
        raise p.error("grip_levels_n", "expected 6 non-decreasing forces, for levels e0..e5")
    low, high = EMG_WINDOW_MS
    return EmgConfig(
        **_common(p, kind),
        sample_rate_hz=_limits(p, "sample_rate_hz", kind, obj.EMG_SAMPLE_RATE_HZ, default=1500),
        window_ms=p.integer("window_ms", 200, low=low, high=high),
        envelope_period_ms=_limits(
            p, "envelope_period_ms", kind, obj.EMG_ENVELOPE_PERIOD_MS, default=10
        ),
        e_min_uv=e_min,
        e_max_uv=e_max,
        grip_mode=p.string("grip_mode", "levels", choices=GRIP_MODES),
        grip_levels_n=tuple(levels),
        grip_max_n=p.number("grip_max_n", 20.0, low=0.0, high=100.0),
    )


def _belt(p: Params, kind: str) -> NodeConfig:
    return NodeConfig(**_common(p, kind))


def _hand(p: Params, kind: str) -> HandConfig:
    low, high = object_limits(kind, obj.HAND_CRUSH_LIMIT_MN)
    rate_low, rate_high = object_limits(kind, obj.HAND_GRIP_RATE_MN_S)
    return HandConfig(
        **_common(p, kind),
        crush_limit_n=p.number("crush_limit_n", 40.0, low=low / 1000, high=high / 1000),
        grip_rate_n_s=p.number("grip_rate_n_s", 50.0, low=rate_low / 1000, high=rate_high / 1000),
    )


# kind -> its configuration class's parser; every kind is mastered unless disabled
_PARSERS: dict[str, Callable[[Params, str], NodeConfig]] = per_kind(
    "gateway/config.py _PARSERS", {"skin": _skin, "emg": _emg, "belt": _belt, "hand": _hand}
)


def _modbus_registers(
    p: Params, config: GatewayConfig
) -> tuple[tuple[ModbusRegister, ...], tuple[ModbusRegister, ...]]:
    """`[[modbus.registers]]` (device objects at input registers) and `[[modbus.holding]]`
    (device objects a client writes), each checked now: a device node, an object its TPDOs
    map (input) or its RPDOs map and it accepts writing (holding), a type that carries it,
    an address of its own above the fixed map."""
    tables = {}
    for key in ("registers", "holding"):
        entries = p.raw(key, [])
        if not isinstance(entries, list) or not all(isinstance(e, dict) for e in entries):
            raise p.error(key, f"expected an array of tables ([[modbus.{key}]])")
        tables[key] = entries
    p.finish()
    return (
        _modbus_entries(p, config, "registers", tables["registers"]),
        _modbus_entries(p, config, "holding", tables["holding"]),
    )


def _mapped(node: NodeConfig, holding: bool) -> dict[tuple[int, int], Any]:
    """A device's objects its TPDOs map (input registers) or its RPDOs map (holding)."""
    codec = PdoCodec.from_od(node.dictionary(), node.node_id)
    if not holding:
        return {(v.index, v.subindex): v for v in codec.tpdo_objects()}
    keys = [m.key for number in codec.rpdo_numbers() for m in codec.rpdo_objects(number)]
    return {key: codec.od_entry(*key) for key in keys}


def _accepted(var: Any) -> tuple[float, float]:
    """What an object accepts: its file's LowLimit/HighLimit, else its type's range (a
    REAL's: any finite number)."""
    if var.data_type in FLOAT_TYPES:
        low, high = var.min, var.max
        return (-math.inf if low is None else low, math.inf if high is None else high)
    return variable_limits(var)


def _modbus_entries(
    p: Params, config: GatewayConfig, table: str, entries: list[dict[str, Any]]
) -> tuple[ModbusRegister, ...]:
    holding = table == "holding"
    devices = sorted(n for n, c in config.nodes.items() if c.kind == DEVICE_ROLE)
    mapped: dict[str, dict[tuple[int, int], Any]] = {}
    out: list[ModbusRegister] = []
    for i, entry in enumerate(entries):
        t = Params(entry, p.source, p.key(f"{table}[{i}]"))
        name = t.string("node")
        node = config.nodes.get(name)
        if node is None or node.kind != DEVICE_ROLE:
            why = (
                "a loop node: its values are in the fixed map" if name in KINDS else "no such node"
            )
            raise t.error(
                "node", f"{name!r} is {why}; device nodes: {', '.join(devices) or 'none'}"
            )
        if name not in mapped:
            mapped[name] = _mapped(node, holding)
        text = t.string("object")
        try:
            index, subindex = object_key(text)
        except ConfigError as exc:
            raise t.error("object", str(exc)) from None
        var = mapped[name].get((index, subindex))
        if var is None:
            listed = ", ".join(f"{i:04X}sub{s:X}" for i, s in mapped[name]) or "none"
            pdo = "RPDO" if holding else "TPDO"
            raise t.error(
                "object", f"{text} is no {pdo}-mapped object of {node.eds} (mapped: {listed})"
            )
        if holding and var.access_type not in ("rw", "wo", "rww"):
            raise t.error(
                "object", f"{var.name} ({text}) is {var.access_type}: a client cannot write it"
            )
        kind = t.string("type", choices=tuple(MODBUS_TYPES))
        known = DATA_TYPES.get(var.data_type)
        data_type = known.name if known else f"0x{var.data_type or 0:04X}"
        if data_type not in MODBUS_TYPES[kind]:
            fits = " or ".join(k for k, carried in MODBUS_TYPES.items() if data_type in carried)
            hint = f"use {fits}" if fits else "no register type carries it"
            raise t.error(
                "type", f"{var.name} is {data_type}, which {kind} does not carry ({hint})"
            )
        words = MODBUS_WORDS[kind]
        address = t.integer("address", low=0, high=0xFFFF)
        if address < MODBUS_DEVICE_BASE:
            what = "holding" if holding else "input"
            raise t.error(
                "address",
                f"{address} is in the fixed map's range ({what} registers below "
                f"{MODBUS_DEVICE_BASE}): a device object starts at {MODBUS_DEVICE_BASE} or above",
            )
        if address + words > 0x10000:
            raise t.error("address", f"{kind} at {address} takes {words} registers, past 65535")
        t.finish()
        register = ModbusRegister(
            name,
            f"{index:04X}sub{subindex:X}",
            index,
            subindex,
            address,
            kind,
            var.name,
            data_type,
            var.unit or "",
            f"{p.source}: {t.prefix}",
            holding,
            _accepted(var) if holding else (-math.inf, math.inf),
        )
        clash = next(
            (r for r in out if r.address < register.end and register.address < r.end), None
        )
        if clash is not None:
            raise t.error(
                "address",
                f"{address}..{register.end - 1} overlaps {clash.where.split(': ')[-1]} "
                f"({clash.node} {clash.key} at {clash.address}..{clash.end - 1})",
            )
        out.append(register)
    return tuple(sorted(out, key=lambda r: r.address))


def scene_config(options: Params, nodes: Mapping[str, Mapping[str, Any]]) -> GatewayConfig:
    """A scene's `[controller] type = "gateway"`: the gateway configuration format
    (`[controller.feedback]`, `[controller.reflex]`, `[controller.nodes.emg]`, ...) with
    the scene's nodes, IDs and skin settings filled in (nodes not in the scene are off)."""
    data = copy.deepcopy(options.table)
    tables = data.setdefault("nodes", {})
    if not isinstance(tables, dict):
        raise options.error("nodes", "expected a table of node settings")
    for kind in KINDS:
        table = tables.setdefault(kind, {})
        if not isinstance(table, dict):
            raise options.error(f"nodes.{kind}", "expected a table")
        if kind not in nodes:
            table["enabled"] = False
            continue
        scene_settings = nodes[kind]
        for key in ("node_id", "sample_rate_hz", "samples_per_pdo", "layout"):
            if key in scene_settings:
                if key in table and table[key] != scene_settings[key]:
                    raise options.error(
                        f"nodes.{kind}.{key}", "is set by the scene's [nodes] table"
                    )
                table[key] = scene_settings[key]
    return parse_config(data, options.source, options.prefix)

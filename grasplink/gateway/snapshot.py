"""What the gateway knows, as the surfaces (telemetry, Modbus, status lines) see it.

`Gateway.snapshot()` returns a `Snapshot`: frozen dataclasses, one per section, with
enums for states and the unit in every field name. It is the one contract between
the runtime and its surfaces: the JSON tree's value and state fields, the Sparkplug
metrics and their types, and the Modbus register paths are all read from these
classes' fields (`section_fields`, `wire_kind`, `check_path`), never listed again.

`Snapshot.to_dict()` is the JSON-ready form every surface publishes: enums as the text
the wire carries (a StrEnum's value, an NMT state's name), the EMCY code as "0xXXXX",
a field marked `omit_if_none` left out while it has no value.

Field metadata says what the type alone does not:

- `integer`: how a count is carried where it is not a signed 32-bit number
  ("uint32", "uint64");
- `counter`: a count of events, reported with the counters (JSON health) rather than
  as the node's state; `fast`: it changes with nearly every frame (or every snapshot:
  an age), so it is reported once per period, not on change;
- `kinds`: the node kinds that have the field (the others leave it None);
- `hex_code`: an error code, carried as "0xXXXX" text;
- `node_values`: a section holding one node kind's decoded values;
- `json`: the function that makes the field's JSON-ready form (a device's values).

A `device` node (mastered, not in the loop: docs/gateway.md, bus description) has its
state in `nodes[NAME]` like any node, and its values in `devices[NAME]`: the objects its
TPDOs map, described once from its EDS/DCF (`DeviceObject`, shared by every snapshot),
and their latest values in that order.
"""

from __future__ import annotations

import dataclasses
import functools
import operator
import types
import typing
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from enum import Enum, StrEnum
from typing import Any

from grasplink.core.nmt import NmtState
from grasplink.gateway.feedback import FeedbackMode, Reason
from grasplink.gateway.levels import Belt
from grasplink.gateway.plausibility import REJECTION_KEYS
from grasplink.gateway.reflex import GripSource, ReflexState
from grasplink.profiles.eds import DATA_TYPES
from grasplink.profiles.pdo_codec import PdoCodec

__all__ = [
    "BeltSnapshot",
    "DeviceObject",
    "DeviceValues",
    "EmgSnapshot",
    "HandSnapshot",
    "HeartbeatStats",
    "LoopSnapshot",
    "NodePhase",
    "NodeSnapshot",
    "Rejected",
    "SkinSnapshot",
    "Snapshot",
    "check_path",
    "device_objects",
    "field_of",
    "node_sections",
    "section_fields",
    "wire_kind",
]


class NodePhase(StrEnum):
    """What the gateway is doing with a node (the order is the Modbus code order)."""

    ABSENT = "absent"  # not heard, or it left OPERATIONAL on its own
    PROVISIONING = "provisioning"  # SDO writes under way
    STARTING = "starting"  # provisioned, NMT start sent
    OPERATIONAL = "operational"  # live: its data is used, commands go to it
    FAILED = "failed"  # a provisioning write failed; retried
    LOST = "lost"  # its heartbeat stopped (one consumer time)
    READY = "ready"  # configured, held until every mandatory node is ready (CiA 302)


_UINT32 = {"integer": "uint32"}
_COUNTER = {"integer": "uint64", "counter": True}
_FAST_COUNTER = {**_COUNTER, "fast": True}


@dataclass(frozen=True, slots=True)
class NodeSnapshot:
    """One configured node: its state (on change), then its counters."""

    node_id: int = field(metadata=_UINT32)
    phase: NodePhase
    nmt_state: NmtState | None  # from its last heartbeat; None: not heard yet
    boots: int = field(metadata=_UINT32)
    last_emcy: int | None = field(metadata={"hex_code": True})  # error code; None: none yet
    failure: str | None  # why provisioning failed, while it does
    pdos_dropped: int = field(metadata=_COUNTER)  # TPDOs that did not fit the node's mapping
    # skin sample packets lost (sequence gaps)
    lost_packets: int | None = field(
        metadata={**_COUNTER, "kinds": ("skin",), "omit_if_none": True}
    )
    # how long the gateway waits for its heartbeat before the node is lost
    heartbeat_consumer_ms: int = field(metadata=_UINT32)
    pdos_rx: int = field(metadata=_FAST_COUNTER)  # TPDOs received and decoded
    # since its last heartbeat (a boot-up too) at the snapshot's time; None: not heard yet
    heartbeat_age_s: float | None = field(metadata={"fast": True})


@dataclass(frozen=True, slots=True)
class SkinSnapshot:
    """The skin decoder's latest estimate (all None before the first)."""

    grip_force_n: float | None
    slip: bool | None
    slip_speed_mm_s: float | None  # |speed|; its range and direction follow
    position_mm: float | None
    confidence: float | None
    slip_speed_low_mm_s: float | None
    slip_speed_high_mm_s: float | None
    slip_direction: int | None  # +1 towards the last ridge, -1 back; None: not told
    slip_direction_confidence: float | None


@dataclass(frozen=True, slots=True)
class EmgSnapshot:
    """The wearer's latest EMG intent (all None before the first)."""

    envelope_uv: float | None
    level: int | None
    grip_intent_n: float | None
    saturated: bool | None


@dataclass(frozen=True, slots=True)
class BeltSnapshot:
    """The feedback mode and the belt's latest command."""

    mode: FeedbackMode
    belt: Belt
    level: int | None
    velocity_mrad_s: int
    reason: Reason | None


@dataclass(frozen=True, slots=True)
class HandSnapshot:
    """The hand's actual grip and the grip commanded."""

    grip_n: float | None
    setpoint_n: float | None
    reflex: ReflexState
    source: GripSource | None


@dataclass(frozen=True, slots=True)
class LoopSnapshot:
    """The closed loop: the gateway's own processing time and the percepts it acted on."""

    latency_p50_us: float | None
    latency_p99_us: float | None
    percepts: int = field(metadata=_COUNTER)


@dataclass(frozen=True, slots=True)
class HeartbeatStats:
    """The gateway's own heartbeat: how late it went out (`master.HeartbeatProducer`)."""

    period_ms: float
    consumer_ms: float
    beats: int
    late: int
    late_max_ms: float
    over_consumer: int
    interval_p50_ms: float | None
    interval_p99_ms: float | None
    interval_max_ms: float


@dataclass(frozen=True, slots=True)
class Rejected:
    """What the loop refused to follow, by `plausibility.REJECTION_KEYS` (same order)."""

    tpdo_out_of_range: int = field(metadata=_COUNTER)
    skin_sample_out_of_range: int = field(metadata=_COUNTER)
    emg_envelope_out_of_range: int = field(metadata=_COUNTER)
    emg_envelope_jump: int = field(metadata=_COUNTER)
    hand_grip_out_of_range: int = field(metadata=_COUNTER)
    hand_grip_jump: int = field(metadata=_COUNTER)
    emcy_unknown_code: int = field(metadata=_COUNTER)
    emcy_invalid: int = field(metadata=_COUNTER)
    hand_command_slew_limited: int = field(metadata=_COUNTER)
    belt_command_slew_limited: int = field(metadata=_COUNTER)
    foreign_nmt: int = field(metadata=_COUNTER)
    second_master_heartbeat: int = field(metadata=_COUNTER)


@dataclass(frozen=True, slots=True)
class DeviceObject:
    """One object a device node's TPDOs map, as its EDS/DCF describes it."""

    key: str  # "6401sub1": how the configuration names it (index, sub-index in hex)
    index: int
    subindex: int
    name: str  # the file's ParameterName
    data_type: str  # its CiA 301 data type: "INTEGER16", "REAL32", "VISIBLE_STRING", ...
    unit: str  # the file's Unit; "" where it gives none


DeviceValue = int | float | bool | str | None  # None: not received yet


@dataclass(frozen=True, slots=True)
class DeviceValues:
    """A device node's TPDO-mapped objects and their latest values, in the same order."""

    objects: tuple[DeviceObject, ...]  # made once per node (`device_objects`), shared
    values: tuple[DeviceValue, ...]

    def as_dict(self) -> dict[str, DeviceValue]:
        """Values by object key: the JSON-ready form."""
        return {obj.key: value for obj, value in zip(self.objects, self.values, strict=True)}


def device_objects(codec: PdoCodec) -> tuple[DeviceObject, ...]:
    """The objects a node's TPDOs map (TPDO by TPDO, in map order), described from its file."""
    out = []
    for var in codec.tpdo_objects():
        known = DATA_TYPES.get(var.data_type) if var.data_type is not None else None
        out.append(
            DeviceObject(
                key=f"{var.index:04X}sub{var.subindex:X}",
                index=var.index,
                subindex=var.subindex,
                name=var.name,
                data_type=known.name if known else f"0x{var.data_type or 0:04X}",
                unit=var.unit or "",
            )
        )
    return tuple(out)


def device_value(value: Any) -> DeviceValue:
    """A decoded TPDO value as a snapshot carries it (an octet string or domain as hex)."""
    if isinstance(value, bytes | bytearray):
        return bytes(value).hex()
    return value  # type: ignore[no-any-return]


def _devices_json(devices: Mapping[str, DeviceValues]) -> dict[str, dict[str, DeviceValue]]:
    return {name: device.as_dict() for name, device in devices.items()}


_NODE_VALUES = {"node_values": True}


@dataclass(frozen=True)
class Snapshot:
    """Everything the gateway knows at one instant; replaced whole, never changed."""

    uptime_s: float
    nodes: Mapping[str, NodeSnapshot]  # by node name (a loop node's is its kind), configured only
    skin: SkinSnapshot = field(metadata=_NODE_VALUES)
    emg: EmgSnapshot = field(metadata=_NODE_VALUES)
    belt: BeltSnapshot = field(metadata=_NODE_VALUES)
    hand: HandSnapshot = field(metadata=_NODE_VALUES)
    loop: LoopSnapshot
    heartbeat: HeartbeatStats
    rejected: Rejected
    alarms: Mapping[str, str]  # key "KIND.CATEGORY" (or "gateway.…") -> text
    # device nodes' TPDO-mapped objects, by node name (JSON: name -> {object key: value})
    devices: Mapping[str, DeviceValues] = field(
        default_factory=dict, metadata={"json": _devices_json}
    )

    def to_dict(self) -> dict[str, Any]:
        """The JSON-ready form (made once per snapshot and shared: do not change it)."""
        made: dict[str, Any] | None = self.__dict__.get("_json")
        if made is None:
            made = _to_json(self)
            object.__setattr__(self, "_json", made)
        return made


if tuple(f.name for f in dataclasses.fields(Rejected)) != REJECTION_KEYS:
    raise ImportError("snapshot.Rejected must have plausibility.REJECTION_KEYS as its fields")


# -- reading the classes -------------------------------------------------------------------
@functools.cache
def _hints(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _bare(hint: Any) -> Any:
    """`X | None` -> X."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        rest = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(rest) == 1:
            return rest[0]
    return hint


def section_fields(cls: type) -> tuple[str, ...]:
    """A section's field names, in order (a node's state, a kind's values, …)."""
    return tuple(f.name for f in dataclasses.fields(cls))


def field_of(cls: type, name: str) -> dataclasses.Field[Any]:
    return next(f for f in dataclasses.fields(cls) if f.name == name)


def node_sections() -> dict[str, type]:
    """Node kind -> the `Snapshot` section holding its decoded values."""
    hints = _hints(Snapshot)
    return {
        f.name: hints[f.name] for f in dataclasses.fields(Snapshot) if f.metadata.get("node_values")
    }


def wire_kind(cls: type, name: str) -> str:
    """How a field is carried: "float", "bool", "int" (signed 32 bits), "uint32",
    "uint64" or "str" (text, enums, error codes): from its type, or its metadata."""
    meta = field_of(cls, name).metadata
    if meta.get("hex_code"):
        return "str"
    if "integer" in meta:
        return str(meta["integer"])
    hint = _bare(_hints(cls)[name])
    if hint is bool:
        return "bool"
    if hint is int:
        return "int"
    if hint is float:
        return "float"
    if hint is str or (isinstance(hint, type) and issubclass(hint, Enum)):
        return "str"
    raise TypeError(f"{cls.__name__}.{name}: no wire kind for {hint!r}")


def check_path(path: tuple[str, ...], root: type = Snapshot) -> None:
    """ValueError unless `path` names a field of the snapshot (a mapping level, such as
    `nodes`, takes any key): ("nodes", "skin", "phase"), ("loop", "percepts")."""
    hint: Any = root
    for depth, key in enumerate(path):
        hint = _bare(hint)
        if typing.get_origin(hint) in (Mapping, dict):
            hint = typing.get_args(hint)[1]
            continue
        if not dataclasses.is_dataclass(hint):
            raise ValueError(f"{'.'.join(path)}: {'.'.join(path[:depth])} has no fields")
        hints = _hints(hint)  # type: ignore[arg-type]
        if key not in hints:
            raise ValueError(
                f"{'.'.join(path)}: {hint.__name__} has no field {key!r} "  # type: ignore[union-attr]
                f"(it has {', '.join(hints)})"
            )
        hint = hints[key]
    if dataclasses.is_dataclass(_bare(hint)):
        raise ValueError(f"{'.'.join(path)} is a section, not a value")


# -- the JSON-ready form -------------------------------------------------------------------
# One function per class, built once from its fields: every field read in one call, then
# only the few that need converting. A snapshot is converted 20 times a second on each
# surface's thread, so this stays a few C calls per section.
Convert = Callable[[Any], Any]


def _enum_value(value: Any) -> Any:
    """A StrEnum member as its plain-str value (anything else as it is)."""
    return str(value) if isinstance(value, str) else value


def _enum_name(value: Any) -> Any:
    """Another enum's member by name (an NMT state: its value is the heartbeat byte)."""
    return value.name if isinstance(value, Enum) else value


def _hex_code(value: int) -> str:
    return f"0x{value:04X}"


def _converter(cls: type, item: dataclasses.Field[Any]) -> Convert | None:
    if "json" in item.metadata:
        return item.metadata["json"]  # type: ignore[no-any-return]
    if item.metadata.get("hex_code"):
        return _hex_code
    hint = _bare(_hints(cls)[item.name])
    if isinstance(hint, type) and issubclass(hint, Enum):
        return _enum_value if issubclass(hint, StrEnum) else _enum_name
    if dataclasses.is_dataclass(hint):
        return _json_maker(hint)  # type: ignore[arg-type]
    if typing.get_origin(hint) in (Mapping, dict):
        inner = typing.get_args(hint)[1]
        if dataclasses.is_dataclass(inner):
            make = _json_maker(inner)  # type: ignore[arg-type]
            return lambda mapping: {key: make(value) for key, value in mapping.items()}
        return dict
    return None


@functools.cache
def _json_maker(cls: type) -> Callable[[Any], dict[str, Any]]:
    items = dataclasses.fields(cls)
    names = tuple(f.name for f in items)
    getter = operator.attrgetter(*names)
    read: Callable[[Any], Any] = getter if len(names) > 1 else lambda obj: (getter(obj),)
    convert = tuple((f.name, c) for f in items if (c := _converter(cls, f)) is not None)
    omit = tuple(f.name for f in items if f.metadata.get("omit_if_none"))

    def make(section: Any) -> dict[str, Any]:
        out = dict(zip(names, read(section), strict=True))
        for name, change in convert:
            value = out[name]
            if value is not None:
                out[name] = change(value)
        for name in omit:
            if out[name] is None:
                del out[name]
        return out

    return make


def _to_json(snapshot: Snapshot) -> dict[str, Any]:
    return _json_maker(Snapshot)(snapshot)

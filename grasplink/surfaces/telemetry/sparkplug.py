"""Sparkplug B 3.0 edge node session (sans-IO): the gateway is the edge node, each CANopen
node a device. Snapshots in, `(topic, payload, qos, retain)` out; see docs/telemetry.md.

- `will()` before every CONNECT: bdSeq advances (0..255) and the NDEATH carrying it
  is the MQTT Will (QoS 1, not retained). A bdSeq kept across restarts of the
  gateway (`last_bdseq`, see `state.BdSeqFile`) goes on from where it was.
- `on_connect()`: NBIRTH (bdSeq, `Node Control/Rebirth`, every node metric) and a
  DBIRTH for every device whose node is operational. With a primary host
  application configured, the births wait until its `spBv1.0/STATE/<host id>`
  says online (`holding` meanwhile: data waits in the store-and-forward buffer);
  the host going offline asks for a new MQTT session (`Incoming.reconnect`), so
  the births that follow its return carry a new bdSeq.
- Metric aliases: every metric has an alias, unique across the edge node and its
  devices (`ALIASES`). Births carry name, alias and datatype; NDATA/DDATA carry
  the alias only (no name, no datatype); NCMD/DCMD are read by alias or by name.
- `update()`: report by exception: NDATA/DDATA carry the metrics that changed, each
  with the timestamp of the snapshot it changed in (fast counters at most once a
  second); DDEATH when a node is lost or leaves OPERATIONAL, DBIRTH when it is back.
- A `device` node (mastered, not in the loop) is a device too, named as the
  configuration names it: a metric per object its TPDOs map, named by the object's
  key ("6401sub1"), typed from its EDS data type (`EDS_TYPES`), its birth carrying the
  file's name, data type and unit as properties (`Documentation`, `edsDataType`,
  `engUnit`), then `State/…` like any node. Its aliases are given when the session
  first sees it, after every fixed one, and kept for the session's life.
  Metrics are grouped by what they are read from (`MetricGroup`), so an unchanged
  group costs one comparison, not one per metric.
- `finalize()` runs as a message is actually sent: it stamps `seq` (NBIRTH 0, then
  +1 mod 256 on every message of the edge node, NDEATH none), so a message that
  waited in the store-and-forward buffer is sequenced in the session that sends
  it; data made before this session's births is marked `is_historical`, births and
  deaths of an earlier session are dropped (the new session's births replace
  them), and data of a device not born in this session is dropped and counted.
- `receive()`: NCMD `Node Control/Rebirth` (births again, same bdSeq) and
  `Control/<command>`, DCMD `Node Control/Restart`, the primary host's STATE;
  `reply()` answers in NDATA (`Command Reply/command`, `…/accepted`, `…/detail`).

Payloads are built and read with the protobuf runtime (`sparkplug_b_pb2`, generated
from `sparkplug_b.proto`), never by hand. `seq` is appended as the runtime's own
encoding of `Payload(seq=n)`: concatenated protobuf messages merge, and seq (field 3)
follows timestamp and metrics (1, 2) in the runtime's field order, so the bytes are
those of the payload serialised with its seq, without parsing it again per message.
"""

from __future__ import annotations

import dataclasses
import json
import operator
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from google.protobuf.message import DecodeError

from grasplink.gateway.commands import Command, CommandResult, shown
from grasplink.gateway.snapshot import (
    DeviceObject,
    LoopSnapshot,
    NodeSnapshot,
    Rejected,
    Snapshot,
    field_of,
    node_sections,
    section_fields,
    wire_kind,
)
from grasplink.surfaces.telemetry import sparkplug_b_pb2 as pb
from grasplink.surfaces.telemetry.buffer import Message, Sample
from grasplink.surfaces.telemetry.protocol import (
    LIVE_PHASE,
    MAX_COMMAND_METRICS,
    CommandRequest,
    Incoming,
    controls_view,
    live_nodes,
    size_error,
)

NAMESPACE = "spBv1.0"
# Sparkplug data types (Metric.datatype)
INT8, INT16, INT32, INT64 = 1, 2, 3, 4
UINT8, UINT16, UINT32, UINT64 = 5, 6, 7, 8
FLOAT, DOUBLE, BOOLEAN, STRING = 9, 10, 11, 12
#: a device object's CiA 301 data type (`snapshot.DeviceObject.data_type`) -> its Sparkplug
#: data type; the integers of odd sizes in the next wider one, any other type as text
#: (octet strings and domains as hex, as the snapshot carries them)
EDS_TYPES = {
    "BOOLEAN": BOOLEAN,
    "INTEGER8": INT8,
    "INTEGER16": INT16,
    "INTEGER24": INT32,
    "INTEGER32": INT32,
    "INTEGER40": INT64,
    "INTEGER48": INT64,
    "INTEGER56": INT64,
    "INTEGER64": INT64,
    "UNSIGNED8": UINT8,
    "UNSIGNED16": UINT16,
    "UNSIGNED24": UINT32,
    "UNSIGNED32": UINT32,
    "UNSIGNED40": UINT64,
    "UNSIGNED48": UINT64,
    "UNSIGNED56": UINT64,
    "UNSIGNED64": UINT64,
    "REAL32": FLOAT,
    "REAL64": DOUBLE,
}
#: how a snapshot field is carried (`snapshot.wire_kind`) -> its Sparkplug data type
WIRE_TYPES = {
    "float": DOUBLE,
    "bool": BOOLEAN,
    "int": INT32,
    "uint32": UINT32,
    "uint64": UINT64,
    "str": STRING,
}
COUNTER_PERIOD_MS = 1000  # counters and latencies that change with every snapshot
BDSEQ = "bdSeq"
REBIRTH = "Node Control/Rebirth"
RESTART = "Node Control/Restart"
REPLY_METRICS = ("Command Reply/command", "Command Reply/accepted", "Command Reply/detail")
CALIBRATION = "Control/emg_calibration/"
BIRTHS_AND_DEATHS = ("NBIRTH", "DBIRTH", "DDEATH", "NDEATH")
# `Payload(seq=n)` as the runtime encodes it: appended to a payload made without seq.
SEQ_BYTES = tuple(pb.Payload(seq=n).SerializeToString() for n in range(256))
_NEVER = -(1 << 62)
_UNSEEN = object()

Getter = Callable[[dict[str, Any] | None, dict[str, Any]], Any]


@dataclass(frozen=True)
class MetricSpec:
    name: str
    datatype: int
    get: Getter
    properties: tuple[tuple[str, str], ...] = ()  # carried by births (a device object's)


@dataclass(frozen=True)
class MetricGroup:
    """Metrics read from the same part of a snapshot. `fingerprint` returns that part (a
    snapshot is replaced whole, never changed in place): equal to the last one, none of
    the group's metrics can have changed. `period_ms`: reported once per period of the
    clock (in the first snapshot of the period that changes them), so every periodic
    report of both protocols falls in the same snapshot: one publication, not several."""

    specs: tuple[MetricSpec, ...]
    fingerprint: Getter
    period_ms: int = 0
    # the metrics' values, in `specs` order, read from the fingerprint (None: by getter)
    values: Callable[[Any], Sequence[Any] | None] | None = None


@dataclass(frozen=True)
class SpMeta:
    """Which session made a message, what it is, for which device."""

    epoch: int
    kind: str
    device: str | None = None


def datatype_of_eds(data_type: str) -> int:
    """The Sparkplug data type of a device object's CiA 301 data type (`EDS_TYPES`)."""
    return EDS_TYPES.get(data_type, STRING)


def datatype(section: type, name: str) -> int:
    """The Sparkplug data type of a snapshot field, from its type (`snapshot.wire_kind`)."""
    return WIRE_TYPES[wire_kind(section, name)]


def _snap(path: tuple[str, ...], default: Any = None) -> Getter:
    """A snapshot field by its path (None when the snapshot or a level is missing)."""
    if len(path) == 2:  # the common case: keep it direct
        section, key = path

        def get2(snap: dict[str, Any] | None, extra: dict[str, Any]) -> Any:
            try:
                return snap[section].get(key, default)  # type: ignore[index]
            except (TypeError, KeyError, AttributeError):
                return default

        return get2

    def get(snap: dict[str, Any] | None, extra: dict[str, Any]) -> Any:
        value: Any = snap
        for key in path:
            if not isinstance(value, dict) or key not in value:
                return default
            value = value[key]
        return value

    return get


def _control(key: str) -> Getter:
    return lambda snap, extra: controls_view(snap, extra).get(key)


def _telemetry(key: str) -> Getter:
    return lambda snap, extra: extra.get("telemetry", {}).get(key, 0)


def _alarms(snap: dict[str, Any] | None, extra: dict[str, Any]) -> str | None:
    if snap is None:
        return None
    return "; ".join(f"{k}: {v}" for k, v in sorted(snap["alarms"].items()))


def _phases_and_alarms(snap: dict[str, Any] | None, extra: dict[str, Any]) -> Any:
    return tuple(node["phase"] for node in snap["nodes"].values()), snap["alarms"]  # type: ignore[index]


def _controls(snap: dict[str, Any] | None, extra: dict[str, Any]) -> Any:
    # `extra["controls"]` is changed in place when a command is accepted: fingerprint a copy
    return tuple(extra.get("controls", {}).items()), snap["belt"].get("mode")  # type: ignore[index]


NODE_GROUPS: tuple[MetricGroup, ...] = (
    MetricGroup(
        (
            MetricSpec(
                "Gateway/nodes_live", STRING, lambda s, e: ",".join(live_nodes(s)) if s else None
            ),
            MetricSpec("Gateway/alarm_count", UINT32, lambda s, e: len(s["alarms"]) if s else None),
            MetricSpec("Gateway/alarms", STRING, _alarms),
        ),
        _phases_and_alarms,
    ),
    MetricGroup(
        (
            MetricSpec("Gateway/uptime_s", datatype(Snapshot, "uptime_s"), _snap(("uptime_s",))),
            *(
                MetricSpec(f"Loop/{name}", datatype(LoopSnapshot, name), _snap(("loop", name)))
                for name in section_fields(LoopSnapshot)
            ),
        ),
        lambda s, e: (s["uptime_s"], s["loop"]),  # type: ignore[index]
        COUNTER_PERIOD_MS,
    ),
    MetricGroup(
        (
            MetricSpec("Control/feedback_mode", STRING, _control("feedback_mode")),
            MetricSpec("Control/reflex_enabled", BOOLEAN, _control("reflex_enabled")),
            MetricSpec("Control/reflex_threshold_mm_s", DOUBLE, _control("reflex_threshold_mm_s")),
            MetricSpec(CALIBRATION + "e_min_uv", DOUBLE, _control("emg_e_min_uv")),
            MetricSpec(CALIBRATION + "e_max_uv", DOUBLE, _control("emg_e_max_uv")),
        ),
        _controls,
    ),
    MetricGroup(
        (
            MetricSpec("Control/emg_calibrate", STRING, lambda s, e: ""),  # write-only: a phase
            MetricSpec("Control/restart_node", STRING, lambda s, e: ""),  # write-only: a kind
        ),
        lambda s, e: None,  # never changes: births only
    ),
    MetricGroup(
        (
            MetricSpec("Telemetry/snapshots_dropped", UINT64, _telemetry("snapshots_dropped")),
            MetricSpec(
                "Telemetry/buffer_dropped_messages", UINT64, _telemetry("buffer_dropped_messages")
            ),
            MetricSpec(
                "Telemetry/buffer_dropped_bytes", UINT64, _telemetry("buffer_dropped_bytes")
            ),
            MetricSpec("Telemetry/historical_dropped", UINT64, _telemetry("historical_dropped")),
        ),
        lambda s, e: e.get("telemetry"),
    ),
    MetricGroup(  # what the loop refused to follow (docs/gateway.md, Plausibility)
        tuple(
            MetricSpec(f"Rejected/{key}", datatype(Rejected, key), _snap(("rejected", key), 0))
            for key in section_fields(Rejected)
        ),
        lambda s, e: s.get("rejected") if s else None,  # on change: rare but news
    ),
)
NODE_METRICS: tuple[MetricSpec, ...] = tuple(spec for group in NODE_GROUPS for spec in group.specs)

# A device's `State/…` metrics: its node's fields, on change; the fast counters once a period.
STATE_METRICS: tuple[tuple[str, int], ...] = tuple(
    (f.name, datatype(NodeSnapshot, f.name))
    for f in dataclasses.fields(NodeSnapshot)
    if not f.metadata.get("fast")
)
COUNTER_STATE_METRICS: tuple[tuple[str, int], ...] = tuple(
    (f.name, datatype(NodeSnapshot, f.name))
    for f in dataclasses.fields(NodeSnapshot)
    if f.metadata.get("fast")
)


def _node_has(kind: str, name: str) -> bool:
    """Whether nodes of `kind` have the state field (`kinds` metadata: only those kinds)."""
    kinds = field_of(NodeSnapshot, name).metadata.get("kinds")
    return kinds is None or kind in kinds


def _node_state(kind: str, name: str) -> Getter:
    def get(snap: dict[str, Any] | None, extra: dict[str, Any]) -> Any:
        try:
            return snap["nodes"][kind].get(name)  # type: ignore[index]
        except (TypeError, KeyError):
            return None

    return get


def _node_fields(kind: str, names: tuple[str, ...]) -> Getter:
    """The node's status fields as one tuple (one C call while every field is there)."""
    pick = operator.itemgetter(*names)

    def fingerprint(snap: dict[str, Any] | None, extra: dict[str, Any]) -> Any:
        status = snap["nodes"].get(kind)  # type: ignore[index]
        if status is None:
            return None
        try:
            return pick(status)
        except KeyError:
            return tuple(status.get(name) for name in names)

    return fingerprint


def _section_values(names: tuple[str, ...]) -> Callable[[Any], Sequence[Any] | None]:
    """A snapshot section's fields as a tuple (None when the section is not all there)."""
    pick = operator.itemgetter(*names)

    def values(section: Any) -> Sequence[Any] | None:
        try:
            return pick(section)  # type: ignore[no-any-return]
        except (KeyError, TypeError):
            return None

    return values


def device_groups(kind: str) -> tuple[MetricGroup, ...]:
    """A device's metrics: its decoded values, then `State/…` from the node's status."""
    section = node_sections()[kind]
    fields = section_fields(section)
    values = tuple(MetricSpec(n, datatype(section, n), _snap((kind, n))) for n in fields)
    groups = [
        MetricGroup(values, lambda s, e: s.get(kind), values=_section_values(fields))  # type: ignore[union-attr]
    ]
    return (*groups, *_state_groups(kind))


def device_node_groups(name: str, objects: tuple[DeviceObject, ...]) -> tuple[MetricGroup, ...]:
    """A `device` node's metrics: its TPDO-mapped objects by key, then `State/…`."""
    values = tuple(
        MetricSpec(
            o.key,
            datatype_of_eds(o.data_type),
            _snap(("devices", name, o.key)),
            (
                ("Documentation", o.name),
                ("edsDataType", o.data_type),
                *((("engUnit", o.unit),) if o.unit else ()),
            ),
        )
        for o in objects
    )

    def fingerprint(snap: dict[str, Any] | None, extra: dict[str, Any]) -> Any:
        return snap["devices"].get(name)  # type: ignore[index]

    def in_order(found: Any) -> Sequence[Any] | None:
        return None if found is None else tuple(found.values())

    return (MetricGroup(values, fingerprint, values=in_order), *_state_groups(name))


def _state_groups(kind: str) -> list[MetricGroup]:
    """A node's `State/…` metrics: on change, and its fast counters once a period."""
    groups = []
    for state, period in ((STATE_METRICS, 0), (COUNTER_STATE_METRICS, COUNTER_PERIOD_MS)):
        names = tuple(n for n, _ in state if _node_has(kind, n))
        specs = tuple(
            MetricSpec(f"State/{n}", t, _node_state(kind, n)) for n, t in state if n in names
        )
        if len(names) > 1:
            group = MetricGroup(specs, _node_fields(kind, names), period, values=lambda fp: fp)
        else:
            group = MetricGroup(specs, _node_state(kind, names[0]), period, values=lambda fp: (fp,))
        groups.append(group)
    return groups


DEVICE_GROUPS = {kind: device_groups(kind) for kind in node_sections()}
DEVICE_METRICS = {
    kind: tuple(spec for group in groups for spec in group.specs)
    for kind, groups in DEVICE_GROUPS.items()
}


def _metric_table() -> tuple[dict[str | None, dict[str, int]], dict[str | None, dict[str, int]]]:
    """Aliases (1, 2, …: unique across the edge node and all its devices, as Sparkplug
    requires) and datatypes of every metric, per device (None: the edge node)."""
    types: dict[str | None, dict[str, int]] = {
        None: {
            BDSEQ: INT64,
            REBIRTH: BOOLEAN,
            **{spec.name: spec.datatype for spec in NODE_METRICS},
            **{name: BOOLEAN if name.endswith("accepted") else STRING for name in REPLY_METRICS},
        }
    }
    for kind, specs in DEVICE_METRICS.items():
        types[kind] = {**{spec.name: spec.datatype for spec in specs}, RESTART: BOOLEAN}
    aliases: dict[str | None, dict[str, int]] = {}
    alias = 0
    for device, names in types.items():
        aliases[device] = {}
        for name in names:
            alias += 1
            aliases[device][name] = alias
    return aliases, types


ALIASES, DATATYPES = _metric_table()
# (device, group index, period) of the groups reported at most once a period
_PERIODIC: dict[str | None, list[tuple[str | None, int, int]]] = {
    device: [(device, i, g.period_ms) for i, g in enumerate(groups) if g.period_ms]
    for device, groups in ((None, NODE_GROUPS), *DEVICE_GROUPS.items())
}
NAMES_BY_ALIAS = {device: {a: n for n, a in table.items()} for device, table in ALIASES.items()}

_VALUE_FIELD = {
    **dict.fromkeys((INT8, INT16, INT32, UINT8, UINT16, UINT32), "int_value"),
    **dict.fromkeys((INT64, UINT64), "long_value"),
    FLOAT: "float_value",
    DOUBLE: "double_value",
    BOOLEAN: "boolean_value",
    STRING: "string_value",
}
_CONVERT: dict[int, Callable[[Any], Any]] = {
    **dict.fromkeys((INT8, INT16, INT32), lambda v: int(v) & 0xFFFFFFFF),
    **dict.fromkeys((UINT8, UINT16, UINT32, UINT64), int),
    INT64: lambda v: int(v) & 0xFFFFFFFFFFFFFFFF,
    FLOAT: float,
    DOUBLE: float,
    BOOLEAN: bool,
    STRING: str,
}


def set_value(
    metric: pb.Payload.Metric, datatype: int, value: Any, *, with_datatype: bool = True
) -> None:
    """Fill a metric's value (None: is_null) and, unless told not to (DATA messages carry
    none), its datatype; signed ints as two's complement."""
    field = _VALUE_FIELD.get(datatype)
    if field is None:
        raise ValueError(f"unsupported Sparkplug datatype {datatype}")
    if with_datatype:
        metric.datatype = datatype
    if value is None:
        metric.is_null = True
    else:
        setattr(metric, field, _CONVERT[datatype](value))


def metric_value(metric: pb.Payload.Metric, datatype: int | None = None) -> Any:
    """A metric's value as Python (None when null), signed types sign-extended. `datatype`:
    the one its birth declared, for a metric that carries none (DATA, by alias)."""
    if metric.is_null:
        return None
    field = metric.WhichOneof("value")
    if field is None:
        return None
    value = getattr(metric, field)
    declared = datatype if datatype is not None else metric.datatype
    bits = {INT8: 8, INT16: 16, INT32: 32, INT64: 64}.get(declared)
    if bits is not None and field in ("int_value", "long_value"):
        width = 32 if field == "int_value" else 64
        value &= (1 << width) - 1
        if value >= 1 << (width - 1):
            value -= 1 << width
    return value


def _last_of_each(
    device: str | None,
    metrics: Sequence[pb.Payload.Metric],
    names: Mapping[int, str],
) -> dict[str, pb.Payload.Metric | None]:
    """A command payload's writes, one per metric: the last of each (by name or by alias,
    the same metric either way), in the order of those last ones; as if the earlier copies
    had not been sent, as a later write of a value replaces an earlier one. A metric that
    names nothing maps its refusal to None (one per distinct alias)."""
    writes: dict[str, pb.Payload.Metric | None] = {}
    for metric in metrics:
        key: str = metric.name
        found: pb.Payload.Metric | None = metric
        if not key and metric.HasField("alias"):
            key = names.get(metric.alias, "")
            if not key:
                target = "the edge node" if device is None else f"device {device}"
                key, found = f"alias {metric.alias} is not a metric of {target}", None
        if not key:
            key, found = "metric without a name or an alias", None
        writes.pop(key, None)
        writes[key] = found
    return writes


def parse_state(payload: bytes) -> tuple[bool, int] | None:
    """A host application's STATE payload (`{"online": bool, "timestamp": ms}`, Sparkplug
    3.0), or None when it is not one."""
    try:
        body = json.loads(payload)
    except (ValueError, UnicodeDecodeError):
        return None
    if not isinstance(body, dict):
        return None
    online, timestamp = body.get("online"), body.get("timestamp")
    if not isinstance(online, bool) or not isinstance(timestamp, int) or timestamp < 0:
        return None
    return online, timestamp


class SparkplugSession:
    """One edge node's Sparkplug state across MQTT sessions; see module docstring."""

    name = "sparkplug"

    def __init__(
        self,
        group_id: str,
        edge_node_id: str,
        *,
        primary_host_id: str | None = None,
        last_bdseq: int | None = None,
    ):
        self.group_id = group_id
        self.edge_node_id = edge_node_id
        self.primary_host_id = primary_host_id or None
        # the first will() moves it on: to 0, or past the one a previous run used
        self.bdseq = last_bdseq % 256 if last_bdseq is not None else -1
        self.seq = 0
        self.epoch = 0  # births so far (a session of the edge node); messages remember theirs
        self.born: set[str] = set()  # devices born on the broker in this session (send side)
        self.historical_dropped = 0  # data of devices not born when it could be sent
        self.holding = False  # connected, waiting for the primary host: keep the outbox
        self.host_online = False  # the primary host's latest STATE (in this connection)
        self.host_state_ms = -1  # the timestamp of the latest STATE applied
        self.next_due_ms = 0  # the next snapshot time a periodic group may report at
        self._alive: set[str] = set()  # devices alive in the latest snapshot (make side)
        self.latest: Sample | None = None
        self._extra: dict[str, Any] = {}
        self._last: dict[str | None, dict[str, Any]] = {}  # device (None: node) -> reported
        self._seen: dict[tuple[str | None, int], Any] = {}  # (device, group) -> fingerprint
        self._reported_ms: dict[tuple[str | None, int], int] = {}  # periodic groups
        self._reply: dict[str, Any] = dict.fromkeys(REPLY_METRICS)
        # per device (None: the edge node): the fixed tables, then the device nodes seen
        self._groups: dict[str | None, tuple[MetricGroup, ...]] = {None: NODE_GROUPS}
        self._groups.update(DEVICE_GROUPS)
        self._metrics: dict[str, tuple[MetricSpec, ...]] = dict(DEVICE_METRICS)
        self._aliases: dict[str | None, dict[str, int]] = dict(ALIASES)
        self._types: dict[str | None, dict[str, int]] = dict(DATATYPES)
        self._names: dict[str | None, dict[int, str]] = dict(NAMES_BY_ALIAS)
        self._periodic = dict(_PERIODIC)
        self._next_alias = max(a for table in ALIASES.values() for a in table.values()) + 1

    def _known(self, device: str, snapshot: Snapshot) -> bool:
        """Whether `device` is one of the session's devices: a loop kind, or a device node
        (given its metrics and fresh aliases the first time it is seen)."""
        if device in self._metrics:
            return True
        found = snapshot.devices.get(device)
        if found is None:
            return False
        groups = device_node_groups(device, found.objects)
        specs = tuple(spec for group in groups for spec in group.specs)
        types = {**{spec.name: spec.datatype for spec in specs}, RESTART: BOOLEAN}
        aliases = {name: self._next_alias + i for i, name in enumerate(types)}
        self._next_alias += len(aliases)
        self._groups[device] = groups
        self._metrics[device] = specs
        self._types[device] = types
        self._aliases[device] = aliases
        self._names[device] = {a: n for n, a in aliases.items()}
        self._periodic[device] = [
            (device, i, g.period_ms) for i, g in enumerate(groups) if g.period_ms
        ]
        return True

    # -- topics ----------------------------------------------------------------------------
    def topic(self, kind: str, device: str | None = None) -> str:
        base = f"{NAMESPACE}/{self.group_id}/{kind}/{self.edge_node_id}"
        return base if device is None else f"{base}/{device}"

    @property
    def state_topic(self) -> str | None:
        """The primary host application's STATE topic (None: no primary host configured)."""
        if self.primary_host_id is None:
            return None
        return f"{NAMESPACE}/STATE/{self.primary_host_id}"

    def subscriptions(self) -> list[str]:
        topics = [self.topic("NCMD"), self.topic("DCMD", "+")]
        if self.state_topic is not None:
            topics.append(self.state_topic)
        return topics

    # -- connection ------------------------------------------------------------------------
    def will(self, t_ms: int, *, new_connect: bool = True) -> Message:
        """Before each connection attempt: the NDEATH to register as the Will. bdSeq moves
        on by one per CONNECT packet, so not after an attempt that never sent one
        (`new_connect` False: the broker was unreachable)."""
        if new_connect or self.bdseq < 0:
            self.bdseq = (self.bdseq + 1) % 256
        return self._ndeath(t_ms)

    def on_connect(self, t_ms: int) -> tuple[list[Message], list[Message]]:
        """Births at once; with a primary host, none until its STATE says online."""
        self.born = set()
        self.host_online = False  # learnt again from its (retained) STATE
        if self.primary_host_id is not None:
            self.holding = True
            return [], []
        return self._new_session(t_ms), []

    def prime(self, sample: Sample, extra: dict[str, Any]) -> None:
        """The gateway's state before the first connection, for the first births: an NBIRTH
        carries every metric's current value (Sparkplug 3.0), not nulls for values the
        gateway already had. The sample still goes through `update` like any other."""
        self.latest = sample
        self._extra = extra

    def _new_session(self, t_ms: int) -> list[Message]:
        self.holding = False
        self.epoch += 1
        return self._births(t_ms)

    def rebirth(self, t_ms: int) -> list[Message]:
        """NBIRTH and DBIRTHs again in this session (same bdSeq; seq restarts at 0)."""
        return [] if self.holding else self._births(t_ms)

    def goodbye(self, t_ms: int) -> list[Message]:
        """A clean stop publishes the NDEATH itself (a DISCONNECT discards the Will)."""
        return [self._ndeath(t_ms)]

    def _ndeath(self, t_ms: int) -> Message:
        payload = pb.Payload(timestamp=t_ms)
        set_value(payload.metrics.add(name=BDSEQ, timestamp=t_ms), INT64, self.bdseq)
        return Message(
            self.topic("NDEATH"),
            payload.SerializeToString(),
            1,
            False,
            SpMeta(self.epoch, "NDEATH"),
        )

    def _births(self, t_ms: int) -> list[Message]:
        snap = self.latest.snapshot.to_dict() if self.latest else None
        ts = self.latest.ts_ms if self.latest else t_ms
        payload = pb.Payload(timestamp=t_ms)
        aliases = ALIASES[None]
        for name, value in ((BDSEQ, self.bdseq), (REBIRTH, False)):
            metric = payload.metrics.add(name=name, alias=aliases[name], timestamp=t_ms)
            set_value(metric, DATATYPES[None][name], value)
        node = self._last[None] = {}
        self._forget(None, ts)
        for spec in NODE_METRICS:
            node[spec.name] = spec.get(snap, self._extra)
            metric = payload.metrics.add(name=spec.name, alias=aliases[spec.name], timestamp=ts)
            set_value(metric, spec.datatype, node[spec.name])
        for name in REPLY_METRICS:
            metric = payload.metrics.add(name=name, alias=aliases[name], timestamp=ts)
            set_value(metric, DATATYPES[None][name], self._reply[name])
        out = [self._message("NBIRTH", payload)]
        if snap is not None:
            out += [self._dbirth(kind, snap, ts, t_ms) for kind in sorted(self._alive)]
        return out

    def _dbirth(self, kind: str, snap: dict[str, Any], ts_ms: int, t_ms: int) -> Message:
        payload = pb.Payload(timestamp=t_ms)
        last = self._last[kind] = {}
        self._forget(kind, ts_ms)
        aliases = self._aliases[kind]
        for spec in self._metrics[kind]:
            last[spec.name] = spec.get(snap, self._extra)
            metric = payload.metrics.add(name=spec.name, alias=aliases[spec.name], timestamp=ts_ms)
            set_value(metric, spec.datatype, last[spec.name])
            for key, text in spec.properties:
                metric.properties.keys.append(key)
                metric.properties.values.add(type=STRING, string_value=text)
        metric = payload.metrics.add(name=RESTART, alias=aliases[RESTART], timestamp=ts_ms)
        set_value(metric, BOOLEAN, False)
        return self._message("DBIRTH", payload, kind)

    def _forget(self, device: str | None, ts_ms: int) -> None:
        """After a birth: compare every group again; periodic ones wait a period."""
        groups = self._groups[device]
        for index, group in enumerate(groups):
            self._seen.pop((device, index), None)
            if group.period_ms:
                self._reported_ms[(device, index)] = ts_ms

    def _message(self, kind: str, payload: pb.Payload, device: str | None = None) -> Message:
        return Message(
            self.topic(kind, device),
            payload.SerializeToString(),
            0,
            False,
            SpMeta(self.epoch, kind, device),
        )

    # -- snapshots -------------------------------------------------------------------------
    def update(self, batch: list[Sample], extra: dict[str, Any]) -> list[Message]:
        """Births, deaths and changes over the batch, in order; one NDATA at the end."""
        self._extra = extra
        out: list[Message] = []
        pending: dict[str, pb.Payload] = {}
        node_payload: pb.Payload | None = None
        for sample in batch:
            self.latest = sample
            snap = sample.snapshot.to_dict()
            for kind, status in snap["nodes"].items():
                if not self._known(kind, sample.snapshot):
                    continue
                groups = self._groups[kind]
                alive = status["phase"] == LIVE_PHASE
                if alive and kind not in self._alive:
                    self._alive.add(kind)
                    out.append(self._dbirth(kind, snap, sample.ts_ms, sample.ts_ms))
                elif not alive and kind in self._alive:
                    self._alive.discard(kind)
                    if kind in pending:
                        out.append(self._message("DDATA", pending.pop(kind), kind))
                    payload = pb.Payload(timestamp=sample.ts_ms)
                    out.append(self._message("DDEATH", payload, kind))
                elif alive:
                    changed = self._changes(kind, groups, sample, pending.get(kind))
                    if changed is not None:
                        pending[kind] = changed
            node_payload = self._changes(None, NODE_GROUPS, sample, node_payload)
        for kind, payload in pending.items():
            out.append(self._message("DDATA", payload, kind))
        if node_payload is not None:
            out.append(self._message("NDATA", node_payload))
        self.next_due_ms = min(
            (self._reported_ms.get((device, index), _NEVER) // period + 1) * period
            for device, index, period in self._periodic[None]
            + [key for kind in self._alive for key in self._periodic[kind]]
        )
        return out

    def _changes(
        self,
        device: str | None,
        groups: tuple[MetricGroup, ...],
        sample: Sample,
        payload: pb.Payload | None,
    ) -> pb.Payload | None:
        """Add what changed in `sample` to `payload` (made when first needed), by alias."""
        snap, ts, extra = sample.snapshot.to_dict(), sample.ts_ms, self._extra
        last = self._last.setdefault(device, {})
        aliases = self._aliases[device]
        for index, group in enumerate(groups):
            key = (device, index)
            period = group.period_ms
            if period and ts // period == self._reported_ms.get(key, _NEVER) // period:
                continue  # once per period of the clock: every periodic report in one snapshot
            seen = group.fingerprint(snap, extra)
            if seen == self._seen.get(key, _UNSEEN):
                continue
            self._seen[key] = seen
            reported = False
            values = group.values(seen) if group.values is not None else None
            if values is None:
                values = [spec.get(snap, extra) for spec in group.specs]
            for spec, value in zip(group.specs, values, strict=True):
                name = spec.name
                if name in last and last[name] == value:
                    continue
                last[name] = value
                if payload is None:
                    payload = pb.Payload()
                metric = payload.metrics.add(alias=aliases[name], timestamp=ts)
                if value is None:
                    metric.is_null = True
                else:  # set_value without the datatype, inlined: the hot path
                    datatype = spec.datatype
                    setattr(metric, _VALUE_FIELD[datatype], _CONVERT[datatype](value))
                reported = True
            if reported:
                payload.timestamp = ts  # type: ignore[union-attr]
                if group.period_ms:
                    self._reported_ms[key] = ts
        return payload

    # -- sending ---------------------------------------------------------------------------
    def finalize(self, message: Message) -> Message | None:
        """Sequence a message as it is sent; see module docstring."""
        meta = message.meta
        if not isinstance(meta, SpMeta) or meta.kind == "NDEATH":
            return message
        current = meta.epoch == self.epoch
        if meta.kind in BIRTHS_AND_DEATHS and not current:
            return None
        if meta.kind == "DDATA" and meta.device not in self.born:
            self.historical_dropped += 1
            return None
        if meta.kind == "NBIRTH":
            self.seq = 0
            self.born = set()
        else:
            self.seq = (self.seq + 1) % 256
        if meta.kind == "DBIRTH":
            self.born.add(meta.device or "")
        elif meta.kind == "DDEATH":
            self.born.discard(meta.device or "")
        if current:
            payload = message.payload + SEQ_BYTES[self.seq]
        else:
            old = pb.Payload.FromString(message.payload)
            old.seq = self.seq
            for metric in old.metrics:
                metric.is_historical = True
            payload = old.SerializeToString()
        return Message(message.topic, payload, message.qos, message.retain)

    # -- commands and the primary host -----------------------------------------------------
    def receive(self, topic: str, payload: bytes, retain: bool, t_ms: int) -> Incoming:
        if topic == self.state_topic:
            return self._host_state(payload, t_ms)
        device = None
        if topic == self.topic("NCMD"):
            label = "NCMD"
        elif topic.startswith(self.topic("DCMD") + "/"):
            device = topic[len(self.topic("DCMD")) + 1 :]
            label = f"DCMD {device}"
        else:
            return Incoming()
        too_big = size_error(payload)  # before parsing: a payload's cost is bounded
        if too_big:
            return Incoming([CommandRequest(label, refused=too_big)])
        try:
            message = pb.Payload.FromString(payload)
        except DecodeError:
            return Incoming([CommandRequest(label, refused="not a Sparkplug B payload")])
        if retain:
            refused = "retained commands are not executed (publish with retain off)"
            return Incoming([CommandRequest(label, refused=refused)])
        if device is not None and device not in self._metrics:
            return Incoming([CommandRequest(label, refused=f"no device {device!r}")])
        count = len(message.metrics)
        if not 1 <= count <= MAX_COMMAND_METRICS:
            refused = (
                f"{label} carries {count} metrics; one carries 1..{MAX_COMMAND_METRICS} "
                "(nothing was executed)"
            )
            return Incoming([CommandRequest(label, refused=refused)])
        incoming = Incoming()
        calibration: dict[str, Any] = {}
        for name, metric in _last_of_each(device, message.metrics, self._names[device]).items():
            if metric is None:
                incoming.requests.append(CommandRequest(label, refused=name))
                continue
            value = metric_value(metric, self._types[device].get(name))
            if name in (REBIRTH, RESTART) and (name == REBIRTH) == (device is None):
                if value is not True:
                    refused = f"{name}: write Boolean true, got {shown(value)}"
                    incoming.requests.append(CommandRequest(label, refused=refused))
                elif device is None:
                    incoming.messages += self.rebirth(t_ms)
                else:
                    command = Command("restart_node", device)
                    incoming.requests.append(CommandRequest("restart_node", command))
            elif device is None and name.startswith(CALIBRATION):
                calibration[name[len(CALIBRATION) :]] = value
            elif device is None and name.startswith("Control/"):
                control = name[len("Control/") :]
                incoming.requests.append(CommandRequest(control, Command(control, value)))
            else:
                incoming.requests.append(
                    CommandRequest(label, refused=f"{name!r} is not a writable metric")
                )
        if calibration:
            if set(calibration) == {"e_min_uv", "e_max_uv"}:
                command = Command("emg_calibration", calibration)
                incoming.requests.append(CommandRequest("emg_calibration", command))
            else:
                refused = f"{CALIBRATION}e_min_uv and e_max_uv must come together in one NCMD"
                incoming.requests.append(CommandRequest("emg_calibration", refused=refused))
        return incoming

    def _host_state(self, payload: bytes, t_ms: int) -> Incoming:
        """The primary host's STATE: online lets the births go (ahead of the data that
        waited for them); offline after our births asks for a new MQTT session (Sparkplug
        3.0: disconnect; the births after the host's return carry a new bdSeq). A STATE
        older than the last one applied is a stale retained copy: ignored."""
        state = parse_state(payload)
        if state is None or state[1] < self.host_state_ms:
            return Incoming()
        online, self.host_state_ms = state
        self.host_online = online
        if online and self.holding:
            return Incoming(urgent=self._new_session(t_ms))
        if not online and not self.holding:
            self.holding = True  # nothing more goes out in this session
            return Incoming(reconnect=f"primary host {self.primary_host_id} went offline")
        return Incoming()

    def reply(self, request: CommandRequest, result: CommandResult, t_ms: int) -> list[Message]:
        """NDATA: `Command Reply/command`, `…/accepted`, `…/detail` (by alias)."""
        values = (request.name, result.accepted, result.detail)
        payload = pb.Payload(timestamp=t_ms)
        for name, value in zip(REPLY_METRICS, values, strict=True):
            self._reply[name] = value
            metric = payload.metrics.add(alias=ALIASES[None][name], timestamp=t_ms)
            set_value(metric, DATATYPES[None][name], value, with_datatype=False)
        return [self._message("NDATA", payload)]

"""Sparkplug B 3.0 edge node session (sans-IO): the gateway is the edge node, each CANopen
node a device. Snapshots in, `(topic, payload, qos, retain)` out; see docs/telemetry.md.

- `will()` before every CONNECT: bdSeq advances (0..255) and the NDEATH carrying it
  is the MQTT Will (QoS 1, not retained).
- `on_connect()`: NBIRTH (bdSeq, `Node Control/Rebirth`, every node metric) and a
  DBIRTH for every device whose node is operational.
- `update()`: report by exception: NDATA/DDATA carry the metrics that changed, each
  with the timestamp of the snapshot it changed in (fast counters at most once a
  second); DDEATH when a node is lost or leaves OPERATIONAL, DBIRTH when it is back.
- `finalize()` runs as a message is actually sent: it stamps `seq` (NBIRTH 0, then
  +1 mod 256 on every message of the edge node, NDEATH none), so a message that
  waited in the store-and-forward buffer is sequenced in the session that sends
  it; data made in an earlier session is marked `is_historical`, births and
  deaths of an earlier session are dropped (the new session's births replace
  them), and data of a device not born in this session is dropped and counted.
- `receive()`: NCMD `Node Control/Rebirth` (births again, same bdSeq) and
  `Control/<command>`, DCMD `Node Control/Restart`; `reply()` answers in NDATA
  (`Command Reply/command`, `…/accepted`, `…/detail`).

Payloads are built and read with the protobuf runtime (`sparkplug_b_pb2`, generated
from `sparkplug_b.proto`), never by hand.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from google.protobuf.message import DecodeError

from grasplink.gateway.commands import Command, CommandResult
from grasplink.gateway.telemetry import sparkplug_b_pb2 as pb
from grasplink.gateway.telemetry.buffer import Message, Sample
from grasplink.gateway.telemetry.protocol import (
    LIVE_PHASE,
    VALUE_FIELDS,
    CommandRequest,
    Incoming,
    controls_view,
    live_nodes,
)

NAMESPACE = "spBv1.0"
# Sparkplug data types (Metric.datatype)
INT8, INT16, INT32, INT64 = 1, 2, 3, 4
UINT8, UINT16, UINT32, UINT64 = 5, 6, 7, 8
FLOAT, DOUBLE, BOOLEAN, STRING = 9, 10, 11, 12
COUNTER_PERIOD_MS = 1000  # counters and latencies that change with every snapshot
REBIRTH = "Node Control/Rebirth"
RESTART = "Node Control/Restart"
REPLY_METRICS = ("Command Reply/command", "Command Reply/accepted", "Command Reply/detail")
CALIBRATION = "Control/emg_calibration/"
BIRTHS_AND_DEATHS = ("NBIRTH", "DBIRTH", "DDEATH", "NDEATH")

Getter = Callable[[dict[str, Any] | None, dict[str, Any]], Any]


@dataclass(frozen=True)
class MetricSpec:
    name: str
    datatype: int
    get: Getter
    period_ms: int = 0  # 0: every change; else at most once per period


@dataclass(frozen=True)
class SpMeta:
    """Which session made a message, what it is, for which device."""

    epoch: int
    kind: str
    device: str | None = None


def _snap(path: tuple[str, ...], default: Any = None) -> Getter:
    """A snapshot field by its path (None when the snapshot or a level is missing)."""
    if len(path) == 2:  # the common case, evaluated ~70 times a snapshot: keep it direct
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


NODE_METRICS: tuple[MetricSpec, ...] = (
    MetricSpec("Gateway/nodes_live", STRING, lambda s, e: ",".join(live_nodes(s)) if s else None),
    MetricSpec("Gateway/alarm_count", UINT32, lambda s, e: len(s["alarms"]) if s else None),
    MetricSpec("Gateway/alarms", STRING, _alarms),
    MetricSpec("Gateway/uptime_s", DOUBLE, _snap(("uptime_s",)), COUNTER_PERIOD_MS),
    MetricSpec("Loop/latency_p50_us", DOUBLE, _snap(("loop", "latency_p50_us")), COUNTER_PERIOD_MS),
    MetricSpec("Loop/latency_p99_us", DOUBLE, _snap(("loop", "latency_p99_us")), COUNTER_PERIOD_MS),
    MetricSpec("Loop/percepts", UINT64, _snap(("loop", "percepts")), COUNTER_PERIOD_MS),
    MetricSpec("Control/feedback_mode", STRING, _control("feedback_mode")),
    MetricSpec("Control/reflex_enabled", BOOLEAN, _control("reflex_enabled")),
    MetricSpec("Control/reflex_threshold_mm_s", DOUBLE, _control("reflex_threshold_mm_s")),
    MetricSpec(CALIBRATION + "e_min_uv", DOUBLE, _control("emg_e_min_uv")),
    MetricSpec(CALIBRATION + "e_max_uv", DOUBLE, _control("emg_e_max_uv")),
    MetricSpec("Control/emg_calibrate", STRING, lambda s, e: ""),  # write-only: a phase
    MetricSpec("Control/restart_node", STRING, lambda s, e: ""),  # write-only: a node kind
    MetricSpec("Telemetry/snapshots_dropped", UINT64, _telemetry("snapshots_dropped")),
    MetricSpec("Telemetry/buffer_dropped_messages", UINT64, _telemetry("buffer_dropped_messages")),
    MetricSpec("Telemetry/buffer_dropped_bytes", UINT64, _telemetry("buffer_dropped_bytes")),
    MetricSpec("Telemetry/historical_dropped", UINT64, _telemetry("historical_dropped")),
)

FIELD_TYPES: dict[str, int] = {
    "grip_force_n": DOUBLE,
    "slip": BOOLEAN,
    "slip_speed_mm_s": DOUBLE,
    "position_mm": DOUBLE,
    "confidence": DOUBLE,
    "envelope_uv": DOUBLE,
    "level": INT32,
    "grip_intent_n": DOUBLE,
    "saturated": BOOLEAN,
    "mode": STRING,
    "belt": STRING,
    "velocity_mrad_s": INT32,
    "reason": STRING,
    "grip_n": DOUBLE,
    "setpoint_n": DOUBLE,
    "reflex": STRING,
    "source": STRING,
}
STATE_METRICS: tuple[tuple[str, int, int], ...] = (  # (field of nodes[kind], type, period)
    ("node_id", UINT32, 0),
    ("phase", STRING, 0),
    ("nmt_state", STRING, 0),
    ("boots", UINT32, 0),
    ("last_emcy", STRING, 0),
    ("failure", STRING, 0),
    ("pdos_dropped", UINT64, 0),
    ("lost_packets", UINT64, 0),
    ("pdos_rx", UINT64, COUNTER_PERIOD_MS),
)


def _node_state(kind: str, name: str) -> Getter:
    def get(snap: dict[str, Any] | None, extra: dict[str, Any]) -> Any:
        try:
            return snap["nodes"][kind].get(name)  # type: ignore[index]
        except (TypeError, KeyError):
            return None

    return get


def device_metrics(kind: str) -> tuple[MetricSpec, ...]:
    """A device's metrics: its decoded values, then `State/…` from the node's status."""
    specs = [
        MetricSpec(name, FIELD_TYPES[name], _snap((kind, name))) for name in VALUE_FIELDS[kind]
    ]
    for name, datatype, period in STATE_METRICS:
        if name == "lost_packets" and kind != "skin":
            continue
        specs.append(MetricSpec(f"State/{name}", datatype, _node_state(kind, name), period))
    return tuple(specs)


DEVICE_METRICS = {kind: device_metrics(kind) for kind in VALUE_FIELDS}


def set_value(metric: pb.Payload.Metric, datatype: int, value: Any) -> None:
    """Fill a metric's datatype and value (None: is_null); signed ints as two's complement."""
    metric.datatype = datatype
    if value is None:
        metric.is_null = True
    elif datatype in (INT8, INT16, INT32):
        metric.int_value = int(value) & 0xFFFFFFFF
    elif datatype in (UINT8, UINT16, UINT32):
        metric.int_value = int(value)
    elif datatype == INT64:
        metric.long_value = int(value) & 0xFFFFFFFFFFFFFFFF
    elif datatype == UINT64:
        metric.long_value = int(value)
    elif datatype == FLOAT:
        metric.float_value = float(value)
    elif datatype == DOUBLE:
        metric.double_value = float(value)
    elif datatype == BOOLEAN:
        metric.boolean_value = bool(value)
    elif datatype == STRING:
        metric.string_value = str(value)
    else:
        raise ValueError(f"unsupported Sparkplug datatype {datatype}")


def metric_value(metric: pb.Payload.Metric) -> Any:
    """A metric's value as Python (None when null), signed types sign-extended."""
    if metric.is_null:
        return None
    field = metric.WhichOneof("value")
    if field is None:
        return None
    value = getattr(metric, field)
    bits = {INT8: 8, INT16: 16, INT32: 32, INT64: 64}.get(metric.datatype)
    if bits is not None and field in ("int_value", "long_value"):
        width = 32 if field == "int_value" else 64
        value &= (1 << width) - 1
        if value >= 1 << (width - 1):
            value -= 1 << width
    return value


class SparkplugSession:
    """One edge node's Sparkplug state across MQTT sessions; see module docstring."""

    name = "sparkplug"

    def __init__(self, group_id: str, edge_node_id: str):
        self.group_id = group_id
        self.edge_node_id = edge_node_id
        self.bdseq = -1  # the first will() makes it 0
        self.seq = 0
        self.epoch = 0  # MQTT sessions so far; messages remember theirs
        self.born: set[str] = set()  # devices born on the broker in this session (send side)
        self.historical_dropped = 0  # data of devices not born when it could be sent
        self._alive: set[str] = set()  # devices alive in the latest snapshot (make side)
        self._latest: Sample | None = None
        self._extra: dict[str, Any] = {}
        self._last: dict[str | None, dict[str, Any]] = {}  # device (None: node) -> reported
        self._last_ms: dict[tuple[str | None, str], int] = {}
        self._reply: dict[str, Any] = dict.fromkeys(REPLY_METRICS)

    # -- topics ----------------------------------------------------------------------------
    def topic(self, kind: str, device: str | None = None) -> str:
        base = f"{NAMESPACE}/{self.group_id}/{kind}/{self.edge_node_id}"
        return base if device is None else f"{base}/{device}"

    def subscriptions(self) -> list[str]:
        return [self.topic("NCMD"), self.topic("DCMD", "+")]

    # -- connection ------------------------------------------------------------------------
    def will(self, t_ms: int, *, new_connect: bool = True) -> Message:
        """Before each connection attempt: the NDEATH to register as the Will. bdSeq moves
        on by one per CONNECT packet, so not after an attempt that never sent one
        (`new_connect` False: the broker was unreachable)."""
        if new_connect or self.bdseq < 0:
            self.bdseq = (self.bdseq + 1) % 256
        return self._ndeath(t_ms)

    def on_connect(self, t_ms: int) -> tuple[list[Message], list[Message]]:
        self.epoch += 1
        self.born = set()
        return self._births(t_ms), []

    def rebirth(self, t_ms: int) -> list[Message]:
        """NBIRTH and DBIRTHs again in this session (same bdSeq; seq restarts at 0)."""
        return self._births(t_ms)

    def goodbye(self, t_ms: int) -> list[Message]:
        """A clean stop publishes the NDEATH itself (a DISCONNECT discards the Will)."""
        return [self._ndeath(t_ms)]

    def _ndeath(self, t_ms: int) -> Message:
        payload = pb.Payload(timestamp=t_ms)
        set_value(payload.metrics.add(name="bdSeq", timestamp=t_ms), INT64, self.bdseq)
        return Message(
            self.topic("NDEATH"),
            payload.SerializeToString(),
            1,
            False,
            SpMeta(self.epoch, "NDEATH"),
        )

    def _births(self, t_ms: int) -> list[Message]:
        snap = self._latest.snapshot if self._latest else None
        ts = self._latest.ts_ms if self._latest else t_ms
        payload = pb.Payload(timestamp=t_ms)
        set_value(payload.metrics.add(name="bdSeq", timestamp=t_ms), INT64, self.bdseq)
        set_value(payload.metrics.add(name=REBIRTH, timestamp=t_ms), BOOLEAN, False)
        node = self._last.setdefault(None, {})
        for spec in NODE_METRICS:
            node[spec.name] = spec.get(snap, self._extra)
            self._last_ms[(None, spec.name)] = ts
            set_value(
                payload.metrics.add(name=spec.name, timestamp=ts), spec.datatype, node[spec.name]
            )
        for name in REPLY_METRICS:
            datatype = BOOLEAN if name.endswith("accepted") else STRING
            set_value(payload.metrics.add(name=name, timestamp=ts), datatype, self._reply[name])
        out = [self._message("NBIRTH", payload)]
        if snap is not None:
            out += [self._dbirth(kind, Sample(ts, snap), t_ms) for kind in sorted(self._alive)]
        return out

    def _dbirth(self, kind: str, sample: Sample, t_ms: int) -> Message:
        payload = pb.Payload(timestamp=t_ms)
        last = self._last[kind] = {}
        for spec in DEVICE_METRICS[kind]:
            last[spec.name] = spec.get(sample.snapshot, self._extra)
            self._last_ms[(kind, spec.name)] = sample.ts_ms
            metric = payload.metrics.add(name=spec.name, timestamp=sample.ts_ms)
            set_value(metric, spec.datatype, last[spec.name])
        set_value(payload.metrics.add(name=RESTART, timestamp=sample.ts_ms), BOOLEAN, False)
        return self._message("DBIRTH", payload, kind)

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
        pending: dict[str, list[pb.Payload.Metric]] = {}
        node_changes: list[pb.Payload.Metric] = []
        for sample in batch:
            self._latest = sample
            snap = sample.snapshot
            for kind, status in snap["nodes"].items():
                if kind not in DEVICE_METRICS:
                    continue
                alive = status["phase"] == LIVE_PHASE
                if alive and kind not in self._alive:
                    self._alive.add(kind)
                    out.append(self._dbirth(kind, sample, sample.ts_ms))
                elif not alive and kind in self._alive:
                    self._alive.discard(kind)
                    if pending.get(kind):
                        out.append(self._data("DDATA", pending.pop(kind), kind))
                    payload = pb.Payload(timestamp=sample.ts_ms)
                    out.append(self._message("DDEATH", payload, kind))
                elif alive:
                    changes = self._changes(kind, DEVICE_METRICS[kind], sample)
                    pending.setdefault(kind, []).extend(changes)
            node_changes += self._changes(None, NODE_METRICS, sample)
        for kind, metrics in pending.items():
            if metrics:
                out.append(self._data("DDATA", metrics, kind))
        if node_changes:
            out.append(self._data("NDATA", node_changes))
        return out

    def _changes(
        self, device: str | None, specs: tuple[MetricSpec, ...], sample: Sample
    ) -> list[pb.Payload.Metric]:
        last = self._last.setdefault(device, {})
        changed = []
        for spec in specs:
            value = spec.get(sample.snapshot, self._extra)
            if spec.name in last and last[spec.name] == value:
                continue
            key = (device, spec.name)
            if (
                spec.period_ms
                and sample.ts_ms - self._last_ms.get(key, -(1 << 62)) < spec.period_ms
            ):
                continue
            last[spec.name] = value
            self._last_ms[key] = sample.ts_ms
            metric = pb.Payload.Metric(name=spec.name, timestamp=sample.ts_ms)
            set_value(metric, spec.datatype, value)
            changed.append(metric)
        return changed

    def _data(
        self, kind: str, metrics: list[pb.Payload.Metric], device: str | None = None
    ) -> Message:
        payload = pb.Payload(timestamp=max(m.timestamp for m in metrics))
        payload.metrics.extend(metrics)
        return self._message(kind, payload, device)

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
        payload = pb.Payload.FromString(message.payload)
        if meta.kind == "NBIRTH":
            self.seq = 0
            self.born = set()
        else:
            self.seq = (self.seq + 1) % 256
        payload.seq = self.seq
        if meta.kind == "DBIRTH":
            self.born.add(meta.device or "")
        elif meta.kind == "DDEATH":
            self.born.discard(meta.device or "")
        if not current:
            for metric in payload.metrics:
                metric.is_historical = True
        return Message(message.topic, payload.SerializeToString(), message.qos, message.retain)

    # -- commands --------------------------------------------------------------------------
    def receive(self, topic: str, payload: bytes, retain: bool, t_ms: int) -> Incoming:
        device = None
        if topic == self.topic("NCMD"):
            label = "NCMD"
        elif topic.startswith(self.topic("DCMD") + "/"):
            device = topic[len(self.topic("DCMD")) + 1 :]
            label = f"DCMD {device}"
        else:
            return Incoming()
        try:
            message = pb.Payload.FromString(payload)
        except DecodeError:
            return Incoming([CommandRequest(label, refused="not a Sparkplug B payload")])
        if retain:
            refused = "retained commands are not executed (publish with retain off)"
            return Incoming([CommandRequest(label, refused=refused)])
        incoming = Incoming()
        calibration: dict[str, Any] = {}
        for metric in message.metrics:
            name, value = metric.name, metric_value(metric)
            if not name:
                refused = "metric without a name (this edge node declares no aliases)"
                incoming.requests.append(CommandRequest(label, refused=refused))
            elif device is None and name == REBIRTH:
                if value is True:
                    incoming.messages += self.rebirth(t_ms)
            elif device is None and name.startswith(CALIBRATION):
                calibration[name[len(CALIBRATION) :]] = value
            elif device is None and name.startswith("Control/"):
                control = name[len("Control/") :]
                incoming.requests.append(CommandRequest(control, Command(control, value)))
            elif device is not None and name == RESTART:
                if value is True:
                    command = Command("restart_node", device)
                    incoming.requests.append(CommandRequest("restart_node", command))
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

    def reply(self, request: CommandRequest, result: CommandResult, t_ms: int) -> list[Message]:
        """NDATA: `Command Reply/command`, `…/accepted`, `…/detail`."""
        values = (request.name, result.accepted, result.detail)
        payload = pb.Payload(timestamp=t_ms)
        for name, value in zip(REPLY_METRICS, values, strict=True):
            self._reply[name] = value
            datatype = BOOLEAN if name.endswith("accepted") else STRING
            set_value(payload.metrics.add(name=name, timestamp=t_ms), datatype, value)
        return [self._message("NDATA", payload)]

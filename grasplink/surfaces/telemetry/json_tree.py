"""The JSON topic tree `grasplink/<gateway-id>/…` (sans-IO; see docs/telemetry.md).

| topic | retained | when |
|---|---|---|
| `status` | yes | `{"online": true}` on connect; the Will, and a clean stop, say false |
| `health` | yes | every `health_period_ms`, and at once when the live node list changes |
| `alarms` | yes | on change |
| `controls` | yes | on change (feedback mode, reflex, EMG calibration) |
| `node/<name>/state` | yes | on change (phase, NMT state, boots, EMCY, failure, consumer time) |
| `node/<name>/values` | no | latest decoded values, when one changed, else every second |
| `node/<name>/objects` | yes | a device node's TPDO-mapped objects, described from its file |
| `cmd/<name>` | — | in: `{"value": …, "id": …}` (id optional, echoed); one command, one reply |
| `reply/<name>` | no | out: `{"id", "command", "accepted", "detail"}` |

A loop node's name is its kind and its values are its snapshot section's fields; a
`device` node's values are its objects by key ("6401sub1": index and sub-index in hex,
as the configuration names them), and `objects` says what each key is.

Every payload carries `ts_ms`, when the snapshot it reports was made (wall
clock, ms since the epoch), so a message replayed after an outage still says
when its values held. Every message is QoS 1: a consumer with a persistent
session misses nothing the broker accepted.
"""

from __future__ import annotations

import json
import operator
from collections import Counter
from typing import Any

from grasplink.gateway.commands import Command, CommandResult
from grasplink.gateway.snapshot import DeviceObject
from grasplink.surfaces.telemetry.buffer import Message, Sample
from grasplink.surfaces.telemetry.protocol import (
    LIVE_PHASE,
    STATE_FIELDS,
    VALUE_FIELDS,
    CommandRequest,
    Incoming,
    controls_view,
    dumps,
    live_nodes,
    nesting_error,
    size_error,
)

ROOT = "grasplink"
_STATE_OF = operator.itemgetter(*STATE_FIELDS)  # a node's state fields, one C call
HEALTH_PERIOD_MS = 1000
VALUES_REFRESH_MS = 1000  # unchanged values are repeated this often (a consumer sees we live)
QOS = 1
VALUES_QOS = QOS  # the values stream (20 Hz); the benchmark's QoS 0 what-if sets it
MAX_REQUEST_ID_CHARS = 64


class _NodeTopics(dict[str, tuple[str, str]]):
    """A node kind's state and values topics, made once."""

    def __init__(self, base: str):
        super().__init__()
        self.base = base

    def __missing__(self, kind: str) -> tuple[str, str]:
        topics = self[kind] = (f"{self.base}/node/{kind}/state", f"{self.base}/node/{kind}/values")
        return topics


class JsonTree:
    """Snapshots in, JSON messages out; commands in, replies out."""

    name = "json"
    holding = False  # waits for nobody: the outbox drains whenever connected
    next_due_ms = 0

    def __init__(
        self,
        gateway_id: str,
        *,
        health_period_ms: int = HEALTH_PERIOD_MS,
        values_refresh_ms: int = VALUES_REFRESH_MS,
    ):
        self.gateway_id = gateway_id
        self.base = f"{ROOT}/{gateway_id}"
        self.health_period_ms = health_period_ms
        self.values_refresh_ms = values_refresh_ms
        self._values: dict[str, tuple[int, Any]] = {}  # kind -> (ts_ms, its snapshot section)
        self._published: dict[str, dict[str, Any]] = {}  # retained topic -> body (no ts)
        self.latest: Sample | None = None
        self._extra: dict[str, Any] = {}
        self._live: list[str] | None = None
        self._last_health_ms: int | None = None
        self._times_lost: Counter[str] = Counter()
        self._was_live: set[str] = set()
        # What the last snapshot's retained topics were made from (a snapshot is replaced
        # whole, never changed in place): equal, the topic's body is not even built.
        self._seen: dict[str, Any] = {}
        self._topics = _NodeTopics(self.base)  # kind -> (its state topic, its values topic)

    # -- connection ------------------------------------------------------------------------
    def will(self, t_ms: int, *, new_connect: bool = True) -> Message:
        body = {"online": False, "gateway_id": self.gateway_id, "reason": "connection lost"}
        return Message(f"{self.base}/status", dumps(body), QOS, True)

    def subscriptions(self) -> list[str]:
        return [f"{self.base}/cmd/+"]

    def on_connect(self, t_ms: int) -> tuple[list[Message], list[Message]]:
        """Online first; then, behind whatever was buffered, the current retained state
        (so a state change the buffer bound pushed out is still right on the broker)."""
        status = {"ts_ms": t_ms, "online": True, "gateway_id": self.gateway_id}
        first = [Message(f"{self.base}/status", dumps(status), QOS, True)]
        after = []
        if self.latest is not None:
            ts = self.latest.ts_ms
            after = [self._retained(topic, body, ts) for topic, body in self._published.items()]
            after.append(self._health(self.latest, ts))
        return first, after

    def goodbye(self, t_ms: int) -> list[Message]:
        body = {"ts_ms": t_ms, "online": False, "gateway_id": self.gateway_id, "reason": "stopped"}
        return [Message(f"{self.base}/status", dumps(body), QOS, True)]

    def finalize(self, message: Message) -> Message | None:
        return message

    # -- snapshots -------------------------------------------------------------------------
    def update(self, batch: list[Sample], extra: dict[str, Any]) -> list[Message]:
        """State changes for every snapshot of the batch; values and health for the latest."""
        self._extra = extra
        out: list[Message] = []
        for sample in batch:
            self._changes(sample, out)
        if not batch:
            return out
        latest = batch[-1]
        self.latest = latest
        snap, ts = latest.snapshot.to_dict(), latest.ts_ms
        devices = snap["devices"]
        for kind in snap["nodes"]:
            fields = VALUE_FIELDS.get(kind)
            section = snap.get(kind) if fields is not None else devices.get(kind)
            last = self._values.get(kind)
            refresh = self.values_refresh_ms
            if last and last[1] == section and ts // refresh == last[0] // refresh:
                continue  # compared before anything is built
            self._values[kind] = (ts, section)
            body: dict[str, Any] = {"ts_ms": ts}
            get = section.get if section is not None else {}.get
            for key in fields if fields is not None else (section or ()):
                body[key] = get(key)
            out.append(Message(self._topics[kind][1], dumps(body), VALUES_QOS, False))
        # Periodic topics go once per period of the clock, all in the same snapshot (and with
        # Sparkplug's counters): a gateway at rest publishes once a second, not four times.
        period = self.health_period_ms
        due = self._last_health_ms is None or ts // period != self._last_health_ms // period
        if due or live_nodes(snap) != self._live:
            out.append(self._health(latest, ts))
        self.next_due_ms = min(
            ((self._last_health_ms or 0) // period + 1) * period,
            *(
                (seen // self.values_refresh_ms + 1) * self.values_refresh_ms
                for seen, _ in self._values.values()
            ),
        )
        return out

    def _changes(self, sample: Sample, out: list[Message]) -> None:
        snap, ts = sample.snapshot.to_dict(), sample.ts_ms
        seen = self._seen
        for kind, node in snap["nodes"].items():
            topic = self._topics[kind][0]
            try:
                fields = _STATE_OF(node)
            except KeyError:  # a field missing: build the body and compare that
                fields = None
            if fields is not None and seen.get(topic) == fields:
                continue
            seen[topic] = fields
            live = node["phase"] == LIVE_PHASE
            if kind in self._was_live and not live:
                self._times_lost[kind] += 1
            (self._was_live.add if live else self._was_live.discard)(kind)
            body = {key: node.get(key) for key in STATE_FIELDS}
            body["live"] = live
            body["times_lost"] = self._times_lost[kind]
            out += self._if_changed(topic, body, ts)
        for name, device in sample.snapshot.devices.items():
            topic = f"{self.base}/node/{name}/objects"
            if seen.get(topic) is not device.objects:  # described once: the same tuple
                seen[topic] = device.objects
                out += self._if_changed(topic, _objects_body(device.objects), ts)
        alarms = snap["alarms"]
        topic = f"{self.base}/alarms"
        if seen.get(topic) != alarms:
            seen[topic] = alarms
            out += self._if_changed(topic, {"count": len(alarms), "alarms": dict(alarms)}, ts)
        controls = self._extra.get("controls", {})
        # the controls dict is changed in place by accepted commands: remember a copy
        fingerprint = (tuple(controls.items()), snap["belt"].get("mode"))
        topic = f"{self.base}/controls"
        if seen.get(topic) != fingerprint:
            seen[topic] = fingerprint
            out += self._if_changed(topic, controls_view(snap, self._extra), ts)

    def _if_changed(self, topic: str, body: dict[str, Any], ts_ms: int) -> list[Message]:
        if self._published.get(topic) == body:
            return []
        self._published[topic] = body
        return [self._retained(topic, body, ts_ms)]

    def _retained(self, topic: str, body: dict[str, Any], ts_ms: int) -> Message:
        return Message(topic, dumps({"ts_ms": ts_ms, **body}), QOS, True)

    def _health(self, sample: Sample, ts_ms: int) -> Message:
        snap = sample.snapshot.to_dict()
        live = live_nodes(snap)
        self._live = live
        self._last_health_ms = sample.ts_ms
        loss = {}
        for kind, node in snap["nodes"].items():
            loss[kind] = {
                "pdos_dropped": node.get("pdos_dropped", 0),
                "times_lost": self._times_lost[kind],
            }
            if "lost_packets" in node:
                loss[kind]["lost_packets"] = node["lost_packets"]
        loop = snap["loop"]
        body = {
            "ts_ms": ts_ms,
            "uptime_s": snap["uptime_s"],
            "nodes_live": live,
            "nodes_down": [kind for kind in snap["nodes"] if kind not in live],
            "loss": loss,
            "pdos_rx": {kind: node.get("pdos_rx", 0) for kind, node in snap["nodes"].items()},
            # since each node's last heartbeat, at this snapshot (null: not heard yet)
            "heartbeat_age_s": {
                kind: node.get("heartbeat_age_s") for kind, node in snap["nodes"].items()
            },
            "loop_latency_p50_us": loop["latency_p50_us"],
            "loop_latency_p99_us": loop["latency_p99_us"],
            "percepts": loop["percepts"],
            "alarm_count": len(snap["alarms"]),
            "rejected": dict(snap.get("rejected") or {}),  # what the loop refused to follow
            "own_heartbeat": snap.get("heartbeat"),  # how late the gateway's own went out
            "telemetry": dict(self._extra.get("telemetry", {})),
        }
        return Message(f"{self.base}/health", dumps(body), QOS, True)

    # -- commands --------------------------------------------------------------------------
    def receive(self, topic: str, payload: bytes, retain: bool, t_ms: int) -> Incoming:
        prefix = f"{self.base}/cmd/"
        if not topic.startswith(prefix) or "/" in topic[len(prefix) :]:
            return Incoming()
        name = topic[len(prefix) :]
        too_big = size_error(payload) or nesting_error(payload)  # before parsing: bounded
        if too_big:
            return Incoming([CommandRequest(name, refused=too_big)])
        try:
            body = json.loads(payload)
        except (ValueError, UnicodeDecodeError):
            return Incoming([CommandRequest(name, refused="payload is not JSON")])
        request_id = body.get("id") if isinstance(body, dict) else None
        if not isinstance(request_id, str | int) or isinstance(request_id, bool):
            request_id = None
        elif len(str(request_id)) > MAX_REQUEST_ID_CHARS:
            request_id = str(request_id)[:MAX_REQUEST_ID_CHARS]
        context = request_id
        if retain:
            refused = "retained commands are not executed (publish with retain off)"
            return Incoming([CommandRequest(name, refused=refused, context=context)])
        if not isinstance(body, dict) or "value" not in body:
            refused = 'expected a JSON object {"value": ..., "id": ...} (id optional)'
            return Incoming([CommandRequest(name, refused=refused, context=context)])
        return Incoming([CommandRequest(name, Command(name, body["value"]), context=context)])

    def reply(self, request: CommandRequest, result: CommandResult, t_ms: int) -> list[Message]:
        body = {"ts_ms": t_ms, "id": request.context, **result.as_dict()}
        return [Message(f"{self.base}/reply/{request.name}", dumps(body), QOS, False)]


def _objects_body(objects: tuple[DeviceObject, ...]) -> dict[str, Any]:
    """A device node's objects as its `objects` topic describes them, in TPDO map order."""
    return {
        "objects": [
            {
                "key": o.key,
                "index": o.index,
                "subindex": o.subindex,
                "name": o.name,
                "type": o.data_type,
                "unit": o.unit,
            }
            for o in objects
        ]
    }

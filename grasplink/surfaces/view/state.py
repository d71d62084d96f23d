"""What the live page shows, as a plain object: fed the JSON tree's messages (topic,
payload, time received), asked for frames the browser draws (docs/view.md).

Sans-IO: no socket, no clock of its own (every call takes the time, in seconds on the
caller's monotonic clock), so the tests drive it message by message. A message that is
not JSON, not an object, or of the wrong schema is refused whole, counted and named
(the last problem shows on the page); the values it would have replaced stay.
"""

from __future__ import annotations

import json
import math
import re
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from grasplink.gateway.snapshot import NodePhase, node_sections, section_fields, wire_kind
from grasplink.surfaces.telemetry.protocol import nesting_error

ROOT = "grasplink"
HISTORY_S = 30.0  # the plots' span: points older than this (as received) are dropped
STALE_S = 3.0  # a gateway publishes health every second: three missed and it is stale
MAX_PAYLOAD_BYTES = 65536  # the largest real message (health) is about 2 KiB
MAX_JSON_DEPTH = 8  # health nests 3 levels; deeper is refused before parsing
MAX_GATEWAYS = 64
MAX_NODES = 64  # per gateway: four loop nodes and the device nodes of its bus
MAX_POINTS = 40_000  # every gateway's points together: 20 Hz x 5 series x 30 s x 13
MAX_PROBLEM_CHARS = 200
_ID = re.compile(r"[A-Za-z0-9_.:-]{1,64}")  # a gateway ID or node name: one topic level
_PHASES = frozenset(p.value for p in NodePhase)
_QUIET = frozenset({"cmd", "reply"})  # commands and their answers: not this part's business

#: per loop node kind: its value fields and how each is carried ("float", "bool", "int",
#: "uint32", "uint64", "str"), read from the gateway's snapshot classes
VALUE_KINDS: dict[str, dict[str, str]] = {
    kind: {name: wire_kind(section, name) for name in section_fields(section)}
    for kind, section in node_sections().items()
}
#: a node's state message (json_tree.py): the snapshot's state fields and two of its own
STATE_KINDS: dict[str, str] = {
    "node_id": "uint32",
    "phase": "str",
    "nmt_state": "str",
    "boots": "uint32",
    "last_emcy": "str",
    "failure": "str",
    "heartbeat_consumer_ms": "uint32",
    "live": "bool",
    "times_lost": "uint64",
}
#: health fields the page shows, and their carriage
HEALTH_KINDS: dict[str, str] = {
    "uptime_s": "float",
    "loop_latency_p50_us": "float",
    "loop_latency_p99_us": "float",
    "percepts": "uint64",
    "alarm_count": "uint64",
}
LOSS_KINDS = {"pdos_dropped": "uint64", "times_lost": "uint64", "lost_packets": "uint64"}


class SchemaError(ValueError):
    """Why one message is refused; its text is shown on the page (never raised out)."""


@dataclass
class NodeView:
    """One node as the gateway reports it."""

    state: dict[str, Any] = field(default_factory=dict)
    loss: dict[str, Any] = field(default_factory=dict)
    heartbeat_age_s: float | None = None  # at its gateway's last health (once a second)
    values: dict[str, Any] = field(default_factory=dict)
    values_at_s: float | None = None  # when its last values message was received


@dataclass
class GatewayView:
    """One gateway's tree: its status, nodes, alarms, health, and what was refused."""

    online: bool | None = None  # its status topic: None until one is seen
    offline_reason: str | None = None
    last_at_s: float | None = None  # when its last good message was received
    newest_ts_ms: int = 0  # the newest `ts_ms` it stamped
    messages: int = 0
    problems: int = 0
    last_problem: str = ""
    nodes: dict[str, NodeView] = field(default_factory=dict)
    alarms: dict[str, str] = field(default_factory=dict)
    controls: dict[str, Any] = field(default_factory=dict)
    health: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Point:
    """One values message (or a health message's loop latency: kind `loop`), for the plots."""

    seq: int
    gateway: str
    kind: str
    ts_ms: int
    values: dict[str, Any]
    received_s: float


class ViewState:
    """Every gateway seen on the broker, the broker link, and the recent points."""

    def __init__(self, gateway_id: str | None = None, *, stale_s: float = STALE_S) -> None:
        self.gateway_id = gateway_id  # only this gateway's tree, or every one
        self.stale_s = stale_s
        self.gateways: dict[str, GatewayView] = {}
        self.broker_connected = False
        self.broker_error = ""
        self.broker_changed_s: float | None = None  # when it connected or was lost
        self.problems = 0  # messages that name no gateway this view may show
        self.last_problem = ""
        self.points: deque[Point] = deque()
        self._seq = 0

    # -- the broker link ------------------------------------------------------------------
    def broker_up(self, t_s: float) -> None:
        self.broker_connected = True
        self.broker_error = ""
        self.broker_changed_s = t_s

    def broker_down(self, t_s: float, why: str) -> None:
        if self.broker_connected or self.broker_changed_s is None:
            self.broker_changed_s = t_s
        self.broker_connected = False
        self.broker_error = why

    # -- messages ---------------------------------------------------------------------------
    def feed(self, topic: str, payload: bytes, t_s: float) -> None:
        """One message of the JSON tree, received at `t_s`; a bad one is counted, named."""
        levels = topic.split("/")
        if len(levels) < 3 or levels[0] != ROOT:
            self._refuse_outside(topic, "not a topic of the JSON tree (grasplink/<id>/…)")
            return
        gateway_id, rest = levels[1], levels[2:]
        if not _ID.fullmatch(gateway_id):
            self._refuse_outside(topic, "not a gateway ID (1..64 of A-Z a-z 0-9 _ . : -)")
            return
        if self.gateway_id is not None and gateway_id != self.gateway_id:
            return  # another gateway's tree: not asked for
        if rest[0] in _QUIET:
            return
        gateway = self.gateways.get(gateway_id)
        if gateway is None:
            if len(self.gateways) >= MAX_GATEWAYS:
                self._refuse_outside(topic, f"more than {MAX_GATEWAYS} gateways; not shown")
                return
            gateway = self.gateways[gateway_id] = GatewayView()
        where = "/".join(rest)
        try:
            body = _parse(payload)
            self._apply(gateway_id, gateway, rest, body, t_s)
        except SchemaError as exc:
            gateway.problems += 1
            gateway.last_problem = _cut(f"{where}: {exc}")
            return
        gateway.messages += 1
        gateway.last_at_s = t_s
        gateway.newest_ts_ms = max(gateway.newest_ts_ms, body["ts_ms"])

    def _refuse_outside(self, topic: str, why: str) -> None:
        self.problems += 1
        self.last_problem = _cut(f"{topic}: {why}")

    def _apply(
        self, gid: str, gateway: GatewayView, rest: list[str], body: dict[str, Any], t_s: float
    ) -> None:
        match rest:
            case ["status"]:
                online = body.get("online")
                if not isinstance(online, bool):
                    raise SchemaError(f"online: expected true or false, got {_shown(online)}")
                reason = _checked(body, "reason", "str")
                gateway.online = online
                gateway.offline_reason = None if online else (reason or "offline")
            case ["health"]:
                ages = {  # checked before anything changes
                    name: _checked({name: age}, name, "float", "heartbeat_age_s.")
                    for name, age in _mapping(body, "heartbeat_age_s").items()
                }
                gateway.health = {k: _checked(body, k, kind) for k, kind in HEALTH_KINDS.items()}
                loss = _mapping(body, "loss")
                for name, counts in loss.items():
                    if not isinstance(counts, dict):
                        raise SchemaError(f"loss.{name}: expected an object")
                    self._node(gateway, name).loss = {
                        k: _checked(counts, k, kind, f"loss.{name}.")
                        for k, kind in LOSS_KINDS.items()
                        if k in counts
                    }
                for name, age in ages.items():
                    self._node(gateway, name).heartbeat_age_s = age
                self._point(gid, "loop", body["ts_ms"], {
                    "latency_p50_us": gateway.health["loop_latency_p50_us"],
                    "latency_p99_us": gateway.health["loop_latency_p99_us"],
                }, t_s)  # fmt: skip
            case ["alarms"]:
                alarms = _mapping(body, "alarms")
                for key, text in alarms.items():
                    if not isinstance(text, str):
                        raise SchemaError(f"alarms.{key}: expected text, got {_shown(text)}")
                gateway.alarms = dict(alarms)
            case ["controls"]:
                gateway.controls = {k: v for k, v in body.items() if k != "ts_ms"}
            case ["node", name, "state"]:
                state = {k: _checked(body, k, kind) for k, kind in STATE_KINDS.items()}
                if state["phase"] not in _PHASES:
                    raise SchemaError(
                        f"phase: expected one of {', '.join(sorted(_PHASES))}, "
                        f"got {_shown(state['phase'])}"
                    )
                self._node(gateway, name).state = state
            case ["node", name, "values"]:
                kinds = VALUE_KINDS.get(name)
                if kinds is None:  # a device node: its objects by key, not plotted
                    values = {k: v for k, v in body.items() if k != "ts_ms"}
                else:
                    values = {k: _checked(body, k, kind) for k, kind in kinds.items()}
                node = self._node(gateway, name)
                node.values, node.values_at_s = values, t_s
                if kinds is not None:
                    self._point(gid, name, body["ts_ms"], values, t_s)
            case ["node", name, "objects"]:
                self._node(gateway, name)
            case _:
                raise SchemaError("not a topic of the JSON tree (docs/telemetry.md)")

    def _node(self, gateway: GatewayView, name: str) -> NodeView:
        node = gateway.nodes.get(name)
        if node is None:
            if not _ID.fullmatch(name):
                raise SchemaError(f"node name {name!r} is not one topic level")
            if len(gateway.nodes) >= MAX_NODES:
                raise SchemaError(f"more than {MAX_NODES} nodes; {name!r} not shown")
            node = gateway.nodes[name] = NodeView()
        return node

    def add_point(
        self, gid: str, kind: str, ts_ms: int, values: dict[str, Any], t_s: float
    ) -> None:
        """A point from beside the JSON tree (a recording's truth), plotted like its values."""
        self._point(gid, kind, ts_ms, values, t_s)

    def _point(self, gid: str, kind: str, ts_ms: int, values: dict[str, Any], t_s: float) -> None:
        self._seq += 1
        self.points.append(Point(self._seq, gid, kind, ts_ms, values, t_s))

    # -- frames for the browser -------------------------------------------------------------
    def prune(self, t_s: float) -> None:
        """Forget points received more than HISTORY_S ago, and beyond MAX_POINTS."""
        points = self.points
        while points and (t_s - points[0].received_s > HISTORY_S or len(points) > MAX_POINTS):
            points.popleft()

    def frame(self, t_s: float, after_seq: int | None = None) -> tuple[dict[str, Any], int]:
        """What the page draws at `t_s`: the summary and the points after `after_seq`
        (None: a page's first frame, with every point kept); the cursor for the next."""
        self.prune(t_s)
        newer: list[Point] = []
        for point in reversed(self.points):  # the new ones are at the end
            if after_seq is not None and point.seq <= after_seq:
                break
            newer.append(point)
        body = {
            "reset": after_seq is None,
            "stale_after_s": self.stale_s,
            "history_s": HISTORY_S,
            "broker": {
                "connected": self.broker_connected,
                "error": self.broker_error,
                "for_s": _age(t_s, self.broker_changed_s),
            },
            "problems": self.problems,
            "last_problem": self.last_problem,
            "gateways": {gid: self._summary(g, t_s) for gid, g in sorted(self.gateways.items())},
            "points": [[p.gateway, p.kind, p.ts_ms, p.values] for p in reversed(newer)],
        }
        return body, self._seq

    def _summary(self, gateway: GatewayView, t_s: float) -> dict[str, Any]:
        age = _age(t_s, gateway.last_at_s)
        stale = (
            not self.broker_connected
            or gateway.online is False
            or age is None
            or age > self.stale_s
        )
        return {
            "online": gateway.online,
            "offline_reason": gateway.offline_reason,
            "age_s": age,
            "stale": stale,
            "newest_ts_ms": gateway.newest_ts_ms,
            "messages": gateway.messages,
            "problems": gateway.problems,
            "last_problem": gateway.last_problem,
            "alarms": gateway.alarms,
            "controls": gateway.controls,
            "health": gateway.health,
            "nodes": {
                name: {
                    **node.state,
                    **{f"loss_{k}": v for k, v in node.loss.items()},
                    "heartbeat_age_s": node.heartbeat_age_s,
                    "heartbeat_overdue": _overdue(node),
                    "values_age_s": _age(t_s, node.values_at_s),
                    "values": node.values,
                }
                for name, node in sorted(gateway.nodes.items())
            },
        }


def _overdue(node: NodeView) -> bool | None:
    """Whether its heartbeat is older than the gateway's consumer time (the gateway loses
    the node then); None while either is unknown."""
    consumer_ms = node.state.get("heartbeat_consumer_ms")
    if node.heartbeat_age_s is None or consumer_ms is None:
        return None
    return bool(node.heartbeat_age_s * 1000 > consumer_ms)


def _parse(payload: bytes) -> dict[str, Any]:
    if not payload:
        raise SchemaError("empty payload (a retained message cleared?)")
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise SchemaError(f"payload of {len(payload)} bytes; at most {MAX_PAYLOAD_BYTES}")
    if problem := nesting_error(payload, MAX_JSON_DEPTH):
        raise SchemaError(problem)
    try:
        body = json.loads(payload, parse_constant=_no_constant)
    except (UnicodeDecodeError, ValueError) as exc:
        raise SchemaError(f"not JSON ({exc})") from None
    if not isinstance(body, dict):
        raise SchemaError(f"expected a JSON object, got {type(body).__name__}")
    ts = body.get("ts_ms")
    if isinstance(ts, bool) or not isinstance(ts, int) or ts < 0:
        raise SchemaError(f"ts_ms: expected whole milliseconds since the epoch, got {_shown(ts)}")
    return body


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a JSON number")  # Python's json reads NaN; browsers not


_EXPECTED = {
    "float": "a number",
    "int": "a whole number",
    "uint32": "a whole number >= 0",
    "uint64": "a whole number >= 0",
    "bool": "true or false",
    "str": "text",
}


def _checked(body: dict[str, Any], key: str, kind: str, prefix: str = "") -> Any:
    """`body[key]` if it is carried as `kind` says (or null, or absent: None)."""
    value = body.get(key)
    if value is None:
        return None
    ok = {
        "float": lambda v: isinstance(v, int | float) and not isinstance(v, bool),
        "bool": lambda v: isinstance(v, bool),
        "str": lambda v: isinstance(v, str),
    }.get(kind, lambda v: isinstance(v, int) and not isinstance(v, bool))(value)
    if ok and kind in ("uint32", "uint64"):
        ok = value >= 0
    if ok and kind == "float":
        ok = math.isfinite(value)
    if not ok:
        raise SchemaError(f"{prefix}{key}: expected {_EXPECTED[kind]} or null, got {_shown(value)}")
    return value


def _mapping(body: dict[str, Any], key: str) -> dict[str, Any]:
    value = body.get(key, {})
    if not isinstance(value, dict):
        raise SchemaError(f"{key}: expected an object, got {_shown(value)}")
    return value


def _age(t_s: float, then_s: float | None) -> float | None:
    return None if then_s is None else round(max(0.0, t_s - then_s), 3)


def _shown(value: Any) -> str:
    return _cut(json.dumps(value), 40)


def _cut(text: str, limit: int = MAX_PROBLEM_CHARS) -> str:
    return text if len(text) <= limit else text[: limit - 1] + "…"

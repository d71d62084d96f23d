"""What the two telemetry protocols share: the sans-IO interface the MQTT edge drives,
command requests, and how a gateway snapshot reads (live nodes, value fields, controls).

The field lists come from the snapshot's classes (`grasplink.gateway.snapshot`): a field
added there is published by both protocols without a change here.

A protocol object is fed snapshots (`update`) and broker events (`on_connect`,
`receive`) and returns `Message`s; it never touches a socket, so the JSON tree
and the Sparkplug session are tested without a broker. The edge
(`transport.py`) calls, per connection::

    will = proto.will(t_ms, new_connect=…)     # before each attempt (Sparkplug: bdSeq)
    first, after = proto.on_connect(t_ms)      # first: sent at once; after: behind the buffer
    outbox.extend(proto.update(batch, extra))  # every publish tick
    proto.holding                              # True: keep the outbox (Sparkplug: no host yet)
    message = proto.finalize(message)          # just before it is sent (None: skip it)
    incoming = proto.receive(topic, payload, retain, t_ms)   # a subscribed topic
    outbox.extend(proto.reply(request, result, t_ms))
    goodbye = proto.goodbye(t_ms)              # a clean stop, before DISCONNECT
"""

from __future__ import annotations

import dataclasses
import json
import math
import operator
from dataclasses import dataclass, field
from typing import Any, Protocol

from grasplink.gateway.commands import Command, CommandResult
from grasplink.gateway.snapshot import (
    NodePhase,
    NodeSnapshot,
    Snapshot,
    node_sections,
    section_fields,
)
from grasplink.surfaces.telemetry.buffer import Message, Sample

LIVE_PHASE = NodePhase.OPERATIONAL.value  # a node is live (a Sparkplug device born) only then

#: per node kind: the snapshot section and its decoded values (units in the names), in the
#: order they are published
VALUE_FIELDS: dict[str, tuple[str, ...]] = {
    kind: section_fields(section) for kind, section in node_sections().items()
}
_NODE_FIELDS = dataclasses.fields(NodeSnapshot)
#: node state fields of `snapshot.nodes[kind]`, published on change (the rest are counters
#: and what changes with every snapshot, a heartbeat's age: JSON health carries those)
STATE_FIELDS = tuple(
    f.name for f in _NODE_FIELDS if not f.metadata.get("counter") and not f.metadata.get("fast")
)
#: what either protocol reports on change of a node (the fast counters go on their own period)
_REPORTED_NODE_FIELDS = operator.attrgetter(
    *(f.name for f in _NODE_FIELDS if not f.metadata.get("fast"))
)
_COMPARED_SECTIONS = (*VALUE_FIELDS, "alarms", "devices")
#: Bounds on what one command message may ask for, checked before it is parsed: the largest
#: real command is a few hundred bytes, 2 levels deep, 8 metrics (every writable one of the
#: edge node); a bigger one is refused whole, answered once, and costs no parsing.
MAX_COMMAND_BYTES = 8192
MAX_JSON_DEPTH = 8  # nested objects/arrays in a JSON command (json.loads recurses per level)
MAX_COMMAND_METRICS = 16  # metrics in one Sparkplug NCMD/DCMD
#: settable gateway values, as `extra["controls"]` carries them (feedback mode: the snapshot's)
CONTROL_KEYS = (
    "reflex_enabled",
    "reflex_threshold_mm_s",
    "emg_e_min_uv",
    "emg_e_max_uv",
)


@dataclass
class CommandRequest:
    """A command read from a topic; `refused` set: answered at once, never posted."""

    name: str
    command: Command | None = None
    refused: str = ""
    context: Any = None  # what the protocol needs to answer it (JSON: the request id)


@dataclass
class Incoming:
    """What one received message asks for: commands, messages to send (`messages` behind
    what is buffered, `urgent` ahead of it), or a new MQTT session (`reconnect`: why)."""

    requests: list[CommandRequest] = field(default_factory=list)
    messages: list[Message] = field(default_factory=list)
    urgent: list[Message] = field(default_factory=list)
    reconnect: str = ""


class TelemetryProtocol(Protocol):
    name: str
    holding: bool
    latest: Sample | None  # the newest snapshot seen (births and retained state report it)
    next_due_ms: int  # snapshot time from which a snapshot like the last one has news

    def will(self, t_ms: int, *, new_connect: bool = True) -> Message: ...
    def subscriptions(self) -> list[str]: ...
    def on_connect(self, t_ms: int) -> tuple[list[Message], list[Message]]: ...
    def update(self, batch: list[Sample], extra: dict[str, Any]) -> list[Message]: ...
    def finalize(self, message: Message) -> Message | None: ...
    def goodbye(self, t_ms: int) -> list[Message]: ...
    def receive(self, topic: str, payload: bytes, retain: bool, t_ms: int) -> Incoming: ...
    def reply(self, request: CommandRequest, result: CommandResult, t_ms: int) -> list[Message]: ...


def same_report(before: Snapshot, after: Snapshot) -> bool:
    """Whether `after` tells nothing `before` did not, apart from uptime and the counters
    the protocols publish on their own period: then a protocol fed `after` has nothing to
    say before its `next_due_ms`, and the snapshot need not go through it at all. Written
    for a thread that wakes with cold caches 20 times a second: a few compares of frozen
    sections, no conversion."""
    for section in _COMPARED_SECTIONS:
        if getattr(before, section) != getattr(after, section):
            return False
    nodes_before, nodes_after = before.nodes, after.nodes
    if nodes_before.keys() != nodes_after.keys():
        return False
    for kind, node in nodes_after.items():
        if _REPORTED_NODE_FIELDS(node) != _REPORTED_NODE_FIELDS(nodes_before[kind]):
            return False
    return True


# The helpers below read a snapshot's JSON-ready form (`Snapshot.to_dict()`): what the
# protocols publish from.
def live_nodes(snapshot: dict[str, Any]) -> list[str]:
    return [kind for kind, node in snapshot["nodes"].items() if node["phase"] == LIVE_PHASE]


def controls_view(snapshot: dict[str, Any] | None, extra: dict[str, Any]) -> dict[str, Any]:
    controls = dict(extra.get("controls", {}))
    controls["feedback_mode"] = snapshot["belt"]["mode"] if snapshot else None
    return controls


def apply_result(controls: dict[str, Any], command: Command, result: CommandResult) -> None:
    """Track a settable value once the gateway accepted its command (for births and topics)."""
    if not result.accepted:
        return
    if command.name in ("reflex_enabled", "reflex_threshold_mm_s"):
        controls[command.name] = (
            bool(command.value) if command.name == "reflex_enabled" else float(command.value)
        )
    elif command.name == "emg_calibration":
        controls["emg_e_min_uv"] = float(command.value["e_min_uv"])
        controls["emg_e_max_uv"] = float(command.value["e_max_uv"])


def size_error(payload: bytes) -> str:
    """Why a command payload is too big to look at ("" when it is not)."""
    if len(payload) <= MAX_COMMAND_BYTES:
        return ""
    return f"payload of {len(payload)} bytes; a command takes at most {MAX_COMMAND_BYTES}"


def nesting_error(payload: bytes, limit: int = MAX_JSON_DEPTH) -> str:
    """Why a JSON payload nests too deep to parse ("" when it does not), found without
    parsing it: json.loads recurses once per level, and a few KiB of "[" reach Python's
    recursion limit. Cheap: a payload with no more brackets than `limit` cannot nest
    deeper and is not scanned; else one pass (brackets inside strings skipped), stopping
    at the first level too deep."""
    if payload.count(b"[") + payload.count(b"{") <= limit:
        return ""
    depth = 0
    in_string = escaped = False
    for byte in payload:
        if in_string:
            if escaped:
                escaped = False
            elif byte == 0x5C:  # backslash
                escaped = True
            elif byte == 0x22:  # quote
                in_string = False
        elif byte == 0x22:
            in_string = True
        elif byte in (0x5B, 0x7B):  # [ {
            depth += 1
            if depth > limit:
                return f"JSON nested deeper than {limit} levels"
        elif byte in (0x5D, 0x7D):  # ] }
            depth -= 1
    return ""


# One encoder for every message: json.dumps with options builds a new one per call.
_COMPACT = json.JSONEncoder(separators=(",", ":"), allow_nan=False)


def dumps(obj: Any) -> bytes:
    """Compact JSON; a non-finite number (never expected from a snapshot) becomes null."""
    try:
        return _COMPACT.encode(obj).encode()
    except ValueError:
        return json.dumps(_finite(obj), separators=(",", ":")).encode()


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_finite(v) for v in obj]
    return obj

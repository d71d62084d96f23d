"""An independent Sparkplug B 3.0 host: reads `spBv1.0/#` on a broker and decodes every
message with pysparkplug (its own protobuf bindings and payload classes, nothing of
grasplink's), checking the rules a host relies on. Our own checks decode with our own
generated code, so they cannot catch a misreading of the schema or the specification
that we share with ourselves; this one can.

It runs in `.venv-check` (made by `make test`): pysparkplug pins paho-mqtt<2, grasplink
pins 2.x, so it cannot share the project's environment and never imports grasplink.

Out on stdout, one JSON object a line (the test asserts on them):
  {"event": "ready"}                                   subscribed: start the edge node
  {"event": "message", "type", "edge", "device", "seq", "bdSeq", "metrics", ...}
  {"event": "violation", "rule", "topic", "detail"}    rule: its Sparkplug 3.0 TCK id
                                                       where it has one
  {"event": "sent", "type", "topic", "metrics"}        a command this host published
  {"event": "end", "reason", "messages", "violations"}
Exit status 1 when any rule was broken.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import paho.mqtt.client as paho
from pysparkplug import (
    DataType,
    DBirth,
    DCmd,
    DData,
    DDeath,
    MessageType,
    Metric,
    NBirth,
    NCmd,
    NData,
    NDeath,
    State,
)
from pysparkplug import _protobuf as raw_pb  # pysparkplug's bindings: field presence

NAMESPACE = "spBv1.0"
BDSEQ = "bdSeq"
REBIRTH = "Node Control/Rebirth"
RESTART = "Node Control/Restart"
DECODERS = {
    MessageType.NBIRTH: NBirth,
    MessageType.DBIRTH: DBirth,
    MessageType.NDATA: NData,
    MessageType.DDATA: DData,
    MessageType.NDEATH: NDeath,
    MessageType.DDEATH: DDeath,
    MessageType.NCMD: NCmd,
    MessageType.DCMD: DCmd,
}
SEQUENCED = ("DBIRTH", "NDATA", "DDATA", "DDEATH")  # seq = previous + 1 (mod 256)


@dataclass
class EdgeNode:
    """What a host knows of one edge node: its session (bdSeq, seq) and its births."""

    online: bool = False
    bdseq: int | None = None
    seq: int | None = None
    nbirth: NBirth | None = None
    dbirths: dict[str, DBirth] = field(default_factory=dict)
    # alias -> (device, name) across the edge node and all its devices (must be unique)
    aliases: dict[int, tuple[str | None, str]] = field(default_factory=dict)
    # devices born when a rebirth came: their DBIRTHs follow the NBIRTH before any data
    awaiting: set[str] = field(default_factory=set)


class Host:
    """Sans-IO: `feed` a message, get the lines it makes (message, violations)."""

    def __init__(self) -> None:
        self.edges: dict[tuple[str, str], EdgeNode] = {}
        self.messages = 0
        self.violations = 0
        self.ndeaths = 0

    def feed(self, topic: str, data: bytes, qos: int, retain: bool) -> list[dict[str, Any]]:
        self.messages += 1
        out: list[dict[str, Any]] = []

        def violation(rule: str, detail: str) -> None:
            self.violations += 1
            out.append({"event": "violation", "rule": rule, "topic": topic, "detail": detail})

        parts = topic.split("/")
        if parts[0] != NAMESPACE or len(parts) < 3:
            violation("topic-structure", "not a Sparkplug B topic")
            return out
        if parts[1] == "STATE":
            try:
                state = State.decode(data)
            except (ValueError, KeyError, TypeError) as error:
                violation("host-state-payload", f"STATE not decoded: {error!r}")
                return out
            out.append(
                {"event": "message", "type": "STATE", "host": parts[2], "online": state.online}
            )
            return out
        if len(parts) not in (4, 5):
            violation("topic-structure", f"{len(parts)} levels")
            return out
        group, kind, edge_id = parts[1], parts[2], parts[3]
        device = parts[4] if len(parts) == 5 else None
        try:
            message_type = MessageType(kind)
        except ValueError:
            violation("topic-message-type", f"unknown message type {kind!r}")
            return out
        if (device is None) != (kind in ("NBIRTH", "NDATA", "NDEATH", "NCMD")):
            violation("topic-structure", f"{kind} {'with' if device else 'without'} a device")
            return out
        edge = self.edges.setdefault((group, edge_id), EdgeNode())
        if retain:
            violation("payloads-retain", f"{kind} published retained")
        try:
            raw = raw_pb.Payload.FromString(data)
        except Exception as error:  # the bindings' DecodeError
            violation("payloads-decode", f"not a Sparkplug B payload: {error!r}")
            return out
        birth = self._birth_for(edge, kind, device)
        try:
            payload = DECODERS[message_type].decode(data, birth=birth)
        except Exception as error:  # whatever pysparkplug refuses is a finding
            violation("payloads-decode", f"pysparkplug {kind}: {type(error).__name__}: {error}")
            return out
        line: dict[str, Any] = {
            "event": "message",
            "type": kind,
            "edge": edge_id,
            "device": device,
            "seq": raw.seq if raw.HasField("seq") else None,
            "qos": qos,
        }
        if not raw.HasField("timestamp"):
            violation("payloads-timestamp", f"{kind} without a payload timestamp")
        if kind in ("NCMD", "DCMD"):
            line["metrics"] = [m.name for m in payload.metrics]
            out.append(line)
            return out
        if kind == "NDEATH":
            self._ndeath(edge, raw, payload, line, violation)
        elif kind == "NBIRTH":
            self._nbirth(edge, raw, payload, qos, line, violation)
        else:
            self._sequenced(edge, kind, device, raw, payload, qos, line, violation)
        out.insert(0, line)
        return out

    @staticmethod
    def _birth_for(edge: EdgeNode, kind: str, device: str | None) -> NBirth | DBirth | None:
        """The birth a DATA or CMD message is read through (pysparkplug resolves its aliases
        and datatypes with it)."""
        if kind in ("NDATA", "NCMD"):
            return edge.nbirth
        if kind in ("DDATA", "DCMD") and device is not None:
            return edge.dbirths.get(device)
        return None

    def _ndeath(self, edge, raw, payload: NDeath, line, violation) -> None:
        self.ndeaths += 1
        bdseq = payload.bd_seq_metric.value
        line["bdSeq"] = bdseq
        line["metrics"] = [m.name for m in raw.metrics]
        if raw.HasField("seq"):
            violation("payloads-ndeath-seq", f"NDEATH carries seq {raw.seq}")
        if [m.name for m in raw.metrics] != [BDSEQ]:
            violation("topics-ndeath-payload", f"NDEATH metrics {line['metrics']}, not [bdSeq]")
        if edge.bdseq is not None and bdseq != edge.bdseq:
            violation("payloads-ndeath-bdseq", f"NDEATH bdSeq {bdseq} != NBIRTH's {edge.bdseq}")
        line["matches_nbirth"] = edge.bdseq is not None and bdseq == edge.bdseq
        edge.online = False
        edge.dbirths.clear()

    def _nbirth(self, edge, raw, payload: NBirth, qos, line, violation) -> None:
        metrics = {m.name: m for m in payload.metrics}
        line["metrics"] = list(metrics)
        line["nulls"] = sum(m.is_null for m in payload.metrics)
        line["null_metrics"] = [m.name for m in payload.metrics if m.is_null]
        if qos != 0:
            violation("payloads-nbirth-qos", f"NBIRTH QoS {qos}")
        if payload.seq != 0 or not raw.HasField("seq"):
            violation("payloads-nbirth-seq", f"NBIRTH seq {line['seq']}")
        bdseq = metrics.get(BDSEQ)
        if bdseq is None or not isinstance(bdseq.value, int):
            violation("payloads-nbirth-bdseq", "NBIRTH without an integer bdSeq metric")
        else:
            line["bdSeq"] = bdseq.value
            if edge.online and edge.bdseq != bdseq.value:
                violation("payloads-nbirth-bdseq", "a rebirth changed bdSeq without a new session")
        rebirth = metrics.get(REBIRTH)
        if rebirth is None or rebirth.datatype != DataType.BOOLEAN or rebirth.value is not False:
            violation("topics-nbirth-rebirth-metric", f"Node Control/Rebirth: {rebirth}")
        edge.awaiting = set(edge.dbirths) if edge.online else set()
        edge.online, edge.seq = True, 0
        edge.bdseq = line.get("bdSeq")
        edge.nbirth = payload
        edge.dbirths.clear()
        edge.aliases = {}
        self._learn(edge, None, raw, line, violation)

    def _sequenced(self, edge, kind, device, raw, payload, qos, line, violation) -> None:
        if not raw.HasField("seq"):
            violation("payloads-sequence-num-always-included", f"{kind} without seq")
        elif not edge.online:
            rule = "message-flow-device-birth-publish-nbirth-wait"
            violation(rule, f"{kind} while the edge node is not born")
        elif raw.seq != (edge.seq + 1) % 256:  # type: ignore[operator]
            violation(
                "payloads-sequence-num-incrementing", f"{kind} seq {raw.seq} after {edge.seq}"
            )
        if raw.HasField("seq"):
            edge.seq = raw.seq
        line["bdSeq"] = edge.bdseq
        if qos != 0:
            violation(f"payloads-{kind.lower()}-qos", f"{kind} QoS {qos}")
        if kind in ("NDATA", "DDATA") and edge.awaiting:
            missing = ", ".join(sorted(edge.awaiting))
            violation("payloads-dbirth-order", f"{kind} before the DBIRTHs of {missing}")
            edge.awaiting.clear()
        if kind == "DBIRTH":
            edge.awaiting.discard(device)
            line["metrics"] = [m.name for m in payload.metrics]
            line["nulls"] = sum(m.is_null for m in payload.metrics)
            edge.dbirths[device] = payload
            self._learn(edge, device, raw, line, violation)
        elif kind == "DDEATH":
            if device not in edge.dbirths:
                violation("payloads-ddeath-order", f"DDEATH of {device}, not born")
            edge.dbirths.pop(device, None)
        else:
            self._resolve(edge, kind, device, raw, payload, line, violation)

    def _learn(self, edge, device, raw, line, violation) -> None:
        """A birth defines name, alias, datatype and a timestamp for every metric; an alias
        is unique across the edge node's entire set of metrics, devices' included."""
        for index in [a for a, (d, _) in edge.aliases.items() if d == device]:
            del edge.aliases[index]
        for metric in raw.metrics:
            if not metric.HasField("alias"):
                violation("payloads-alias-birth-requirement", f"{metric.name!r} without alias")
                continue
            if not metric.HasField("timestamp"):
                violation("payloads-name-birth-data-requirement", f"{metric.name!r}: no timestamp")
            if metric.alias in edge.aliases:
                other = edge.aliases[metric.alias]
                violation(
                    "payloads-alias-uniqueness",
                    f"alias {metric.alias}: {metric.name!r} and {other}",
                )
            edge.aliases[metric.alias] = (device, metric.name)
        line["aliases"] = len(raw.metrics)

    def _resolve(self, edge, kind, device, raw, payload, line, violation) -> None:
        """DATA by alias only: the name and datatype come from the birth, and the value sits
        in the protobuf field the birth's datatype says."""
        birth = edge.nbirth if kind == "NDATA" else edge.dbirths.get(device)
        if birth is None:
            violation("payloads-ddata-order", f"{kind} for {device}, not born")
            return
        names: list[str] = []
        resolved = 0
        for wire, metric in zip(raw.metrics, payload.metrics, strict=True):
            names.append(metric.name)
            if wire.HasField("name"):
                violation("payloads-alias-data-cmd-requirement", f"{kind} names {wire.name!r}")
            if wire.HasField("datatype"):
                violation("payloads-metric-datatype-not-req", f"{kind} {metric.name!r} datatype")
            if not wire.HasField("timestamp"):
                violation("payloads-name-birth-data-requirement", f"{metric.name!r}: no timestamp")
            declared = birth.get_dtype(metric.name)
            if wire.HasField("datatype") and wire.datatype != declared:
                violation("payloads-metric-datatype", f"{metric.name!r}: {wire.datatype} != birth")
            found = wire.WhichOneof("value")
            if not wire.is_null and found != declared.field:
                violation(
                    "payloads-metric-datatype",
                    f"{metric.name!r} ({declared.name}) carried in {found}",
                )
            elif wire.HasField("alias") and not wire.HasField("name"):
                resolved += 1
        line["metrics"] = names
        line["resolved"] = resolved
        line["historical"] = sum(m.is_historical for m in payload.metrics)


class Runner:
    """paho 1.x (pysparkplug's) on its own thread; commands published as a host would."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.host = Host()
        self.lock = threading.RLock()  # paho's thread feeds, the main thread commands
        self.first_nbirth: float | None = None  # ... and the DBIRTHs of --devices
        self.last_ndeath: float | None = None
        self.client = paho.Client(client_id=f"spb-check-{time.monotonic_ns()}", clean_session=True)
        self.client.on_connect = lambda c, u, f, rc: c.subscribe(f"{NAMESPACE}/#", qos=1)
        self.client.on_subscribe = lambda *a: self.emit({"event": "ready"})
        self.client.on_message = self.on_message

    def emit(self, line: dict[str, Any]) -> None:
        with self.lock:
            sys.stdout.write(json.dumps(line) + "\n")
            sys.stdout.flush()

    def on_message(self, client, userdata, message) -> None:
        with self.lock:
            lines = self.host.feed(message.topic, message.payload, message.qos, message.retain)
            kind = message.topic.split("/")[2] if message.topic.count("/") >= 2 else ""
            if kind in ("NBIRTH", "DBIRTH") and self.first_nbirth is None:
                born = max((len(e.dbirths) for e in self.host.edges.values()), default=0)
                if born >= self.args.devices:
                    self.first_nbirth = time.monotonic()
            elif kind == "NDEATH":
                self.last_ndeath = time.monotonic()
            for line in lines:
                self.emit(line)

    def command(self, kind: str, device: str | None, name: str) -> None:
        """An NCMD/DCMD as Sparkplug 3.0 has a host send it: by the birth's alias, no name."""
        group, edge_id, edge = next(
            (g, e, node) for (g, e), node in self.host.edges.items() if node.online
        )
        birth = edge.nbirth if device is None else edge.dbirths[device]
        alias = next(a for a, (d, n) in edge.aliases.items() if d == device and n == name)
        now = int(time.time() * 1000)
        metric = Metric(now, None, birth.get_dtype(name), value=True, alias=alias)
        payload = (NCmd if device is None else DCmd)(now, (metric,)).encode()
        topic = f"{NAMESPACE}/{group}/{kind}/{edge_id}" + (f"/{device}" if device else "")
        self.client.publish(topic, payload, qos=0)
        self.emit({"event": "sent", "type": kind, "topic": topic, "metrics": [name]})

    def run(self) -> int:
        args = self.args
        self.client.connect(args.host, args.port, keepalive=10)
        self.client.loop_start()
        deadline = time.monotonic() + args.timeout_s
        pending = []
        if args.rebirth_after_s is not None:
            pending.append((args.rebirth_after_s, "NCMD", None, REBIRTH))
        if args.restart_device:
            pending.append((args.restart_after_s, "DCMD", args.restart_device, RESTART))
        reason = "timeout"
        while time.monotonic() < deadline:
            time.sleep(0.02)
            born = self.first_nbirth
            for item in list(pending):
                after_s, kind, device, name = item
                if born is not None and time.monotonic() - born >= after_s:
                    pending.remove(item)
                    with self.lock:
                        self.command(kind, device, name)
            ended = self.last_ndeath
            if args.until_ndeath and ended is not None and time.monotonic() - ended > args.grace_s:
                reason = "ndeath"
                break
        self.client.disconnect()
        self.client.loop_stop()
        host = self.host
        self.emit(
            {
                "event": "end",
                "reason": reason,
                "messages": host.messages,
                "violations": host.violations,
            }
        )
        return 1 if host.violations else 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, required=True)
    parser.add_argument("--timeout-s", type=float, default=60.0)
    parser.add_argument("--until-ndeath", action="store_true", help="stop after an NDEATH")
    parser.add_argument("--grace-s", type=float, default=0.5, help="listen on after the NDEATH")
    parser.add_argument("--devices", type=int, default=0, help="commands wait for N DBIRTHs")
    parser.add_argument("--rebirth-after-s", type=float, help="NCMD Node Control/Rebirth")
    parser.add_argument("--restart-device", help="DCMD Node Control/Restart to this device")
    parser.add_argument("--restart-after-s", type=float, default=2.0)
    return Runner(parser.parse_args(argv)).run()


if __name__ == "__main__":
    sys.exit(main())

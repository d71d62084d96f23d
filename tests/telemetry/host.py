"""A strict Sparkplug B host for tests: decodes with the generated classes and checks the
session rules (bdSeq in NBIRTH/NDEATH, seq 0..255 with NBIRTH at 0, births before data)
and the alias rules (births: name, alias and datatype for every metric, aliases unique
across the edge node; NDATA/DDATA: alias only, no name or datatype, resolved through the
births). Optionally it is the primary host application: `state(online)` is the retained
STATE payload it would publish."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any

from grasplink.surfaces.telemetry import sparkplug_b_pb2 as pb
from grasplink.surfaces.telemetry.sparkplug import metric_value


@dataclass
class Seen:
    kind: str
    device: str | None
    payload: pb.Payload
    # (name, metric, value) in payload order: names resolved through the births' aliases
    named: list[tuple[str, pb.Payload.Metric, Any]] = field(default_factory=list)

    def metrics(self) -> dict[str, Any]:
        return {name: value for name, _, value in self.named}

    def values_of(self, name: str) -> list[tuple[int, Any]]:
        """(timestamp, value) of every metric `name` in this message."""
        return [(m.timestamp, value) for n, m, value in self.named if n == name]


@dataclass
class SparkplugHost:
    group: str
    edge: str
    messages: list[Seen] = field(default_factory=list)
    errors: list[str] = field(default_factory=list)
    bdseq: int | None = None
    seq: int | None = None
    online: bool = False
    born: set[str] = field(default_factory=set)
    values: dict[str | None, dict[str, Any]] = field(default_factory=dict)
    # per device (None: the edge node): alias -> (name, datatype), from the births
    aliases: dict[str | None, dict[int, tuple[str, int]]] = field(default_factory=dict)

    @staticmethod
    def state(online: bool, timestamp_ms: int | None = None) -> bytes:
        """A primary host application's STATE payload (Sparkplug 3.0)."""
        stamp = timestamp_ms if timestamp_ms is not None else time.time_ns() // 1_000_000
        return json.dumps({"online": online, "timestamp": stamp}).encode()

    def feed(self, topic: str, data: bytes) -> Seen | None:
        parts = topic.split("/")
        if parts[:2] != ["spBv1.0", self.group] or len(parts) < 4 or parts[3] != self.edge:
            return None
        kind, device = parts[2], (parts[4] if len(parts) > 4 else None)
        if kind in ("NCMD", "DCMD"):
            return None
        payload = pb.Payload.FromString(data)
        seen = Seen(kind, device, payload)
        self.messages.append(seen)
        if kind in ("NBIRTH", "DBIRTH"):
            self._learn_aliases(seen)
        elif kind in ("NDATA", "DDATA"):
            self._resolve(seen)
        else:
            seen.named = [(m.name, m, metric_value(m)) for m in payload.metrics]
        metrics = seen.metrics()
        if kind == "NDEATH":
            if payload.HasField("seq"):
                self.errors.append("NDEATH carries a seq")
            if metrics.get("bdSeq") != self.bdseq:
                self.errors.append(f"NDEATH bdSeq {metrics.get('bdSeq')} != NBIRTH's {self.bdseq}")
            self.online = False
            self.born.clear()
            return seen
        if not payload.HasField("seq") or not 0 <= payload.seq <= 255:
            self.errors.append(f"{kind} without a seq in 0..255")
            return seen
        if kind == "NBIRTH":
            if payload.seq != 0:
                self.errors.append(f"NBIRTH seq {payload.seq}")
            self.bdseq = metrics.get("bdSeq")
            if "Node Control/Rebirth" not in metrics:
                self.errors.append("NBIRTH without Node Control/Rebirth")
            self.online, self.seq = True, 0
            self.born.clear()
            self.values[None] = {k: v for k, v in metrics.items()}
            return seen
        if not self.online:
            self.errors.append(f"{kind} before NBIRTH")
        elif payload.seq != (self.seq + 1) % 256:
            self.errors.append(f"{kind} seq {payload.seq} after {self.seq}")
        self.seq = payload.seq
        historical = all(m.is_historical for m in payload.metrics) and len(payload.metrics) > 0
        if kind == "DBIRTH":
            self.born.add(device or "")
            self.values[device] = metrics
        elif kind == "DDEATH":
            self.born.discard(device or "")
        elif kind == "DDATA":
            if device not in self.born:
                self.errors.append(f"DDATA for {device} not born")
            if not historical:
                self.values.setdefault(device, {}).update(metrics)
        elif kind == "NDATA" and not historical:
            self.values.setdefault(None, {}).update(metrics)
        return seen

    def _learn_aliases(self, seen: Seen) -> None:
        """A birth defines its metrics: name, alias and datatype each; an NBIRTH starts the
        edge node's alias table afresh, a DBIRTH redefines its device's part of it."""
        if seen.kind == "NBIRTH":
            self.aliases = {}
        table: dict[int, tuple[str, int]] = {}
        others = {
            alias: (device, name)
            for device, entries in self.aliases.items()
            if device != seen.device
            for alias, (name, _) in entries.items()
        }
        for metric in seen.payload.metrics:
            if not metric.name or not metric.HasField("alias") or not metric.datatype:
                self.errors.append(f"{seen.kind} metric {metric.name!r} without name/alias/type")
                continue
            if metric.alias in table or metric.alias in others:
                self.errors.append(f"{seen.kind} alias {metric.alias} ({metric.name}) not unique")
            table[metric.alias] = (metric.name, metric.datatype)
            seen.named.append((metric.name, metric, metric_value(metric)))
        self.aliases[seen.device] = table

    def _resolve(self, seen: Seen) -> None:
        """DATA metrics by alias only, through the births (no name, no datatype)."""
        table = self.aliases.get(seen.device, {})
        for metric in seen.payload.metrics:
            if metric.name or metric.HasField("datatype"):
                self.errors.append(f"{seen.kind} metric {metric.name!r} with a name or datatype")
            if not metric.HasField("alias") or metric.alias not in table:
                self.errors.append(f"{seen.kind} {seen.device} alias {metric.alias} not born")
                continue
            name, datatype = table[metric.alias]
            seen.named.append((name, metric, metric_value(metric, datatype)))

    def kinds(self) -> list[str]:
        return [m.kind + (f"/{m.device}" if m.device else "") for m in self.messages]

"""A strict Sparkplug B host for tests: decodes with the generated classes and checks the
session rules (bdSeq in NBIRTH/NDEATH, seq 0..255 with NBIRTH at 0, births before data)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from grasplink.gateway.telemetry import sparkplug_b_pb2 as pb
from grasplink.gateway.telemetry.sparkplug import metric_value


@dataclass
class Seen:
    kind: str
    device: str | None
    payload: pb.Payload

    def metrics(self) -> dict[str, Any]:
        return {m.name: metric_value(m) for m in self.payload.metrics}


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

    def kinds(self) -> list[str]:
        return [m.kind + (f"/{m.device}" if m.device else "") for m in self.messages]

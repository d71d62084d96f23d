"""Snapshots like the one before are not encoded at all (`same_report` + `next_due_ms`):
that must be lossless, the same messages as when every snapshot goes through."""

from __future__ import annotations

from typing import Any

from grasplink.surfaces.telemetry.buffer import Sample
from grasplink.surfaces.telemetry.json_tree import JsonTree
from grasplink.surfaces.telemetry.protocol import same_report
from grasplink.surfaces.telemetry.sparkplug import SparkplugSession
from tests.telemetry.snapshots import snapshot

EXTRA = {"controls": {"reflex_enabled": True}, "telemetry": {}}


def a_gateway_mostly_at_rest(count: int) -> list[Sample]:
    """Counters, uptime and heartbeat ages move every snapshot; values, states and alarms
    now and then."""
    samples = []
    for k in range(count):
        changes: dict[str, Any] = {"loop": {"percepts": 3 * k, "latency_p50_us": 100.0 + k // 7}}
        if 40 <= k < 45 or k % 97 == 0:
            changes["skin"] = {"slip": True, "slip_speed_mm_s": 30.0 + k}
        if k >= 120:
            changes["alarms"] = {"belt.emcy": "EMCY 0x8130"}
        if 200 <= k < 230:
            changes["nodes"] = {"hand": {"phase": "lost", "nmt_state": None}}
        counted = {
            kind: {"pdos_rx": 17 * k, "heartbeat_age_s": (k % 3) / 20}
            for kind in ("skin", "emg", "belt", "hand")
        }
        for kind, fields in changes.get("nodes", {}).items():
            counted[kind].update(fields)
        changes["nodes"] = counted
        snap = snapshot(1 + k / 20, **changes)
        samples.append(Sample(1_000_000 + 50 * k + k % 3, snap))
    return samples


def test_skipping_snapshots_with_no_news_changes_no_message() -> None:
    samples = a_gateway_mostly_at_rest(400)
    for make in (lambda: JsonTree("gw"), lambda: SparkplugSession("grp", "gw")):
        every, news = make(), make()
        for protocol in (every, news):
            protocol.will(0)
            protocol.on_connect(0)
        sent_every, sent_news, previous, skipped = [], [], None, 0
        for sample in samples:
            sent_every += every.update([sample], EXTRA)
            quiet = previous is not None and same_report(previous, sample.snapshot)
            previous = sample.snapshot
            if quiet and sample.ts_ms < news.next_due_ms:
                skipped += 1
                continue
            sent_news += news.update([sample], EXTRA)
        assert [(m.topic, m.payload) for m in sent_news] == [
            (m.topic, m.payload) for m in sent_every
        ]
        assert skipped > 300  # most of a gateway at rest is never encoded

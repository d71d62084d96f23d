"""The JSON topic tree without a broker: retained state on change, values every tick,
health, commands and replies."""

from __future__ import annotations

import json

from grasplink.gateway.commands import Command, CommandResult
from grasplink.surfaces.telemetry.buffer import Sample
from grasplink.surfaces.telemetry.json_tree import JsonTree
from tests.telemetry.snapshots import snapshot

EXTRA = {"controls": {"reflex_enabled": True}, "telemetry": {"snapshots_dropped": 0}}


def by_topic(messages) -> dict[str, dict]:
    return {m.topic: json.loads(m.payload) for m in messages}


def test_first_update_publishes_state_values_and_health_with_units_in_names() -> None:
    tree = JsonTree("gw")
    messages = tree.update([Sample(1000, snapshot(2.0, skin={"grip_force_n": 4.5}))], EXTRA)
    topics = by_topic(messages)
    base = "grasplink/gw"
    assert set(topics) == {
        f"{base}/alarms",
        f"{base}/controls",
        f"{base}/health",
        *(
            f"{base}/node/{k}/{t}"
            for k in ("skin", "emg", "belt", "hand")
            for t in ("state", "values")
        ),
    }
    assert topics[f"{base}/node/skin/values"] == {
        "ts_ms": 1000,
        "grip_force_n": 4.5,
        "slip": None,
        "slip_speed_mm_s": None,
        "position_mm": None,
        "confidence": None,
        "slip_speed_low_mm_s": None,
        "slip_speed_high_mm_s": None,
        "slip_direction": None,
        "slip_direction_confidence": None,
    }
    state = topics[f"{base}/node/skin/state"]
    assert state["live"] is True and state["phase"] == "operational" and state["node_id"] == 0x10
    health = topics[f"{base}/health"]
    assert health["nodes_live"] == ["skin", "emg", "belt", "hand"] and health["nodes_down"] == []
    assert health["telemetry"] == {"snapshots_dropped": 0}
    assert "loop_latency_p99_us" in health and "uptime_s" in health
    retained = {m.topic for m in messages if m.retain}
    assert retained == set(topics) - {
        f"{base}/node/{k}/values" for k in ("skin", "emg", "belt", "hand")
    }
    assert all(m.qos == 1 for m in messages)


def test_heartbeat_ages_ride_in_health_and_never_make_a_state_message() -> None:
    """An age changes with every snapshot: in the retained node state it would republish
    every node 20 times a second; health, once a second, carries it with the counters."""
    tree = JsonTree("gw")
    ages = {"skin": 0.04, "emg": 0.09, "belt": None, "hand": 1.5}
    first = by_topic(tree.update([Sample(1000, snapshot(1.0, nodes=_aged(ages)))], EXTRA))
    assert first["grasplink/gw/health"]["heartbeat_age_s"] == ages
    state = first["grasplink/gw/node/skin/state"]
    assert state["heartbeat_consumer_ms"] == 500 and "heartbeat_age_s" not in state
    older = {kind: None if age is None else age + 0.05 for kind, age in ages.items()}
    assert tree.update([Sample(1050, snapshot(1.05, nodes=_aged(older)))], EXTRA) == []
    later = by_topic(tree.update([Sample(2000, snapshot(2.0, nodes=_aged(older)))], EXTRA))
    assert later["grasplink/gw/health"]["heartbeat_age_s"] == older


def _aged(ages: dict[str, float | None]) -> dict[str, dict[str, float | None]]:
    return {kind: {"heartbeat_age_s": age} for kind, age in ages.items()}


def test_state_and_alarms_are_published_only_when_they_change() -> None:
    tree = JsonTree("gw")
    tree.update([Sample(1000, snapshot(1.0))], EXTRA)
    assert tree.update([Sample(1050, snapshot(1.05))], EXTRA) == []
    lost = snapshot(1.1, nodes={"skin": {"phase": "lost"}}, alarms={"skin.lost": "heartbeat lost"})
    topics = by_topic(tree.update([Sample(1100, lost)], EXTRA))
    assert topics["grasplink/gw/alarms"]["alarms"] == {"skin.lost": "heartbeat lost"}
    assert topics["grasplink/gw/node/skin/state"]["live"] is False
    assert topics["grasplink/gw/node/skin/state"]["times_lost"] == 1
    assert topics["grasplink/gw/health"]["nodes_down"] == ["skin"]  # at once, not in a second


def test_values_go_out_when_they_change_and_in_each_new_second_when_they_do_not() -> None:
    tree = JsonTree("gw")
    tree.update([Sample(1000, snapshot(1.0))], EXTRA)
    changed = tree.update([Sample(1050, snapshot(1.05, skin={"grip_force_n": 2.0}))], EXTRA)
    assert [m.topic for m in changed] == ["grasplink/gw/node/skin/values"]
    assert tree.update([Sample(1900, snapshot(1.9, skin={"grip_force_n": 2.0}))], EXTRA) == []
    refresh = tree.update([Sample(2000, snapshot(2.0, skin={"grip_force_n": 2.0}))], EXTRA)
    # every refresh falls in the first snapshot of a second of the clock, whenever the
    # last one went (skin's at 1050): one publication a second for a gateway at rest
    assert {m.topic.split("/")[3] for m in refresh if m.topic.endswith("/values")} == {
        "skin",
        "emg",
        "belt",
        "hand",
    }
    assert any(m.topic.endswith("/health") for m in refresh) and tree.next_due_ms == 3000


def test_every_state_change_inside_a_batch_is_published_in_order() -> None:
    tree = JsonTree("gw")
    tree.update([Sample(1000, snapshot(1.0))], EXTRA)
    batch = [
        Sample(1050, snapshot(1.05, nodes={"belt": {"phase": "lost"}})),
        Sample(1100, snapshot(1.1)),
    ]
    states = [json.loads(m.payload) for m in tree.update(batch, EXTRA) if "belt/state" in m.topic]
    assert [(s["ts_ms"], s["live"]) for s in states] == [(1050, False), (1100, True)]


def test_reconnect_republishes_current_retained_state_behind_the_buffer() -> None:
    tree = JsonTree("gw")
    tree.update([Sample(1000, snapshot(1.0))], EXTRA)
    first, after = tree.on_connect(2000)
    assert [m.topic for m in first] == ["grasplink/gw/status"]
    assert json.loads(first[0].payload)["online"] is True and first[0].retain
    assert {m.topic.split("/", 2)[2] for m in after} >= {"alarms", "node/skin/state", "health"}
    will = tree.will(0)
    assert will.retain and json.loads(will.payload)["online"] is False


def test_commands_need_a_value_and_are_answered_on_the_reply_topic_with_the_id() -> None:
    tree = JsonTree("gw")
    incoming = tree.receive(
        "grasplink/gw/cmd/feedback_mode", b'{"value": "slip_speed", "id": "a1"}', False, 0
    )
    (request,) = incoming.requests
    assert request.command == Command("feedback_mode", "slip_speed")
    (reply,) = tree.reply(request, CommandResult("feedback_mode", True, "feedback mode x"), 5)
    assert reply.topic == "grasplink/gw/reply/feedback_mode" and not reply.retain
    assert json.loads(reply.payload) == {
        "ts_ms": 5,
        "id": "a1",
        "command": "feedback_mode",
        "accepted": True,
        "detail": "feedback mode x",
    }
    for payload, why in (
        (b"slip", "not JSON"),
        (b'"slip_speed"', '{"value"'),
        (b'{"id": 3}', '{"value"'),
    ):
        (refused,) = tree.receive("grasplink/gw/cmd/feedback_mode", payload, False, 0).requests
        assert why in refused.refused and refused.command is None
    (retained,) = tree.receive("grasplink/gw/cmd/x", b'{"value": 1}', True, 0).requests
    assert "retained" in retained.refused
    assert tree.receive("grasplink/other/cmd/x", b'{"value": 1}', False, 0).requests == []

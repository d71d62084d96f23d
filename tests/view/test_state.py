"""What the page shows, without a socket: the real JSON tree's messages fed to `ViewState`,
garbage and wrong schemas counted and named, staleness, history, several gateways."""

from __future__ import annotations

import json

import pytest

from grasplink.surfaces.telemetry.buffer import Sample
from grasplink.surfaces.telemetry.json_tree import JsonTree
from grasplink.surfaces.view.state import HISTORY_S, MAX_GATEWAYS, STALE_S, ViewState
from tests.telemetry.snapshots import snapshot

EXTRA = {"controls": {"reflex_enabled": True}, "telemetry": {"snapshots_dropped": 0}}
T0_MS = 1_800_000_000_000


def publish(view: ViewState, tree: JsonTree, t_s: float, **changes) -> None:
    """One snapshot through the real JSON tree into the view, received at `t_s`."""
    sample = Sample(T0_MS + int(t_s * 1000), snapshot(t_s, **changes))
    for message in tree.update([sample], EXTRA):
        view.feed(message.topic, message.payload, t_s)


def connected(gateway_id: str | None = None) -> ViewState:
    view = ViewState(gateway_id)
    view.broker_up(0.0)
    return view


def test_the_json_tree_of_a_live_gateway_shows_its_nodes_values_and_health() -> None:
    view, tree = connected(), JsonTree("arm-7")
    publish(view, tree, 1.0, skin={"grip_force_n": 4.5, "slip": True, "slip_speed_mm_s": 42.0})
    frame, _ = view.frame(1.2)
    gateway = frame["gateways"]["arm-7"]
    assert frame["broker"]["connected"] and not gateway["stale"] and gateway["problems"] == 0
    assert {name: n["phase"] for name, n in gateway["nodes"].items()} == dict.fromkeys(
        ("belt", "emg", "hand", "skin"), "operational"
    )
    skin = gateway["nodes"]["skin"]
    assert skin["values"]["slip_speed_mm_s"] == 42.0 and skin["values_age_s"] == pytest.approx(0.2)
    assert skin["loss_lost_packets"] == 0 and skin["nmt_state"] == "OPERATIONAL"
    assert gateway["age_s"] == pytest.approx(0.2)
    assert "loop_latency_p50_us" in gateway["health"]
    kinds = {kind for _, kind, _, _ in frame["points"]}
    assert kinds == {"skin", "emg", "belt", "hand", "loop"}  # loop: latency from health
    assert json.loads(json.dumps(frame, allow_nan=False)) == frame  # what the page is sent


def test_a_lost_node_and_its_alarm_show_as_the_gateway_reports_them() -> None:
    view, tree = connected(), JsonTree("gw")
    publish(view, tree, 1.0)
    publish(
        view, tree, 1.5, nodes={"belt": {"phase": "lost"}}, alarms={"belt.lost": "heartbeat lost"}
    )
    gateway = view.frame(1.6)[0]["gateways"]["gw"]
    assert (
        gateway["nodes"]["belt"]["phase"] == "lost" and gateway["nodes"]["belt"]["times_lost"] == 1
    )
    assert gateway["alarms"] == {"belt.lost": "heartbeat lost"}


def test_each_nodes_heartbeat_age_shows_and_is_overdue_past_the_consumer_time() -> None:
    """From health (once a second); overdue when older than the gateway's consumer time
    (500 ms here), as a node the gateway is about to lose, or has lost."""
    view, tree = connected(), JsonTree("gw")
    publish(view, tree, 1.0, nodes={"skin": {"heartbeat_age_s": 0.04}})
    nodes = view.frame(1.0)[0]["gateways"]["gw"]["nodes"]
    assert nodes["skin"]["heartbeat_consumer_ms"] == 500
    assert (nodes["skin"]["heartbeat_age_s"], nodes["skin"]["heartbeat_overdue"]) == (0.04, False)
    assert (nodes["belt"]["heartbeat_age_s"], nodes["belt"]["heartbeat_overdue"]) == (None, None)
    silent = {"skin": {"heartbeat_age_s": 0.501, "phase": "lost"}}
    publish(view, tree, 2.0, nodes=silent, alarms={"skin.lost": "heartbeat lost"})
    skin = view.frame(2.0)[0]["gateways"]["gw"]["nodes"]["skin"]
    assert (skin["heartbeat_age_s"], skin["heartbeat_overdue"]) == (0.501, True)


@pytest.mark.parametrize(
    ("topic", "payload", "problem"),
    [
        ("grasplink/gw/health", b"\xff\xfe", "health: not JSON"),
        ("grasplink/gw/health", b"[1, 2]", "health: expected a JSON object, got list"),
        ("grasplink/gw/health", b'{"uptime_s": 1}', "health: ts_ms: expected whole milliseconds"),
        ("grasplink/gw/alarms", b"", "alarms: empty payload"),
        ("grasplink/gw/status", b'{"ts_ms": 1, "online": "yes"}', "status: online: expected"),
        (
            "grasplink/gw/node/skin/values",
            b'{"ts_ms": 1, "grip_force_n": "heavy"}',
            'node/skin/values: grip_force_n: expected a number or null, got "heavy"',
        ),
        (
            "grasplink/gw/node/skin/values",
            b'{"ts_ms": 1, "grip_force_n": NaN}',
            "node/skin/values: not JSON",
        ),
        (
            "grasplink/gw/node/belt/state",
            b'{"ts_ms": 1, "phase": "dancing"}',
            "node/belt/state: phase: expected one of",
        ),
        ("grasplink/gw/node/hand/values", b"[" * 5000, "node/hand/values: JSON nested deeper"),
        (
            "grasplink/gw/health",
            b'{"ts_ms": 1, "loss": {"skin": 3}}',
            "health: loss.skin: expected",
        ),
        (
            "grasplink/gw/health",
            b'{"ts_ms": 1, "heartbeat_age_s": {"skin": "old"}}',
            'health: heartbeat_age_s.skin: expected a number or null, got "old"',
        ),
        ("grasplink/gw/whatever", b'{"ts_ms": 1}', "whatever: not a topic of the JSON tree"),
    ],
)
def test_garbage_is_counted_and_named_and_the_last_good_values_stay(
    topic: str, payload: bytes, problem: str
) -> None:
    view, tree = connected(), JsonTree("gw")
    publish(view, tree, 1.0, skin={"grip_force_n": 4.5})
    before = view.frame(1.0)[0]["gateways"]["gw"]
    view.feed(topic, payload, 1.1)
    after = view.frame(1.1)[0]["gateways"]["gw"]
    assert after["problems"] == 1 and after["last_problem"].startswith(problem), after
    assert after["nodes"]["skin"]["values"] == before["nodes"]["skin"]["values"]
    assert after["messages"] == before["messages"]


def test_messages_outside_any_gateways_tree_are_counted_by_the_view() -> None:
    view = connected()
    view.feed("grasplink/a b/health", b'{"ts_ms": 1}', 1.0)
    view.feed("grasplink", b"{}", 1.0)
    frame = view.frame(1.0)[0]
    assert frame["problems"] == 2 and frame["gateways"] == {}
    assert "not a topic of the JSON tree" in frame["last_problem"]


def test_commands_and_replies_on_the_tree_are_not_problems() -> None:
    view = connected()
    view.feed("grasplink/gw/cmd/feedback_mode", b"garbage", 1.0)
    view.feed("grasplink/gw/reply/feedback_mode", b'{"ts_ms": 1}', 1.0)
    assert view.frame(1.0)[0]["problems"] == 0 and view.gateways == {}


def test_a_gateway_is_stale_past_the_bound_offline_on_its_will_and_with_the_broker_away() -> None:
    view, tree = connected(), JsonTree("gw")
    publish(view, tree, 1.0)
    assert not view.frame(1.0 + STALE_S)[0]["gateways"]["gw"]["stale"]
    assert view.frame(1.01 + STALE_S)[0]["gateways"]["gw"]["stale"]
    view.feed(
        "grasplink/gw/status", b'{"ts_ms": 1, "online": false, "reason": "connection lost"}', 2
    )
    gateway = view.frame(2.0)[0]["gateways"]["gw"]
    assert gateway["stale"] and gateway["online"] is False
    assert gateway["offline_reason"] == "connection lost"
    view.feed("grasplink/gw/status", b'{"ts_ms": 2, "online": true}', 3.0)
    assert not view.frame(3.0)[0]["gateways"]["gw"]["stale"]
    view.broker_down(3.5, "[Errno 111] Connection refused")
    frame = view.frame(4.0)[0]
    assert frame["gateways"]["gw"]["stale"] and frame["broker"]["for_s"] == pytest.approx(0.5)
    assert frame["broker"] == {
        "connected": False,
        "error": "[Errno 111] Connection refused",
        "for_s": 0.5,
    }


def test_points_come_once_per_page_and_only_the_last_history_is_kept() -> None:
    view, tree = connected(), JsonTree("gw")
    for k in range(10):
        publish(view, tree, 1.0 + k * 0.05, skin={"grip_force_n": float(k)})
    first, cursor = view.frame(1.5)
    forces = [v["grip_force_n"] for _, kind, _, v in first["points"] if kind == "skin"]
    assert first["reset"] and forces == [float(k) for k in range(10)]
    publish(view, tree, 1.6, skin={"grip_force_n": 10.0})
    second, cursor = view.frame(1.6, cursor)
    assert not second["reset"]
    assert [v["grip_force_n"] for _, kind, _, v in second["points"] if kind == "skin"] == [10.0]
    assert view.frame(1.7, cursor)[0]["points"] == []
    late = view.frame(1.55 + HISTORY_S)[0]  # a page opened later gets what is kept
    assert [v["grip_force_n"] for _, kind, _, v in late["points"] if kind == "skin"] == [10.0]


def test_several_gateways_each_have_their_tree_and_an_id_given_shows_only_it() -> None:
    view = connected()
    for gid in ("arm-1", "arm-2"):
        publish(view, JsonTree(gid), 1.0)
    assert sorted(view.frame(1.0)[0]["gateways"]) == ["arm-1", "arm-2"]
    only = connected("arm-2")
    for gid in ("arm-1", "arm-2"):
        publish(only, JsonTree(gid), 1.0)
    assert list(only.frame(1.0)[0]["gateways"]) == ["arm-2"]


def test_gateways_past_the_bound_are_refused_not_kept() -> None:
    view = connected()
    for k in range(MAX_GATEWAYS + 3):
        view.feed(f"grasplink/gw{k}/status", b'{"ts_ms": 1, "online": true}', 1.0)
    frame = view.frame(1.0)[0]
    assert len(frame["gateways"]) == MAX_GATEWAYS and frame["problems"] == 3
    assert f"more than {MAX_GATEWAYS} gateways" in frame["last_problem"]


def test_a_device_node_shows_its_state_and_values_without_being_plotted() -> None:
    view = connected()
    view.feed("grasplink/gw/node/fsr/values", b'{"ts_ms": 5, "6041sub0": 567}', 1.0)
    frame = view.frame(1.0)[0]
    assert frame["gateways"]["gw"]["nodes"]["fsr"]["values"] == {"6041sub0": 567}
    assert frame["points"] == []

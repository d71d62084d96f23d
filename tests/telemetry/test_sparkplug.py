"""The Sparkplug B session without a broker: births, report by exception, device death and
rebirth, seq/bdSeq across sessions, store-and-forward as historical data, commands."""

from __future__ import annotations

from grasplink.gateway.commands import Command, CommandResult
from grasplink.profiles.kinds import KINDS
from grasplink.surfaces.telemetry import sparkplug_b_pb2 as pb
from grasplink.surfaces.telemetry.buffer import Message, Sample
from grasplink.surfaces.telemetry.protocol import Incoming
from grasplink.surfaces.telemetry.sparkplug import (
    BOOLEAN,
    DOUBLE,
    INT32,
    INT64,
    STRING,
    SparkplugSession,
    metric_value,
    set_value,
)
from tests.telemetry.host import SparkplugHost
from tests.telemetry.snapshots import snapshot

EXTRA = {"controls": {"reflex_enabled": True, "reflex_threshold_mm_s": 45.0}, "telemetry": {}}


def send(session: SparkplugSession, host: SparkplugHost, messages: list[Message]) -> list[Message]:
    """What the transport does: finalize each message as it goes out, feed the host."""
    sent = []
    for message in messages:
        final = session.finalize(message)
        if final is not None:
            host.feed(final.topic, final.payload)
            sent.append(final)
    return sent


def connected(t_ms: int = 1000) -> tuple[SparkplugSession, SparkplugHost, Message]:
    session = SparkplugSession("grp", "gw")
    host = SparkplugHost("grp", "gw")
    will = session.will(t_ms)
    first, after = session.on_connect(t_ms)
    send(session, host, first + after)
    return session, host, will


def test_will_is_an_ndeath_with_the_bdseq_of_the_nbirth_that_follows() -> None:
    _, host, will = connected()
    assert will.topic == "spBv1.0/grp/NDEATH/gw" and will.qos == 1 and not will.retain
    death = pb.Payload.FromString(will.payload)
    assert not death.HasField("seq")
    assert {m.name: metric_value(m) for m in death.metrics} == {"bdSeq": 0}
    assert death.metrics[0].datatype == INT64
    assert host.kinds() == ["NBIRTH"] and host.bdseq == 0 and not host.errors
    host.feed(will.topic, will.payload)  # the broker publishes it when the link dies
    assert not host.errors and not host.online


def test_births_then_data_report_only_what_changed_with_its_snapshot_time() -> None:
    session, host, _ = connected()
    send(session, host, session.update([Sample(2000, snapshot(1.0))], EXTRA))
    kinds = host.kinds()
    assert kinds[0] == "NBIRTH" and kinds[5:] == ["NDATA"]
    assert sorted(kinds[1:5]) == ["DBIRTH/belt", "DBIRTH/emg", "DBIRTH/hand", "DBIRTH/skin"]
    skin_birth = next(m for m in host.messages if m.kind == "DBIRTH" and m.device == "skin")
    types = {m.name: m.datatype for m in skin_birth.payload.metrics}
    assert types["grip_force_n"] == DOUBLE and types["slip"] == BOOLEAN
    assert types["State/phase"] == STRING and types["Node Control/Restart"] == BOOLEAN
    before = len(host.messages)
    slipping = snapshot(1.05, skin={"slip": True, "slip_speed_mm_s": 40.0, "grip_force_n": 5.0})
    send(session, host, session.update([Sample(2050, slipping)], EXTRA))
    data = [m for m in host.messages[before:] if m.kind == "DDATA"]
    assert [m.device for m in data] == ["skin"]
    assert data[0].metrics() == {"slip": True, "slip_speed_mm_s": 40.0, "grip_force_n": 5.0}
    assert {m.timestamp for m in data[0].payload.metrics} == {2050}
    assert not host.errors


def test_a_devices_heartbeat_age_is_born_and_then_sent_once_a_second() -> None:
    """It changes with every snapshot: reported like the fast counters, not on change."""
    session, host, _ = connected()
    aged = {"nodes": {"skin": {"heartbeat_age_s": 0.04}}}
    send(session, host, session.update([Sample(2000, snapshot(1.0, **aged))], EXTRA))
    birth = next(m for m in host.messages if m.kind == "DBIRTH" and m.device == "skin")
    assert {m.name: m.datatype for m in birth.payload.metrics}["State/heartbeat_age_s"] == DOUBLE
    assert birth.metrics()["State/heartbeat_age_s"] == 0.04
    assert birth.metrics()["State/heartbeat_consumer_ms"] == 500
    before = len(host.messages)
    for k in range(1, 21):  # 2050 .. 3000 ms: one new second of the clock
        older = {"nodes": {"skin": {"heartbeat_age_s": 0.04 + k / 20}}}
        send(session, host, session.update([Sample(2000 + 50 * k, snapshot(1.0, **older))], EXTRA))
    ages = [
        value
        for m in host.messages[before:]
        if m.kind == "DDATA" and m.device == "skin"
        for value in m.values_of("State/heartbeat_age_s")
    ]
    assert ages == [(3000, 1.04)] and not host.errors


def test_a_batch_carries_every_change_with_its_own_timestamp() -> None:
    session, host, _ = connected()
    send(session, host, session.update([Sample(2000, snapshot(1.0))], EXTRA))
    batch = [
        Sample(2000 + 50 * k, snapshot(1.0 + k / 20, skin={"grip_force_n": float(k)}))
        for k in range(1, 5)
    ]
    sent = send(session, host, session.update(batch, EXTRA))
    (ddata,) = [m for m in host.messages[-len(sent) :] if m.kind == "DDATA"]
    forces = ddata.values_of("grip_force_n")
    assert forces == [(2050, 1.0), (2100, 2.0), (2150, 3.0), (2200, 4.0)]


def test_a_lost_node_is_a_device_death_and_its_return_a_new_birth() -> None:
    session, host, _ = connected()
    send(session, host, session.update([Sample(2000, snapshot(1.0))], EXTRA))
    lost = snapshot(1.05, nodes={"skin": {"phase": "lost", "nmt_state": None}})
    send(session, host, session.update([Sample(2050, lost)], EXTRA))
    assert host.kinds()[-2:] == ["DDEATH/skin", "NDATA"]
    assert host.values[None]["Gateway/nodes_live"] == "emg,belt,hand"
    assert "skin" not in host.born
    preop = snapshot(1.1, nodes={"skin": {"phase": "starting", "nmt_state": "PRE_OPERATIONAL"}})
    send(session, host, session.update([Sample(2100, preop)], EXTRA))
    assert "skin" not in host.born  # not operational yet: still dead
    send(session, host, session.update([Sample(2150, snapshot(1.15))], EXTRA))
    assert "DBIRTH/skin" in host.kinds()[-2:] and "skin" in host.born
    assert not host.errors


def test_seq_wraps_from_255_to_0() -> None:
    session, host, _ = connected()
    for k in range(300):
        snap = snapshot(1.0 + k / 20, skin={"grip_force_n": float(k)})
        send(session, host, session.update([Sample(2000 + 50 * k, snap)], EXTRA))
    seqs = [m.payload.seq for m in host.messages]
    assert 255 in seqs and seqs[seqs.index(255) + 1] == 0
    assert not host.errors


def test_rebirth_command_sends_births_again_with_seq_0_and_the_same_bdseq() -> None:
    session, host, _ = connected()
    send(session, host, session.update([Sample(2000, snapshot(1.0))], EXTRA))
    command = pb.Payload(timestamp=3000)
    set_value(command.metrics.add(name="Node Control/Rebirth"), BOOLEAN, True)
    incoming = session.receive(
        "spBv1.0/grp/NCMD/gw", command.SerializeToString(), retain=False, t_ms=3000
    )
    assert not incoming.requests
    before = len(host.messages)
    send(session, host, incoming.messages)
    reborn = host.messages[before:]
    assert [m.kind for m in reborn] == ["NBIRTH"] + ["DBIRTH"] * 4
    assert reborn[0].payload.seq == 0 and reborn[0].metrics()["bdSeq"] == 0
    assert not host.errors


def test_outage_data_is_replayed_as_historical_after_the_new_session_births() -> None:
    session, host, _ = connected()
    send(session, host, session.update([Sample(2000, snapshot(1.0))], EXTRA))
    # The broker is gone: data keeps being made and buffered.
    buffered = []
    for k in range(1, 4):
        snap = snapshot(1.0 + k / 20, skin={"grip_force_n": float(k)})
        buffered += session.update([Sample(2000 + 50 * k, snap)], EXTRA)
    will = session.will(5000)
    assert pb.Payload.FromString(will.payload).metrics[0].long_value == 1
    first, after = session.on_connect(5000)
    send(session, host, first + after + buffered)
    kinds = host.kinds()
    rebirth = kinds.index("NBIRTH", 1)
    assert host.messages[rebirth].metrics()["bdSeq"] == 1
    replayed = [m for m in host.messages[rebirth:] if m.kind == "DDATA"]
    assert [m.metrics()["grip_force_n"] for m in replayed] == [1.0, 2.0, 3.0]
    assert all(m.is_historical for r in replayed for m in r.payload.metrics)
    assert host.values["skin"]["grip_force_n"] == 3.0  # the birth had the latest value
    assert not host.errors


def test_stale_births_are_dropped_and_data_of_an_unborn_device_counted() -> None:
    session, host, _ = connected()
    send(session, host, session.update([Sample(2000, snapshot(1.0))], EXTRA))
    gone = snapshot(1.05, nodes={"skin": {"phase": "lost"}})
    buffered = session.update([Sample(2050, snapshot(1.02, skin={"grip_force_n": 9.0}))], EXTRA)
    buffered += session.update([Sample(2100, gone)], EXTRA)
    session.will(5000)
    first, _ = session.on_connect(5000)
    send(session, host, first + buffered)
    second = host.kinds()[host.kinds().index("NBIRTH", 1) :]
    assert "DDEATH/skin" not in second and "DBIRTH/skin" not in second  # the new session's
    assert "skin" not in host.born  # births are the current truth: skin is lost
    assert session.historical_dropped == 1 and not host.errors


def test_ncmd_control_metrics_become_gateway_commands_and_replies_go_in_ndata() -> None:
    session, host, _ = connected()
    payload = pb.Payload(timestamp=3000)
    set_value(payload.metrics.add(name="Control/feedback_mode"), STRING, "slip_speed")
    set_value(payload.metrics.add(name="Control/reflex_threshold_mm_s"), DOUBLE, 30.0)
    set_value(payload.metrics.add(name="Control/emg_calibration/e_min_uv"), DOUBLE, 40.0)
    set_value(payload.metrics.add(name="Control/emg_calibration/e_max_uv"), DOUBLE, 400.0)
    set_value(payload.metrics.add(name="Gateway/uptime_s"), DOUBLE, 1.0)
    incoming = session.receive("spBv1.0/grp/NCMD/gw", payload.SerializeToString(), False, 3000)
    commands = [r.command for r in incoming.requests if r.command]
    assert commands == [
        Command("feedback_mode", "slip_speed"),
        Command("reflex_threshold_mm_s", 30.0),
        Command("emg_calibration", {"e_min_uv": 40.0, "e_max_uv": 400.0}),
    ]
    (refused,) = [r for r in incoming.requests if r.refused]
    assert "not a writable metric" in refused.refused
    request = incoming.requests[0]
    result = CommandResult("feedback_mode", False, "feedback_mode: expected ...")
    send(session, host, session.reply(request, result, 3001))
    assert host.messages[-1].kind == "NDATA"
    assert host.messages[-1].metrics() == {
        "Command Reply/command": "feedback_mode",
        "Command Reply/accepted": False,
        "Command Reply/detail": "feedback_mode: expected ...",
    }


def test_dcmd_restart_names_the_device_and_retained_or_garbage_commands_are_refused() -> None:
    session, _, _ = connected()
    payload = pb.Payload(timestamp=3000)
    set_value(payload.metrics.add(name="Node Control/Restart"), BOOLEAN, True)
    data = payload.SerializeToString()
    incoming = session.receive("spBv1.0/grp/DCMD/gw/belt", data, False, 3000)
    assert [r.command for r in incoming.requests] == [Command("restart_node", "belt")]
    retained = session.receive("spBv1.0/grp/DCMD/gw/belt", data, True, 3000)
    assert "retained" in retained.requests[0].refused
    garbage = session.receive("spBv1.0/grp/NCMD/gw", b"\xff\xff\xff", False, 3000)
    assert "not a Sparkplug B payload" in garbage.requests[0].refused
    half = pb.Payload()
    set_value(half.metrics.add(name="Control/emg_calibration/e_min_uv"), DOUBLE, 1.0)
    lone = session.receive("spBv1.0/grp/NCMD/gw", half.SerializeToString(), False, 3000)
    assert "must come together" in lone.requests[0].refused
    assert session.receive("spBv1.0/other/NCMD/gw", data, False, 3000).requests == []


def test_signed_metric_values_round_trip_through_the_protobuf_runtime() -> None:
    for datatype, value in ((INT32, -4500), (INT64, -1), (INT32, 7000), (STRING, None)):
        metric = pb.Payload.Metric(name="x")
        set_value(metric, datatype, value)
        decoded = pb.Payload.Metric.FromString(metric.SerializeToString())
        assert metric_value(decoded) == value


def test_births_define_an_alias_per_metric_unique_across_the_edge_node() -> None:
    session, host, _ = connected()
    send(session, host, session.update([Sample(2000, snapshot(1.0))], EXTRA))
    births = [m for m in host.messages if m.kind in ("NBIRTH", "DBIRTH")]
    aliases = [metric.alias for seen in births for metric in seen.payload.metrics]
    assert len(births) == 5 and len(aliases) == len(set(aliases))
    metrics = [m for seen in births for m in seen.payload.metrics]
    assert all(m.name and m.HasField("alias") and m.datatype for m in metrics)
    assert not host.errors


def test_data_carries_aliases_only_and_decodes_through_the_births() -> None:
    session, host, _ = connected()
    send(session, host, session.update([Sample(2000, snapshot(1.0))], EXTRA))
    moving = snapshot(1.05, belt={"velocity_mrad_s": -4500}, skin={"slip": True})
    sent = send(session, host, session.update([Sample(2050, moving)], EXTRA))
    ddata = [pb.Payload.FromString(m.payload) for m in sent if "/DDATA/" in m.topic]
    metrics = [m for payload in ddata for m in payload.metrics]
    assert len(metrics) == 2
    assert all(not m.name and not m.HasField("datatype") and m.alias for m in metrics)
    decoded = {seen.device: seen.metrics() for seen in host.messages if seen.kind == "DDATA"}
    assert decoded == {"belt": {"velocity_mrad_s": -4500}, "skin": {"slip": True}}
    assert not host.errors


def test_the_appended_seq_is_the_payload_the_runtime_serialises_with_its_seq() -> None:
    session, host, _ = connected()
    for message in send(session, host, session.update([Sample(2000, snapshot(1.0))], EXTRA)):
        payload = pb.Payload.FromString(message.payload)
        assert payload.SerializeToString() == message.payload and payload.HasField("seq")


def test_ncmd_by_alias_is_a_command_and_an_unknown_alias_is_refused() -> None:
    session, host, _ = connected()
    alias = {name: m.alias for name, m, _ in host.messages[0].named}
    payload = pb.Payload(timestamp=3000)
    payload.metrics.add(alias=alias["Control/reflex_threshold_mm_s"], double_value=30.0)
    payload.metrics.add(alias=alias["Control/feedback_mode"], string_value="off")
    payload.metrics.add(alias=999_999, boolean_value=True)
    incoming = session.receive("spBv1.0/grp/NCMD/gw", payload.SerializeToString(), False, 3000)
    assert [r.command for r in incoming.requests if r.command] == [
        Command("reflex_threshold_mm_s", 30.0),
        Command("feedback_mode", "off"),
    ]
    (refused,) = [r.refused for r in incoming.requests if r.refused]
    assert "alias 999999" in refused


def test_births_wait_for_the_primary_host_and_what_waited_follows_as_historical() -> None:
    session = SparkplugSession("grp", "gw", primary_host_id="scada")
    host = SparkplugHost("grp", "gw")
    assert "spBv1.0/STATE/scada" in session.subscriptions()
    session.will(1000)
    first, after = session.on_connect(1000)
    assert first == after == [] and session.holding
    waited = session.update([Sample(2000, snapshot(1.0))], EXTRA)
    waited += session.update([Sample(2050, snapshot(1.05, skin={"grip_force_n": 3.0}))], EXTRA)
    offline = session.receive("spBv1.0/STATE/scada", host.state(False, 5), True, 2100)
    assert offline.urgent == [] and not offline.reconnect and session.holding
    online = session.receive("spBv1.0/STATE/scada", host.state(True, 10), True, 2100)
    assert not session.holding and online.urgent
    send(session, host, online.urgent + waited)
    kinds = host.kinds()
    assert kinds[0] == "NBIRTH" and sorted(kinds[1:5]) == [f"DBIRTH/{k}" for k in sorted(KINDS)]
    assert kinds.count("NBIRTH") == 1 and kinds.count("DBIRTH/skin") == 1  # the waiting ones
    (replayed,) = [m for m in host.messages if m.kind == "DDATA"]  # were of no session: gone
    assert replayed.metrics() == {"grip_force_n": 3.0} and replayed.payload.metrics[0].is_historical
    assert not host.errors


def test_the_primary_host_going_offline_asks_for_a_new_session_and_a_new_bdseq() -> None:
    session = SparkplugSession("grp", "gw", primary_host_id="scada")
    host = SparkplugHost("grp", "gw")
    state = "spBv1.0/STATE/scada"
    session.will(1000)
    session.on_connect(1000)
    send(session, host, session.receive(state, host.state(True, 10), True, 1).urgent)
    stale = session.receive("spBv1.0/STATE/scada", host.state(False, 9), False, 2)
    assert not stale.reconnect  # older than the STATE applied: a stale copy
    assert session.receive("spBv1.0/STATE/scada", b"not json", False, 2) == Incoming()
    gone = session.receive("spBv1.0/STATE/scada", host.state(False, 20), False, 3)
    assert gone.reconnect and session.holding
    assert pb.Payload.FromString(session.will(4000).payload).metrics[0].long_value == 1
    assert session.on_connect(4000) == ([], [])  # waits for the host again
    send(session, host, session.receive(state, host.state(True, 30), True, 5).urgent)
    births = [m for m in host.messages if m.kind == "NBIRTH"]
    assert [b.metrics()["bdSeq"] for b in births] == [0, 1] and not host.errors


def test_a_bdseq_kept_from_a_previous_run_goes_on_from_there() -> None:
    assert (
        pb.Payload.FromString(SparkplugSession("g", "e", last_bdseq=7).will(0).payload)
        .metrics[0]
        .long_value
        == 8
    )
    wrapped = SparkplugSession("g", "e", last_bdseq=255).will(0)
    assert pb.Payload.FromString(wrapped.payload).metrics[0].long_value == 0

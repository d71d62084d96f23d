"""A device node through a real mosquitto: its JSON subtree read by an MQTT client, and its
Sparkplug device read by pysparkplug (`spb_check.py`, a third-party host in `.venv-check`),
with the live gateway mastering a generic node built from a vendor's file."""

from __future__ import annotations

import json
import uuid
from pathlib import Path

import pytest

from grasplink.bus.runner import NodeRunner
from grasplink.bus.url import open_bus
from grasplink.gateway.live import LiveGateway
from grasplink.gateway.snapshot import NodePhase
from grasplink.surfaces.telemetry import TelemetryPublisher, parse_broker_url
from tests.device_nodes import GRIP, GRIP_KEY, STATUS_KEY, STATUSWORD, device_config, fsr_node
from tests.live import wait_until
from tests.telemetry.broker import Mosquitto, Recorder
from tests.telemetry.test_sparkplug_third_party import Checker

pytestmark = pytest.mark.slow


def test_a_device_node_is_read_by_mqtt_clients_and_a_third_party_sparkplug_host(
    broker: Mosquitto, tmp_path: Path
) -> None:
    checker = Checker(broker, "--until-ndeath", "--timeout-s", "90", "--grace-s", "0.5")
    recorder = Recorder(broker, ["grasplink/devs/node/fsr/#"])
    channel = f"virtual:devtel-{uuid.uuid4().hex[:12]}"
    config = device_config(tmp_path)  # (writes the vendor's file)
    device = fsr_node(tmp_path, values={(GRIP, 0): 2.5, (STATUSWORD, 0): 0x0237})
    bus = open_bus(channel)
    runner = NodeRunner(bus, [device], name="test fsr")
    try:
        with LiveGateway(channel, config) as live:
            runner.start()
            url = parse_broker_url(broker.url)
            with TelemetryPublisher(live.edge, url, "devs", state_dir=tmp_path / "state"):
                wait_until(
                    lambda: (
                        live.gateway.latest is not None
                        and live.gateway.latest.nodes["fsr"].phase is NodePhase.OPERATIONAL
                    ),
                    timeout_s=30,
                    what="the device operational",
                )
                assert checker.wait_for(
                    lambda lines: any(
                        line.get("type") == "DDATA" and line.get("device") == "fsr"
                        for line in lines
                    ),
                    timeout_s=30,
                ), checker.lines
    finally:
        runner.stop()
        bus.shutdown()
    code = checker.finish()
    assert checker.of("violation") == [] and code == 0
    messages = [m for m in checker.of("message") if m.get("edge") == "devs"]
    (birth,) = [m for m in messages if m["type"] == "DBIRTH"]
    assert birth["device"] == "fsr"  # its births' properties decoded without a finding
    assert birth["metrics"][:2] == [STATUS_KEY, GRIP_KEY] and "State/phase" in birth["metrics"]
    data = [m for m in messages if m["type"] == "DDATA"]
    assert data and all(m["resolved"] == len(m["metrics"]) for m in data)
    assert messages[-1]["type"] == "NDEATH"
    # the JSON subtree, as any MQTT client reads it
    recorder.flush()
    received = {m.topic: m for m in recorder.taken()}
    recorder.close()
    base = "grasplink/devs/node/fsr"
    values = json.loads(received[f"{base}/values"].payload)
    assert values[GRIP_KEY] == 2.5 and values[STATUS_KEY] == 0x0237
    objects = json.loads(received[f"{base}/objects"].payload)["objects"]
    assert [(o["key"], o["type"], o["unit"]) for o in objects] == [
        (STATUS_KEY, "UNSIGNED16", ""),
        (GRIP_KEY, "REAL32", "N"),
    ]
    assert json.loads(received[f"{base}/state"].payload)["live"] is True

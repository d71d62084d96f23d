"""Retained commands through a real mosquitto: refused whether the broker delivers them at
subscribe time (retain set by MQTT's rules) or forwards one published retained while the
gateway is subscribed (MQTT 3.1.1 clears the flag then; the links subscribe with MQTT 5's
retain-as-published so it tells the truth)."""

from __future__ import annotations

import json

import pytest

from grasplink.surfaces.telemetry import TelemetryPublisher, parse_broker_url
from grasplink.surfaces.telemetry import sparkplug_b_pb2 as pb
from grasplink.surfaces.telemetry.sparkplug import STRING, set_value
from tests.telemetry.broker import FakeGateway, Mosquitto, Recorder
from tests.telemetry.host import SparkplugHost

pytestmark = pytest.mark.slow
REFUSED = "retained commands are not executed (publish with retain off)"


def ncmd(mode: str) -> bytes:
    payload = pb.Payload(timestamp=1)
    set_value(payload.metrics.add(name="Control/feedback_mode"), STRING, mode)
    return payload.SerializeToString()


def replies(recorder: Recorder) -> dict[object, dict]:
    return {
        json.loads(m.payload)["id"]: json.loads(m.payload)
        for m in recorder.taken()
        if "/reply/" in m.topic
    }


def sparkplug_replies(recorder: Recorder) -> list[dict]:
    host = SparkplugHost("grasplink", "gw")
    for message in recorder.taken():
        if message.topic.startswith("spBv1.0/"):
            host.feed(message.topic, message.payload)
    assert host.errors == []
    return [
        seen.metrics()
        for seen in host.messages
        if seen.kind == "NDATA" and "Command Reply/command" in seen.metrics()
    ]


def test_a_retained_command_is_refused_at_subscribe_time_and_when_forwarded_live(
    broker: Mosquitto, fake: FakeGateway
) -> None:
    mode = fake.real.feedback.mode.value
    recorder = Recorder(broker, ["grasplink/gw/reply/#", "spBv1.0/grasplink/+/gw/#"])
    # stored before the gateway subscribes: delivered with the retain flag by any broker
    recorder.publish(
        "grasplink/gw/cmd/feedback_mode", b'{"value": "off", "id": "stored"}', retain=True
    )
    recorder.publish("spBv1.0/grasplink/NCMD/gw", ncmd("off"), retain=True)
    publisher = TelemetryPublisher(fake, parse_broker_url(broker.url), "gw")
    with publisher:
        assert recorder.wait_for(lambda m: "/reply/" in m.topic)
        assert recorder.wait_for(lambda m: m.topic.endswith("NDATA/gw"))
        # published retained while the gateway is subscribed: forwarded live
        recorder.publish(
            "grasplink/gw/cmd/feedback_mode", b'{"value": "off", "id": "live"}', retain=True
        )
        recorder.publish("spBv1.0/grasplink/NCMD/gw", ncmd("grip_force"), retain=True)
        recorder.publish("grasplink/gw/cmd/reflex_enabled", b'{"value": false, "id": "plain"}')
        assert recorder.wait_for(
            lambda m: "live" in replies(recorder) and "plain" in replies(recorder)
        )
        assert recorder.wait_for(lambda m: len(sparkplug_replies(recorder)) >= 2)
    answers = replies(recorder)
    for request_id in ("stored", "live"):
        assert answers[request_id]["accepted"] is False
        assert answers[request_id]["detail"] == REFUSED
    assert answers["plain"]["accepted"] is True  # a command without retain runs
    assert (
        sparkplug_replies(recorder)[:2]
        == [
            {
                "Command Reply/command": "NCMD",
                "Command Reply/accepted": False,
                "Command Reply/detail": REFUSED,
            }
        ]
        * 2
    )
    assert fake.real.feedback.mode.value == mode  # no retained command changed it
    recorder.close()

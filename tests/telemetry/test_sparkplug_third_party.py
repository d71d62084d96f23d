"""The gateway's Sparkplug B output read by a third-party implementation: pysparkplug
(its own protobuf bindings and payload classes) in `spb_check.py`, a host in its own
virtual environment (`.venv-check`, made by `make test`: pysparkplug pins paho-mqtt<2),
on a real mosquitto, against `grasplink gateway` as users run it. Every other Sparkplug
test decodes with our own generated code, which shares any misreading of the schema or
the specification with the encoder; this one does not."""

from __future__ import annotations

import itertools
import json
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from grasplink.surfaces.telemetry import sparkplug_b_pb2 as pb
from grasplink.surfaces.telemetry.sparkplug import ALIASES, SparkplugSession
from tests.telemetry.broker import Mosquitto, Recorder

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
CHECK_PYTHON = ROOT / ".venv-check" / "bin" / "python"
SPB_CHECK = Path(__file__).with_name("spb_check.py")
KINDS = {"skin", "emg", "belt", "hand"}


class Checker:
    """spb_check.py running against `broker`: its JSON lines, collected as they come."""

    def __init__(self, broker: Mosquitto, *options: str) -> None:
        if not CHECK_PYTHON.exists():
            pytest.skip(f"{CHECK_PYTHON.parent.parent.name} missing: `make test` creates it")
        command = [str(CHECK_PYTHON), str(SPB_CHECK), "--port", str(broker.port), *options]
        self.process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.lines: list[dict[str, Any]] = []
        self.ready = threading.Event()
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()
        if not self.ready.wait(20):
            self.process.kill()
            raise AssertionError(f"spb_check.py did not subscribe: {self.process.stderr.read()}")  # type: ignore[union-attr]

    def _read(self) -> None:
        for text in self.process.stdout:  # type: ignore[union-attr]
            line = json.loads(text)
            self.lines.append(line)
            if line["event"] == "ready":
                self.ready.set()

    def finish(self, timeout_s: float = 30) -> int:
        try:
            code = self.process.wait(timeout_s)
        finally:
            if self.process.poll() is None:
                self.process.kill()
                self.process.wait(5)
        self.reader.join(5)
        assert "Traceback" not in (stderr := self.process.stderr.read()), stderr  # type: ignore[union-attr]
        return code

    def wait_for(self, predicate, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and self.process.poll() is None:
            if predicate(list(self.lines)):
                return True
            time.sleep(0.05)
        return predicate(list(self.lines))

    def of(self, event: str) -> list[dict[str, Any]]:
        return [line for line in self.lines if line["event"] == event]


def gateway_config(folder: Path) -> Path:
    """A gateway configuration keeping telemetry's state (the bdSeq) in `folder`."""
    config = folder / "gateway.toml"
    config.write_text(f'[telemetry]\nstate_dir = "{folder / "state"}"\n')
    return config


def belt_born_again(lines: list[dict[str, Any]]) -> bool:
    kinds = [(line.get("type"), line.get("device")) for line in lines]
    return ("DDEATH", "belt") in kinds and ("DBIRTH", "belt") in kinds[
        kinds.index(("DDEATH", "belt")) :
    ]


def test_pysparkplug_reads_the_gateway_births_data_rebirth_and_death_without_a_violation(
    broker: Mosquitto, tmp_path: Path
) -> None:
    # once the four devices are born, the host asks for a rebirth (NCMD by alias) and a
    # second later restarts the belt node (DCMD); when the belt is born again and data
    # has flowed a little longer, the gateway is stopped (SIGTERM: a clean stop, NDEATH)
    checker = Checker(
        broker,
        *("--until-ndeath", "--timeout-s", "90", "--devices", "4", "--rebirth-after-s", "1"),
        *("--restart-device", "belt", "--restart-after-s", "2"),
    )
    log = tmp_path / "gateway.log"
    with log.open("wb") as out:
        gateway = subprocess.Popen(
            [
                *(sys.executable, "-m", "grasplink.cli", "gateway", "--with-nodes"),
                *("--bus", "virtual:spb-third-party", "--duration", "60"),
                *("--config", str(gateway_config(tmp_path))),
                *("--mqtt", broker.url, "--mqtt-id", "third"),
            ],
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=ROOT,
        )
    try:
        assert checker.wait_for(belt_born_again, timeout_s=45), checker.lines
        time.sleep(1.0)
        gateway.send_signal(signal.SIGTERM)
        code = gateway.wait(20)  # 128 + 15: stopped by SIGTERM, cleanly
        assert code == 128 + signal.SIGTERM, log.read_text()
    finally:
        if gateway.poll() is None:
            gateway.kill()
            gateway.wait(5)
    code = checker.finish()
    assert checker.of("violation") == [] and code == 0
    (end,) = checker.of("end")
    assert end["reason"] == "ndeath"
    commands = ("NCMD", "DCMD")  # the host's own, read back
    messages = [
        m for m in checker.of("message") if m.get("edge") == "third" and m["type"] not in commands
    ]
    kinds = [m["type"] + (f"/{m['device']}" if m["device"] else "") for m in messages]
    # two births in one MQTT session (the rebirth keeps bdSeq), each followed by all devices
    births = [i for i, m in enumerate(messages) if m["type"] == "NBIRTH"]
    assert len(births) == 2 and [messages[i]["bdSeq"] for i in births] == [0, 0]
    # the first NBIRTH carries the gateway's current values, not nulls for what it knew
    known = {"Gateway/nodes_live", "Gateway/uptime_s", "Control/feedback_mode"}
    known |= {"Control/reflex_enabled", "Control/reflex_threshold_mm_s"}
    assert not known & set(messages[births[0]]["null_metrics"])
    after_rebirth = kinds[births[1] + 1 : births[1] + 5]
    assert sorted(after_rebirth) == sorted(f"DBIRTH/{kind}" for kind in KINDS)
    assert {k for k in kinds[: births[1]] if k.startswith("DBIRTH")} == {
        f"DBIRTH/{kind}" for kind in KINDS
    }
    # the restarted belt: DDEATH, then born again
    death = kinds.index("DDEATH/belt")
    assert death > births[1] and "DBIRTH/belt" in kinds[death:]
    # seq: 0 at NBIRTH, then +1 (mod 256) on every message of the edge node
    sequenced = [m for m in messages if m["type"] != "NDEATH"]
    for before, after in itertools.pairwise(sequenced):
        expected = 0 if after["type"] == "NBIRTH" else (before["seq"] + 1) % 256
        assert after["seq"] == expected, (before, after)
    # data flowed, by alias only, every alias resolved through the births
    data = [m for m in messages if m["type"] in ("NDATA", "DDATA")]
    assert sum(m["type"] == "NDATA" for m in data) >= 3
    assert {m["device"] for m in data if m["type"] == "DDATA"} == KINDS
    assert all(m["metrics"] and m["resolved"] == len(m["metrics"]) for m in data)
    # the clean stop: NDEATH last, QoS 1, with the bdSeq of the births it ends
    ndeath = messages[-1]
    assert ndeath["type"] == "NDEATH" and ndeath["seq"] is None and ndeath["qos"] == 1
    assert ndeath["bdSeq"] == 0 and ndeath["matches_nbirth"] is True
    sent = [(line["type"], line["metrics"]) for line in checker.of("sent")]
    assert sent == [("NCMD", ["Node Control/Rebirth"]), ("DCMD", ["Node Control/Restart"])]


def test_the_third_party_host_reports_a_broken_stream(broker: Mosquitto) -> None:
    """The checker can fail: a seq gap, an alias no birth defined and an NDEATH whose bdSeq
    is not the NBIRTH's are each reported under their Sparkplug 3.0 rule."""
    checker = Checker(broker, "--until-ndeath", "--timeout-s", "20", "--grace-s", "0.2")
    session = SparkplugSession("grasplink", "broken")
    now = int(time.time() * 1000)
    session.will(now)
    births, _ = session.on_connect(now)
    nbirth = session.finalize(births[0])
    assert nbirth is not None
    uptime = ALIASES[None]["Gateway/uptime_s"]
    gap = pb.Payload(timestamp=now, seq=2)  # after the NBIRTH's 0
    gap.metrics.add(alias=uptime, timestamp=now, double_value=1.0)
    unknown = pb.Payload(timestamp=now, seq=3)
    unknown.metrics.add(alias=9999, timestamp=now, double_value=1.0)
    wrong_bdseq = pb.Payload(timestamp=now)
    wrong_bdseq.metrics.add(name="bdSeq", timestamp=now, datatype=4, long_value=7)
    publisher = Recorder(broker, ["grasplink-test/unused"])
    for topic, payload, qos in (
        (nbirth.topic, nbirth.payload, 0),
        ("spBv1.0/grasplink/NDATA/broken", gap.SerializeToString(), 0),
        ("spBv1.0/grasplink/NDATA/broken", unknown.SerializeToString(), 0),
        ("spBv1.0/grasplink/NDEATH/broken", wrong_bdseq.SerializeToString(), 1),
    ):
        publisher.client.publish(topic, payload, qos=qos).wait_for_publish(5)
    code = checker.finish()
    publisher.close()
    rules = [line["rule"] for line in checker.of("violation")]
    assert code == 1
    assert rules == [
        "payloads-sequence-num-incrementing",
        "payloads-decode",
        "payloads-ndeath-bdseq",
    ]

"""Real peers for the telemetry tests: a mosquitto broker on a free 127.0.0.1 port (password
file, ACL, TLS, persistence as asked), a recording MQTT client, TLS files, a gateway stand-in.

The `broker` and `secured` fixtures are shared: a conftest that wants them imports them
(tests/telemetry and tests/view do), so every suite starts the same brokers."""

from __future__ import annotations

import getpass
import os
import shutil
import signal
import socket
import subprocess
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import paho.mqtt.client as paho
import pytest
from paho.mqtt.enums import CallbackAPIVersion

from grasplink.gateway.config import load_config
from grasplink.gateway.edge import Mailbox
from grasplink.gateway.service import Gateway
from grasplink.gateway.snapshot import Snapshot
from tests.telemetry.snapshots import snapshot

MOSQUITTO = shutil.which("mosquitto") or "/usr/sbin/mosquitto"
PASSWORDS = {"gateway": "gw-secret", "reader": "rd-secret", "operator": "op-secret"}
ACL = """\
user gateway
topic readwrite grasplink/#
topic readwrite spBv1.0/#

user reader
topic read grasplink/#
topic read spBv1.0/#

user operator
topic read grasplink/#
topic write grasplink/+/cmd/#
topic read spBv1.0/#
topic write spBv1.0/+/NCMD/#
topic write spBv1.0/+/DCMD/#
"""


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


@dataclass
class TlsFiles:
    ca: Path
    cert: Path
    key: Path


def make_tls(folder: Path, name: str = "ca") -> TlsFiles:
    """A throw-away CA and a server certificate for 127.0.0.1 (openssl)."""
    folder.mkdir(parents=True, exist_ok=True)
    ca, ca_key = folder / f"{name}.pem", folder / f"{name}.key"
    key, csr, cert = folder / "server.key", folder / "server.csr", folder / "server.pem"
    ext = folder / "san.ext"
    ext.write_text("subjectAltName=IP:127.0.0.1\n")
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    run = [
        [
            *("openssl", "req", "-x509", *ec, "-keyout", ca_key, "-out", ca, "-days", "2"),
            *("-subj", f"/CN=grasplink test {name}"),
        ],
        ["openssl", "req", *ec, "-keyout", key, "-out", csr, "-subj", "/CN=127.0.0.1"],
        [
            *("openssl", "x509", "-req", "-in", csr, "-CA", ca, "-CAkey", ca_key),
            *("-CAcreateserial", "-out", cert, "-days", "2", "-extfile", ext),
        ],
    ]
    for command in run:
        subprocess.run([str(c) for c in command], check=True, capture_output=True)
    return TlsFiles(ca, cert, key)


@dataclass
class Mosquitto:
    """A broker in `folder`; `secured`: password file and ACL, no anonymous clients."""

    folder: Path
    secured: bool = False
    tls: TlsFiles | None = None
    persistence: bool = False
    port: int = field(default_factory=free_port)
    process: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"{'mqtts' if self.tls else 'mqtt'}://127.0.0.1:{self.port}"

    def url_for(self, user: str, password: str | None = None) -> str:
        scheme = "mqtts" if self.tls else "mqtt"
        return f"{scheme}://{user}:{password or PASSWORDS[user]}@127.0.0.1:{self.port}"

    def start(self) -> Mosquitto:
        self.folder.mkdir(parents=True, exist_ok=True)
        lines = [f"listener {self.port} 127.0.0.1", f"user {getpass.getuser()}"]
        if self.secured:
            passwords = self.folder / "passwords"
            passwords.write_text("")
            for user, password in PASSWORDS.items():
                subprocess.run(
                    ["mosquitto_passwd", "-b", str(passwords), user, password], check=True
                )
            acl = self.folder / "acl"
            acl.write_text(ACL)
            os.chmod(passwords, 0o600)
            os.chmod(acl, 0o600)
            lines += ["allow_anonymous false", f"password_file {passwords}", f"acl_file {acl}"]
        else:
            lines.append("allow_anonymous true")
        if self.tls:
            lines += [
                f"cafile {self.tls.ca}",
                f"certfile {self.tls.cert}",
                f"keyfile {self.tls.key}",
            ]
        if self.persistence:
            lines += [
                "persistence true",
                f"persistence_location {self.folder}/",
                "queue_qos0_messages true",
                "max_queued_messages 100000",
            ]
        config = self.folder / "mosquitto.conf"
        config.write_text("\n".join(lines) + "\n")
        log = open(self.folder / "mosquitto.log", "ab")  # noqa: SIM115 - closed with the process
        self.process = subprocess.Popen([MOSQUITTO, "-c", str(config)], stdout=log, stderr=log)
        log.close()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError((self.folder / "mosquitto.log").read_text())
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=0.2).close()
                return self
            except OSError:
                time.sleep(0.05)
        raise RuntimeError("mosquitto did not listen")

    def stop(self, sig: int = signal.SIGTERM) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(sig)
            try:
                self.process.wait(5)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait(5)
        self.process = None


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[Mosquitto]:
    """mosquitto with anonymous clients allowed (stopped after the test)."""
    server = Mosquitto(tmp_path / "broker").start()
    yield server
    server.stop()


@pytest.fixture
def secured(tmp_path: Path) -> Iterator[Mosquitto]:
    """mosquitto with a password file and an ACL (`PASSWORDS`, `ACL`): gateway, reader
    (read only), operator (reads, and writes the command topics)."""
    server = Mosquitto(tmp_path / "secured", secured=True).start()
    yield server
    server.stop()


@dataclass
class Received:
    topic: str
    payload: bytes
    retain: bool
    t_mono: float
    t_wall_ms: float


#: Where a recorder sends itself the marker that `Recorder.flush` waits for.
FLUSH_ROOT = "grasplink-test/flush"


class Recorder:
    """An MQTT client recording what it receives (paho in its own thread)."""

    def __init__(
        self,
        broker: Mosquitto,
        topics: list[str],
        *,
        user: str | None = None,
        client_id: str = "",
        persistent: bool = False,
    ):
        self.messages: list[Received] = []
        self.lock = threading.Lock()
        self.subscribed = threading.Event()
        self.topics = topics
        self.flush_topic = f"{FLUSH_ROOT}/{uuid.uuid4().hex}"
        self.flushed = threading.Event()
        self.client = paho.Client(
            CallbackAPIVersion.VERSION2, client_id=client_id, clean_session=not persistent
        )
        if user is not None:
            self.client.username_pw_set(user, PASSWORDS[user])
        if broker.tls is not None:
            self.client.tls_set(ca_certs=str(broker.tls.ca))
        self.client.reconnect_delay_set(0.05, 0.2)
        self.client.on_connect = self._on_connect
        self.client.on_message = self._on_message
        self.client.on_subscribe = lambda *args: self.subscribed.set()
        self.client.connect("127.0.0.1", broker.port, keepalive=5)
        self.client.loop_start()
        assert self.subscribed.wait(5), "subscription not acknowledged"

    def _on_connect(self, client, userdata, flags, reason, properties) -> None:
        client.subscribe([(topic, 1) for topic in [*self.topics, self.flush_topic]])

    def _on_message(self, client, userdata, message) -> None:
        if message.topic == self.flush_topic:
            self.flushed.set()
            return
        with self.lock:
            self.messages.append(
                Received(
                    message.topic,
                    bytes(message.payload),
                    bool(message.retain),
                    time.monotonic(),
                    time.time() * 1000,
                )
            )

    def publish(self, topic: str, payload: bytes, *, retain: bool = False) -> None:
        self.client.publish(topic, payload, qos=1, retain=retain).wait_for_publish(5)

    def taken(self) -> list[Received]:
        with self.lock:
            return list(self.messages)

    def wait_for(self, predicate, timeout_s: float = 5.0) -> list[Received]:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            found = [m for m in self.taken() if predicate(m)]
            if found:
                return found
            time.sleep(0.02)
        return []

    def flush(self, timeout_s: float = 15.0) -> None:
        """Wait until every message the broker accepted before this call has reached this
        recorder: mosquitto queues a session's messages in the order it accepts them, so our
        own marker coming back means all before it came (a fixed sleep is timing luck).
        Only where anonymous clients may publish (not on the secured broker)."""
        self.flushed.clear()
        self.publish(self.flush_topic, b"")
        assert self.flushed.wait(timeout_s), f"the flush marker took over {timeout_s} s"

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


class FakeGateway:
    """The telemetry surface of a gateway at 20 Hz: snapshot k reports skin grip force k N
    (so a consumer can tell whether it missed one), commands run by a real `Gateway`."""

    def __init__(self, period_s: float = 0.05):
        self.real = Gateway(load_config(None))
        self.mailbox = Mailbox()
        self.period_s = period_s
        self.latest: Snapshot | None = None
        self.count = 0
        self.phases: dict[str, str] = {}
        self._stop = threading.Event()
        self._start = time.monotonic()
        self._thread = threading.Thread(target=self._run, daemon=True, name="fake-gateway")
        self._thread.start()

    def post(self, command):
        return self.mailbox.post(command)

    def _run(self) -> None:
        next_t = self._start
        while not self._stop.is_set():
            now = time.monotonic()
            t_us = int((now - self._start) * 1e6)
            for command, future in self.mailbox.drain():
                result, _ = self.real.execute(command, t_us)
                future.set_result(result)
            self.count += 1
            nodes = {k: {"phase": p, "nmt_state": None} for k, p in self.phases.items()}
            self.latest = snapshot(
                now - self._start,
                skin={"grip_force_n": float(self.count)},
                belt={"mode": self.real.feedback.mode.value},
                nodes=nodes,
            )
            next_t += self.period_s
            self._stop.wait(max(0.0, next_t - time.monotonic()))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2)

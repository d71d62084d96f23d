"""Bus URLs, the loopback CAN hub, the real-time NodeRunner and bus-load arithmetic.

Everything here runs without SocketCAN: in-process ``virtual`` buses and a
hub bound to 127.0.0.1 on an ephemeral port, stopped by each test.
"""

from __future__ import annotations

import errno
import inspect
import os
import queue
import re
import select
import signal
import socket
import statistics
import struct
import subprocess
import sys
import textwrap
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import pytest

from grasplink.bus import url as bus_url
from grasplink.bus.hub import CanHub
from grasplink.bus.load import BusLoadMeter, frame_bits_worst_case, frame_time_us
from grasplink.bus.options import accepted_options
from grasplink.bus.reconnect import Backoff
from grasplink.bus.runner import MultiRunner, NodeRunner, on_tick
from grasplink.bus.url import (
    BusDisconnected,
    BusSpec,
    frame_to_message,
    message_to_frame,
    open_bus,
    parse_bus_url,
    socketcan_available,
)
from grasplink.core.frames import Frame
from grasplink.errors import BusError
from tests.live import first_from

REPO = Path(__file__).resolve().parents[1]
TIMEOUT_S = 5.0


# -- helpers --------------------------------------------------------------------------


def unique_virtual_url() -> str:
    return f"virtual:test-{uuid.uuid4().hex[:10]}"


def send(bus: can.BusABC, frame: Frame) -> None:
    bus.send(frame_to_message(frame))


def recv_until(
    bus: can.BusABC, done: Callable[[list[Frame]], bool], timeout: float = TIMEOUT_S
) -> list[Frame]:
    """Frames received until `done(frames)` holds; fails the test on timeout."""
    frames: list[Frame] = []
    deadline = time.monotonic() + timeout
    while not done(frames):
        left = deadline - time.monotonic()
        if left <= 0:
            pytest.fail(f"timed out; received {frames}")
        msg = bus.recv(timeout=min(left, 0.1))
        if msg is not None:
            frame = message_to_frame(msg)
            if frame is not None:
                frames.append(frame)
    return frames


def has(*can_ids: int) -> Callable[[list[Frame]], bool]:
    return lambda frames: set(can_ids) <= {f.can_id for f in frames}


def wait_for(condition: Callable[[], bool], timeout: float = TIMEOUT_S) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail("condition not met in time")
        time.sleep(0.005)


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(REPO) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.fixture
def hub() -> Iterator[CanHub]:
    with CanHub("127.0.0.1", 0) as running:
        yield running


@pytest.fixture
def closing() -> Iterator[Callable[[can.BusABC], can.BusABC]]:
    """Register buses to shut down at teardown."""
    buses: list[can.BusABC] = []

    def register(bus: can.BusABC) -> can.BusABC:
        buses.append(bus)
        return bus

    yield register
    for bus in reversed(buses):
        bus.shutdown()


# -- URL parsing ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("url", "spec"),
    [
        ("virtual:grasplink", BusSpec("virtual", "grasplink")),
        ("remote:ws://127.0.0.1:54701/", BusSpec("remote", "ws://127.0.0.1:54701/")),
        ("remote:127.0.0.1:5000", BusSpec("remote", "ws://127.0.0.1:5000/")),
        ("remote:ws://127.0.0.1", BusSpec("remote", "ws://127.0.0.1:54701/")),
        (
            "remote:wss://hub.example.org:443/can",
            BusSpec("remote", "wss://hub.example.org:443/can"),
        ),
        ("socketcan:vcan0", BusSpec("socketcan", "vcan0")),
        (" SocketCAN:can0 ", BusSpec("socketcan", "can0")),
        (
            "socketcan:can0?fd=false&receive_own_messages=TRUE&local_loopback=true",
            BusSpec(
                "socketcan",
                "can0",
                {"fd": False, "receive_own_messages": True, "local_loopback": True},
            ),
        ),
        (
            "virtual:x?rx_queue_size=0x10&preserve_timestamps=false",
            BusSpec("virtual", "x", {"rx_queue_size": 16, "preserve_timestamps": False}),
        ),
        (
            "remote:127.0.0.1:5000?connect_timeout=2&receive_own_messages=false",
            BusSpec(
                "remote",
                "ws://127.0.0.1:5000/",
                {"connect_timeout": 2.0, "receive_own_messages": False},
            ),
        ),
        (
            "serial:/dev/ttyUSB0?baudrate=115200&timeout=1&rtscts=false",
            BusSpec(
                "serial", "/dev/ttyUSB0", {"baudrate": 115200, "timeout": 1.0, "rtscts": False}
            ),
        ),
        ("pcan:PCAN_USBBUS1?bitrate=500000", BusSpec("pcan", "PCAN_USBBUS1", {"bitrate": 500000})),
        (  # an enum option; a keyword python-can documents but takes through **kwargs
            "pcan:PCAN_USBBUS1?state=passive&f_clock_mhz=80",
            BusSpec("pcan", "PCAN_USBBUS1", {"state": can.BusState.PASSIVE, "f_clock_mhz": 80}),
        ),
        (  # a text option keeps its leading zeros
            "usb2can:ED000100?serial=0012&bitrate=1000000",
            BusSpec("usb2can", "ED000100", {"serial": "0012", "bitrate": 1_000_000}),
        ),
        ("kvaser:0?bitrate=1000000&sjw=1", BusSpec("kvaser", "0", {"bitrate": 10**6, "sjw": 1})),
    ],
)
def test_parse_bus_url_good(url: str, spec: BusSpec) -> None:
    parsed = parse_bus_url(url)
    assert parsed == spec
    assert parse_bus_url(parsed.url) == parsed  # canonical form round-trips


@pytest.mark.parametrize(
    ("url", "expected"),
    [
        ("", ["empty bus URL", "INTERFACE:CHANNEL", "virtual:grasplink", "remote:ws://127.0.0.1"]),
        ("   ", ["empty bus URL"]),
        ("vcan0", ["malformed bus URL 'vcan0'", "INTERFACE:CHANNEL", "socketcan:vcan0"]),
        (":vcan0", ["malformed bus URL"]),
        ("virtual:", ["names no channel", "virtual:grasplink"]),
        ("socketcan:?bitrate=1", ["names no channel"]),
        ("foo:bar", ["unknown CAN interface 'foo'", "valid interfaces: canalystii, "]),
        ("udp_multicast:239.74.163.2", ["multicast", "not allowed", "grasplink bus hub"]),
        ("remote:http://127.0.0.1:1/", ["ws:// or wss://"]),
        ("remote:ws://:5000/", ["names no hub host"]),
        ("remote:ws://127.0.0.1:99999/", ["bad hub address"]),
        ("remote:ws://127.0.0.1:0/", ["port 0"]),
        ("socketcan:vcan0?bitrate", ["malformed options", "?key=value"]),
        ("socketcan:vcan0?bitrate=", ["option 'bitrate' has no value"]),
        ("socketcan:vcan0?bitrate=1&bitrate=2", ["option 'bitrate' is given twice"]),
        ("socketcan:vcan0?channel=vcan1", ["'channel' cannot be an option"]),
        ("socketcan:vcan0?bit-rate=1", ["'bit-rate' is not a valid name"]),
        (
            "virtual:x?foo=1",
            [
                "unknown option 'foo' for the virtual interface",
                "accepted options: preserve_timestamps, receive_own_messages, rx_queue_size",
            ],
        ),
        ("virtual:x?rx_queue_size=-1", ["'rx_queue_size' must be an integer >= 0, got '-1'"]),
        ("virtual:x?rx_queue_size=1.5", ["'rx_queue_size' must be an integer"]),
        ("virtual:x?receive_own_messages=1", ["'receive_own_messages' must be true or false"]),
        ("virtual:x?bitrate=500000", ["unknown option 'bitrate'", "a virtual bus has no bitrate"]),
        (
            "remote:127.0.0.1?connect_timeout=0",
            ["'connect_timeout' must be a number > 0", "accepted options: connect_timeout, "],
        ),
        ("remote:127.0.0.1?connect_timeout=soon", ["'connect_timeout' must be a number"]),
        ("remote:127.0.0.1?timeout=3", ["unknown option 'timeout' for the remote interface"]),
        (
            "socketcan:can0?bitrate=1000000",
            ["unknown option 'bitrate'", "ip link set CHANNEL type can bitrate", "accepted"],
        ),
        ("socketcan:can0?fd=yes", ["'fd' must be true or false, got 'yes'"]),
        (
            "serial:/dev/ttyUSB0?mask=0x7F0",
            ["unknown option 'mask'", "accepted options: baudrate, rtscts, timeout"],
        ),
        ("serial:/dev/ttyUSB0?baudrate=fast", ["'baudrate' must be an integer, got 'fast'"]),
        ("pcan:PCAN_USBBUS1?state=on", ["'state' must be ACTIVE or PASSIVE or ERROR"]),
        ("kvaser:0?bitrat=1000000", ["unknown option 'bitrat'", "bitrate, "]),
        ("slcan:/dev/ttyACM0?can_filters=1", ["unknown option 'can_filters'"]),
        ("virtual:x?ignore_config=true", ["'ignore_config' cannot be an option"]),
    ],
)
def test_parse_bus_url_bad(url: str, expected: list[str]) -> None:
    with pytest.raises(BusError) as info:
        parse_bus_url(url)
    for text in expected:
        assert text in str(info.value)


def test_every_python_can_interface_has_known_options() -> None:
    # Read from each bus class's source; a python-can upgrade that broke this would
    # silently turn the option check off.
    for interface in bus_url.valid_interfaces():
        assert accepted_options(interface) is not None, interface


def test_introspected_options_are_the_bus_class_parameters() -> None:
    from can.interfaces.serial.serial_can import SerialBus

    named = set(inspect.signature(SerialBus.__init__).parameters) - {"self", "channel", "kwargs"}
    assert set(accepted_options("serial")) == named


def test_open_bus_refuses_an_unknown_option_before_opening() -> None:
    with pytest.raises(BusError, match="unknown option 'foo'"):
        open_bus(unique_virtual_url() + "?foo=1")


def test_unknown_interface_lists_valid_ones_but_not_multicast() -> None:
    with pytest.raises(BusError) as info:
        parse_bus_url("nosuchcard:0")
    listed = str(info.value).split("valid interfaces: ", 1)[1]
    assert listed == ", ".join(sorted(set(can.interfaces.VALID_INTERFACES) - {"udp_multicast"}))
    assert "virtual" in listed and "remote" in listed and "socketcan" in listed


# -- frame conversion -----------------------------------------------------------------


@pytest.mark.parametrize(
    "frame",
    [
        Frame(0x000, b"\x01\x05"),
        Frame(0x7FF, bytes(range(8))),
        Frame(0x1A5),
        Frame(0x705, rtr=True, dlc=1),
    ],
)
def test_frame_message_round_trip(frame: Frame) -> None:
    msg = frame_to_message(frame, timestamp=12.5)
    assert not msg.is_extended_id and msg.timestamp == 12.5
    assert msg.dlc == frame.length and msg.is_remote_frame == frame.rtr
    assert message_to_frame(msg) == frame


@pytest.mark.parametrize(
    "msg",
    [
        can.Message(is_error_frame=True, arbitration_id=0x20000004, data=bytes(8)),
        can.Message(arbitration_id=0x18FF1234, is_extended_id=True, data=b"\x01"),
        can.Message(arbitration_id=0x100, is_extended_id=False, is_fd=True, data=bytes(12)),
    ],
)
def test_message_to_frame_rejects_what_canopen_cannot_carry(msg: can.Message) -> None:
    assert message_to_frame(msg) is None


# -- open_bus: virtual and failures ---------------------------------------------------


def test_open_bus_virtual_two_handles_exchange_frames(closing) -> None:
    url = unique_virtual_url()
    a, b = closing(open_bus(url)), closing(open_bus(url))
    send(a, Frame(0x181, b"\x11\x22"))
    send(a, Frame(0x701, rtr=True, dlc=1))
    frames = recv_until(b, lambda fs: len(fs) == 2)
    assert frames == [Frame(0x181, b"\x11\x22"), Frame(0x701, rtr=True, dlc=1)]
    assert a.recv(timeout=0.05) is None  # no echo of own frames by default


def test_open_bus_receive_own_messages(closing) -> None:
    a = closing(open_bus(unique_virtual_url(), receive_own_messages=True))
    send(a, Frame(0x123, b"x"))
    assert recv_until(a, has(0x123)) == [Frame(0x123, b"x")]


def test_open_bus_wraps_other_python_can_failures() -> None:
    with pytest.raises(BusError, match=r"cannot open CAN bus serial:/nonexistent/grasplink-tty"):
        open_bus("serial:/nonexistent/grasplink-tty")


@pytest.mark.skipif(socketcan_available(), reason="this kernel has SocketCAN")
def test_socketcan_without_af_can_explains_alternatives() -> None:
    with pytest.raises(BusError) as info:
        open_bus("socketcan:vcan0")
    text = str(info.value)
    assert "SocketCAN is not available on this kernel" in text
    assert "virtual:grasplink" in text and "remote:ws://127.0.0.1:54701/" in text


@pytest.mark.parametrize(
    ("channel", "code", "hint"),
    [
        ("vcan0", errno.ENODEV, "sudo ip link add dev vcan0 type vcan"),
        ("can0", errno.ENODEV, "ip link show"),
        ("can0", errno.ENETDOWN, "sudo ip link set up can0"),
    ],
)
def test_socketcan_missing_or_down_interface_hints(monkeypatch, channel, code, hint) -> None:
    def fail(**_kwargs):
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(bus_url, "socketcan_available", lambda: True)
    monkeypatch.setattr(bus_url.can, "Bus", fail)
    with pytest.raises(BusError, match=re.escape(hint)):
        open_bus(f"socketcan:{channel}")


def vcan0_present() -> bool:
    return socketcan_available() and Path("/sys/class/net/vcan0").exists()


@pytest.mark.socketcan
@pytest.mark.skipif(not vcan0_present(), reason="needs SocketCAN (AF_CAN) and a vcan0 interface")
def test_socketcan_vcan0_exchange(closing) -> None:
    a, b = closing(open_bus("socketcan:vcan0")), closing(open_bus("socketcan:vcan0"))
    send(a, Frame(0x77F, b"vcan"))
    assert Frame(0x77F, b"vcan") in recv_until(b, has(0x77F))


# -- the hub --------------------------------------------------------------------------


def test_hub_relays_between_clients(hub: CanHub, closing) -> None:
    assert hub.port != 0 and hub.url == f"remote:ws://127.0.0.1:{hub.port}/"
    assert hub.channel.startswith("grasplink-hub-")  # private virtual channel
    a, b, c = (closing(open_bus(hub.url)) for _ in range(3))
    wait_for(lambda: hub.client_count == 3)
    send(a, Frame(0x201, b"\x01\x02\x03"))
    assert recv_until(b, has(0x201)) == [Frame(0x201, b"\x01\x02\x03")]
    assert recv_until(c, has(0x201)) == [Frame(0x201, b"\x01\x02\x03")]
    send(c, Frame(0x080))
    assert recv_until(a, has(0x080)) == [Frame(0x080)]
    assert a.recv(timeout=0.05) is None  # the sender does not hear itself


@pytest.mark.slow
def test_hub_stop_disconnects_clients() -> None:
    running = CanHub("127.0.0.1", 0).start()
    client = open_bus(running.url)
    try:
        wait_for(lambda: running.client_count == 1)
        started = time.monotonic()
        running.stop()
        assert time.monotonic() - started < 3.0
        assert not running.running
        with pytest.raises(can.CanOperationError):
            for _ in range(50):
                client.recv(timeout=0.1)
                send(client, Frame(0x100))
    finally:
        client.shutdown()
    with pytest.raises(BusError, match="no CAN hub"):
        open_bus(running.url)


def test_unreachable_hub_says_how_to_start_one(refused_port: int) -> None:
    port = refused_port
    with pytest.raises(BusError) as info:
        open_bus(f"remote:ws://127.0.0.1:{port}/")
    assert str(info.value) == (
        f"no CAN hub at ws://127.0.0.1:{port}/ — start one with `grasplink bus hub --port {port}`"
    )


@pytest.mark.slow
def test_silent_listener_is_not_a_hub() -> None:
    with socket.socket() as listener:
        listener.bind(("127.0.0.1", 0))
        listener.listen()
        port = listener.getsockname()[1]
        started = time.monotonic()
        with pytest.raises(BusError, match="did not answer as a CAN hub"):
            open_bus(f"remote:ws://127.0.0.1:{port}/?connect_timeout=0.3")
        assert time.monotonic() - started < 2.0


def test_hub_port_in_use(hub: CanHub) -> None:
    with pytest.raises(BusError, match=f"cannot start a CAN hub on 127.0.0.1:{hub.port}"):
        CanHub("127.0.0.1", hub.port).start()


CHILD_CLIENT = textwrap.dedent(
    """
    import sys, time
    from grasplink.bus.url import frame_to_message, message_to_frame, open_bus
    from grasplink.core.frames import Frame

    bus = open_bus(sys.argv[1])
    try:
        bus.send(frame_to_message(Frame(0x181, b"child")))
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            msg = bus.recv(0.2)
            if msg is not None and message_to_frame(msg) == Frame(0x201, b"parent"):
                print("child got reply", flush=True)
                break
        else:
            sys.exit(3)
    finally:
        bus.shutdown()
    """
)


def test_hub_carries_frames_across_processes(hub: CanHub, closing) -> None:
    parent = closing(open_bus(hub.url))
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD_CLIENT, hub.url],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=child_env(),
    )
    try:
        assert recv_until(parent, has(0x181), timeout=15) == [Frame(0x181, b"child")]
        send(parent, Frame(0x201, b"parent"))
        out, err = child.communicate(timeout=15)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    assert child.returncode == 0, err
    assert "child got reply" in out


@pytest.mark.slow
def test_run_hub_process_serves_and_stops_on_sigterm(closing, tmp_path: Path) -> None:
    code = "from grasplink.bus.hub import run_hub; run_hub('127.0.0.1', 0)"
    with (tmp_path / "stderr.txt").open("w+") as err:
        proc = subprocess.Popen(
            [sys.executable, "-c", code],
            stdout=subprocess.PIPE,
            stderr=err,
            text=True,
            env=child_env(),
        )
        lines: queue.Queue[str] = queue.Queue()
        reader = threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout])
        reader.start()
        try:
            url = hub_url_from(lines, timeout=15)
            a, b = closing(open_bus(url)), closing(open_bus(url))
            send(a, Frame(0x602, b"\x40\x00\x10\x00"))
            assert recv_until(b, has(0x602)) == [Frame(0x602, b"\x40\x00\x10\x00")]
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            reader.join(timeout=5)
            proc.stdout.close()
        err.seek(0)
        assert proc.returncode == 0, err.read()
    assert "CAN hub stopped" in list(lines.queue)[-1]


def hub_url_from(lines: queue.Queue[str], timeout: float) -> str:
    found = first_from(
        lines, timeout, lambda line: re.search(r"remote:ws://127\.0\.0\.1:\d+/", line)
    )
    if found:
        return found.group(0)
    pytest.fail("hub process printed no URL")


# -- NodeRunner -----------------------------------------------------------------------


class Ticker:
    """Emits 0x180+id every `period_us` from advance(); records what it hears."""

    def __init__(self, node_id: int = 1, period_us: int = 10_000) -> None:
        self.node_id = node_id
        self.period_us = period_us
        self.next_us: int | None = None
        self.fired: list[tuple[int, int]] = []  # (deadline, t) per tick
        self.heard: list[Frame] = []

    def start(self, t_us: int) -> list[Frame]:
        self.next_us = t_us + self.period_us
        return [Frame(0x700 + self.node_id, b"\x00")]

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        self.heard.append(frame)
        return []

    def advance(self, t_us: int) -> list[Frame]:
        assert self.next_us is not None
        if t_us < self.next_us:
            return []
        self.fired.append((self.next_us, t_us))
        while self.next_us <= t_us:
            self.next_us += self.period_us
        return [Frame(0x180 + self.node_id, len(self.fired).to_bytes(2, "little"))]

    def next_deadline_us(self) -> int | None:
        return self.next_us


class Echo:
    """Answers SDO requests to its node (0x600+id) with 0x580+id; no timers."""

    def __init__(self, node_id: int = 2) -> None:
        self.node_id = node_id
        self.heard: list[Frame] = []

    def start(self, t_us: int) -> list[Frame]:
        return [Frame(0x700 + self.node_id, b"\x00")]

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        self.heard.append(frame)
        if frame.can_id == 0x600 + self.node_id:
            return [Frame(0x580 + self.node_id, frame.data)]
        return []

    def advance(self, t_us: int) -> list[Frame]:
        return []

    def next_deadline_us(self) -> int | None:
        return None


class Faulty:
    """Raises from everything but start(); must not take the runner down."""

    node_id = 9

    def start(self, t_us: int) -> list[Frame]:
        return []

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        raise RuntimeError("receive exploded")

    def advance(self, t_us: int) -> list[Frame]:
        raise RuntimeError("advance exploded")

    def next_deadline_us(self) -> int | None:
        return 0


@pytest.mark.slow
def test_runner_boot_periodic_local_and_external_delivery(closing) -> None:
    url = unique_virtual_url()
    bus, outside = closing(open_bus(url)), closing(open_bus(url))
    ticker, echo = Ticker(1, period_us=10_000), Echo(2)
    runner = NodeRunner(bus, [ticker, echo])
    with runner:
        # boot-ups reach the bus, and each device heard the other's boot-up locally
        recv_until(outside, has(0x701, 0x702))
        assert Frame(0x702, b"\x00") in ticker.heard
        assert Frame(0x701, b"\x00") in echo.heard
        time.sleep(0.3)
        wait_for(lambda: any(f.can_id == 0x181 for f in echo.heard))
        # an external SDO request is answered on the bus; both devices saw it
        send(outside, Frame(0x602, b"\x40\x18\x10\x01"))
        frames = recv_until(outside, has(0x582))
        assert Frame(0x582, b"\x40\x18\x10\x01") in frames
        wait_for(lambda: Frame(0x602, b"\x40\x18\x10\x01") in ticker.heard)
    assert not runner.running

    # periodic frames: never early, roughly every 10 ms
    assert len(ticker.fired) >= 15
    lateness = [t - deadline for deadline, t in ticker.fired]
    assert min(lateness) >= 0
    assert statistics.median(lateness) < 10_000
    ticks = [f for f in echo.heard if f.can_id == 0x181]
    assert len(ticks) == len(ticker.fired)  # every tick delivered locally
    assert not any(f.can_id == 0x181 for f in ticker.heard)  # not back to the sender

    stats = runner.stats
    assert stats.tx_by_node[1] == 1 + len(ticker.fired)
    assert stats.tx_by_node[2] == 2  # boot-up + SDO answer
    assert stats.tx_by_cob_id[0x181] == len(ticker.fired)
    assert stats.rx_by_cob_id[0x602] == 1 and stats.frames_rx >= 1
    assert stats.frames_tx == sum(stats.tx_by_cob_id.values())
    assert stats.device_errors == stats.send_errors == stats.bus_errors == 0


@pytest.mark.slow
def test_runner_submit_injects_frames(closing) -> None:
    url = unique_virtual_url()
    bus, outside = closing(open_bus(url)), closing(open_bus(url))
    echo = Echo(2)
    with NodeRunner(bus, [echo]) as runner:
        recv_until(outside, has(0x702))
        assert runner.submit(Frame(0x602, b"\x01"))  # goes to the bus and the device
        frames = recv_until(outside, has(0x602, 0x582))
        assert frames == [Frame(0x602, b"\x01"), Frame(0x582, b"\x01")]
        assert runner.submit(Frame(0x602, b"\x02"), to_bus=False)  # local only
        assert recv_until(outside, has(0x582)) == [Frame(0x582, b"\x02")]
        assert Frame(0x602, b"\x02") in echo.heard
        with pytest.raises(TypeError):
            runner.submit(can.Message(arbitration_id=0x602))  # type: ignore[arg-type]
    assert runner.stats.injected == 2


def test_runner_submit_queue_is_bounded(closing) -> None:
    bus = closing(open_bus(unique_virtual_url()))
    runner = NodeRunner(bus, [Echo(2)], submit_queue_size=3)  # not started: nothing drains
    accepted = [runner.submit(Frame(0x602, bytes([i]))) for i in range(5)]
    assert accepted == [True, True, True, False, False]
    assert runner.stats.dropped == 2


@pytest.mark.slow
def test_runner_survives_faulty_device_and_counts_ignored_frames(closing, caplog) -> None:
    url = unique_virtual_url()
    bus, outside = closing(open_bus(url)), closing(open_bus(url))
    echo = Echo(2)
    with NodeRunner(bus, [Faulty(), echo]) as runner:
        recv_until(outside, has(0x702))
        outside.send(can.Message(arbitration_id=0x18FF0102, is_extended_id=True, data=b"\x01"))
        send(outside, Frame(0x602, b"\x05"))
        assert Frame(0x582, b"\x05") in recv_until(outside, has(0x582))
        wait_for(lambda: runner.stats.ignored >= 1)
        wait_for(lambda: any("advance() failed" in r.getMessage() for r in caplog.records))
        assert runner.running
    stats = runner.stats
    assert stats.device_errors >= 2  # receive() and advance() both raised
    assert stats.ignored == 1
    assert any("device node 9: advance() failed" in r.getMessage() for r in caplog.records)
    # a device raising at its deadline is retried after a back-off, not in a tight loop
    assert stats.device_errors < 50


@pytest.mark.slow
def test_runner_stop_joins_thread_and_is_idempotent(closing) -> None:
    bus = closing(open_bus(unique_virtual_url()))
    runner = NodeRunner(bus, [Ticker(1)]).start()
    assert runner.running
    started = time.monotonic()
    runner.stop()
    assert time.monotonic() - started < 1.0
    assert not runner.running
    assert not any(t.name == "grasplink-node-runner" for t in threading.enumerate())
    runner.stop()
    with pytest.raises(RuntimeError):
        runner.start()


@pytest.mark.slow
def test_runner_uses_injected_clock(closing) -> None:
    url = unique_virtual_url()
    bus, outside = closing(open_bus(url)), closing(open_bus(url))
    fake_now = [5_000_000]
    ticker = Ticker(1, period_us=1_000)
    with NodeRunner(bus, [ticker], clock_us=lambda: fake_now[0]):
        recv_until(outside, has(0x701))
        time.sleep(0.05)
        assert ticker.fired == []  # frozen clock: no deadline has passed
        fake_now[0] += 1_000
        recv_until(outside, has(0x181))
    assert ticker.fired == [(5_001_000, 5_001_000)]


def test_runner_over_hub_between_processes_style_clients(hub: CanHub, closing) -> None:
    bus, outside = closing(open_bus(hub.url)), closing(open_bus(hub.url))
    with NodeRunner(bus, [Echo(5)]):
        recv_until(outside, has(0x705))
        send(outside, Frame(0x605, b"\x2f"))
        assert Frame(0x585, b"\x2f") in recv_until(outside, has(0x585))


@pytest.mark.slow
def test_runner_without_reopen_gives_up_when_its_hub_connection_closes(closing) -> None:
    running = CanHub("127.0.0.1", 0).start()
    try:
        bus = closing(open_bus(running.url))
        ticker = Ticker(1, period_us=10_000)
        with NodeRunner(bus, [ticker]) as runner:
            wait_for(lambda: len(ticker.fired) >= 2)
            running.stop()
            wait_for(lambda: not runner.running)
            assert isinstance(runner.failure, BusError)
            assert str(runner.failure).startswith(f"lost the bus ws://127.0.0.1:{running.port}/")
            assert "cannot reopen it" in str(runner.failure)
    finally:
        running.stop()


def tick_of(frame: Frame) -> int:
    """The tick count a `Ticker` frame carries (-1 for other frames)."""
    return int.from_bytes(frame.data, "little") if frame.can_id == 0x181 else -1


class FlakyBus:
    """A virtual bus whose receive fails while `broken` is set (a controller gone bus-off)."""

    def __init__(self, url: str) -> None:
        self.inner = open_bus(url)
        self.channel = url
        self.broken = threading.Event()
        self.recv_calls = 0

    def recv(self, timeout: float | None = None) -> can.Message | None:
        self.recv_calls += 1
        if self.broken.is_set():
            raise can.CanOperationError("bus-off")
        return self.inner.recv(timeout)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.inner.send(msg, timeout)

    def shutdown(self) -> None:
        self.inner.shutdown()


@pytest.mark.slow
def test_runner_retries_a_failing_bus_with_back_off_and_resumes(closing, caplog) -> None:
    url = unique_virtual_url()
    flaky = FlakyBus(url)
    outside = closing(open_bus(url))
    ticker = Ticker(1, period_us=10_000)
    try:
        with NodeRunner(flaky, [ticker], first_retry_s=0.05) as runner:
            recv_until(outside, has(0x181))
            flaky.broken.set()
            wait_for(lambda: runner.outage_s is not None)
            calls, ticks_at_loss = flaky.recv_calls, len(ticker.fired)
            time.sleep(0.5)  # attempts at 0.05, +0.1, +0.2 s: three reads, not a poll loop
            assert 2 <= flaky.recv_calls - calls <= 4
            assert runner.stats.offline_drops > 0  # ticks went on, their frames were dropped
            flaky.broken.clear()
            wait_for(lambda: runner.outage_s is None)
            recv_until(outside, lambda fs: any(tick_of(f) > ticks_at_loss + 20 for f in fs))
            assert runner.stats.reconnects == 1 and runner.failure is None
    finally:
        flaky.shutdown()
    messages = [r.getMessage() for r in caplog.records]
    assert sum("lost the bus" in m for m in messages) == 1
    assert any("reconnect attempt 1 failed (bus-off); next attempt in 0.1 s" in m for m in messages)
    assert any("back after" in m and "kept their state" in m for m in messages)


@pytest.mark.slow
def test_runner_reconnects_to_a_hub_restarted_on_the_same_port(closing, caplog) -> None:
    first = CanHub("127.0.0.1", 0).start()
    port = first.port
    second: CanHub | None = None
    try:
        bus = closing(open_bus(first.url))
        ticker = Ticker(1, period_us=200_000)
        runner = NodeRunner(bus, [ticker], reopen=lambda: open_bus(first.url), first_retry_s=0.05)
        with runner:
            wait_for(lambda: len(ticker.fired) >= 1)
            ticks_at_loss = len(ticker.fired)
            first.stop()
            wait_for(lambda: runner.stats.bus_errors >= 1)
            time.sleep(0.2)
            cpu_before, wall_before = time.process_time(), time.monotonic()
            time.sleep(1.0)
            cpu_share = (time.process_time() - cpu_before) / (time.monotonic() - wall_before)
            assert cpu_share < 0.05  # asleep between attempts, not polling a dead socket
            assert runner.running and runner.outage_s is not None
            second = CanHub("127.0.0.1", port).start()
            outside = closing(open_bus(second.url))
            frames = recv_until(outside, has(0x181), timeout=10)
            assert runner.stats.reconnects == 1 and runner.failure is None
            assert 0x701 not in {f.can_id for f in frames}  # no second boot-up: state kept
            assert tick_of(frames[-1]) > ticks_at_loss + 4  # its count went on while down
    finally:
        first.stop()
        if second is not None:
            second.stop()
    messages = [r.getMessage() for r in caplog.records]
    assert sum("lost the bus" in m for m in messages) == 1
    assert any(
        re.search(r"reconnect attempt \d+ failed \(no CAN hub at .*next attempt in", m)
        for m in messages
    )


@pytest.mark.slow
def test_runner_gives_up_after_the_reconnect_timeout(closing) -> None:
    running = CanHub("127.0.0.1", 0).start()
    try:
        bus = closing(open_bus(running.url))
        runner = NodeRunner(
            bus, [Ticker(1)], reopen=lambda: open_bus(running.url), reconnect_timeout_s=0.5
        )
        with runner:
            stopping = time.monotonic()  # the connection is lost after this
            running.stop()
            wait_for(lambda: not runner.running)
            assert 0.5 <= time.monotonic() - stopping <= 3.0
    finally:
        running.stop()
    assert isinstance(runner.failure, BusError)
    text = str(runner.failure)
    assert "could not get it back within 0.5 s" in text
    assert "no CAN hub at" in text and "\n" not in text


def test_backoff_doubles_up_to_its_cap_and_ends_on_the_deadline() -> None:
    backoff = Backoff(lost_at_us=1_000, timeout_us=20_000_000)
    assert backoff.next_attempt_us == 101_000
    delays, t_us = [], backoff.next_attempt_us
    while (delay := backoff.failed(t_us)) is not None:
        delays.append(delay)
        t_us = backoff.next_attempt_us
    assert delays == [
        200_000,
        400_000,
        800_000,
        1_600_000,
        3_200_000,
        5_000_000,
        5_000_000,
        3_700_000,
    ]  # the last attempt exactly at the deadline
    assert t_us == backoff.deadline_us == 20_001_000 and backoff.attempts == 9


def test_backoff_with_zero_timeout_makes_one_attempt() -> None:
    backoff = Backoff(lost_at_us=5, timeout_us=0)
    assert backoff.due(5)
    assert backoff.failed(5) is None


# -- bus load -------------------------------------------------------------------------


def test_frame_bits_worst_case() -> None:
    # 47 + 8n + floor((33 + 8n) / 4), intermission included
    assert frame_bits_worst_case(8) == 135
    assert frame_bits_worst_case(0) == 55
    assert [frame_bits_worst_case(n) for n in range(9)] == [55 + 10 * n for n in range(9)]
    assert frame_bits_worst_case(8, rtr=True) == 55  # remote frames carry no data field
    assert frame_time_us(8, bitrate=1_000_000) == 135.0
    assert frame_time_us(8, bitrate=500_000) == 270.0
    with pytest.raises(ValueError):
        frame_bits_worst_case(9)


def test_bus_load_meter_window() -> None:
    meter = BusLoadMeter(bitrate=1_000_000, window_us=100_000)
    for i in range(100):  # 100 eight-byte frames in 100 ms = 13 500 bits of 100 000
        meter.record(Frame(0x181, bytes(8)), t_us=i * 1_000)
    assert meter.percent(now_us=99_000) == pytest.approx(13.5)
    assert meter.percent(now_us=149_000) == pytest.approx(6.75)  # half the frames expired
    assert meter.percent(now_us=1_000_000) == 0.0
    assert meter.total_frames == 100 and meter.total_bits == 13_500
    meter.record(Frame(0x080), t_us=1_000_000)
    assert meter.bits_in_window(1_000_000) == 55
    with pytest.raises(ValueError):
        BusLoadMeter(bitrate=0)


# -- MultiRunner -------------------------------------------------------------------------


class SocketPairBus(can.BusABC):
    """One end of a Unix SOCK_SEQPACKET pair as a CAN bus: one frame per record, and a
    file descriptor a MultiRunner can select on (like SocketCAN)."""

    RECORD = struct.Struct("<IB8s")

    def __init__(self, sock: socket.socket) -> None:
        super().__init__(channel=f"pair{sock.fileno()}")
        self.sock = sock

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self.sock.send(self.RECORD.pack(msg.arbitration_id, msg.dlc, bytes(msg.data)))

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not select.select([self.sock], [], [], timeout)[0]:
            return None, False
        try:
            record = self.sock.recv(self.RECORD.size)
        except OSError as exc:
            record = b""
            why = str(exc)
        else:
            why = "link closed"
        if not record:  # the peer closed the link: gone for good, like a closed hub client
            raise BusDisconnected(why)
        can_id, dlc, data = self.RECORD.unpack(record)
        msg = can.Message(arbitration_id=can_id, data=data[:dlc], is_extended_id=False)
        return msg, False

    def fileno(self) -> int:
        return self.sock.fileno()

    def shutdown(self) -> None:
        super().shutdown()
        self.sock.close()


@pytest.fixture
def socket_links(closing) -> Callable[[], tuple[SocketPairBus, SocketPairBus]]:
    def link() -> tuple[SocketPairBus, SocketPairBus]:
        mine, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_SEQPACKET)
        return closing(SocketPairBus(mine)), closing(SocketPairBus(theirs))

    return link


def heard_on(bus: can.BusABC) -> list[Frame]:
    """Every frame waiting on `bus` now (nothing is waited for)."""
    out = []
    while (msg := bus.recv(0.0)) is not None:
        frame = message_to_frame(msg)
        assert frame is not None
        out.append(frame)
    return out


def test_multi_runner_serves_each_bus_its_own_devices_frames_and_timers(socket_links) -> None:
    (bus_a, peer_a), (bus_b, peer_b) = socket_links(), socket_links()
    now = [1_000_000]

    def clock() -> int:
        return now[0]

    ticker, echo_a, echo_b = Ticker(1, period_us=10_000), Echo(2), Echo(3)
    runner_a = NodeRunner(bus_a, [ticker, echo_a], clock_us=clock)
    runner_b = NodeRunner(bus_b, [echo_b], clock_us=clock)
    multi = MultiRunner([runner_a, runner_b])
    multi.power_on()
    assert heard_on(peer_a) == [Frame(0x701, b"\x00"), Frame(0x702, b"\x00")]
    assert heard_on(peer_b) == [Frame(0x703, b"\x00")]

    send(peer_b, Frame(0x603, b"\x40\x00\x10\x00"))  # wakes the one thread for bus B only
    multi.step()
    assert heard_on(peer_b) == [Frame(0x583, b"\x40\x00\x10\x00")]
    assert heard_on(peer_a) == []
    assert Frame(0x603, b"\x40\x00\x10\x00") not in echo_a.heard

    now[0] += 10_000  # bus A's ticker is due: its timer runs with no frame on any bus
    multi.step()
    assert heard_on(peer_a) == [Frame(0x181, b"\x01\x00")]
    assert heard_on(peer_b) == []
    assert ticker.fired == [(1_010_000, 1_010_000)]


def test_multi_runner_polls_buses_without_a_file_descriptor(closing) -> None:
    urls = [unique_virtual_url(), unique_virtual_url()]
    buses = [closing(open_bus(u)) for u in urls]
    peers = [closing(open_bus(u)) for u in urls]
    multi = MultiRunner([NodeRunner(bus, [Echo(2)]) for bus in buses])
    multi.power_on()
    for peer in peers:
        assert heard_on(peer) == [Frame(0x702, b"\x00")]
    send(peers[1], Frame(0x602, b"\x07"))
    multi.step()
    assert heard_on(peers[1]) == [Frame(0x582, b"\x07")]
    assert heard_on(peers[0]) == []


def test_multi_runner_tick_wakes_for_timers_on_the_tick_grid_only() -> None:
    # due in 2.3 ms on a 1 ms grid from 0.4 ms past a tick: wake at the 3 ms tick
    assert on_tick(10_400, 0.0023, 1_000) == pytest.approx(0.0026)
    assert on_tick(10_000, 0.002, 1_000) == pytest.approx(0.002)  # already on the grid
    assert on_tick(10_400, 0.0, 1_000) == pytest.approx(0.0006)  # never earlier than asked


def test_multi_runner_refuses_a_tick_longer_than_its_longest_wait(closing) -> None:
    runner = NodeRunner(closing(open_bus(unique_virtual_url())), [Echo(2)])
    with pytest.raises(ValueError, match="tick_s"):
        MultiRunner([runner], max_wait_s=0.02, tick_s=0.05)
    with pytest.raises(ValueError, match="tick_s"):
        MultiRunner([runner], tick_s=-0.001)


def test_multi_runner_refuses_runners_with_their_own_thread(closing) -> None:
    runner = NodeRunner(closing(open_bus(unique_virtual_url())), [Echo(2)]).start()
    try:
        with pytest.raises(ValueError, match="own thread"):
            MultiRunner([runner])
    finally:
        runner.stop()


@pytest.mark.slow
def test_multi_runner_thread_starts_serves_and_stops(socket_links) -> None:
    links = [socket_links() for _ in range(3)]
    multi = MultiRunner([NodeRunner(bus, [Echo(2)]) for bus, _ in links])
    with multi:
        assert multi.running
        for i, (_, peer) in enumerate(links):
            recv_until(peer, has(0x702))
            send(peer, Frame(0x602, bytes([i])))
            assert Frame(0x582, bytes([i])) in recv_until(peer, has(0x582))
    assert not multi.running
    assert not any(t.name == "grasplink-multi-runner" for t in threading.enumerate())


def test_multi_runner_drops_a_runner_that_gives_up_and_serves_the_others(socket_links) -> None:
    (bus_a, peer_a), (bus_b, peer_b) = socket_links(), socket_links()
    runner_a, runner_b = NodeRunner(bus_a, [Echo(2)]), NodeRunner(bus_b, [Echo(3)])
    multi = MultiRunner([runner_a, runner_b])
    multi.power_on()
    peer_a.sock.close()  # bus A is gone and cannot be reopened
    multi.step()
    assert runner_a.failure is not None and runner_b.failure is None
    send(peer_b, Frame(0x603, b"\x01"))
    multi.step()  # bus B is still served
    assert heard_on(peer_b) == [Frame(0x703, b"\x00"), Frame(0x583, b"\x01")]

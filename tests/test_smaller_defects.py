"""Issue 21, item 9: smaller defects a new user meets (config keys, URLs, the hub, `run`, docs).

Each test names what a user sees; each failed on the code before its fix.
"""

from __future__ import annotations

import itertools
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import can
import pytest

from grasplink.decoding import registry
from grasplink.errors import ConfigError
from grasplink.gateway.config import load_config
from tests.live import first_from

ROOT = Path(__file__).resolve().parents[1]


# -- 1. a gateway configuration's decoder ---------------------------------------------------


@pytest.mark.parametrize("name", ["nope", "mmse", "dtw"])
def test_a_decoder_the_gateway_cannot_run_names_file_key_and_valid_decoders(
    tmp_path: Path, name: str
) -> None:
    """`[nodes.skin] decoder = "nope"` failed at start-up without file or key; mmse and dtw
    (which need reference slips) passed the file and failed when the gateway started."""
    path = tmp_path / "gw.toml"
    path.write_text(f'[nodes.skin]\ndecoder = "{name}"\n')
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: nodes.skin.decoder: ")
    assert repr(name) in message and "fft, ratio, tracker" in message
    assert "\n" not in message


def test_a_decoder_in_a_scenes_gateway_controller_names_the_controller_key() -> None:
    from grasplink.gateway.config import parse_config

    with pytest.raises(ConfigError, match=r"^s\.toml: controller\.nodes\.skin\.decoder: unknown"):
        parse_config({"nodes": {"skin": {"decoder": "nope"}}}, "s.toml", "controller")


def test_every_live_decoder_is_accepted_and_the_default_is_one() -> None:
    from grasplink.gateway.config import SkinConfig, parse_config

    assert registry.DEFAULT_DECODER in registry.live_decoders()
    for name in registry.live_decoders():
        skin = parse_config({"nodes": {"skin": {"decoder": name}}}, "gw.toml").nodes["skin"]
        assert isinstance(skin, SkinConfig) and skin.decoder == name


def test_the_reference_decoders_named_in_the_registry_are_those_whose_class_says_so() -> None:
    """The registry names them so a configuration is checked without importing every decoder."""
    for name in registry.DECODERS:
        needs = bool(getattr(registry.decoder_class(name), "needs_references", False))
        assert needs == (name in registry.NEEDS_REFERENCES), name


# -- 2, 3. Modbus, MQTT and hub URLs: the port and the host ------------------------------------


@pytest.mark.parametrize("text", ["tcp://", "tcp://127.0.0.1", "tcp://0.0.0.0"])
def test_a_modbus_tcp_url_without_a_port_is_refused_not_bound_to_502(text: str) -> None:
    """`--modbus tcp://` bound the privileged port 502 silently (as root) before."""
    from grasplink.surfaces.modbus.url import parse_modbus_url

    with pytest.raises(ConfigError) as caught:
        parse_modbus_url(text)
    message = str(caught.value)
    assert "give a port, e.g. tcp://" in message and ":1502" in message and "\n" not in message


def test_modbus_port_502_is_taken_when_named() -> None:
    from grasplink.surfaces.modbus.url import parse_modbus_url

    assert parse_modbus_url("tcp://127.0.0.1:502").port == 502


BAD_HOSTS = [
    ("256.1.1.1", "'256.1.1.1' is not an IPv4 address"),
    ("1.2.3.4.5", "'1.2.3.4.5' is not an IPv4 address"),
    ("bad_-.host..x", "'bad_-.host..x' is not a host name"),
]


@pytest.mark.parametrize(("host", "says"), BAD_HOSTS)
def test_a_malformed_modbus_host_is_named_not_unknown_error_2(host: str, says: str) -> None:
    """`tcp://256.1.1.1:1502` said "cannot listen on ...: Unknown error -2" at bind time."""
    from grasplink.surfaces.modbus.url import parse_modbus_url

    with pytest.raises(ConfigError, match=f"^modbus URL 'tcp://{host}:1502': {says}"):
        parse_modbus_url(f"tcp://{host}:1502")


def test_a_modbus_host_that_does_not_resolve_is_named() -> None:
    from grasplink.surfaces.modbus.url import parse_modbus_url

    # .invalid never resolves (RFC 2606); the resolver answers from its own rules.
    with pytest.raises(ConfigError, match=r"cannot resolve host 'nohost\.invalid' \("):
        parse_modbus_url("tcp://nohost.invalid:1502")


@pytest.mark.parametrize(
    "text", ["tcp://127.0.0.1:1502", "tcp://localhost:1502", "tcp://[::1]:1502", "tcp://:0"]
)
def test_modbus_hosts_that_are_addresses_or_local_names_are_accepted(text: str) -> None:
    from grasplink.surfaces.modbus.url import parse_modbus_url

    assert parse_modbus_url(text).scheme == "tcp"


@pytest.mark.parametrize(("host", "says"), BAD_HOSTS)
def test_a_malformed_broker_host_is_named_before_connecting(host: str, says: str) -> None:
    """`mqtt://256.1.1.1` got as far as connecting: "Name or service not known"."""
    from grasplink.surfaces.telemetry.url import parse_broker_url

    with pytest.raises(ConfigError, match=f"^--mqtt 'mqtt://{host}:1883': {says}"):
        parse_broker_url(f"mqtt://{host}:1883")


@pytest.mark.parametrize(("host", "says"), BAD_HOSTS)
def test_a_malformed_hub_host_is_named_not_no_hub_there(host: str, says: str) -> None:
    """`remote:ws://256.1.1.1:54701/` said "no CAN hub at ... start one with ..."."""
    from grasplink.bus.url import parse_bus_url
    from grasplink.errors import BusError

    with pytest.raises(BusError, match=f"bad hub host: {says}"):
        parse_bus_url(f"remote:ws://{host}:54701/")


def test_a_hub_host_that_does_not_resolve_is_named_not_no_hub_there() -> None:
    from grasplink.bus.url import open_bus
    from grasplink.errors import BusError

    with pytest.raises(BusError) as caught:
        open_bus("remote:ws://nohost.invalid:54701/?connect_timeout=2")
    message = str(caught.value)
    assert "cannot resolve hub host 'nohost.invalid'" in message
    assert "start one" not in message


# -- 4. the hub: a client that drops is one line, not tracebacks --------------------------------

# Joins, then leaves what the hub sends it unread: killed so, its socket closes with a reset
# (data unread), as a crashed or unplugged client's does, not with an orderly end of stream.
DROPPING_CLIENT = """
import select, sys
from grasplink.bus.url import open_bus
bus = open_bus(sys.argv[1])
print("joined", flush=True)
select.select([bus.fileno()], [], [], 30)
print("hearing", flush=True)
sys.stdin.readline()  # the test kills this process here, without a goodbye
"""


def _child_env() -> dict[str, str]:
    import os

    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


def _lines_of(stream, sink) -> threading.Thread:  # type: ignore[no-untyped-def]
    thread = threading.Thread(target=lambda: [sink.put(line) for line in stream], daemon=True)
    thread.start()
    return thread


def _wait_line(lines: queue.Queue[str], pattern: str, timeout_s: float, seen: list[str]) -> str:
    def matching(line: str) -> str | None:
        seen.append(line)
        return line if re.search(pattern, line) else None

    line = first_from(lines, timeout_s, matching)
    if line is not None:
        return line
    pytest.fail(f"no line matching {pattern!r} within {timeout_s} s; got {seen!r}")


@pytest.mark.slow
def test_a_hub_client_that_drops_is_one_line_on_stderr_and_the_hub_serves_on() -> None:
    """A killed client made `grasplink bus hub` print two third-party tracebacks (the
    session's send thread: BrokenPipeError; its receive loop: ConnectionResetError)."""
    from grasplink.bus.url import open_bus

    hub = subprocess.Popen(
        [sys.executable, "-m", "grasplink.cli", "bus", "hub", "--port", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=_child_env(),
    )
    out: queue.Queue[str] = queue.Queue()
    err: queue.Queue[str] = queue.Queue()
    readers = [_lines_of(hub.stdout, out), _lines_of(hub.stderr, err)]
    client = None
    seen_out: list[str] = []
    seen_err: list[str] = []
    try:
        url = re.search(
            r"remote:ws://\S+", _wait_line(out, r"--bus remote:ws://", 30, seen_out)
        ).group(0)  # type: ignore[union-attr]
        client = subprocess.Popen(
            [sys.executable, "-c", DROPPING_CLIENT, url],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
            env=_child_env(),
        )
        client_out: queue.Queue[str] = queue.Queue()
        readers.append(_lines_of(client.stdout, client_out))
        _wait_line(client_out, "joined", 30, [])
        sender, other = open_bus(url), open_bus(url)
        try:
            frame = can.Message(arbitration_id=0x181, data=b"\x01" * 8, is_extended_id=False)
            sender.send(frame)
            _wait_line(client_out, "hearing", 30, [])
            client.kill()  # no websocket goodbye: the hub's next send meets a dead socket
            client.wait(timeout=30)
            deadline = time.monotonic() + 30
            while err.empty() and time.monotonic() < deadline:
                sender.send(frame)  # keep the hub writing to the dead client
                time.sleep(0.01)
            line = _wait_line(err, r"CAN hub: client 127\.0\.0\.1:\d+ dropped \(", 30, seen_err)
            # The hub serves on: the two clients left still hear each other.
            while other.recv(0) is not None:
                pass
            sender.send(can.Message(arbitration_id=0x202, data=b"on", is_extended_id=False))
            deadline = time.monotonic() + 30
            heard = None
            while time.monotonic() < deadline and (heard is None or heard.arbitration_id != 0x202):
                heard = other.recv(1.0)
            assert heard is not None and heard.arbitration_id == 0x202
        finally:
            sender.shutdown()
            other.shutdown()
        hub.send_signal(signal.SIGTERM)
        hub.wait(timeout=30)
    finally:
        for proc in (client, hub):
            if proc is not None and proc.poll() is None:
                proc.kill()
                proc.wait()
        for reader in readers:
            reader.join(timeout=10)
    while not err.empty():
        seen_err.append(err.get())
    stderr = "".join(seen_err)
    assert "Traceback" not in stderr, stderr
    assert "dropped" in line and stderr.count("dropped") == 1, stderr
    assert hub.returncode == 0, stderr


# -- 5. a python-canopen slave on the hub ---------------------------------------------------------


def _wait(condition, timeout_s: float = 30.0) -> bool:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


@pytest.mark.slow
def test_a_canopen_local_nodes_heartbeat_on_the_hub_is_heard_by_another_client() -> None:
    """python-can-remote's periodic task broke python-canopen's heartbeat producer: the
    first state change raised "TypeError: super() argument 1 must be a type, not
    CyclicSendTask" (its modify_data), so no python-canopen slave could join a hub."""
    import canopen

    from grasplink.bus import CanHub
    from grasplink.bus.url import open_bus

    eds = str(ROOT / "grasplink" / "profiles" / "belt.eds")
    with CanHub("127.0.0.1", 0) as hub:
        slave_net = canopen.Network(open_bus(hub.url)).connect()
        master_net = canopen.Network(open_bus(hub.url)).connect()
        try:
            slave = canopen.LocalNode(0x05, eds)
            slave_net.add_node(slave)
            watched = master_net.add_node(canopen.RemoteNode(0x05, eds))
            slave.nmt.state = "PRE-OPERATIONAL"
            slave.nmt.start_heartbeat(50)
            assert _wait(lambda: watched.nmt.state == "PRE-OPERATIONAL")
            slave.nmt.state = "OPERATIONAL"  # the heartbeat's data changes: modify_data
            assert _wait(lambda: watched.nmt.state == "OPERATIONAL")
            slave.nmt.stop_heartbeat()
        finally:
            slave_net.disconnect()
            master_net.disconnect()


@pytest.mark.slow
def test_network_send_periodic_on_the_hub_sends_updated_data() -> None:
    import canopen

    from grasplink.bus import CanHub
    from grasplink.bus.url import open_bus

    with CanHub("127.0.0.1", 0) as hub:
        network = canopen.Network(open_bus(hub.url)).connect()
        listener = open_bus(hub.url)
        try:
            task = network.send_periodic(0x181, b"\x01", 0.02)
            task.update(b"\x02")
            deadline = time.monotonic() + 30
            data = None
            while time.monotonic() < deadline and data != b"\x02":
                msg = listener.recv(1.0)
                data = None if msg is None else bytes(msg.data)
            assert data == b"\x02"
            task.stop()
        finally:
            network.disconnect()
            listener.shutdown()


# -- 6. `grasplink run`: how fast a scene ran -----------------------------------------------------


@pytest.mark.parametrize(
    ("wall_per_simulated_s", "says"),
    [
        (2.5, "(0.4x real time (2.5x slower))"),  # said "(0x real time)"
        (1 / 2.5, "(2.5x real time)"),  # said "(2x real time)"
        (1 / 38, "(38x real time)"),
        (250.0, "(0.004x real time (250x slower))"),
    ],
)
def test_run_prints_the_speed_with_two_significant_digits_even_below_real_time(
    tmp_path: Path, monkeypatch, capsys, wall_per_simulated_s: float, says: str
) -> None:
    from grasplink import cli
    from grasplink.simulators.engine import Simulation

    scene = tmp_path / "belt.toml"
    scene.write_text('[scene]\nname = "belt"\nduration_s = 0.2\n[nodes.belt]\n')
    run = Simulation.run

    def run_on_a_slow_machine(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        summary = run(self, *args, **kwargs)
        self.wall_s = summary["simulated_s"] * wall_per_simulated_s  # what the clock said
        return summary

    monkeypatch.setattr(Simulation, "run", run_on_a_slow_machine)
    assert cli.main(["run", str(scene), "--out", str(tmp_path / "out")]) == 0
    first = capsys.readouterr().out.splitlines()[0]
    assert first.startswith("belt: 0.2 s simulated in ") and first.endswith(says), first


# -- 7. the commands the docs show still work as written ------------------------------------------

DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
COMMAND = re.compile(r"^\s*(?:\$\s+)?(?:\.venv/bin/)?grasplink\s+(.*)$")
# A synopsis, not a command: optional parts, choices, repetition or a placeholder (URL, FILE).
SYNOPSIS = re.compile(r"[\[{|]|\.\.\.|(?<![\w.:/=-])[A-Z][A-Z0-9_]*(?:\.[a-z{][\w,}]*)?(?![\w:/])")


def _doc_commands() -> list[tuple[str, str, str]]:
    """(where, the command after `grasplink`, the next line of its block) for every command
    line in a fenced block of README.md and docs/*.md (continuation lines joined)."""
    found = []
    for path in DOCS:
        lines = path.read_text().splitlines()
        fenced = False
        i = 0
        while i < len(lines):
            line = lines[i]
            if line.lstrip().startswith("```"):
                fenced = not fenced
            elif fenced and (match := COMMAND.match(line)):
                where = f"{path.relative_to(ROOT)}:{i + 1}"
                text = match.group(1)
                while text.rstrip().endswith("\\") and i + 1 < len(lines):
                    i += 1
                    text = text.rstrip()[:-1] + " " + lines[i].strip()
                following = lines[i + 1] if i + 1 < len(lines) else ""
                found.append((where, text, following))
            i += 1
    return found


def _words(text: str) -> list[str]:
    import shlex

    words = shlex.split(text, comments=True)
    return words[:-1] if words and words[-1] == "&" else words


def _help_of(words: list[str]) -> str:
    """The --help text of the (sub)command the words start with."""
    import contextlib
    import io

    from grasplink.cli import build_parser

    path = []
    for word in words[:2]:
        if not re.fullmatch(r"[a-z]+", word):
            break
        path.append(word)
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit) as exited:
        build_parser().parse_args([*path, "--help"])
    assert exited.value.code == 0, path
    return out.getvalue()


def test_the_docs_show_commands() -> None:
    assert len(_doc_commands()) > 40


@pytest.mark.parametrize(("where", "text", "following"), _doc_commands())
def test_a_command_in_the_docs_parses_and_its_urls_are_valid(
    where: str, text: str, following: str, capsys
) -> None:
    """Every `grasplink ...` line of README.md and docs/*.md: a synopsis names only options
    its subcommand has; a command parses, and its --bus/--modbus/--mqtt URLs parse (or fail
    with the error the docs print beside them)."""
    from grasplink.bus.url import parse_bus_url
    from grasplink.cli import build_parser
    from grasplink.errors import GrasplinkError
    from grasplink.surfaces.modbus.url import parse_modbus_url
    from grasplink.surfaces.telemetry.url import parse_broker_url

    words = _words(text)  # without a trailing comment or `&`
    if SYNOPSIS.search(" ".join(words)):
        help_text = _help_of(words)
        for flag in re.findall(r"(?<![\w-])--[a-z][a-z-]*", " ".join(words)):
            assert flag in help_text, f"{where}: {flag} is not an option of grasplink {words[0]}"
        return
    try:
        build_parser().parse_args(words)
    except SystemExit:
        pytest.fail(f"{where}: grasplink {text}: {capsys.readouterr().err.strip()}")
    shown_error = re.search(r"error: (.*)$", following)
    parsers = {"--bus": parse_bus_url, "--modbus": parse_modbus_url, "--mqtt": parse_broker_url}
    for flag, value in itertools.pairwise(words):
        if flag not in parsers:
            continue
        if shown_error:
            with pytest.raises(GrasplinkError) as caught:
                parsers[flag](value)
            assert shown_error.group(1) in str(caught.value), where
        else:
            parsers[flag](value)


def test_python_examples_in_the_docs_name_valid_bus_urls() -> None:
    """docs/buses.md showed parse_bus_url("socketcan:can0?bitrate=1000000"), which raises:
    SocketCAN takes its bitrate from `ip link`, not from the URL."""
    from grasplink.bus.url import parse_bus_url

    for path in DOCS:
        for url in re.findall(r"(?:parse_bus_url|open_bus)\(\"([^\"]+)\"\)", path.read_text()):
            parse_bus_url(url)

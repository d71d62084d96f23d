"""`grasplink gateway --modbus URL`: served beside the live gateway, errors on one line."""

from __future__ import annotations

import os
import re
import signal
import socket
import subprocess
import sys
import uuid

import pytest

from grasplink import cli
from tests.modbus.conftest import ALL_NODES, RMAP, mbpoll, mbpoll_values, wait_until

pytestmark = pytest.mark.slow


def gateway_args(*extra: str) -> list[str]:
    return ["gateway", "--with-nodes", "--bus", f"virtual:cli-{uuid.uuid4().hex[:12]}", *extra]


def one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("grasplink: error: modbus") and "\n" not in err, err
    return err


def test_a_bad_modbus_url_exits_1_before_the_bus_is_touched(capsys):
    assert cli.main(gateway_args("--modbus", "modbus://127.0.0.1:1502")) == 1
    assert "unknown scheme" in one_line_error(capsys)


def test_a_port_in_use_exits_1_with_one_line(capsys):
    with socket.create_server(("127.0.0.1", 0)) as taken:
        port = taken.getsockname()[1]
        assert cli.main(gateway_args("--modbus", f"tcp://127.0.0.1:{port}", "--duration", "5")) == 1
    assert "already in use" in one_line_error(capsys)


def test_a_missing_serial_device_exits_1_with_one_line(capsys, tmp_path):
    device = tmp_path / "ttyUSB9"
    assert cli.main(gateway_args("--modbus", f"rtu://{device}", "--duration", "5")) == 1
    assert one_line_error(capsys) == f"grasplink: error: modbus: no serial device {device}"


def test_grasplink_gateway_serves_modbus_until_stopped():
    """The CLI end to end: the printed port answers mbpoll with the live nodes, Ctrl-C stops."""
    process = subprocess.Popen(
        [sys.executable, "-m", "grasplink.cli", *gateway_args("--modbus", "tcp://127.0.0.1:0")],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    try:
        line = process.stdout.readline()
        match = re.match(r"modbus tcp://127\.0\.0\.1:(\d+) ", line)
        assert match, line + process.stderr.read()
        address = ["-p", match.group(1), "127.0.0.1"]
        operational = RMAP["nodes_operational"].address

        def nodes_running() -> bool:
            run = mbpoll("-t", "3", "-r", str(operational), *address)
            return mbpoll_values(run.stdout).get(operational) == ALL_NODES

        wait_until(nodes_running, what="every node operational, read over Modbus")
        run = mbpoll("-t", "4", "-r", str(RMAP["reflex_enabled"].address), *address, "0")
        assert run.returncode == 0, run.stderr
        run = mbpoll("-t", "4", "-r", str(RMAP["reflex_enabled"].address), *address)
        assert mbpoll_values(run.stdout) == {RMAP["reflex_enabled"].address: 0}
    finally:
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=20)
    assert process.returncode == 0, err
    assert "stopped:" in out

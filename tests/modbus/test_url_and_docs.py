"""Modbus URLs (localhost unless told otherwise, one-line errors) and the generated docs."""

from __future__ import annotations

from pathlib import Path

import pytest

from grasplink import cli
from grasplink.errors import ConfigError
from grasplink.surfaces.modbus.docgen import render_modbus_markdown
from grasplink.surfaces.modbus.registers import register_map
from grasplink.surfaces.modbus.url import ModbusUrl, parse_modbus_url

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("tcp://127.0.0.1:1502", ModbusUrl("tcp", host="127.0.0.1", port=1502)),
        ("tcp://:1502", ModbusUrl("tcp", host="127.0.0.1", port=1502)),  # localhost by default
        ("tcp://0.0.0.0:1502", ModbusUrl("tcp", host="0.0.0.0", port=1502)),  # explicit
        ("tcp://[::1]:1502", ModbusUrl("tcp", host="::1", port=1502)),
        ("tcp://127.0.0.1:0", ModbusUrl("tcp", host="127.0.0.1", port=0)),
        ("tcp://127.0.0.1:502", ModbusUrl("tcp", host="127.0.0.1", port=502)),  # when named
        (
            "rtu:///dev/ttyUSB0?baud=115200&parity=N&unit=1",
            ModbusUrl("rtu", device="/dev/ttyUSB0", baud=115200, parity="N", unit=1),
        ),
        ("rtu:///dev/ttyS0", ModbusUrl("rtu", device="/dev/ttyS0", baud=19200, parity="E", unit=1)),
        (
            "rtu:///dev/ttyS0?parity=odd&stopbits=2&unit=17",
            ModbusUrl("rtu", device="/dev/ttyS0", parity="O", stopbits=2, unit=17),
        ),
    ],
)
def test_modbus_urls_parse_with_localhost_and_serial_line_defaults(text, expected):
    assert parse_modbus_url(text) == expected


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("1502", "expected tcp://"),
        ("http://127.0.0.1:1502", "unknown scheme"),
        ("tcp://127.0.0.1:70000", "out of range"),
        ("tcp://127.0.0.1:1502?unit=3", "every unit id"),
        ("tcp://127.0.0.1:1502/x", "tcp://HOST:PORT"),
        ("rtu://", "no serial device"),
        ("rtu:///dev/ttyS0?baud=fast", "baud"),
        ("rtu:///dev/ttyS0?parity=X", "parity"),
        ("rtu:///dev/ttyS0?unit=0", "unit must be a whole number 1..247"),
        ("rtu:///dev/ttyS0?unit=248", "unit"),
        ("rtu:///dev/ttyS0?speed=9600", "unknown option 'speed'"),
    ],
)
def test_a_bad_modbus_url_is_one_config_error_saying_what_is_wrong(text, says):
    with pytest.raises(ConfigError) as caught:
        parse_modbus_url(text)
    message = str(caught.value)
    assert says in message and "\n" not in message and repr(text) in message


def test_committed_docs_equal_the_generators_output():
    """docs/modbus.md is generated: regenerate with `make docs` after changing the map."""
    assert (ROOT / "docs" / "modbus.md").read_text() == render_modbus_markdown()


def test_docs_list_every_register_and_command():
    text = render_modbus_markdown()
    rmap = register_map()
    for register in rmap.inputs + rmap.holding:
        assert f"`{register.name}`" in text
    for group in rmap.groups:
        assert f"`{group.command}`" in text
    for heading in ("word order", "sentinel", "two's complement", "exception"):
        assert heading in text.lower()


def test_print_register_map_writes_the_document(capsys):
    assert cli.main(["gateway", "--print-register-map"]) == 0
    assert capsys.readouterr().out == render_modbus_markdown()

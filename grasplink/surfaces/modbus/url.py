"""Modbus endpoint URLs: `tcp://HOST:PORT` and `rtu:///dev/ttyX?baud=..&parity=..&unit=..`.

A gateway on a prosthesis must not expose its command registers to a network
by accident: TCP binds 127.0.0.1 unless the URL names another address
(`tcp://0.0.0.0:1502` listens on every interface, on purpose). Nor does it take
Modbus's own port 502 unless told: a URL without a port is refused (502 needs
root, and a gateway run as root would have bound it silently). The host is
checked and resolved here, so a bad one is named before anything starts. RTU
defaults are the Modbus serial line's (19200 baud, even parity, one stop bit),
which are also mbpoll's.
"""

from __future__ import annotations

from dataclasses import dataclass
from urllib.parse import parse_qsl, urlsplit

from grasplink.core.hosts import host_problem, resolve_problem
from grasplink.errors import BusError, ConfigError

DEFAULT_HOST = "127.0.0.1"
MODBUS_TCP_PORT = 502  # Modbus's registered port: taken only when a URL names it
EXAMPLE_TCP_PORT = 1502  # what the docs and messages suggest: no privileges needed
DEFAULT_BAUD = 19200
DEFAULT_UNIT = 1
MAX_UNIT = 247  # the highest Modbus unit (slave) address
PARITIES = {"N": "none", "E": "even", "O": "odd"}
EXAMPLES = "tcp://127.0.0.1:1502 or rtu:///dev/ttyUSB0?baud=115200&parity=N&unit=1"


@dataclass(frozen=True, slots=True)
class ModbusUrl:
    """Where the server listens. `unit` (RTU) is the only unit id it answers; over TCP
    it answers every unit id (a TCP end device, not a gateway to a serial line). With a
    gateway per bus, units count up from `unit` (TCP: from 1), one per gateway."""

    scheme: str  # "tcp" or "rtu"
    host: str = DEFAULT_HOST
    port: int = MODBUS_TCP_PORT
    device: str = ""
    baud: int = DEFAULT_BAUD
    parity: str = "E"
    stopbits: int = 1
    unit: int | None = None

    def __str__(self) -> str:
        if self.scheme == "tcp":
            return f"tcp://{_bracketed(self.host)}:{self.port}"
        return (
            f"rtu://{self.device}?baud={self.baud}&parity={self.parity}"
            f"&stopbits={self.stopbits}&unit={self.unit}"
        )


def parse_modbus_url(text: str) -> ModbusUrl:
    """A ModbusUrl, or a one-line ConfigError saying what is wrong and what is expected."""
    if not isinstance(text, str) or "://" not in text:
        raise ConfigError(f"modbus URL {text!r}: expected {EXAMPLES}")
    try:
        parts = urlsplit(text)
        port = parts.port
    except ValueError as exc:
        raise ConfigError(f"modbus URL {text!r}: {exc}") from None
    try:
        query = dict(
            parse_qsl(parts.query, keep_blank_values=True, strict_parsing=bool(parts.query))
        )
    except ValueError:
        raise ConfigError(f"modbus URL {text!r}: malformed query {parts.query!r}") from None
    if parts.fragment:
        raise ConfigError(f"modbus URL {text!r}: unexpected #{parts.fragment}")
    if parts.scheme == "tcp":
        if query:
            raise ConfigError(
                f"modbus URL {text!r}: tcp takes no options (it answers every unit id), "
                f"got {', '.join(query)}"
            )
        if parts.path not in ("", "/"):
            raise ConfigError(f"modbus URL {text!r}: expected tcp://HOST:PORT")
        host = parts.hostname or DEFAULT_HOST
        if port is None:
            raise ConfigError(
                f"modbus URL {text!r}: give a port, e.g. tcp://{_bracketed(host)}:"
                f"{EXAMPLE_TCP_PORT}; Modbus's own port {MODBUS_TCP_PORT} needs root and is "
                f"taken only when named (tcp://{_bracketed(host)}:{MODBUS_TCP_PORT})"
            )
        problem = host_problem(host) or resolve_problem(host, port, passive=True)
        if problem:
            raise ConfigError(f"modbus URL {text!r}: {problem}")
        # Port 0 takes any free port (tests); the server reports the one it got.
        return ModbusUrl("tcp", host=host, port=port)
    if parts.scheme == "rtu":
        device = parts.netloc + parts.path
        if not device:
            raise ConfigError(f"modbus URL {text!r}: no serial device; expected rtu:///dev/ttyX")
        options = dict(query)
        baud = _integer(text, options, "baud", DEFAULT_BAUD, 50, 4_000_000)
        stopbits = _integer(text, options, "stopbits", 1, 1, 2)
        unit = _integer(text, options, "unit", DEFAULT_UNIT, 1, MAX_UNIT)
        raw_parity = options.pop("parity", "E")
        parity = raw_parity.upper()[:1]
        if raw_parity.lower() not in {*"neo", *PARITIES.values()}:
            raise ConfigError(f"modbus URL {text!r}: parity must be N, E or O, got {raw_parity!r}")
        if options:
            raise ConfigError(
                f"modbus URL {text!r}: unknown option {sorted(options)[0]!r}; "
                "options: baud, parity, stopbits, unit"
            )
        return ModbusUrl(
            "rtu", device=device, baud=baud, parity=parity, stopbits=stopbits, unit=unit
        )
    raise ConfigError(f"modbus URL {text!r}: unknown scheme {parts.scheme!r}; expected {EXAMPLES}")


def _bracketed(host: str) -> str:
    return f"[{host}]" if ":" in host else host


def unit_ids(url: ModbusUrl, count: int) -> list[int | None]:
    """The unit ids `count` gateways are served at: one gateway as before (a TCP server
    answers every unit id: None); several, consecutive from the URL's unit (TCP: from 1)."""
    if count < 1:
        raise ValueError("ModbusServer needs at least one gateway")
    if count == 1:
        return [url.unit]
    first = url.unit or 1
    if first + count - 1 > MAX_UNIT:
        raise BusError(
            f"modbus: {count} gateways from unit {first} need units up to "
            f"{first + count - 1}; the highest is {MAX_UNIT}"
        )
    return list(range(first, first + count))


def _integer(
    text: str, options: dict[str, str], key: str, default: int, low: int, high: int
) -> int:
    if key not in options:
        return default
    raw = options.pop(key)
    try:
        value = int(raw)
    except ValueError:
        value = None
    if value is None or not low <= value <= high:
        raise ConfigError(
            f"modbus URL {text!r}: {key} must be a whole number {low}..{high}, got {raw!r}"
        )
    return value

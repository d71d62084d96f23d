"""Broker URLs (`mqtt://user:pass@host:port?group=…`), telemetry identifiers and TLS contexts.

Everything a user can get wrong here is a one-line `ConfigError`, raised before
the bus or the broker is touched.
"""

from __future__ import annotations

import re
import ssl
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import parse_qsl, unquote, urlsplit

from grasplink.core.hosts import host_problem
from grasplink.errors import ConfigError

DEFAULT_PORTS = {"mqtt": 1883, "mqtts": 8883}
DEFAULT_GROUP = "grasplink"
DEFAULT_BUFFER_KIB = 8192  # store-and-forward bound per connection: > 60 s of outage at 20 Hz
DEFAULT_KEEPALIVE_S = 10
URL_FORM = "mqtt://[user[:password]@]host[:port][?group=G&buffer_kib=N&keepalive_s=S] or mqtts://…"
QUERY_KEYS = ("group", "buffer_kib", "keepalive_s")
# MQTT topic levels and Sparkplug IDs: no separators, wildcards, spaces or control characters.
_ID = re.compile(r"[A-Za-z0-9_.:-]{1,64}")


@dataclass(frozen=True)
class BrokerUrl:
    """Where the broker is and how to log in; `display` never shows the password."""

    scheme: str
    host: str
    port: int
    username: str | None = None
    password: str | None = field(default=None, repr=False)
    group: str = DEFAULT_GROUP
    buffer_bytes: int = DEFAULT_BUFFER_KIB * 1024
    keepalive_s: int = DEFAULT_KEEPALIVE_S

    @property
    def tls(self) -> bool:
        return self.scheme == "mqtts"

    @property
    def display(self) -> str:
        user = f"{self.username}@" if self.username else ""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"{self.scheme}://{user}{host}:{self.port}"


def parse_broker_url(text: str) -> BrokerUrl:
    """`mqtt://…` or `mqtts://…`; ConfigError naming the URL (without its password)."""
    shown = _hide_password(text)
    try:
        parts = urlsplit(text)
        port = parts.port
    except ValueError as exc:
        raise ConfigError(f"--mqtt {shown!r}: {exc}; expected {URL_FORM}") from None
    if parts.scheme not in DEFAULT_PORTS:
        raise ConfigError(f"--mqtt {shown!r}: expected {URL_FORM}")
    if not parts.hostname:
        raise ConfigError(f"--mqtt {shown!r}: no host; expected {URL_FORM}")
    problem = host_problem(parts.hostname)
    if problem:  # the resolver's own word for 256.1.1.1 was "Name or service not known"
        raise ConfigError(f"--mqtt {shown!r}: {problem}")
    if parts.path not in ("", "/") or parts.fragment:
        raise ConfigError(f"--mqtt {shown!r}: a broker URL has no path; expected {URL_FORM}")
    if port == 0:
        raise ConfigError(f"--mqtt {shown!r}: port 0 is not a broker's port")
    options: dict[str, str] = {}
    for key, value in parse_qsl(parts.query, keep_blank_values=True, strict_parsing=False):
        if key not in QUERY_KEYS:
            raise ConfigError(
                f"--mqtt {shown!r}: unknown option {key!r}; options: {', '.join(QUERY_KEYS)}"
            )
        options[key] = value
    group = options.get("group", DEFAULT_GROUP)
    check_id(group, f"--mqtt {shown!r}: group")
    return BrokerUrl(
        scheme=parts.scheme,
        host=parts.hostname,
        port=port or DEFAULT_PORTS[parts.scheme],
        username=unquote(parts.username) if parts.username else None,
        password=unquote(parts.password) if parts.password is not None else None,
        group=group,
        buffer_bytes=_integer(options, "buffer_kib", DEFAULT_BUFFER_KIB, 16, 1 << 20, shown) * 1024,
        keepalive_s=_integer(options, "keepalive_s", DEFAULT_KEEPALIVE_S, 2, 3600, shown),
    )


def check_id(value: str, what: str = "--mqtt-id") -> str:
    """A gateway ID or Sparkplug group: one MQTT topic level, also valid in Sparkplug."""
    if not _ID.fullmatch(value):
        raise ConfigError(
            f"{what} {value!r}: expected 1..64 of the characters A-Z a-z 0-9 _ . : - "
            "(no '/', '+', '#' or spaces: it is one topic level)"
        )
    return value


def tls_context(url: BrokerUrl, ca_file: Path | None) -> ssl.SSLContext | None:
    """The TLS context for `mqtts://` (the CA file, else the system's trust store)."""
    if not url.tls:
        if ca_file is not None:
            raise ConfigError(f"--mqtt-ca {ca_file}: needs an mqtts:// broker URL")
        return None
    if ca_file is not None and not ca_file.is_file():
        raise ConfigError(f"--mqtt-ca {ca_file}: no such file")
    try:
        return ssl.create_default_context(cafile=str(ca_file) if ca_file else None)
    except (ssl.SSLError, OSError, ValueError) as exc:
        raise ConfigError(f"--mqtt-ca {ca_file}: not a PEM CA certificate ({exc})") from None


def _integer(
    options: dict[str, str], key: str, default: int, low: int, high: int, shown: str
) -> int:
    if key not in options:
        return default
    text = options[key]
    if not text.isdigit() or not low <= int(text) <= high:
        raise ConfigError(
            f"--mqtt {shown!r}: {key}={text!r}: expected a whole number {low}..{high}"
        )
    return int(text)


def _hide_password(text: str) -> str:
    return re.sub(r"(//[^:/@]*):[^@/]*@", r"\1:***@", text)

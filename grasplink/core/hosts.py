"""Host names and addresses in URLs (Modbus, MQTT, the CAN hub), checked before any socket.

The socket layer reports a malformed host badly: `tcp://256.1.1.1:1502` became
"Unknown error -2" (getaddrinfo's EAI_NONAME through os.strerror). Every URL
parser asks `host_problem` first, so the message names the host and what is
wrong with it; `resolve_problem` asks the resolver and names the host too.
"""

from __future__ import annotations

import ipaddress
import re
import socket

# RFC 1123 labels; "_" is let through, as resolvers and container networks do.
_LABEL = re.compile(r"(?!-)[A-Za-z0-9_-]{1,63}(?<!-)")
_DOTTED = re.compile(r"[0-9.]+")


def host_problem(host: str) -> str | None:
    """What is wrong with `host` (an IP address or a host name), or None if it is well formed."""
    if ":" in host:
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            return f"{host!r} is not an IPv6 address"
        return None
    if _DOTTED.fullmatch(host):
        try:
            ipaddress.IPv4Address(host)
        except ValueError:
            return f"{host!r} is not an IPv4 address (four numbers 0..255, e.g. 127.0.0.1)"
        return None
    name = host[:-1] if host.endswith(".") else host
    if len(name) > 253 or not all(_LABEL.fullmatch(label) for label in name.split(".")):
        return (
            f"{host!r} is not a host name (labels of letters, digits and '-', "
            "separated by dots) or an IP address"
        )
    return None


def resolve_problem(host: str, port: int, *, passive: bool = False) -> str | None:
    """Why `host` cannot be resolved (naming it), or None if the resolver finds it.

    `passive` asks for an address to listen on rather than to connect to.
    """
    flags = socket.AI_PASSIVE if passive else 0
    try:
        socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=flags)
    except socket.gaierror as exc:
        return f"cannot resolve host {host!r} ({exc.strerror or exc})"
    except (OSError, UnicodeError) as exc:
        return f"cannot resolve host {host!r} ({exc})"
    return None

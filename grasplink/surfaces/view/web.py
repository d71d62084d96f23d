"""The page's HTTP, sans-IO: a request head in, a response out (docs/view.md, Security).

The server answers GET (and HEAD) for a fixed list of its own files and the event
stream; nothing is looked up on disk from the request (no path traversal to guard). A
request whose Host does not name this server is answered 421, so a web page elsewhere
cannot reach the view through a name of its own that resolves here (DNS rebinding).
"""

from __future__ import annotations

import ipaddress
from dataclasses import dataclass
from importlib import resources

MAX_HEAD_BYTES = 8192
EVENTS_PATH = "/events"
#: URL path -> (file under static/, content type): everything the server sends
STATIC: dict[str, tuple[str, str]] = {
    "/": ("index.html", "text/html; charset=utf-8"),
    "/view.js": ("view.js", "text/javascript; charset=utf-8"),
    "/view.css": ("view.css", "text/css; charset=utf-8"),
    "/uplot/uPlot.iife.min.js": ("uplot/uPlot.iife.min.js", "text/javascript; charset=utf-8"),
    "/uplot/uPlot.min.css": ("uplot/uPlot.min.css", "text/css; charset=utf-8"),
}
REASONS = {
    200: "OK",
    400: "Bad Request",
    404: "Not Found",
    405: "Method Not Allowed",
    421: "Misdirected Request",
    431: "Request Header Fields Too Large",
    503: "Service Unavailable",
}
# Everything the page needs comes from this server; no frame may embed it.
SECURITY_HEADERS = (
    ("Content-Security-Policy", "default-src 'self'; img-src 'self' data:; "
     "frame-ancestors 'none'; base-uri 'none'; form-action 'none'"),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
    ("Cache-Control", "no-store"),
)  # fmt: skip
_LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})


class HttpError(Exception):
    """A request answered with an error status (and closed)."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status


@dataclass(frozen=True)
class Request:
    method: str
    path: str  # without the query
    host: str | None


@dataclass(frozen=True)
class Response:
    status: int
    body: bytes = b""
    content_type: str = "text/plain; charset=utf-8"
    events: bool = False  # the event stream: the head now, frames after it


def load_files() -> dict[str, bytes]:
    """Every file of STATIC, read once (a package installed without them fails here)."""
    folder = resources.files("grasplink.surfaces.view") / "static"
    return {path: (folder / name).read_bytes() for path, (name, _) in STATIC.items()}


def parse_head(head: bytes) -> Request:
    """The request line and Host of an HTTP/1.x request head (up to the blank line)."""
    if len(head) > MAX_HEAD_BYTES:
        raise HttpError(431, f"request head over {MAX_HEAD_BYTES} bytes")
    try:
        text = head.decode("ascii")
    except UnicodeDecodeError:
        raise HttpError(400, "request head is not ASCII") from None
    lines = text.split("\r\n")
    parts = lines[0].split(" ")
    if len(parts) != 3 or not parts[2].startswith("HTTP/1."):
        raise HttpError(400, f"not an HTTP/1.x request line: {lines[0][:80]!r}")
    method, target, _ = parts
    hosts = [
        line.split(":", 1)[1].strip()
        for line in lines[1:]
        if ":" in line and line.split(":", 1)[0].strip().lower() == "host"
    ]
    if len(hosts) > 1:
        raise HttpError(400, "more than one Host header")
    return Request(method, target.split("?", 1)[0], hosts[0] if hosts else None)


class HostRule:
    """Which Host headers name this server: bound to loopback, 127.0.0.1, localhost and
    [::1]; bound to every address, any IP address (a name could be anyone's); bound to a
    name or address, that one. Always with the server's port."""

    def __init__(self, bound_host: str, port: int) -> None:
        self.port = port
        host = bound_host.strip("[]").lower()
        self.any_ip = host in ("0.0.0.0", "::", "")
        self.names = {host} | (_LOOPBACK_NAMES if _is_loopback(host) else set())

    def allows(self, header: str | None) -> bool:
        if header is None:
            return False
        name, port = _split_host(header)
        if port != self.port:
            return False
        return name in self.names or (self.any_ip and (_is_ip(name) or name == "localhost"))


def respond(request: Request, hosts: HostRule, files: dict[str, bytes]) -> Response:
    """The answer to one request: a file, the event stream, or an error."""
    if not hosts.allows(request.host):
        return Response(421, b"this server does not answer to that Host\n")
    if request.method not in ("GET", "HEAD"):
        return Response(405, b"read-only: GET only\n")
    if request.path == EVENTS_PATH:
        return Response(200, content_type="text/event-stream", events=True)
    if request.path in files:
        return Response(200, files[request.path], STATIC[request.path][1])
    return Response(404, b"not found\n")


def encode_head(response: Response, body_length: int | None = None) -> bytes:
    """The status line and headers; the body's length unless it is the event stream."""
    lines = [f"HTTP/1.1 {response.status} {REASONS[response.status]}"]
    lines.append(f"Content-Type: {response.content_type}")
    lines += [f"{name}: {value}" for name, value in SECURITY_HEADERS]
    if response.events:
        lines.append("Connection: keep-alive")
    else:
        length = len(response.body) if body_length is None else body_length
        lines += [f"Content-Length: {length}", "Connection: close"]
    return ("\r\n".join(lines) + "\r\n\r\n").encode("ascii")


def encode(response: Response, *, head_only: bool = False) -> bytes:
    head = encode_head(response)
    return head if head_only else head + response.body


def _split_host(header: str) -> tuple[str, int | None]:
    header = header.strip().lower()
    if header.startswith("["):
        name, _, rest = header[1:].partition("]")
        port_text = rest[1:] if rest.startswith(":") else ""
    else:
        name, _, port_text = header.rpartition(":") if ":" in header else (header, "", "")
    return name, int(port_text) if port_text.isdigit() else None


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def _is_loopback(host: str) -> bool:
    return host == "localhost" or (_is_ip(host) and ipaddress.ip_address(host).is_loopback)

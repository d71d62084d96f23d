"""The page's HTTP, sans-IO: a request head in, a response out (docs/view.md, Security).

The server answers GET (and HEAD) for a fixed list of its own files and the event
stream; nothing is looked up on disk from the request (no path traversal to guard). A
request whose Host does not name this server is answered 421, so a web page elsewhere
cannot reach the view through a name of its own that resolves here (DNS rebinding).
With commands allowed, one more: POST to COMMAND_PATH, JSON, carrying a token this
server put in a page it served (another site can make a browser post, not read a page).
"""

from __future__ import annotations

import html
import ipaddress
import json
from dataclasses import dataclass, field
from importlib import resources

from grasplink.surfaces.view.commands import MAX_BODY_BYTES, Tokens, offered

MAX_HEAD_BYTES = 8192
EVENTS_PATH = "/events"
COMMAND_PATH = "/command"
TOKEN_HEADER = "x-grasplink-token"
# where the page learns it may command: filled in per page with the token (commands allowed)
COMMANDS_META = b'<meta name="grasplink-commands" content="">'
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
    403: "Forbidden",
    405: "Method Not Allowed",
    411: "Length Required",
    413: "Content Too Large",
    415: "Unsupported Media Type",
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
    headers: dict[str, str] = field(default_factory=dict)  # names in lower case
    query: str = ""  # after the "?" (a recording's event stream: where to play from)

    @property
    def content_length(self) -> int | None:
        text = self.headers.get("content-length")
        return int(text) if text is not None and text.isdigit() else None


@dataclass(frozen=True)
class Response:
    status: int
    body: bytes = b""
    content_type: str = "text/plain; charset=utf-8"
    events: bool = False  # the event stream: the head now, frames after it
    command: bool = False  # a command: its body (content_length bytes) to read and run


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
    headers: dict[str, str] = {}
    for line in lines[1:]:
        name, sep, value = line.partition(":")
        if not sep:
            continue
        key = name.strip().lower()
        if key in headers and key in _SINGLE:
            raise HttpError(400, f"more than one {name.strip()} header")
        headers[key] = value.strip()
    path, _, query = target.partition("?")
    return Request(method, path, headers.get("host"), headers, query)


_SINGLE = frozenset({"host", "content-length", "content-type", "origin", TOKEN_HEADER})


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


def respond(
    request: Request, hosts: HostRule, files: dict[str, bytes], tokens: Tokens | None = None
) -> Response:
    """The answer to one request: a file, the event stream, a command to run, or an error.
    `tokens`: commands are allowed (each page gets one); None: read-only."""
    if not hosts.allows(request.host):
        return Response(421, b"this server does not answer to that Host\n")
    if request.method == "POST" and tokens is not None and request.path == COMMAND_PATH:
        return _command(request, tokens)
    if request.method not in ("GET", "HEAD"):
        if tokens is None:
            return Response(405, b"read-only: GET only (commands need --allow-commands)\n")
        return Response(405, f"GET, or POST to {COMMAND_PATH}\n".encode())
    if request.path == EVENTS_PATH:
        return Response(200, content_type="text/event-stream", events=True)
    if request.path == "/" and tokens is not None:
        return Response(200, page_with_token(files["/"], tokens.issue()), STATIC["/"][1])
    if request.path in files:
        return Response(200, files[request.path], STATIC[request.path][1])
    return Response(404, b"not found\n")


def page_with_token(page: bytes, token: str) -> bytes:
    """The page with what it may command and the token it commands with."""
    spec = html.escape(json.dumps(offered(), separators=(",", ":")))
    meta = f'<meta name="grasplink-commands" content="{spec}" data-token="{token}">'
    return page.replace(COMMANDS_META, meta.encode(), 1)


def _command(request: Request, tokens: Tokens) -> Response:
    """A POST to COMMAND_PATH, checked before its body is read."""
    origin = request.headers.get("origin")
    if origin is not None and origin.lower() != f"http://{request.host}".lower():
        return Response(403, f"a command from {origin[:80]}, not from this page\n".encode())
    if not tokens.valid(request.headers.get(TOKEN_HEADER)):
        return Response(403, b"no valid page token: reload the page\n")
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
        return Response(415, b"a command is application/json\n")
    length = request.content_length
    if length is None:
        return Response(411, b"a command needs its Content-Length\n")
    if length > MAX_BODY_BYTES:
        return Response(413, f"a command of {length} bytes; at most {MAX_BODY_BYTES}\n".encode())
    return Response(200, content_type="application/json", command=True)


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

"""The page's HTTP without a socket: its own files only, the Host rule, read-only,
bad request heads refused, and the `--http` address checked."""

from __future__ import annotations

import socket

import pytest

from grasplink import cli
from grasplink.errors import ConfigError
from grasplink.surfaces.view.server import parse_http_address
from grasplink.surfaces.view.web import (
    MAX_HEAD_BYTES,
    STATIC,
    HostRule,
    HttpError,
    Request,
    encode,
    load_files,
    parse_head,
    respond,
)

FILES = load_files()
LOCAL = HostRule("127.0.0.1", 8642)


def get(path: str, host: str | None = "127.0.0.1:8642", method: str = "GET", rule=LOCAL):
    return respond(Request(method, path, host), rule, FILES)


def test_every_file_of_the_page_is_shipped_and_served_with_its_type() -> None:
    assert set(FILES) == set(STATIC)
    for path, (_, content_type) in STATIC.items():
        response = get(path)
        assert response.status == 200 and response.body == FILES[path]
        assert response.content_type == content_type and len(response.body) > 100
    assert b"uPlot" in FILES["/uplot/uPlot.iife.min.js"]
    assert b'src="/uplot/uPlot.iife.min.js"' in FILES["/"]


def test_the_page_loads_nothing_from_the_internet() -> None:
    for path in ("/", "/view.js", "/view.css"):
        assert b"http://" not in FILES[path] and b"https://" not in FILES[path], path


@pytest.mark.parametrize(
    "path", ["/../pyproject.toml", "/static/index.html", "/view.py", "/%2e%2e/x", "//etc/passwd"]
)
def test_anything_but_its_own_files_is_not_found(path: str) -> None:
    assert get(path).status == 404


def test_the_event_stream_is_answered_as_one() -> None:
    response = get("/events")
    assert response.status == 200 and response.events
    assert response.content_type == "text/event-stream"


@pytest.mark.parametrize("method", ["POST", "PUT", "DELETE", "OPTIONS", "PATCH"])
def test_it_is_read_only(method: str) -> None:
    assert get("/", method=method).status == 405
    assert get("/events", method=method).status == 405
    assert get("/command", method=method).status == 405  # without --allow-commands
    assert b'grasplink-commands" content=""' in get("/").body  # no token, no commands


@pytest.mark.parametrize(
    ("rule", "host", "allowed"),
    [
        (LOCAL, "127.0.0.1:8642", True),
        (LOCAL, "localhost:8642", True),
        (LOCAL, "[::1]:8642", True),
        (LOCAL, "LOCALHOST:8642", True),
        (LOCAL, "127.0.0.1:8643", False),  # another port
        (LOCAL, "127.0.0.1", False),
        (LOCAL, "evil.example:8642", False),  # a name resolving here: DNS rebinding
        (LOCAL, "192.168.1.7:8642", False),
        (LOCAL, None, False),
        (HostRule("0.0.0.0", 80), "192.168.1.7:80", True),  # every address: any IP
        (HostRule("0.0.0.0", 80), "[fe80::1]:80", True),
        (HostRule("0.0.0.0", 80), "evil.example:80", False),
        (HostRule("bench-pc.lab", 80), "bench-pc.lab:80", True),  # bound to it by name
        (HostRule("bench-pc.lab", 80), "127.0.0.1:80", False),
        (HostRule("::1", 8642), "[::1]:8642", True),
    ],
)
def test_only_hosts_naming_this_server_are_answered(rule: HostRule, host, allowed: bool) -> None:
    assert rule.allows(host) is allowed
    assert get("/", host, rule=rule).status == (200 if allowed else 421)


def test_every_answer_says_where_the_page_may_load_from() -> None:
    head = encode(get("/"), head_only=True).decode()
    assert head.startswith("HTTP/1.1 200 OK\r\n") and head.endswith("\r\n\r\n")
    assert "Content-Security-Policy: default-src 'self'" in head
    assert "X-Content-Type-Options: nosniff" in head and "frame-ancestors 'none'" in head
    assert f"Content-Length: {len(FILES['/'])}" in head


def test_a_request_head_is_read_for_its_method_path_and_host() -> None:
    head = b"GET /view.js?v=2 HTTP/1.1\r\nHost: localhost:8642\r\nAccept: */*\r\n\r\n"
    request = parse_head(head)
    assert (request.method, request.path, request.host) == ("GET", "/view.js", "localhost:8642")
    assert request.headers == {"host": "localhost:8642", "accept": "*/*"}


@pytest.mark.parametrize(
    ("head", "status", "detail"),
    [
        (b"GARBAGE\r\n\r\n", 400, "not an HTTP/1.x request line"),
        (b"GET / SPDY/3\r\n\r\n", 400, "not an HTTP/1.x request line"),
        (b"GET / HTTP/1.1\r\nHost: \xff\r\n\r\n", 400, "not ASCII"),
        (b"GET / HTTP/1.1\r\nHost: a:1\r\nHost: b:1\r\n\r\n", 400, "more than one Host"),
        (b"GET / HTTP/1.1\r\nX: " + b"a" * MAX_HEAD_BYTES + b"\r\n\r\n", 431, "request head over"),
    ],
)
def test_bad_request_heads_are_refused_with_a_reason(head: bytes, status: int, detail: str) -> None:
    with pytest.raises(HttpError, match=detail) as caught:
        parse_head(head)
    assert caught.value.status == status


@pytest.mark.parametrize(
    ("text", "host", "port"),
    [("127.0.0.1:8642", "127.0.0.1", 8642), ("[::1]:0", "::1", 0), ("0.0.0.0:80", "0.0.0.0", 80)],
)
def test_http_addresses_name_a_host_and_a_port(text: str, host: str, port: int) -> None:
    address = parse_http_address(text)
    assert (address.host, address.port) == (host, port)


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("127.0.0.1", "expected HOST:PORT"),
        ("127.0.0.1:http", "expected HOST:PORT"),
        ("127.0.0.1:70000", "expected HOST:PORT"),
        (":8642", "expected HOST:PORT"),
        ("256.1.1.1:8642", "256.1.1.1"),
    ],
)
def test_a_bad_http_address_is_one_line_naming_it(text: str, problem: str) -> None:
    with pytest.raises(ConfigError, match=problem) as caught:
        parse_http_address(text)
    assert f"--http {text!r}" in str(caught.value)


def test_a_port_already_taken_is_one_line_and_exit_1(capsys) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code = cli.main(["view", "--mqtt", "mqtt://127.0.0.1:1", "--http", f"127.0.0.1:{port}"])
    err = capsys.readouterr().err.strip()
    assert code == 1 and err.count("\n") == 0 and f"--http 127.0.0.1:{port}" in err


def test_bad_view_options_are_one_line_before_anything_starts(capsys) -> None:
    for args, problem in (
        (["--mqtt", "http://x"], "expected mqtt://"),
        (["--mqtt", "mqtt://127.0.0.1", "--gateway-id", "a/b"], "--gateway-id 'a/b'"),
        (["--mqtt", "mqtt://127.0.0.1", "--http", "nowhere"], "--http 'nowhere'"),
    ):
        assert cli.main(["view", *args]) == 1
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and problem in err, err

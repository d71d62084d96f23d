"""Commands from the page without a socket: only a page this server served may post one
(its token, its origin, JSON, bounded), and each is checked with the gateway's own parser
before it is published, a refusal naming the problem."""

from __future__ import annotations

import html
import json
import re

import pytest

from grasplink.gateway.commands import COMMANDS
from grasplink.surfaces.view.commands import (
    MAX_BODY_BYTES,
    OFFERED,
    CommandRefused,
    Tokens,
    prepare,
    read_reply,
)
from grasplink.surfaces.view.web import (
    COMMAND_PATH,
    TOKEN_HEADER,
    HostRule,
    Request,
    load_files,
    parse_head,
    respond,
)

FILES = load_files()
LOCAL = HostRule("127.0.0.1", 8642)
HOST = "127.0.0.1:8642"


def page_token(tokens: Tokens) -> tuple[str, dict]:
    page = respond(Request("GET", "/", HOST), LOCAL, FILES, tokens).body.decode()
    meta = re.search(
        r'<meta name="grasplink-commands" content="([^"]*)" data-token="([^"]+)">', page
    )
    assert meta is not None, "the page carries no command spec and token"
    return meta.group(2), json.loads(html.unescape(meta.group(1)))


def post(tokens: Tokens, headers: dict[str, str], path: str = COMMAND_PATH, host: str = HOST):
    return respond(Request("POST", path, host, {"host": host, **headers}), LOCAL, FILES, tokens)


def good_headers(token: str, length: int = 50) -> dict[str, str]:
    return {
        TOKEN_HEADER: token,
        "content-type": "application/json",
        "content-length": str(length),
        "origin": f"http://{HOST}",
    }


def test_each_page_gets_its_own_token_and_the_commands_offered() -> None:
    tokens = Tokens()
    first, spec = page_token(tokens)
    second, _ = page_token(tokens)
    assert first != second and tokens.valid(first) and tokens.valid(second)
    assert set(spec) == set(OFFERED) <= set(COMMANDS)
    assert spec["reflex_threshold_mm_s"] == {
        "number": [1.0, 1000.0],
        "expected": "a number 1..1000",
    }
    assert "slip_speed" in spec["feedback_mode"]["choices"]


def test_a_command_from_the_page_is_taken_to_be_run() -> None:
    tokens = Tokens()
    token, _ = page_token(tokens)
    response = post(tokens, good_headers(token))
    assert response.status == 200 and response.command


@pytest.mark.parametrize(
    ("change", "status", "why"),
    [
        ({TOKEN_HEADER: "guessed"}, 403, "no valid page token"),
        ({TOKEN_HEADER: None}, 403, "no valid page token"),
        ({"origin": "http://evil.example"}, 403, "from http://evil.example"),
        ({"origin": "null"}, 403, "from null"),
        ({"content-type": "application/x-www-form-urlencoded"}, 415, "application/json"),
        ({"content-type": None}, 415, "application/json"),
        ({"content-length": None}, 411, "Content-Length"),
        ({"content-length": str(MAX_BODY_BYTES + 1)}, 413, f"at most {MAX_BODY_BYTES}"),
    ],
)
def test_a_post_not_from_a_page_of_this_server_is_refused_before_its_body(
    change: dict[str, str | None], status: int, why: str
) -> None:
    tokens = Tokens()
    token, _ = page_token(tokens)
    headers = {k: v for k, v in {**good_headers(token), **change}.items() if v is not None}
    response = post(tokens, headers)
    assert response.status == status and why in response.body.decode()
    assert not response.command


def test_a_post_anywhere_else_or_from_another_host_is_not_a_command() -> None:
    tokens = Tokens()
    token, _ = page_token(tokens)
    assert post(tokens, good_headers(token), path="/").status == 405
    assert post(tokens, good_headers(token), path="/events").status == 405
    assert post(tokens, good_headers(token), host="evil.example:8642").status == 421


def test_the_oldest_tokens_are_forgotten_beyond_the_bound() -> None:
    tokens = Tokens(limit=3)
    issued = [tokens.issue() for _ in range(4)]
    assert not tokens.valid(issued[0]) and all(tokens.valid(t) for t in issued[1:])


def test_a_repeated_token_or_length_header_is_refused() -> None:
    head = (
        f"POST /command HTTP/1.1\r\nHost: {HOST}\r\n{TOKEN_HEADER}: a\r\n{TOKEN_HEADER}: b\r\n\r\n"
    )
    with pytest.raises(Exception, match=f"more than one {TOKEN_HEADER}"):
        parse_head(head.encode())


def body(command: str, value, gateway="arm-7") -> bytes:
    return json.dumps({"gateway": gateway, "command": command, "value": value}).encode()


@pytest.mark.parametrize(
    ("command", "value"),
    [
        ("feedback_mode", "slip_speed"),
        ("feedback_mode", 2),
        ("reflex_enabled", False),
        ("reflex_threshold_mm_s", 30),
        ("emg_calibration", {"e_min_uv": 40, "e_max_uv": 400}),
        ("emg_calibrate", "rest"),
    ],
)
def test_a_command_within_the_gateway_limits_goes_to_its_command_topic(command, value) -> None:
    out = prepare(body(command, value), "view-1-7")
    assert out.topic == f"grasplink/arm-7/cmd/{command}"
    assert json.loads(out.payload) == {"value": value, "id": "view-1-7"}


@pytest.mark.parametrize(
    ("request_body", "why"),
    [
        (
            body("reflex_threshold_mm_s", 5000),
            "reflex_threshold_mm_s: expected a number 1..1000, got 5000",
        ),
        (
            body("reflex_threshold_mm_s", None),
            "reflex_threshold_mm_s: expected a number 1..1000, got None",
        ),
        (body("feedback_mode", "loud"), "feedback_mode: expected one of"),
        (body("emg_calibration", {"e_min_uv": 400, "e_max_uv": 40}), "0 <= e_min_uv < e_max_uv"),
        (body("restart_node", "belt"), "the view offers feedback_mode"),
        (body("write_object", {}), "the view offers"),
        (body("feedback_mode", "slip_speed", gateway="a/b"), "gateway: not a gateway ID"),
        (body("feedback_mode", "slip_speed", gateway=None), "gateway: not a gateway ID"),
        (b"{not json", "not JSON"),
        (b'{"gateway": "arm-7", "command": "reflex_threshold_mm_s", "value": NaN}', "not JSON"),
        (b'{"command": "feedback_mode"}', 'expected {"gateway", "command", "value"}'),
        (b"[1]", 'expected {"gateway", "command", "value"}'),
        (b" " * (MAX_BODY_BYTES + 1), f"at most {MAX_BODY_BYTES}"),
    ],
)
def test_a_command_the_gateway_would_refuse_is_not_sent_and_says_why(request_body, why) -> None:
    with pytest.raises(CommandRefused) as caught:
        prepare(request_body, "view-1-1")
    assert why in str(caught.value)


def test_a_view_of_one_gateway_commands_that_one_only() -> None:
    assert prepare(body("emg_calibrate", "rest"), "x", only_gateway="arm-7").gateway == "arm-7"
    with pytest.raises(CommandRefused, match="this view shows arm-7 only"):
        prepare(body("emg_calibrate", "rest", gateway="arm-8"), "x", only_gateway="arm-7")


def test_a_reply_is_read_as_telemetry_sends_it_and_anything_else_is_not_one() -> None:
    reply = read_reply(
        b'{"ts_ms": 1, "id": "view-1-2", "command": "feedback_mode", "accepted": true,'
        b' "detail": "feedback mode slip_speed"}'
    )
    assert reply is not None and reply.id == "view-1-2" and reply.accepted
    assert reply.as_dict()["detail"] == "feedback mode slip_speed"
    for garbage in (b"", b"nope", b"[]", b'{"id": 3, "command": "x", "accepted": true}'):
        assert read_reply(garbage) is None

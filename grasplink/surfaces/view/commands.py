"""Commands from the page, sans-IO (docs/view.md, Commands): which the view offers, the
per-page tokens that prove a request comes from a page this server gave out, and the
check of a command before it is published.

A command is checked with the gateway's own parser (`grasplink.gateway.commands`), so the
view never publishes one the gateway's limits would refuse: the refusal is answered here,
with the gateway's words, and nothing reaches the broker.
"""

from __future__ import annotations

import json
import re
import secrets
from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

from grasplink.gateway.commands import (
    CALIBRATION_PHASES,
    COMMANDS,
    MAX_THRESHOLD_MM_S,
    MIN_THRESHOLD_MM_S,
    Command,
    CommandError,
    parse_value,
)
from grasplink.gateway.feedback import FeedbackMode

MAX_BODY_BYTES = 8192  # what telemetry takes as one command payload
MAX_TOKENS = 64  # pages served and still able to command; the oldest is forgotten first
REPLY_TIMEOUT_S = 5.0  # telemetry waits up to 2 s for the gateway's answer, then answers
_ID = re.compile(r"[A-Za-z0-9_.:-]{1,64}")  # a gateway ID: one topic level
#: what the page offers, and the input each takes: the tuning of a session (restarting a
#: node or writing a device's object stays with the integrator's tools)
OFFERED: dict[str, dict[str, Any]] = {
    "feedback_mode": {"choices": [m.value for m in FeedbackMode]},
    "reflex_enabled": {"choices": [True, False]},
    "reflex_threshold_mm_s": {"number": [MIN_THRESHOLD_MM_S, MAX_THRESHOLD_MM_S]},
    "emg_calibration": {"pair": ["e_min_uv", "e_max_uv"]},
    "emg_calibrate": {"choices": list(CALIBRATION_PHASES)},
}


def offered() -> dict[str, dict[str, Any]]:
    """The page's command spec: each offered command, its input and what it expects."""
    return {name: {**spec, "expected": COMMANDS[name]} for name, spec in OFFERED.items()}


class CommandRefused(ValueError):
    """A command the view does not publish; the message says why (shown on the page)."""


class Tokens:
    """Random tokens handed to each page with its HTML; a command must carry one. Another
    site can make a browser post here but cannot read the page, so it has no token."""

    def __init__(self, limit: int = MAX_TOKENS) -> None:
        self.limit = limit
        self._tokens: OrderedDict[str, None] = OrderedDict()

    def issue(self) -> str:
        token = secrets.token_urlsafe(24)
        self._tokens[token] = None
        while len(self._tokens) > self.limit:
            self._tokens.popitem(last=False)
        return token

    def valid(self, token: str | None) -> bool:
        return token is not None and token in self._tokens


@dataclass(frozen=True)
class Outgoing:
    """A checked command: where it goes and the payload telemetry reads (`{value, id}`)."""

    gateway: str
    name: str
    id: str
    topic: str
    payload: bytes


def prepare(body: bytes, request_id: str, only_gateway: str | None = None) -> Outgoing:
    """The page's `{"gateway", "command", "value"}`, checked as the gateway would check
    it; CommandRefused naming the problem."""
    if len(body) > MAX_BODY_BYTES:
        raise CommandRefused(f"a command of {len(body)} bytes; at most {MAX_BODY_BYTES}")
    try:
        request = json.loads(body, parse_constant=_no_constant)
    except (UnicodeDecodeError, ValueError) as exc:
        raise CommandRefused(f"not JSON ({exc})") from None
    if not isinstance(request, dict) or set(request) != {"gateway", "command", "value"}:
        raise CommandRefused('expected {"gateway", "command", "value"}')
    gateway, name, value = request["gateway"], request["command"], request["value"]
    if not isinstance(gateway, str) or not _ID.fullmatch(gateway):
        raise CommandRefused(f"gateway: not a gateway ID, got {json.dumps(gateway)[:40]}")
    if only_gateway is not None and gateway != only_gateway:
        raise CommandRefused(f"gateway {gateway}: this view shows {only_gateway} only")
    if name not in OFFERED:
        raise CommandRefused(
            f"command {json.dumps(name)[:40]}: the view offers {', '.join(OFFERED)}"
        )
    try:
        parse_value(Command(name, value))
    except CommandError as exc:
        raise CommandRefused(str(exc)) from None
    payload = json.dumps({"value": value, "id": request_id}, separators=(",", ":"))
    return Outgoing(gateway, name, request_id, f"grasplink/{gateway}/cmd/{name}", payload.encode())


@dataclass(frozen=True)
class Reply:
    """The gateway's answer on `grasplink/<id>/reply/<name>`."""

    id: str
    command: str
    accepted: bool
    detail: str

    def as_dict(self) -> dict[str, Any]:
        return {"command": self.command, "accepted": self.accepted, "detail": self.detail}


def read_reply(payload: bytes) -> Reply | None:
    """A reply telemetry sent (docs/telemetry.md, Commands), or None if it is not one."""
    try:
        body = json.loads(payload)
    except (UnicodeDecodeError, ValueError):
        return None
    if not isinstance(body, dict):
        return None
    rid, command, accepted, detail = (body.get(k) for k in ("id", "command", "accepted", "detail"))
    if not (isinstance(rid, str) and isinstance(command, str) and isinstance(accepted, bool)):
        return None
    return Reply(rid, command, accepted, detail if isinstance(detail, str) else "")


def _no_constant(name: str) -> None:
    raise ValueError(f"{name} is not a JSON number")

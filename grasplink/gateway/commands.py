"""Run-time commands to the gateway, from whatever surface carries them (MQTT, Modbus).

A command is validated like any other input before anything changes, and
answered with accepted/rejected and the reason; a rejected command changes
nothing. The sans-IO gateway executes a command when it is handed one
(`Gateway.execute`); surfaces in other threads post theirs to the live edge's
mailbox (`edge.GatewayEdge.post`), which hands them over on the gateway's thread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from grasplink.gateway.feedback import FeedbackMode
from grasplink.profiles.kinds import KINDS

SHOWN_CHARS = 60  # of a refused value, in the error message
MIN_THRESHOLD_MM_S, MAX_THRESHOLD_MM_S = 1.0, 1000.0
CALIBRATION_PHASES = ("rest", "maximum", "finish", "cancel")


@dataclass(frozen=True, slots=True)
class Command:
    """`name` and its `value`; see COMMANDS for what each takes."""

    name: str
    value: Any = None


@dataclass(frozen=True, slots=True)
class CommandResult:
    command: str
    accepted: bool
    detail: str

    def as_dict(self) -> dict[str, Any]:
        return {"command": self.command, "accepted": self.accepted, "detail": self.detail}


#: name -> what its value must be (for docs and error messages)
COMMANDS: dict[str, str] = {
    "feedback_mode": "one of " + ", ".join(m.value for m in FeedbackMode) + " (or 0..4)",
    "reflex_enabled": "true or false",
    "reflex_threshold_mm_s": f"a number {MIN_THRESHOLD_MM_S:g}..{MAX_THRESHOLD_MM_S:g}",
    "emg_calibration": "{e_min_uv, e_max_uv}, numbers with 0 <= e_min_uv < e_max_uv <= 65535",
    "emg_calibrate": "one of " + ", ".join(CALIBRATION_PHASES),
    "restart_node": "a node's name in the bus description (" + ", ".join(KINDS) + ", or a "
    "device's table name)",
    "write_object": "{node, object, value}: a device's RPDO-mapped object the configuration "
    "offers for writing ([[modbus.holding]]), a finite number",
}
WRITE_OBJECT_KEYS = frozenset({"node", "object", "value"})
NODE_NAME_CHARS = 32  # a description's node name is at most this long (config.NODE_NAME)


class CommandError(ValueError):
    """A command that is refused; the message says why."""


def parse_value(command: Command) -> Any:
    """The command's value, checked; CommandError naming what was expected."""
    name, value = command.name, command.value
    if name not in COMMANDS:
        raise CommandError(f"unknown command {name!r}; commands: {', '.join(COMMANDS)}")
    expected = COMMANDS[name]
    if name == "feedback_mode":
        modes = list(FeedbackMode)
        if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(modes):
            return modes[value]
        if isinstance(value, str) and value in {m.value for m in modes}:
            return FeedbackMode(value)
    elif name == "reflex_enabled":
        if isinstance(value, bool):
            return value
    elif name == "reflex_threshold_mm_s":
        if _number(value) and MIN_THRESHOLD_MM_S <= value <= MAX_THRESHOLD_MM_S:
            return float(value)
    elif name == "emg_calibration":
        if isinstance(value, dict) and set(value) == {"e_min_uv", "e_max_uv"}:
            low, high = value["e_min_uv"], value["e_max_uv"]
            if _number(low) and _number(high) and 0 <= low < high <= 65535:
                return float(low), float(high)
    elif name == "emg_calibrate":
        if value in CALIBRATION_PHASES:
            return value
    elif name == "restart_node" and isinstance(value, str) and 0 < len(value) <= NODE_NAME_CHARS:
        return value  # which names exist is for the gateway's description to say
    elif name == "write_object" and isinstance(value, dict) and set(value) == WRITE_OBJECT_KEYS:
        node, key, number = value["node"], value["object"], value["value"]
        if isinstance(node, str) and isinstance(key, str) and _number(number):
            return node, key, number  # which objects may be written: the configuration's
    raise CommandError(f"{name}: expected {expected}, got {shown(value)}")


def shown(value: Any, limit: int = SHOWN_CHARS) -> str:
    """A value as an error message quotes it: its repr, cut short (a command's value may be
    kilobytes of whatever a client sent; the reply names it, it need not repeat it)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 3]}... ({len(text)} chars)"


def _number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)

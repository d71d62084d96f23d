"""Commands as a careless or hostile client sends them, without a broker: a command payload
is bounded (bytes, JSON depth, Sparkplug metrics) before it is parsed, repeated metrics run
once (the last), and every malformed command gets exactly one answer naming the problem."""

from __future__ import annotations

import json

from grasplink.gateway.commands import Command, parse_value
from grasplink.surfaces.telemetry import sparkplug_b_pb2 as pb
from grasplink.surfaces.telemetry.json_tree import JsonTree
from grasplink.surfaces.telemetry.protocol import (
    MAX_COMMAND_BYTES,
    MAX_COMMAND_METRICS,
    MAX_JSON_DEPTH,
    nesting_error,
)
from grasplink.surfaces.telemetry.sparkplug import (
    ALIASES,
    BOOLEAN,
    DOUBLE,
    STRING,
    SparkplugSession,
    set_value,
)

NCMD = "spBv1.0/grp/NCMD/gw"


def session() -> SparkplugSession:
    spb = SparkplugSession("grp", "gw")
    spb.will(0)
    spb.on_connect(0)
    return spb


def ncmd(*metrics: tuple[str | int, int, object]) -> bytes:
    """An NCMD payload: (name or alias, datatype, value) per metric."""
    payload = pb.Payload(timestamp=1)
    for key, datatype, value in metrics:
        metric = payload.metrics.add(**({"alias": key} if isinstance(key, int) else {"name": key}))
        set_value(metric, datatype, value, with_datatype=isinstance(key, str))
    return payload.SerializeToString()


def test_an_ncmd_of_10000_copies_of_a_metric_is_refused_once_unparsed() -> None:
    data = ncmd(*[("Control/reflex_enabled", BOOLEAN, False)] * 10_000)
    assert len(data) > MAX_COMMAND_BYTES
    incoming = session().receive(NCMD, data, False, 5)
    (request,) = incoming.requests  # one answer, nothing executed
    assert request.command is None
    assert f"payload of {len(data)} bytes" in request.refused
    assert str(MAX_COMMAND_BYTES) in request.refused


def test_more_metrics_than_the_bound_in_a_small_ncmd_are_refused_whole() -> None:
    alias = ALIASES[None]["Control/reflex_enabled"]
    data = ncmd(*[(alias, BOOLEAN, False)] * (MAX_COMMAND_METRICS + 1))
    assert len(data) < MAX_COMMAND_BYTES
    (request,) = session().receive(NCMD, data, False, 5).requests
    assert request.command is None
    assert f"carries {MAX_COMMAND_METRICS + 1} metrics" in request.refused
    assert (
        f"1..{MAX_COMMAND_METRICS}" in request.refused and "nothing was executed" in request.refused
    )


def test_repeated_metrics_run_once_with_the_last_value_by_name_or_alias() -> None:
    alias = ALIASES[None]["Control/reflex_threshold_mm_s"]
    data = ncmd(
        ("Control/reflex_threshold_mm_s", DOUBLE, 10.0),
        ("Control/feedback_mode", STRING, "off"),
        (alias, DOUBLE, 20.0),  # the same metric by alias
        ("Control/feedback_mode", STRING, "slip_speed"),
        ("Control/reflex_threshold_mm_s", DOUBLE, 30.0),
        (9999, DOUBLE, 1.0),
        (9999, DOUBLE, 2.0),
    )
    incoming = session().receive(NCMD, data, False, 5)
    # in the order of the last copies; one refusal for the unknown alias
    assert [(r.command, r.refused) for r in incoming.requests] == [
        (Command("feedback_mode", "slip_speed"), ""),
        (Command("reflex_threshold_mm_s", 30.0), ""),
        (None, "alias 9999 is not a metric of the edge node"),
    ]


def test_a_command_with_no_metrics_is_answered() -> None:
    (request,) = session().receive(NCMD, ncmd(), False, 5).requests
    assert "carries 0 metrics" in request.refused


def test_node_control_writes_of_the_wrong_type_or_false_are_answered_naming_the_value() -> None:
    spb = session()
    for value, datatype, shown in (("yes", STRING, "'yes'"), (False, BOOLEAN, "False")):
        data = ncmd(("Node Control/Restart", datatype, value))
        (request,) = spb.receive("spBv1.0/grp/DCMD/gw/belt", data, False, 5).requests
        assert request.command is None and request.name == "DCMD belt"
        assert request.refused == f"Node Control/Restart: write Boolean true, got {shown}"
    data = ncmd(("Node Control/Rebirth", STRING, "now"))
    incoming = spb.receive(NCMD, data, False, 5)
    assert not incoming.messages  # no births
    assert incoming.requests[0].refused == "Node Control/Rebirth: write Boolean true, got 'now'"
    restart = ncmd(("Node Control/Restart", BOOLEAN, True))
    (request,) = spb.receive("spBv1.0/grp/DCMD/gw/belt", restart, False, 5).requests
    assert request.command == Command("restart_node", "belt")


# -- JSON ------------------------------------------------------------------------------------


def json_command(payload: bytes, retain: bool = False):
    (request,) = (
        JsonTree("gw").receive("grasplink/gw/cmd/feedback_mode", payload, retain, 0).requests
    )
    return request


def test_deeply_nested_json_is_refused_before_parsing_with_an_answer() -> None:
    deep = b'{"value": ' + b"[" * 4000 + b"]" * 4000 + b"}"  # json.loads: RecursionError
    assert len(deep) <= MAX_COMMAND_BYTES
    request = json_command(deep)
    assert request.command is None
    assert request.refused == f"JSON nested deeper than {MAX_JSON_DEPTH} levels"
    huge = b'{"value": "' + b"x" * MAX_COMMAND_BYTES + b'"}'
    assert f"payload of {len(huge)} bytes" in json_command(huge).refused


def test_the_depth_check_counts_levels_not_brackets_in_strings() -> None:
    brackets = json.dumps({"value": "[" * 50 + "{" * 50, "id": 'a\\"[['}).encode()
    assert nesting_error(brackets) == ""
    assert json_command(brackets).command == Command("feedback_mode", "[" * 50 + "{" * 50)
    nested = json.dumps({"value": {"e_min_uv": [[[[[[[1]]]]]]]}}).encode()  # 9 levels
    assert nesting_error(nested) == f"JSON nested deeper than {MAX_JSON_DEPTH} levels"
    assert nesting_error(json.dumps({"value": [[[[[[1]]]]]]}).encode()) == ""  # 7 levels


def test_a_refused_value_is_named_but_cut_short() -> None:
    try:
        parse_value(Command("feedback_mode", "x" * 5000))
    except ValueError as error:
        message = str(error)
    assert message.startswith("feedback_mode: expected one of") and len(message) < 200
    assert "'xxxx" in message and "(5002 chars)" in message

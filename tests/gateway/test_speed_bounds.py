"""Speed and direction as separate outputs (issue 22) through the gateway: a speed without
a direction and a bound without a speed reach the belt, the reflex, telemetry and Modbus,
and a bound is acted on at its lower end - never ignored, never overstated."""

from __future__ import annotations

import json
import math

import pytest

from grasplink.decoding.base import SlipEstimate
from grasplink.gateway.config import load_config
from grasplink.gateway.feedback import FeedbackConfig, FeedbackController, Reason
from grasplink.gateway.live import slip_text
from grasplink.gateway.percept import Percept
from grasplink.gateway.reflex import GripArbiter, ReflexConfig, ReflexState
from grasplink.gateway.service import Gateway
from grasplink.gateway.snapshot import Snapshot
from grasplink.surfaces.modbus.registers import register_map
from grasplink.surfaces.telemetry.buffer import Sample
from grasplink.surfaces.telemetry.json_tree import JsonTree
from grasplink.surfaces.telemetry.sparkplug import DOUBLE, INT32, SparkplugSession
from tests.telemetry.host import SparkplugHost
from tests.telemetry.snapshots import snapshot

MS = 1000
EXTRA = {"controls": {"reflex_enabled": True, "reflex_threshold_mm_s": 45.0}, "telemetry": {}}


def bound(t_ms: float, low: float | None, high: float | None, confidence=0.9) -> Percept:
    """A slip whose speed the decoder has not determined, only bounded, and no direction."""
    return Percept(round(t_ms * MS), 5.0, True, None, confidence, low, high)


# -- the percept ----------------------------------------------------------------------------


def test_a_percept_carries_a_bound_and_no_direction_from_the_estimate():
    estimate = SlipEstimate(1.0, True, None, None, 5.0, 0.7, None, None, 12.0, 60.0)
    p = Percept.from_estimate(estimate, t_us=1_000_000)
    assert (p.slip_speed_mm_s, p.slip_speed_low_mm_s, p.slip_speed_high_mm_s) == (None, 12, 60)
    assert (p.slip_direction, p.slip_direction_confidence, p.velocity_mm_s) == (None, None, None)
    assert p.speed_is_bound
    assert (p.speed_floor_mm_s(), p.speed_ceiling_mm_s()) == (12.0, 60.0)
    assert p.speed_floor_mm_s(min_confidence=0.8) is None  # trusted less: not acted on


def test_a_known_speed_is_both_floor_and_ceiling_whatever_its_range():
    p = Percept(0, 5.0, True, 40.0, 0.9, 30.0, 55.0, 1, 0.95)
    assert (p.speed_floor_mm_s(), p.speed_ceiling_mm_s(), p.velocity_mm_s) == (40, 40, 40)
    assert not p.speed_is_bound


@pytest.mark.parametrize(
    ("field", "name"),
    [(3, "slip_speed_mm_s"), (5, "slip_speed_low_mm_s"), (6, "slip_speed_high_mm_s")],
)
def test_a_negative_speed_or_bound_in_a_percept_is_an_error_naming_it(field, name):
    values: list = [0, 5.0, True, None, 0.9, None, None, None, None]
    values[field] = -31.5
    with pytest.raises(ValueError, match=rf"{name} is a magnitude, got -31\.5: give the sign"):
        Percept(*values)
    with pytest.raises(ValueError, match="slip_direction must be"):
        Percept(0, 5.0, True, 31.5, 0.9, None, None, 0, 0.9)


def test_cleaning_drops_unusable_bounds_and_a_direction_without_a_usable_confidence():
    p = Percept(0, 5.0, True, math.inf, 0.9, math.nan, -math.inf, -1, math.nan).clean()
    assert (p.slip_speed_mm_s, p.slip_speed_low_mm_s, p.slip_speed_high_mm_s) == (None,) * 3
    assert (p.slip_direction, p.slip_direction_confidence) == (None, None)
    p = Percept(0, 5.0, True, 20.0, 0.9, None, None, -1, 1.7).clean()
    assert (p.slip_direction, p.slip_direction_confidence) == (-1, 1.0)


# -- the reflex -----------------------------------------------------------------------------


def holding(voluntary_n: float = 5.0) -> GripArbiter:
    arbiter = GripArbiter(ReflexConfig())  # threshold 45 mm/s, hysteresis 5, gain 0.1 N/mm/s
    arbiter.set_voluntary(0, voluntary_n)
    return arbiter


def test_the_reflex_fires_on_a_lower_bound_above_its_threshold_and_grips_for_that_bound():
    command = holding(5.0).update(bound(10, 50.0, 90.0))
    assert command.reflex == ReflexState.ACTIVE
    assert command.grip_n == pytest.approx(5.0 + 0.1 * 50.0)  # the low end, not 70 or 90


def test_the_reflex_does_not_fire_on_a_bound_straddling_its_threshold():
    arbiter = holding(5.0)
    for t_ms, (low, high) in enumerate([(30.0, 60.0), (44.9, 200.0), (None, 90.0)], start=1):
        command = arbiter.update(bound(10 * t_ms, low, high))
        assert command.reflex == ReflexState.IDLE and command.grip_n == 5.0


def test_an_active_reflex_holds_only_once_the_bound_is_wholly_below_its_release_speed():
    arbiter = holding(5.0)
    assert arbiter.update(bound(10, 50.0, 90.0)).reflex == ReflexState.ACTIVE
    # might still be fast (up to 60 mm/s): the reflex stays active, the grip never drops
    command = arbiter.update(bound(20, 30.0, 60.0))
    assert command.reflex == ReflexState.ACTIVE and command.grip_n == pytest.approx(10.0)
    assert arbiter.update(bound(30, 10.0, 39.0)).reflex == ReflexState.HOLD  # < 45 - 5


# -- the belt -------------------------------------------------------------------------------


@pytest.mark.parametrize("dwell_us", [0, 500_000])
def test_the_belt_never_shows_more_than_the_lower_bound_while_only_a_bound_is_known(dwell_us):
    config = FeedbackConfig(level_dwell_us=dwell_us)
    table = config.slip_table
    c = FeedbackController(config, mode="slip_speed")
    lows = [1.0, 3.0, 8.0, 14.0, 14.9, 16.0, 22.0, 29.0, 31.0, 40.0, 44.0, 46.0, 60.0]
    for k, low in enumerate(lows):
        output = c.update(bound(100 * k, low, 250.0))  # a wide range: its middle is far higher
        belt = output.belt
        assert belt.reason == Reason.SLIP_SPEED_AT_LEAST
        assert belt.level is not None and 1 <= belt.level <= max(1, table.level_of(low)), low
        assert -belt.velocity_mrad_s <= table.velocities_mrad_s[max(1, table.level_of(low)) - 1]
        # the stimulators too: the lower end, not the occurrence code of an unknown speed
        encoded = config.encoder.encode(True, low)
        assert output.stimuli.electrotactile_speed == encoded.electrotactile_speed
    if not dwell_us:
        assert belt.level == table.levels  # a bound that high is shown as the top level


def test_a_bound_below_the_second_level_is_shown_slower_than_a_slip_of_unknown_speed():
    c = FeedbackController(mode="slip_speed")
    shown = c.update(bound(0, 5.0, 120.0)).belt
    unknown = FeedbackController(mode="slip_speed").update(bound(0, None, None)).belt
    assert (unknown.level, unknown.reason) == (None, Reason.SLIP_SPEED_UNKNOWN)
    assert -shown.velocity_mrad_s < -unknown.velocity_mrad_s  # occurrence would overstate


def test_the_first_speed_after_a_bound_is_shown_at_once_not_held_by_the_dwell():
    c = FeedbackController(mode="slip_speed")  # level dwell 500 ms
    assert c.update(bound(0, 5.0, 120.0)).belt.level == 1
    known = c.update(Percept(100 * MS, 5.0, True, 40.0, 0.9)).belt
    assert (known.level, known.reason) == (3, Reason.SLIP_SPEED)
    # from a known speed on the dwell holds again: a bound's lower level waits for it
    held = c.update(bound(200, 5.0, 120.0)).belt
    assert (held.level, held.reason) == (3, Reason.SLIP_SPEED)
    assert c.update(bound(700, 5.0, 120.0)).belt.level == 1


# -- telemetry and Modbus -------------------------------------------------------------------


def gateway_snapshot(estimate: SlipEstimate) -> Snapshot:
    gateway = Gateway(load_config(None))
    gateway.last_estimate = estimate
    return gateway.snapshot()


BOUND_ONLY = SlipEstimate(1.0, True, None, None, 5.0, 0.7, None, None, 12.0, 60.0)
UNDIRECTED = SlipEstimate(1.0, True, 41.3, None, 5.0, 0.7, None, None, 38.0, 44.5)
DIRECTED = SlipEstimate.from_velocity(1.0, True, -41.3, 20.0, 5.0, 0.7, 0.93)


@pytest.mark.parametrize("estimate", [BOUND_ONLY, UNDIRECTED, DIRECTED])
def test_speed_bounds_and_direction_reach_the_snapshot_and_the_json_tree(estimate):
    snap = gateway_snapshot(estimate)
    expected = {
        "slip": True,
        "slip_speed_mm_s": estimate.speed_mm_s,
        "slip_speed_low_mm_s": estimate.speed_low_mm_s,
        "slip_speed_high_mm_s": estimate.speed_high_mm_s,
        "slip_direction": estimate.direction,
        "slip_direction_confidence": estimate.direction_confidence,
    }
    assert {k: getattr(snap.skin, k) for k in expected} == expected
    messages = JsonTree("gw").update([Sample(1000, snap)], EXTRA)
    (values,) = [json.loads(m.payload) for m in messages if m.topic.endswith("skin/values")]
    assert {k: values[k] for k in expected} == expected


def test_speed_bounds_and_direction_reach_sparkplug_with_their_types():
    session, host = SparkplugSession("grp", "gw"), SparkplugHost("grp", "gw")
    session.will(1000)
    first, after = session.on_connect(1000)

    def send(messages: list) -> None:  # what the transport does
        for message in messages:
            final = session.finalize(message)
            if final is not None:
                host.feed(final.topic, final.payload)

    def publish(t_ms: int, estimate: SlipEstimate) -> None:
        live = snapshot(1.0, skin=gateway_snapshot(estimate).skin)  # every node operational
        send(session.update([Sample(t_ms, live)], EXTRA))

    send(first + after)
    publish(2000, BOUND_ONLY)
    (birth,) = [m for m in host.messages if m.kind == "DBIRTH" and m.device == "skin"]
    types = {m.name: m.datatype for m in birth.payload.metrics}
    assert types["slip_direction"] == INT32 and types["slip_direction_confidence"] == DOUBLE
    assert types["slip_speed_low_mm_s"] == types["slip_speed_high_mm_s"] == DOUBLE
    born = birth.metrics()
    assert (born["slip_speed_low_mm_s"], born["slip_speed_high_mm_s"]) == (12.0, 60.0)
    assert born["slip_direction"] is None and born["slip_speed_mm_s"] is None
    publish(2050, DIRECTED)
    (data,) = [m for m in host.messages if m.kind == "DDATA" and m.device == "skin"]
    got = data.metrics()
    assert (got["slip_speed_mm_s"], got["slip_direction"]) == (41.3, -1)
    assert got["slip_direction_confidence"] == 0.93 and got["slip_speed_low_mm_s"] is None
    assert not host.errors


@pytest.mark.parametrize("estimate", [BOUND_ONLY, UNDIRECTED, DIRECTED])
def test_speed_bounds_and_direction_read_back_through_the_modbus_registers(estimate):
    rmap = register_map()
    table = rmap.encode_inputs(gateway_snapshot(estimate))

    def read(name: str) -> float | int | None:
        register = rmap[name]
        return register.engineering(table[register.address : register.end])

    assert read("skin.slip_speed_mm_s") == pytest.approx(estimate.speed_mm_s, abs=0.05)
    assert read("skin.slip_speed_low_mm_s") == pytest.approx(estimate.speed_low_mm_s, abs=0.05)
    assert read("skin.slip_speed_high_mm_s") == pytest.approx(estimate.speed_high_mm_s, abs=0.05)
    assert read("skin.slip_direction") == estimate.direction  # the sentinel: not told
    assert read("skin.slip_direction_confidence") == pytest.approx(
        estimate.direction_confidence, abs=0.0005
    )


def test_the_new_registers_were_added_after_every_existing_one():
    """Map version 2 moved no address: a client of version 1 reads what it read."""
    rmap = register_map()
    version_1 = {"skin.slip_speed_mm_s": 48, "skin.confidence": 51, "loop.percepts": 75}
    assert {name: rmap[name].address for name in version_1} == version_1
    new = ("low_mm_s", "high_mm_s", "slip_direction", "slip_direction_confidence")
    added = [r.address for r in rmap.inputs if r.name.endswith(new)]
    assert len(added) == 4
    assert min(added) >= rmap["loop.percepts"].end


def test_the_status_line_tells_a_bound_as_at_least_its_lower_end():
    assert slip_text(gateway_snapshot(BOUND_ONLY).skin) == ">= 12 mm/s ?"
    assert slip_text(gateway_snapshot(UNDIRECTED).skin) == "41 mm/s ?"
    assert slip_text(gateway_snapshot(DIRECTED).skin) == "41 mm/s -"

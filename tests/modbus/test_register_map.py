"""The register map as plain data and pure functions: layout, encoding, write decoding."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from pymodbus.client import ModbusTcpClient

from grasplink.controllers import simulation
from grasplink.gateway.commands import Command, parse_value
from grasplink.gateway.config import parse_config
from grasplink.gateway.reflex import ReflexState
from grasplink.gateway.service import Gateway
from grasplink.profiles import load_profile, object_limits
from grasplink.profiles import objects as obj
from grasplink.simulators.scene import load_scene
from grasplink.surfaces.modbus.registers import (
    I16,
    I32,
    MAP_VERSION,
    MAX_READ,
    U16,
    U32,
    ExceptionCode,
    RegisterError,
    alarm_bit,
    from_words,
    register_map,
    settings_of,
    to_words,
)
from tests.gateway.test_service import ROOT, go_on
from tests.telemetry.snapshots import snapshot as gateway_snapshot

RMAP = register_map()
DATATYPE = ModbusTcpClient.DATATYPE


def words_of(name: str, table: list[int]) -> list[int]:
    register = RMAP[name]
    return table[register.address : register.end]


def test_both_tables_are_contiguous_named_and_read_whole_in_one_request():
    assert 0 < RMAP.input_count <= MAX_READ and 0 < RMAP.holding_count <= MAX_READ
    for table in (RMAP.inputs, RMAP.holding):
        address = 0
        for register in table:
            assert register.address == address and register.name and register.description
            assert register.type in (U16, I16, U32, I32) and register.scale > 0
            address = register.end
    names = [r.name for r in RMAP.inputs + RMAP.holding]
    assert len(names) == len(set(names))


def test_32_bit_values_are_two_registers_high_word_first_in_twos_complement():
    assert to_words(I32, -7000) == [0xFFFF, 0xE4A8]
    assert to_words(U32, 70_000) == [0x0001, 0x1170]
    assert to_words(I16, -1) == [0xFFFF]
    # pymodbus's own conversion (big word order) reads the same numbers.
    assert ModbusTcpClient.convert_from_registers([0xFFFF, 0xE4A8], DATATYPE.INT32) == -7000
    assert ModbusTcpClient.convert_from_registers([0x0001, 0x1170], DATATYPE.UINT32) == 70_000
    for word_type, raw in ((I32, -2_000_000_000), (U32, 4_000_000_000), (I16, -32767)):
        assert from_words(word_type, to_words(word_type, raw)) == raw


@pytest.mark.parametrize(
    ("word_type", "sentinel"),
    [(U16, [0xFFFF]), (I16, [0x8000]), (U32, [0xFFFF, 0xFFFF]), (I32, [0x8000, 0x0000])],
)
def test_unknown_reads_as_the_sentinel_and_known_values_saturate_one_step_short(
    word_type, sentinel
):
    register = next(r for r in RMAP.inputs if r.type == word_type and r.has_sentinel)
    for unknown in (None, math.nan, math.inf, "no such state"):
        assert register.encode(unknown) == sentinel
    assert register.decode(sentinel) is None
    huge = 1e12 * register.scale
    assert from_words(word_type, register.encode(huge)) == word_type.high
    if word_type.signed:
        assert from_words(word_type, register.encode(-huge)) == word_type.low
        assert word_type.low == -word_type.high
    assert register.decode(register.encode(huge)) is not None


def test_counters_wrap_and_have_no_sentinel():
    pdos = RMAP["nodes.skin.pdos_rx"]
    assert pdos.counter and not pdos.has_sentinel
    assert pdos.encode(2**32 + 5) == [0, 5]
    assert pdos.encode(2**32 - 1) == [0xFFFF, 0xFFFF] and pdos.decode([0xFFFF, 0xFFFF]) == 2**32 - 1
    assert pdos.encode(None) == [0, 0]  # unknown (node not configured): 0
    assert RMAP["nodes.skin.boots"].encode(65537) == [1]


def test_registers_carrying_a_profile_object_take_its_type_unit_and_limits_from_the_eds():
    carried = [r for r in RMAP.inputs + RMAP.holding if r.profile is not None]
    assert {r.name for r in carried} >= {
        "skin.grip_force_n",
        "emg.envelope_uv",
        "emg.level",
        "belt.belt",
        "belt.velocity_mrad_s",
        "hand.grip_n",
        "hand.setpoint_n",
        "emg_e_min_uv",
        "emg_e_max_uv",
    }
    sizes = {2: 16, 3: 16, 4: 32, 5: 16, 6: 16, 7: 32}  # INTEGER8..UNSIGNED32: register bits
    signed = {2, 3, 4}
    for register in carried:
        p = register.profile
        entry = load_profile(p.kind, obj.DEFAULT_NODE_IDS[p.kind])[p.index]
        if not hasattr(entry, "data_type"):
            entry = entry[p.subindex]
        assert register.type.bits == sizes[entry.data_type], register.name
        assert register.type.signed == (entry.data_type in signed), register.name
        assert f"[{p.raw_unit}]" in entry.name or not p.raw_unit
        assert (p.low, p.high) == object_limits(p.kind, p.index, p.subindex)
    assert RMAP["hand.grip_n"].unit == "N" and RMAP["hand.grip_n"].scale == 0.001  # mN in EDS
    assert RMAP["belt.velocity_mrad_s"].type == I32
    low, high = object_limits("emg", obj.EMG_CALIBRATION, 2)
    assert (RMAP["emg_e_max_uv"].low, RMAP["emg_e_max_uv"].high) == (low, min(high, 0xFFFE))


@pytest.fixture(scope="module")
def slipping():
    """The shipped closed-loop scene once the object slips and the reflex acts."""
    sim = simulation(load_scene(ROOT / "scenes" / "loop_headline.toml"))
    sim.network.start()
    go_on(sim, 1.5)
    gateway = sim.controllers[0]
    for _ in range(100):  # the slip starts at 1 s; the reflex acts within 0.5 s of the limit
        snapshot = gateway.snapshot()
        if snapshot.hand.reflex is ReflexState.ACTIVE:
            return gateway, snapshot
        go_on(sim, 0.01)
    raise AssertionError(f"no reflex by 2.5 s: {snapshot.hand}, {snapshot.skin}")


def test_a_slipping_gateways_snapshot_reads_back_through_the_registers(slipping):
    _, snapshot = slipping
    assert snapshot.skin.slip and snapshot.belt.velocity_mrad_s < 0
    assert snapshot.hand.reflex is ReflexState.ACTIVE
    table = RMAP.encode_inputs(snapshot)
    assert len(table) == RMAP.input_count and all(0 <= w <= 0xFFFF for w in table)
    checked = 0
    for register in RMAP.inputs:
        if not register.path:
            continue
        value = register.value_of(snapshot)
        words = words_of(register.name, table)
        if value is None:
            assert register.decode(words) is None or register.default is not None
        elif register.codes is not None and isinstance(value, str):
            assert register.decode(words) == register.codes[value], register.name
        elif register.counter:
            assert register.decode(words) == value % (1 << register.type.bits)
        else:
            assert register.engineering(words) == pytest.approx(
                float(value), abs=register.scale / 2 + 1e-9
            ), register.name
        checked += 1
    assert checked > 40
    assert table[RMAP["map_version"].address] == MAP_VERSION
    velocity = snapshot.belt.velocity_mrad_s  # the slip belt runs backwards: signed
    assert velocity < 0 and words_of("belt.velocity_mrad_s", table) == to_words(I32, velocity)


def _one_by_one(table, data):
    """The reference encoding: each register's own value_of and encode."""
    return [word for register in table for word in register.encode(register.value_of(data))]


def test_the_table_encoder_equals_each_registers_own_encoding(slipping):
    """`encode_inputs`/`encode_holding` inline the common cases for speed; every kind of
    value (float, int, bool, code, NaN, inf, out of range, numpy, absent) must come out as
    the registers themselves encode it."""
    _, snapshot = slipping
    skin = replace(
        snapshot.skin,
        grip_force_n=math.nan,
        slip_speed_mm_s=-math.inf,
        position_mm=1e12,
        confidence=np.float32(0.25),
    )
    emg = replace(snapshot.emg, envelope_uv=np.int64(-7), level="not a level", saturated=None)
    belt = replace(snapshot.belt, mode="no such mode", velocity_mrad_s=-(1 << 40))
    loop = replace(snapshot.loop, percepts=(1 << 40) + 5, latency_p50_us=2.5)
    hand = replace(snapshot.hand, grip_n=None, setpoint_n=None, reflex=None, source=None)
    nodes = {**snapshot.nodes, "emg": replace(snapshot.nodes["emg"], boots=-1)}
    odd = replace(snapshot, skin=skin, emg=emg, belt=belt, loop=loop, hand=hand, nodes=nodes)
    for data in (snapshot, odd, None):
        assert RMAP.encode_inputs(data) == _one_by_one(RMAP.inputs, data)
    gateway = Gateway(parse_config({}, "<test>"))
    for settings in (settings_of(gateway), {"reflex_threshold_mm_s": math.inf}, {}, None):
        assert RMAP.encode_holding(settings) == _one_by_one(RMAP.holding, settings)


def test_node_bits_alarm_bits_and_emcy_codes():
    node = {"node_id": 16, "phase": "operational", "nmt_state": "OPERATIONAL", "boots": 1}
    four = gateway_snapshot(
        3.5,
        nodes={
            "skin": {**node, "phase": "lost"},  # heard once, now overdue
            "emg": {**node, "node_id": 48, "last_emcy": 0x8130},
            "belt": {
                **node,
                "node_id": 32,
                "phase": "provisioning",
                "nmt_state": "PRE_OPERATIONAL",
            },
        },
        alarms={"skin.lost": "heartbeat lost", "emg.emcy": "EMCY", "decoder.stuck": "?"},
    )
    nodes = {kind: four.nodes[kind] for kind in ("skin", "emg", "belt")}  # no hand: not configured
    snapshot = replace(four, nodes=nodes)
    table = RMAP.encode_inputs(snapshot)
    read = {r.name: r.decode(words_of(r.name, table)) for r in RMAP.inputs}
    assert read["nodes_configured"] == 0b0111
    assert read["nodes_live"] == 0b0110
    assert read["nodes_operational"] == 0b0010
    assert read["alarms"] == (1 << alarm_bit("skin.lost")) | (1 << 6) | (1 << 31)
    assert read["alarm_count"] == 3
    assert read["nodes.emg.last_emcy_code"] == 0x8130 and read["nodes.skin.last_emcy_code"] == 0
    assert read["nodes.belt.nmt_state"] == 0x7F and read["nodes.belt.phase"] == 1
    assert read["nodes.hand.node_id"] == 0 and read["nodes.hand.phase"] is None
    assert read["nodes.hand.pdos_rx"] == 0 and read["uptime_ms"] == 3500


def test_before_the_first_snapshot_only_the_map_version_is_known():
    table = RMAP.encode_inputs(None)
    read = {r.name: r.decode(words_of(r.name, table)) for r in RMAP.inputs}
    assert read.pop("map_version") == MAP_VERSION
    for name, value in read.items():
        register = RMAP[name]
        expected = register.default if register.default is not None else None
        assert value == (0 if register.counter else expected), name


@pytest.mark.parametrize(
    ("address", "words", "command"),
    [
        (0, [2], Command("feedback_mode", 2)),
        (1, [0], Command("reflex_enabled", False)),
        (2, [455], Command("reflex_threshold_mm_s", 45.5)),
        (3, [80, 450], Command("emg_calibration", {"e_min_uv": 80.0, "e_max_uv": 450.0})),
        (5, [3], Command("emg_calibrate", "finish")),
        (6, [4], Command("restart_node", "hand")),
    ],
)
def test_a_write_of_one_command_group_is_that_command(address, words, command):
    assert RMAP.command_for_write(address, words) == command
    parse_value(command)  # and commands.py accepts what the map produces


@pytest.mark.parametrize(
    ("address", "words", "code"),
    [
        (0, [5], ExceptionCode.ILLEGAL_VALUE),  # no mode 5
        (1, [2], ExceptionCode.ILLEGAL_VALUE),  # not a boolean
        (2, [9], ExceptionCode.ILLEGAL_VALUE),  # 0.9 mm/s, below 1
        (2, [10001], ExceptionCode.ILLEGAL_VALUE),
        (3, [450, 80], ExceptionCode.ILLEGAL_VALUE),  # e_min above e_max
        (3, [80, 80], ExceptionCode.ILLEGAL_VALUE),
        (3, [80, 0xFFFF], ExceptionCode.ILLEGAL_VALUE),  # the sentinel is not a value
        (5, [0], ExceptionCode.ILLEGAL_VALUE),
        (6, [5], ExceptionCode.ILLEGAL_VALUE),
        (3, [80], ExceptionCode.ILLEGAL_ADDRESS),  # half the pair
        (4, [450], ExceptionCode.ILLEGAL_ADDRESS),  # the other half
        (0, [2, 1], ExceptionCode.ILLEGAL_ADDRESS),  # two commands in one write
        (2, [400, 80, 450], ExceptionCode.ILLEGAL_ADDRESS),
        (7, [1], ExceptionCode.ILLEGAL_ADDRESS),  # beyond the table
        (100, [1], ExceptionCode.ILLEGAL_ADDRESS),
    ],
)
def test_a_bad_write_is_refused_with_its_exception_code(address, words, code):
    with pytest.raises(RegisterError) as caught:
        RMAP.command_for_write(address, words)
    assert caught.value.code == code and str(caught.value)


def test_reads_outside_a_table_are_illegal_address():
    table = RMAP.encode_inputs(None)
    assert len(RMAP.read(table, 0, RMAP.input_count)) == RMAP.input_count
    for address, count in ((RMAP.input_count - 1, 2), (RMAP.input_count, 1), (-1, 1)):
        with pytest.raises(RegisterError) as caught:
            RMAP.read(table, address, count)
        assert caught.value.code == ExceptionCode.ILLEGAL_ADDRESS


def test_holding_registers_read_the_gateways_current_settings():
    gateway = Gateway(parse_config({}, "<test>"))
    table = RMAP.encode_holding(settings_of(gateway))
    read = {r.name: r.decode(words_of(r.name, table)) for r in RMAP.holding}
    assert read == {
        "feedback_mode": 4,
        "reflex_enabled": 1,
        "reflex_threshold_mm_s": 450,
        "emg_e_min_uv": 50,
        "emg_e_max_uv": 500,
        "emg_calibrate": 0,
        "restart_node": 0,
    }
    gateway.execute(Command("reflex_threshold_mm_s", 12.3), 0)
    table = RMAP.encode_holding(settings_of(gateway, {"restart_node": "belt"}))
    assert words_of("reflex_threshold_mm_s", table) == [123]
    assert words_of("restart_node", table) == [3]


def test_without_an_emg_node_the_calibration_reads_unknown():
    gateway = Gateway(parse_config({"nodes": {"emg": {"enabled": False}}}, "<test>"))
    table = RMAP.encode_holding(settings_of(gateway))
    assert words_of("emg_e_min_uv", table) == [0xFFFF] == words_of("emg_e_max_uv", table)

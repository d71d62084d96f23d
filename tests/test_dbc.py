"""`grasplink profiles dbc`: the network's PDO maps as a DBC that CAN analysers and cantools read.

The DBC must decode the bus exactly as the gateway does: every frame of a
recorded closed-loop run decodes through it to the values `PdoCodec` (the
EDS mapping through python-canopen) gives.
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

import cantools
import pytest

from grasplink.cli import main
from grasplink.core.frames import EMCY_BASE, HEARTBEAT_BASE, SDO_RX_BASE, SDO_TX_BASE, TPDO_BASES
from grasplink.core.nmt import NmtState
from grasplink.devices import emcy
from grasplink.errors import ConfigError
from grasplink.profiles import objects as obj
from grasplink.profiles.dbc import (
    EMCY_CODES,
    MASTER,
    NODE_NAMES,
    build_database,
    dbc_text,
    node_ids_with,
    pdo_messages,
)
from grasplink.profiles.kinds import KINDS
from grasplink.profiles.objects import DEFAULT_NODE_IDS
from grasplink.profiles.pdo_codec import PdoCodec

ROOT = Path(__file__).resolve().parents[1]
RUN_S = 2.5  # long enough for provisioning, EMG levels, belt and hand commands


@pytest.fixture(scope="module")
def dbc_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("dbc") / "grasplink.dbc"
    assert main(["profiles", "dbc", "--out", str(path)]) == 0
    return path


@pytest.fixture(scope="module")
def recorded_run(tmp_path_factory) -> Path:
    """`grasplink run` of the closed-loop headline scene, shortened: its can.asc."""
    folder = tmp_path_factory.mktemp("loop")
    text = (ROOT / "scenes" / "loop_headline.toml").read_text()
    scene = folder / "loop_short.toml"
    scene.write_text(re.sub(r"(?m)^duration_s = .*$", f"duration_s = {RUN_S}", text))
    assert main(["run", str(scene), "--out", str(folder / "out")]) == 0
    return folder / "out" / "can.asc"


@pytest.mark.slow
def test_cantools_loads_the_dbc_and_cantools_dump_prints_every_message(dbc_file):
    db = cantools.database.load_file(str(dbc_file), database_format="dbc")
    names = {m.name for m in db.messages}
    assert {"Skin_TPDO1", "EMG_TPDO1", "Belt_RPDO1", "Hand_RPDO1", "NMT", "SYNC"} <= names
    dump = subprocess.run(
        [sys.executable, "-m", "cantools", "dump", str(dbc_file)],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert dump.returncode == 0, dump.stderr
    for name in ("Skin_TPDO1", "Hand_RPDO1", "Belt_Heartbeat", "EMG_EMCY", "TargetGripForce"):
        assert name in dump.stdout


def test_every_frame_of_a_recorded_run_decodes_as_pdo_codec_decodes_it(dbc_file, recorded_run):
    import can

    db = cantools.database.load_file(str(dbc_file), database_format="dbc")
    codecs = {kind: PdoCodec(kind, DEFAULT_NODE_IDS[kind]) for kind in KINDS}
    # (CAN-ID) -> (codec, RPDO number or None for a TPDO, {signal name: (index, sub)})
    pdos = {}
    for kind in KINDS:
        for pdo in pdo_messages(kind, DEFAULT_NODE_IDS[kind]):
            keys = {s.name: s.key for s in pdo.signals}
            number = pdo.number if pdo.direction == "RPDO" else None
            pdos[pdo.can_id] = (pdo.name, codecs[kind], number, keys)
    compared: Counter[str] = Counter()
    states: Counter[str] = Counter()
    for msg in can.LogReader(str(recorded_run)):
        if msg.is_error_frame:
            continue
        data = bytes(msg.data)
        if msg.arbitration_id in pdos:
            name, codec, number, keys = pdos[msg.arbitration_id]
            if number is None:
                expected = codec.decode(msg.arbitration_id, data)
            else:
                rpdo = codec.rpdo(number)
                rpdo.data = bytearray(data)
                expected = {(v.od.index, v.od.subindex): v.raw for v in rpdo.map}
            decoded = db.decode_message(msg.arbitration_id, data, decode_choices=False)
            assert {keys[s]: v for s, v in decoded.items()} == expected, name
            compared[name] += 1
        elif msg.arbitration_id & ~0x7F == HEARTBEAT_BASE:
            state = db.decode_message(msg.arbitration_id, data)["State"]
            states[str(state)] += 1
    # the loop on the bus: skin samples, EMG envelope, belt velocity, hand grip, all compared
    for name in ("Skin_TPDO1", "EMG_TPDO1", "Belt_RPDO1", "Hand_RPDO1", "Belt_TPDO1"):
        assert compared[name] > 10, compared
    assert states["operational"] > 0 and states["boot-up"] >= 4, states


def test_signals_sit_where_the_eds_mapping_puts_them(dbc_file):
    db = cantools.database.load_file(str(dbc_file), database_format="dbc")
    for kind in KINDS:
        for pdo in pdo_messages(kind, DEFAULT_NODE_IDS[kind]):
            message = db.get_message_by_frame_id(pdo.can_id)
            assert message.length == pdo.length_bytes
            node, gateway = NODE_NAMES[kind], NODE_NAMES[MASTER]
            sender, receiver = (node, gateway) if pdo.direction == "TPDO" else (gateway, node)
            assert message.senders == [sender]
            for s in pdo.signals:
                signal = message.get_signal_by_name(s.name)
                assert (signal.start, signal.length) == (s.start_bit, s.length_bits)
                assert signal.byte_order == "little_endian"
                assert signal.receivers == [receiver]
                assert f"{s.index:04X}h:{s.subindex:02X}" in signal.comment


def test_units_limits_and_signedness_come_from_the_eds(dbc_file):
    db = cantools.database.load_file(str(dbc_file), database_format="dbc")
    grip = db.get_message_by_name("Hand_RPDO1").get_signal_by_name("TargetGripForce")
    assert (grip.unit, grip.minimum, grip.maximum, grip.is_signed) == ("mN", 0, 100000, False)
    assert (grip.scale, grip.offset) == (1, 0)  # raw object-dictionary units, exact integers
    velocity = db.get_message_by_name("Belt_RPDO1").get_signal_by_name("TargetVelocity")
    assert (velocity.unit, velocity.minimum, velocity.maximum) == ("mrad/s", -7400, 8000)
    assert velocity.is_signed
    envelope = db.get_message_by_name("EMG_TPDO1").get_signal_by_name("EMGEnvelope")
    assert envelope.unit == "uV"
    active = db.get_message_by_name("Belt_TPDO2").get_signal_by_name("ActiveBelt")
    assert active.choices[2] == "slip belt"


def test_heartbeat_state_and_nmt_commands_have_value_tables(dbc_file):
    db = cantools.database.load_file(str(dbc_file), database_format="dbc")
    heartbeat = db.get_message_by_frame_id(HEARTBEAT_BASE + DEFAULT_NODE_IDS["hand"])
    assert str(heartbeat.decode(bytes([NmtState.PRE_OPERATIONAL]))["State"]) == "pre-operational"
    assert heartbeat.cycle_time == 100  # the EDS's producer heartbeat time (1017h)
    assert str(db.decode_message(0, bytes([0x81, 0x10]))["Command"]) == "reset node"
    assert str(db.decode_message(0, bytes([0x01, 0x00]))["NodeID"]) == "all nodes"
    emcy_frame = db.get_message_by_frame_id(EMCY_BASE + DEFAULT_NODE_IDS["skin"])
    decoded = emcy_frame.decode(bytes([0x01, 0xFF, 0x80, 0, 0, 0, 0, 0]))
    assert str(decoded["ErrorCode"]) == "sensor saturated (manufacturer-specific)"


def test_emcy_value_table_names_every_code_the_devices_send():
    sent = {
        value
        for name, value in vars(emcy).items()
        if name.isupper() and isinstance(value, int) and not name.startswith(("REG_", "COB_"))
        if name != "QUEUE_LIMIT"
    }
    assert sent <= set(EMCY_CODES)


def test_node_id_override_moves_every_frame_of_that_node():
    db = build_database({"skin": 0x11})
    ids = {m.frame_id for m in db.messages}
    for base in (TPDO_BASES[0], TPDO_BASES[1], EMCY_BASE, HEARTBEAT_BASE, SDO_TX_BASE, SDO_RX_BASE):
        assert base + 0x11 in ids and base + 0x10 not in ids
    assert "skin node 0x11" in db.get_message_by_frame_id(TPDO_BASES[0] + 0x11).comment


def test_node_id_override_from_the_command_line(tmp_path, capsys):
    out = tmp_path / "moved.dbc"
    assert main(["profiles", "dbc", "--out", str(out), "--node-id", "hand=0x41"]) == 0
    db = cantools.database.load_file(str(out))
    assert db.get_message_by_name("Hand_RPDO1").frame_id == 0x241
    assert main(["profiles", "dbc", "--node-id", "hand=0x20"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "two nodes share a node-ID" in err


def test_unknown_kind_or_clashing_node_ids_are_refused():
    with pytest.raises(ConfigError, match="unknown node kind"):
        node_ids_with({"arm": 5})
    with pytest.raises(ConfigError, match="share a node-ID"):
        node_ids_with({MASTER: DEFAULT_NODE_IDS["skin"]})


def test_names_are_dbc_identifiers_unique_within_their_message():
    db = build_database()
    ident = re.compile(r"^[A-Za-z_][A-Za-z0-9_]{0,31}$")
    for message in db.messages:
        assert ident.match(message.name), message.name
        names = [s.name for s in message.signals]
        assert len(names) == len(set(names))
        assert all(ident.match(n) for n in names), names


def test_the_export_is_deterministic_and_names_each_object():
    text = dbc_text()
    assert text == dbc_text()
    assert f"object {obj.HAND_TARGET_GRIP_MN:04X}h:00 Target grip force [mN]" in text


def test_stdout_without_out(capsys):
    assert main(["profiles", "dbc"]) == 0
    text = capsys.readouterr().out
    db = cantools.database.load_string(text, database_format="dbc")
    assert db.get_message_by_name("Skin_TPDO1").frame_id == TPDO_BASES[0] + 0x10


def test_the_gateway_in_the_dbc_is_the_gateway_at_its_defaults():
    from grasplink.gateway.config import load_config

    config = load_config(None)
    heartbeat = build_database().get_message_by_name("Gateway_Heartbeat")
    assert heartbeat.frame_id == HEARTBEAT_BASE + config.node_id
    assert heartbeat.cycle_time == config.heartbeat_ms

"""Conformance cases 9.1-9.4 (NMT states) and 10.1-10.4 (NMT transitions), CiA 301 7.3.2.

States are observed the way the tool does: the heartbeat (1017h shortened to
20 ms) carries the state, the boot-up message (700h+node-ID, one byte 00h)
marks the end of initialisation, and what a state allows (CiA 301 table 79:
SDO/EMCY/SYNC in pre-operational and operational, PDO in operational only,
NMT and error control always) is probed.
"""

from __future__ import annotations

import struct
import time

from grasplink.profiles import objects as obj
from tests.conformance.conftest import (
    APP_PARAMETER,
    NMT_PRE_OP,
    NMT_RESET_COMM,
    NMT_RESET_NODE,
    NMT_START,
    NMT_STOP,
    SILENCE_S,
    STATE_BOOTUP,
    STATE_OPERATIONAL,
    STATE_PRE_OP,
    STATE_STOPPED,
    Dut,
    cob,
    upload_request,
)

STATE_COMMAND = {STATE_PRE_OP: NMT_PRE_OP, STATE_OPERATIONAL: NMT_START, STATE_STOPPED: NMT_STOP}


def is_pdo(m) -> bool:
    return not m.is_remote_frame and 0x180 <= m.arbitration_id <= 0x57F


def rpdo_applied(dut: Dut) -> bool:
    """Send RPDO1 with controlword 0x0006; True if the device took it."""
    dut.send(0x200 + dut.node_id, struct.pack("<HI", 0x0006, 0))
    dut.barrier()
    return dut.get(obj.CONTROLWORD) == 0x0006


def sync_answered(dut: Dut, can_id: int) -> bool:
    mark = dut.log.mark()
    dut.sync()
    dut.barrier()
    return bool(dut.log.since(mark, cob(can_id)))


def boot(dut: Dut, command: int) -> None:
    """Send a reset command; check the boot-up message, then pre-operational behaviour:
    after the boot-up no PDO and no heartbeat of the old state."""
    mark = dut.log.mark()
    dut.nmt(command)
    bootup = dut.wait_bootup(mark)
    assert bootup is not None, f"no boot-up after NMT 0x{command:02X}"
    assert bootup.dlc == 1 and bytes(bootup.data) == bytes([STATE_BOOTUP])
    dut.barrier()
    frames = dut.log.since(mark)
    after = frames[next(i for i, m in enumerate(frames) if m is bootup) + 1 :]
    assert [m for m in after if is_pdo(m)] == [], "PDO after the boot-up message"
    assert {m.data[0] for m in after if m.arbitration_id == dut.heartbeat_id} <= {STATE_PRE_OP}


def test_9_1_bootup_and_defaults(dut: Dut) -> None:
    """9.1 State 01: "Test if DUT correctly supports the Boot-up message and resets the parameters
    to their default values."

    The power-on boot-up is one byte 00h on 700h+node-ID. After changing a
    communication (1017h) and an application parameter, NMT reset node gives
    a boot-up again (and no PDO after it) and both parameters have their
    EDS defaults; the first heartbeat then says pre-operational.
    """
    power_on = dut.log.since(dut.bootup_mark)[0]
    assert power_on.arbitration_id == dut.heartbeat_id and bytes(power_on.data) == b"\x00"
    app_index, app_sub, app_value = APP_PARAMETER[dut.kind]
    dut.set_heartbeat()
    dut.set(app_index, app_sub, app_value)
    boot(dut, NMT_RESET_NODE)
    assert dut.get(obj.HEARTBEAT_PRODUCER_MS) == dut.od[obj.HEARTBEAT_PRODUCER_MS].default
    assert dut.get(app_index, app_sub) == dut.entry(app_index, app_sub).var.default
    assert dut.wait_heartbeat().data[0] == STATE_PRE_OP


def test_9_2_pre_operational(dut: Dut) -> None:
    """9.2 State 02: "Test if DUT supports correctly NMT state pre-operational and generates a
    boot-up message during the change form NMT state initialization to pre-operational."

    After the boot-up the device is PRE-OPERATIONAL: heartbeats say 7Fh, SDO
    works, no PDO is sent (not even a TPDO of type 1 on SYNC), RPDOs are
    ignored (belt/hand) and an EMCY may be sent (heartbeat-consumer timeout).
    """
    boot(dut, NMT_RESET_COMM)
    dut.set_heartbeat()
    assert dut.wait_heartbeat().data[0] == STATE_PRE_OP
    can_id, _ = dut.configure_tpdo(1, transmission_type=1)
    mark = dut.log.mark()
    assert not sync_answered(dut, can_id)
    if dut.has_rpdos:
        assert not rpdo_applied(dut)
    time.sleep(SILENCE_S)
    assert dut.log.since(mark, is_pdo) == []
    dut.set(obj.HEARTBEAT_CONSUMER, 2, 0x05 << 16 | 30)
    dut.send(0x705, b"\x05")
    assert dut.log.wait_for(cob(dut.emcy_id)) is not None, "no EMCY in pre-operational"


def test_9_3_operational(dut: Dut) -> None:
    """9.3 State 03: "Test if DUT supports NMT state operational correctly."

    After NMT start heartbeats say 05h, SDO still works, TPDOs are sent
    (type 1 on SYNC, and the device's own event-driven ones), RPDOs are taken
    (belt/hand).
    """
    dut.set_heartbeat()
    dut.nmt(NMT_START)
    assert dut.wait_heartbeat(STATE_OPERATIONAL) is not None
    assert dut.read(obj.DEVICE_TYPE)
    can_id, _ = dut.configure_tpdo(4, transmission_type=1)
    assert sync_answered(dut, can_id)
    first = dut.log.wait_for(cob(0x180 + dut.node_id))
    assert first is not None, "TPDO1 (event driven by default) not sent"
    if dut.has_rpdos:
        assert rpdo_applied(dut)


def test_9_4_stopped(dut: Dut) -> None:
    """9.4 State 04: "Test if DUT supports NMT state stopped correctly."

    After NMT stop heartbeats say 04h; SDO requests get no answer, SYNC
    gives no TPDO, no PDO at all is sent, RPDOs are ignored (belt/hand: the
    controlword is unchanged afterwards) and no EMCY is sent. NMT still
    works: enter pre-operational brings SDO back.
    """
    dut.configure_tpdo(1, transmission_type=1)  # would answer every SYNC if it could
    dut.set(obj.HEARTBEAT_CONSUMER, 2, 0x05 << 16 | 30)
    dut.set_heartbeat()
    dut.start()
    dut.enter(NMT_STOP, STATE_STOPPED)
    mark = dut.log.mark()
    assert dut.sdo_silence(upload_request(obj.DEVICE_TYPE))
    dut.sync()
    dut.send(0x705, b"\x05")  # arms the consumer: it times out while stopped
    if dut.has_rpdos:
        dut.send(0x200 + dut.node_id, struct.pack("<HI", 0x0006, 0))
    time.sleep(SILENCE_S)
    assert dut.log.since(mark, is_pdo) == []
    assert dut.log.since(mark, cob(dut.emcy_id)) == []
    assert dut.log.since(mark, cob(dut.sdo_tx)) == []
    assert {m.data[0] for m in dut.log.since(mark, cob(dut.heartbeat_id))} == {STATE_STOPPED}
    dut.enter(NMT_PRE_OP, STATE_PRE_OP)
    if dut.has_rpdos:
        assert dut.get(obj.CONTROLWORD) == 0


def enter_state(dut: Dut, state: int) -> None:
    dut.enter(STATE_COMMAND[state], state)


def test_10_1_reset_node_and_communication(dut: Dut) -> None:
    """10.1 Transition 01: "Test if DUT supports the execution of the NMT service reset node and the
    NMT service reset communication correctly."

    From pre-operational, operational and stopped: reset communication
    gives a boot-up, then pre-operational, with the communication parameters
    (1017h) back to default and the application parameter kept; reset node
    gives a boot-up, then pre-operational, with both back to default.
    """
    app_index, app_sub, app_value = APP_PARAMETER[dut.kind]
    app_default = dut.entry(app_index, app_sub).var.default
    for state in (STATE_PRE_OP, STATE_OPERATIONAL, STATE_STOPPED):
        for command in (NMT_RESET_COMM, NMT_RESET_NODE):
            dut.set(app_index, app_sub, app_value)
            dut.set_heartbeat()
            enter_state(dut, state)
            boot(dut, command)
            assert dut.get(obj.HEARTBEAT_PRODUCER_MS) == dut.od[obj.HEARTBEAT_PRODUCER_MS].default
            expected = app_value if command == NMT_RESET_COMM else app_default
            assert dut.get(app_index, app_sub) == expected
            dut.set_heartbeat()
            assert dut.wait_heartbeat().data[0] == STATE_PRE_OP


def test_10_2_enter_pre_operational(dut: Dut) -> None:
    """10.2 Transition 02: "Test if DUT supports the execution of the NMT service enter
    pre-operational correctly."

    From operational (TPDO1 flowing) and from stopped: heartbeats say 7Fh,
    no PDO is sent any more, SDO answers.
    """
    dut.set_heartbeat()
    for state in (STATE_OPERATIONAL, STATE_STOPPED):
        enter_state(dut, state)
        if state == STATE_OPERATIONAL:
            assert dut.log.wait_for(cob(0x180 + dut.node_id)) is not None
        enter_state(dut, STATE_PRE_OP)
        mark = dut.log.mark()
        time.sleep(SILENCE_S)
        assert dut.log.since(mark, is_pdo) == []
        assert dut.read(obj.DEVICE_TYPE)


def test_10_3_start_remote_node(dut: Dut) -> None:
    """10.3 Transition 03: "Test if DUT supports the execution of the NMT service start remote node
    correctly."

    A start for another node-ID is ignored; addressed (node-ID) from
    pre-operational and broadcast (node-ID 0) from stopped, it makes the
    heartbeats say 05h and TPDO1 flow.
    """
    dut.set_heartbeat()
    mark = dut.log.mark()
    dut.nmt(NMT_START, dut.node_id + 1)
    assert dut.wait_heartbeat(since=mark).data[0] == STATE_PRE_OP
    for node_id in (dut.node_id, 0):
        if node_id == 0:
            enter_state(dut, STATE_STOPPED)
        mark = dut.log.mark()
        dut.nmt(NMT_START, node_id)
        assert dut.wait_heartbeat(STATE_OPERATIONAL, since=mark) is not None
        assert dut.log.wait_for(cob(0x180 + dut.node_id), since=mark) is not None


def test_10_4_stop_remote_node(dut: Dut) -> None:
    """10.4 Transition 04: "Test if DUT supports the execution of the NMT service stop remote node
    correctly."

    From pre-operational and from operational (broadcast): heartbeats say
    04h, SDO gets no answer and no PDO is sent.
    """
    dut.set_heartbeat()
    for node_id, state in ((dut.node_id, STATE_PRE_OP), (0, STATE_OPERATIONAL)):
        enter_state(dut, state)
        mark = dut.log.mark()
        dut.nmt(NMT_STOP, node_id)
        assert dut.wait_heartbeat(STATE_STOPPED, since=mark) is not None
        mark = dut.log.mark()
        assert dut.sdo_silence(upload_request(obj.DEVICE_TYPE))
        assert dut.log.since(mark, is_pdo) == []
        enter_state(dut, STATE_PRE_OP)

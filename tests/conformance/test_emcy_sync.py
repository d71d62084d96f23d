"""Conformance cases 5.1-5.6 (EMCY producer, CiA 301 7.2.7) and 6.1-6.3 (SYNC consumer).

The devices are SYNC consumers only (no 1006h/1019h): 6.4-6.10 do not apply,
see test_not_applicable.py. An EMCY is forced by an RPDO shorter than its
mapping (error code 8210h) on the belt/hand, and by a heartbeat-consumer
timeout (8130h) on the skin/EMG node, which have no RPDO.
"""

from __future__ import annotations

import struct
import time

from grasplink.profiles import objects as obj
from tests.conformance.conftest import (
    ABORT_INVALID_VALUE,
    ABORT_NO_DATA,
    COB_INVALID,
    SILENCE_S,
    Dut,
    SdoAbort,
    cob,
    emcy_code,
)

REG_GENERIC, REG_COMMUNICATION = 0x01, 0x10
FORCED_CODE = {"belt": 0x8210, "hand": 0x8210, "skin": 0x8130, "emg": 0x8130}


def test_5_1_emcy_cob_id(dut: Dut) -> None:
    """5.1 Emergency 01: "read 1014:0 and check is cob-id is correct"

    1014h = 80h + node-ID (EDS default $NODEID+0x80), valid (bit 31 clear),
    11-bit (bit 29 clear).
    """
    value = dut.get(obj.COB_ID_EMCY)
    assert value == 0x80 + dut.node_id == dut.od[obj.COB_ID_EMCY].default
    assert not value & (COB_INVALID | 0x20000000)


def test_5_2_error_register_no_error(dut: Dut) -> None:
    """5.2 Emergency 02: "read object 1001:0"

    After boot no error is active: the error register is 0.
    """
    assert dut.get(obj.ERROR_REGISTER) == 0


def test_5_3_error_history_empty(dut: Dut) -> None:
    """5.3 Emergency 03: "read object 1003:1"

    After boot the history is empty (1003h:00 = 0). Reading 1003h:01 then
    gives 0 or aborts with 0x08000024 (no data available); CiA 301 allows
    both.
    """
    assert dut.get(obj.ERROR_HISTORY, 0) == 0
    try:
        assert dut.get(obj.ERROR_HISTORY, 1) == 0
    except SdoAbort as exc:
        assert exc.code == ABORT_NO_DATA


def test_5_4_force_emcy(dut: Dut) -> None:
    """5.4 Emergency 04: "Force transmission of emergency message"

    Belt/hand: an RPDO1 of 1 byte where 6 are mapped gives EMCY 8210h (PDO
    not processed due to length error). Skin/EMG: a monitored heartbeat
    (1016h:02, node 05h, 30 ms) that stops gives EMCY 8130h. The frame goes
    on 1014h's CAN-ID with 8 bytes: error code, error register (generic and
    communication bits set), manufacturer field; python-canopen's EMCY
    consumer decodes it as an active error.
    """
    emcy = dut.force_emcy()
    assert emcy.arbitration_id == dut.get(obj.COB_ID_EMCY) & 0x7FF
    assert len(emcy.data) == 8
    assert emcy_code(emcy) == FORCED_CODE[dut.kind]
    assert emcy.data[2] & (REG_GENERIC | REG_COMMUNICATION) == REG_GENERIC | REG_COMMUNICATION
    decoded = dut.node.emcy.log[-1]  # python-canopen's EMCY consumer saw the same
    assert (decoded.code, decoded.register) == (emcy_code(emcy), emcy.data[2])
    assert decoded in dut.node.emcy.active


def test_5_5_error_register_after_emcy(dut: Dut) -> None:
    """5.5 Emergency 05: "read object 1001:0"

    After the forced EMCY the error register reads as the EMCY sent it, with
    the generic (bit 0) and communication (bit 4) bits set.
    """
    emcy = dut.force_emcy()
    register = dut.get(obj.ERROR_REGISTER)
    assert register == emcy.data[2]
    assert register & (REG_GENERIC | REG_COMMUNICATION) == REG_GENERIC | REG_COMMUNICATION


def test_5_6_error_history_after_emcy(dut: Dut) -> None:
    """5.6 Emergency 06: "read object 1003:1 and compare it with received msg"

    1003h:00 counts the error and 1003h:01 (newest) holds the EMCY's error
    code in its low 16 bits. Writing 0 to 1003h:00 clears the history; other
    values abort with 0x06090030.
    """
    emcy = dut.force_emcy()
    assert dut.get(obj.ERROR_HISTORY, 0) >= 1
    assert dut.get(obj.ERROR_HISTORY, 1) & 0xFFFF == emcy_code(emcy)
    assert dut.abort_of(dut.set, obj.ERROR_HISTORY, 0, 1) == ABORT_INVALID_VALUE
    dut.set(obj.ERROR_HISTORY, 0, 0)
    assert dut.get(obj.ERROR_HISTORY, 0) == 0


def test_6_1_default_sync_cob_id(dut: Dut) -> None:
    """6.1 Synchronization 01: "Test default SYNC COB-ID"

    1005h = 80h as in the EDS: 11-bit, bit 30 (generate SYNC) clear, since the
    device is a SYNC consumer only. Setting bit 30 is refused with
    0x06090030 and 1005h keeps its value.
    """
    assert dut.get(obj.COB_ID_SYNC) == 0x80 == dut.od[obj.COB_ID_SYNC].default
    assert dut.abort_of(dut.set, obj.COB_ID_SYNC, 0, 0x40000080) == ABORT_INVALID_VALUE
    assert dut.get(obj.COB_ID_SYNC) == 0x80


def test_6_2_count_sync_messages(dut: Dut) -> None:
    """6.2 Synchronization 02: "Count SYNC messages"

    For a SYNC consumer (1005h bit 30 clear, no 1006h) the count must be 0:
    in PRE-OPERATIONAL and OPERATIONAL the device sends no SYNC frame.
    """
    mark = dut.log.mark()
    dut.start()
    assert dut.log.collect(cob(0x080), 2 * SILENCE_S, mark) == []


def test_6_3_count_transmit_pdos(dut: Dut) -> None:
    """6.3 Synchronization 03: "Count Transmit PDOs"

    TPDO1 with transmission type 1: n SYNCs give exactly n TPDOs. After the
    SYNC COB-ID is moved to 0FFh, SYNCs on 080h give none and SYNCs on 0FFh
    give one each.
    """
    can_id, length = dut.configure_tpdo(1, transmission_type=1)
    dut.start()
    dut.barrier()

    def count(sync_id: int, n: int) -> int:
        mark = dut.log.mark()
        for _ in range(n):
            time.sleep(0.005)  # a TPDO without SYNC would be counted too
            dut.send(sync_id, b"")
            dut.barrier()
        frames = dut.log.since(mark, cob(can_id))
        assert {len(f.data) for f in frames} <= {length}
        return len(frames)

    assert count(0x080, 10) == 10
    dut.set(obj.COB_ID_SYNC, 0, 0x0FF)
    assert count(0x080, 3) == 0
    assert count(0x0FF, 5) == 5
    data = struct.pack("<B", 1)
    mark = dut.log.mark()
    dut.send(0x0FF, data)  # a SYNC with counter is a SYNC too
    dut.barrier()
    assert len(dut.log.since(mark, cob(can_id))) == 1

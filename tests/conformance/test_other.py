"""Conformance cases 8.1-8.8 (store/restore parameters, CiA 301 7.5.2.13/14) and 8.10
(restricted CAN-IDs, CiA 301 7.3.5). 8.9 needs 1020h and does not apply.

The tool writes the signatures as UNSIGNED32 and shows them byte-reversed:
'evas' is "save" (0x65766173), 'daol' is "load" (0x64616F6C); 'wron' is a
wrong signature. CiA 301: a wrong signature is refused with 0x08000020; a
restore takes effect at the next reset node (sub-index 1, 3) or reset
communication (sub-index 2).
"""

from __future__ import annotations

import struct

from grasplink.profiles import objects as obj
from tests.conformance.conftest import (
    ABORT_CANNOT_TRANSFER,
    ABORT_INVALID_VALUE,
    APP_PARAMETER,
    COB_INVALID,
    COB_NO_RTR,
    LOAD,
    NMT_RESET_COMM,
    NMT_RESET_NODE,
    RESTRICTED_CAN_IDS,
    SAVE,
    Dut,
)


def signature(text: str) -> int:
    """The UNSIGNED32 the tool shows as `text` (most significant byte first)."""
    return int.from_bytes(text.encode("ascii"), "big")


WRONG = signature("wron")
COMM_PARAMETER = (obj.HEARTBEAT_PRODUCER_MS, 0, 40)
assert signature("evas") == SAVE and signature("daol") == LOAD


def reset(dut: Dut, command: int) -> None:
    mark = dut.log.mark()
    dut.nmt(command)
    assert dut.wait_bootup(mark) is not None, "no boot-up after the reset"


def change(dut: Dut, *params: tuple[int, int, int]) -> None:
    for index, sub, value in params:
        dut.set(index, sub, value)
        assert dut.get(index, sub) == value


def is_default(dut: Dut, param: tuple[int, int, int]) -> bool:
    index, sub, _ = param
    return dut.get(index, sub) == dut.entry(index, sub).var.default


def is_changed(dut: Dut, param: tuple[int, int, int]) -> bool:
    index, sub, value = param
    return dut.get(index, sub) == value


def supported(dut: Dut, index: int, sub: int) -> None:
    """1010h/1011h read bit 0 = 1: the device saves/restores on command."""
    assert dut.get(index, sub) & 0x1


def refuse(dut: Dut, index: int, sub: int) -> None:
    assert dut.abort_of(dut.set, index, sub, WRONG) == ABORT_CANNOT_TRANSFER


def test_8_1_store_all_wrong_signature(dut: Dut) -> None:
    """8.1 Testing other 01: "Write dictionary entry, if storing is supported (bit 0)"

    1010h:01 reads bit 0 = 1. Writing 'wron' is refused with 0x08000020 and
    nothing is stored: after reset node the changed parameters are defaults.
    """
    supported(dut, obj.STORE_PARAMETERS, 1)
    app = APP_PARAMETER[dut.kind]
    change(dut, COMM_PARAMETER, app)
    refuse(dut, obj.STORE_PARAMETERS, 1)
    reset(dut, NMT_RESET_NODE)
    assert is_default(dut, COMM_PARAMETER) and is_default(dut, app)


def test_8_2_store_all(dut: Dut) -> None:
    """8.2 Testing other 02: "Write dictionary entry, if storing is supported (bit 0)"

    1010h:01 = 'evas' ("save") is accepted: communication and application
    parameters survive reset node and reset communication.
    """
    app = APP_PARAMETER[dut.kind]
    change(dut, COMM_PARAMETER, app)
    dut.set(obj.STORE_PARAMETERS, 1, SAVE)
    reset(dut, NMT_RESET_NODE)
    assert is_changed(dut, COMM_PARAMETER) and is_changed(dut, app)
    reset(dut, NMT_RESET_COMM)
    assert is_changed(dut, COMM_PARAMETER) and is_changed(dut, app)


def test_8_3_restore_all_wrong_signature(dut: Dut) -> None:
    """8.3 Testing other 03: "Write dictionary entry, if restoring is supported (bit 0)(node-ID,
    1011h, 01h, 'wron')"

    1011h:01 reads bit 0 = 1. 'wron' is refused with 0x08000020; stored
    parameters stay stored across reset node.
    """
    supported(dut, obj.RESTORE_DEFAULTS, 1)
    app = APP_PARAMETER[dut.kind]
    change(dut, COMM_PARAMETER, app)
    dut.set(obj.STORE_PARAMETERS, 1, SAVE)
    refuse(dut, obj.RESTORE_DEFAULTS, 1)
    reset(dut, NMT_RESET_NODE)
    assert is_changed(dut, COMM_PARAMETER) and is_changed(dut, app)


def test_8_4_restore_all(dut: Dut) -> None:
    """8.4 Testing other 04: "Write dictionary entry, if restoring is supported (bit 0)(node-ID,
    1011h, 01h, 'daol'"

    After storing, 1011h:01 = 'daol' ("load") is accepted; the current
    values stay until the reset, and after reset node every parameter has
    its EDS default again.
    """
    app = APP_PARAMETER[dut.kind]
    change(dut, COMM_PARAMETER, app)
    dut.set(obj.STORE_PARAMETERS, 1, SAVE)
    dut.set(obj.RESTORE_DEFAULTS, 1, LOAD)
    assert is_changed(dut, COMM_PARAMETER) and is_changed(dut, app)
    reset(dut, NMT_RESET_NODE)
    assert is_default(dut, COMM_PARAMETER) and is_default(dut, app)


def test_8_5_store_communication_wrong_signature(dut: Dut) -> None:
    """8.5 Testing other 05: "Write dictionary entry, if storing is supported (bit 0)"

    1010h:02 (communication parameters) reads bit 0 = 1; 'wron' is refused
    with 0x08000020 and reset communication brings the defaults back.
    """
    supported(dut, obj.STORE_PARAMETERS, 2)
    change(dut, COMM_PARAMETER)
    refuse(dut, obj.STORE_PARAMETERS, 2)
    reset(dut, NMT_RESET_COMM)
    assert is_default(dut, COMM_PARAMETER)


def test_8_6_store_communication(dut: Dut) -> None:
    """8.6 Testing other 06: "Write dictionary entry, if storing is supported (bit 0)"

    1010h:02 = 'evas' stores the communication parameters (1000h-1FFFh)
    only: after reset node 1017h keeps its new value, the application
    parameter is back to its default.
    """
    app = APP_PARAMETER[dut.kind]
    change(dut, COMM_PARAMETER, app)
    dut.set(obj.STORE_PARAMETERS, 2, SAVE)
    reset(dut, NMT_RESET_NODE)
    assert is_changed(dut, COMM_PARAMETER)
    assert is_default(dut, app)


def test_8_7_restore_communication_wrong_signature(dut: Dut) -> None:
    """8.7 Testing other 07: "Write dictionary entry, if restoring is supported (bit 0)(node-ID,
    1011h, 02h, 'wron')"

    1011h:02 reads bit 0 = 1; 'wron' is refused with 0x08000020 and the
    stored communication parameters survive reset communication.
    """
    supported(dut, obj.RESTORE_DEFAULTS, 2)
    change(dut, COMM_PARAMETER)
    dut.set(obj.STORE_PARAMETERS, 2, SAVE)
    refuse(dut, obj.RESTORE_DEFAULTS, 2)
    reset(dut, NMT_RESET_COMM)
    assert is_changed(dut, COMM_PARAMETER)


def test_8_8_restore_communication(dut: Dut) -> None:
    """8.8 Testing other 08: "Write dictionary entry, if restoring is supported (bit 0)(node-ID,
    1011h, 02h, 'daol'"

    With communication and application parameters stored, 1011h:02 =
    'daol' restores the communication defaults at the next reset
    communication; the stored application parameter is untouched (also
    after reset node).
    """
    app = APP_PARAMETER[dut.kind]
    change(dut, COMM_PARAMETER, app)
    dut.set(obj.STORE_PARAMETERS, 1, SAVE)
    dut.set(obj.RESTORE_DEFAULTS, 2, LOAD)
    assert is_changed(dut, COMM_PARAMETER)
    reset(dut, NMT_RESET_COMM)
    assert is_default(dut, COMM_PARAMETER) and is_changed(dut, app)
    reset(dut, NMT_RESET_NODE)
    assert is_default(dut, COMM_PARAMETER) and is_changed(dut, app)


def test_8_10_restricted_can_ids(dut: Dut) -> None:
    """8.10 Testing other 10: "test restricted CAN-IDs"

    CiA 301 7.3.5 (table 31): 000h, 001h-07Fh, 101h-180h, 581h-5FFh,
    601h-67Fh, 6E0h-6FFh, 701h-77Fh and 780h-7FFh may not be used by a PDO,
    SYNC or EMCY. Each range's ends, written as a valid COB-ID to every TPDO
    (and RPDO on belt/hand, made invalid first), 1014h (made invalid first)
    and 1005h, are refused with 0x06090030 and the COB-ID stays. A free
    CAN-ID is accepted.
    """
    targets = [(0x1800 + n - 1, 1, COB_NO_RTR) for n in dut.tpdo_numbers()]
    targets += [(0x1400 + n - 1, 1, 0) for n in dut.rpdo_numbers()]
    targets += [(obj.COB_ID_EMCY, 0, 0), (obj.COB_ID_SYNC, 0, 0)]
    for index, sub, flags in targets:
        if index != obj.COB_ID_SYNC:
            dut.set(index, sub, dut.get(index, sub) | COB_INVALID)
        before = dut.get(index, sub)
        for can_id in RESTRICTED_CAN_IDS:
            code = dut.abort_of(dut.write, index, sub, struct.pack("<I", can_id | flags))
            assert code == ABORT_INVALID_VALUE, f"{index:04X}h <- {can_id:03X}h: 0x{code:08X}"
        assert dut.get(index, sub) == before
    dut.set(0x1803, 1, 0x4FF | COB_NO_RTR)  # free: accepted
    assert dut.get(0x1803, 1) == 0x4FF | COB_NO_RTR

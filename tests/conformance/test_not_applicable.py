"""Evidence for the conformance cases that do not apply (docs/conformance.md).

A case is not applicable when the feature it tests is not claimed in the EDS.
These tests check that the feature is really absent on the device too — the
object does not exist (0x06020000) whichever SDO protocol is used — so that the
"not applicable" verdicts stay true if a device or an EDS changes.
"""

from __future__ import annotations

import struct

import pytest

from tests.conformance.conftest import (
    ABORT_NO_OBJECT,
    NMT_RESET_COMM,
    SAVE,
    Dut,
)

GUARD_TIME, LIFE_TIME_FACTOR = 0x100C, 0x100D


def absent(dut: Dut, index: int) -> None:
    assert index not in dut.od, f"{index:04X}h is in the EDS"
    assert dut.abort_of(dut.read, index, 0) == ABORT_NO_OBJECT, f"{index:04X}h"


@pytest.mark.parametrize("transfer", ["segmented", "block", "block-crc"])
def test_na_2_14_2_20_2_24_write_100ch(dut: Dut, transfer: str) -> None:
    """2.14 / 2.20 / 2.24: "Write 100Ch:00h segmented / with block transfer without CRC
    / with block transfer and CRC - if guarding is supported."

    Not applicable: no node guarding. A write of 100Ch by each protocol is
    aborted with 0x06020000 (the block download may abort at its end).
    """
    data = struct.pack("<H", 100)
    if transfer == "segmented":
        code = dut.abort_of(dut.write, GUARD_TIME, 0, data, force_segment=True)
    else:

        def block() -> None:
            from canopen.sdo.exceptions import SdoAbortedError

            from tests.conformance.conftest import SdoAbort

            try:
                with dut.sdo.open(
                    GUARD_TIME,
                    0,
                    "wb",
                    size=2,
                    block_transfer=True,
                    request_crc_support=transfer == "block-crc",
                ) as fp:
                    fp.write(data)
            except SdoAbortedError as exc:
                raise SdoAbort(exc.code) from None

        code = dut.abort_of(block)
    assert code == ABORT_NO_OBJECT
    absent(dut, GUARD_TIME)


def test_na_2_28_2_29_2_30_further_sdo_channels(dut: Dut) -> None:
    """2.28 / 2.29 / 2.30: "Read 1201h and following objects (for reset comm)",
    "Read 1280h and following objects with SAVE 1010h:01h and reset communication."

    Not applicable: one SDO server (1200h) and no SDO client. 1201h-127Fh and
    1280h-12FFh do not exist, also after "save" and reset communication.
    """
    for phase in ("boot", "after save + reset communication"):
        for index in range(0x1201, 0x1300):
            assert index not in dut.od
            assert dut.abort_of(dut.read, index, 0) == ABORT_NO_OBJECT, f"{index:04X}h {phase}"
        if phase == "boot":
            dut.write(0x1010, 1, struct.pack("<I", SAVE))
            mark = dut.log.mark()
            dut.nmt(NMT_RESET_COMM)
            assert dut.wait_bootup(mark) is not None


def test_na_6_4_to_6_10_sync_producer_objects(dut: Dut) -> None:
    """6.4-6.10: SYNC counter, overflow value and period (1006h, 1019h).

    Not applicable: the devices are SYNC consumers only; 1006h (communication
    cycle period), 1007h (synchronous window) and 1019h (synchronous counter
    overflow value) do not exist.
    """
    for index in (0x1006, 0x1007, 0x1019):
        absent(dut, index)


def test_na_7_guarding(dut: Dut) -> None:
    """7.1-7.6, 7.203, 7.206, 7.207: node guarding.

    Not applicable: no node guarding (heartbeat is used). 100Ch (guard time)
    and 100Dh (life time factor) do not exist, so guarding cannot be switched
    on; guarding RTRs are not answered (see 7.202, 7.205).
    """
    for index in (GUARD_TIME, LIFE_TIME_FACTOR):
        absent(dut, index)


def test_na_7_2_guarding_rtr_is_ignored_and_the_device_stays_up(dut: Dut) -> None:
    """7.2 "Transmit RTR and wait for response", on a device without guarding.

    The RTRs the tool sends get no reply (with 1017h = 0 nothing at all appears on
    700h+node-ID), no EMCY (an RTR is no duplicate node-ID), and the device keeps
    running: it still answers SDO and heartbeats again when 1017h is set.
    """
    dut.set_heartbeat(0)
    dut.barrier()
    mark = dut.log.mark()
    for _ in range(10):
        dut.send(dut.heartbeat_id, rtr=True, dlc=1)
    dut.barrier()

    def reply(m) -> bool:
        return m.arbitration_id in (dut.heartbeat_id, dut.emcy_id) and not m.is_remote_frame

    assert dut.log.since(mark, reply) == []  # exact after the barrier: frames are in order
    assert dut.device.duplicate_frames == 0
    assert dut.get(0x1000, 0) == dut.entry(0x1000).var.default
    dut.set_heartbeat(20)
    assert dut.wait_heartbeat() is not None


def test_na_8_9_verify_configuration(dut: Dut) -> None:
    """8.9: "If object 1010h and 1020h is supported, ..."

    Not applicable: 1020h (verify configuration) does not exist.
    """
    absent(dut, 0x1020)

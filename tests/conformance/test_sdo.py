"""Conformance cases 2.1-2.30: the SDO server (CiA 301 7.2.4).

Cases 2.14, 2.20, 2.24 (node guarding) and 2.28-2.30 (further SDO servers,
SDO client) do not apply; test_not_applicable.py checks why.
"""

from __future__ import annotations

import random
import struct
from itertools import pairwise
from statistics import median

import pytest

from grasplink.profiles import objects as obj
from tests.conformance.conftest import (
    ABORT_BLOCK_SIZE,
    ABORT_CANNOT_TRANSFER,
    ABORT_COMMAND,
    ABORT_LENGTH_HIGH,
    ABORT_LENGTH_LOW,
    ABORT_LENGTH_MISMATCH,
    ABORT_NO_OBJECT,
    ABORT_NO_SUBINDEX,
    ABORT_READ_ONLY,
    ABORT_SEQUENCE,
    ABORT_TOGGLE,
    ABORT_VALUE_HIGH,
    ABORT_VALUE_LOW,
    ABORT_WRITE_ONLY,
    Dut,
    abort_code,
    cob,
    mapping_locked,
    raw_upload,
    upload_request,
)
from tests.conformance.host_timing import heartbeats_on_a_kept_grid

STRING_OBJECTS = (obj.DEVICE_NAME, obj.HARDWARE_VERSION, obj.SOFTWARE_VERSION)
TOO_LONG = {ABORT_LENGTH_MISMATCH, ABORT_LENGTH_HIGH}  # CiA 301 allows either
TOO_SHORT = {ABORT_LENGTH_MISMATCH, ABORT_LENGTH_LOW}


def device_type(dut: Dut) -> bytes:
    return dut.entry(obj.DEVICE_TYPE).encode(dut.od[obj.DEVICE_TYPE].default)


def string_default(dut: Dut, index: int) -> bytes:
    return dut.od[index].default.encode("ascii")


def test_2_1_read_1000h_expedited(dut: Dut) -> None:
    """2.1 SDO 01: "Read 1000h:00h with expedited transfer."

    The initiate upload response is expedited (e=1, s=1, n=0) and carries the
    device type from the EDS.
    """
    reply = dut.sdo_request(upload_request(obj.DEVICE_TYPE))
    assert reply is not None and abort_code(reply) is None
    assert reply[0] == 0x43, f"0x{reply[0]:02X}: expected expedited, size indicated, 4 bytes"
    assert reply[1:4] == b"\x00\x10\x00"
    assert reply[4:8] == device_type(dut)


def test_2_2_read_write_random_rw_entries(dut: Dut) -> None:
    """2.2 SDO 02: "Read and write randomly dictionary RW entry (1000h to 1FFFh)."

    A seeded random sample of the rw entries of the communication area is read,
    written back and read again. Excluded: 1010h/1011h (command objects whose
    read value is a capability flag; writing it back is a wrong signature,
    cases 8.x) and PDO mapping entries the mapping procedure locks at the
    moment (PDO valid, or sub-index 0 not 0: they are refused, see 3.23/3.24).
    """
    rng = random.Random(f"2.2-{dut.kind}")
    candidates = [
        e
        for e in dut.entries
        if 0x1000 <= e.index <= 0x1FFF
        and e.access == "rw"
        and e.index not in (obj.STORE_PARAMETERS, obj.RESTORE_DEFAULTS)
        and not mapping_locked(dut, e.index, e.subindex)
    ]
    sample = rng.sample(candidates, min(15, len(candidates)))
    for entry in sample:
        value = dut.read(entry.index, entry.subindex)
        dut.write(entry.index, entry.subindex, value)
        assert dut.read(entry.index, entry.subindex) == value, str(entry)
    # 1010h/1011h read as capability flags; written back they are a wrong signature.
    for index in (obj.STORE_PARAMETERS, obj.RESTORE_DEFAULTS):
        for sub in (1, 2, 3):
            value = dut.read(index, sub)
            assert dut.abort_of(dut.write, index, sub, value) == ABORT_CANNOT_TRANSFER


def test_2_3_write_1000h_refused(dut: Dut) -> None:
    """2.3 SDO 03: "Try to write to 1000h:00h."

    1000h is ro: the download is aborted with 0x06010002 and the value stays.
    """
    assert dut.abort_of(dut.write, obj.DEVICE_TYPE, 0, b"\x00\x00\x00\x00") == ABORT_READ_ONLY
    assert dut.read(obj.DEVICE_TYPE) == device_type(dut)


def test_2_4_read_write_only_object(dut: Dut) -> None:
    """2.4 SDO 04: "Try to read write-only object."

    Every wo entry of the EDS is read; the upload is aborted with 0x06010001.
    None of the grasplink EDS files has a wo entry, so the case does not apply.
    """
    write_only = [e for e in dut.entries if e.access == "wo"]
    if not write_only:
        pytest.skip(f"{dut.kind}.eds has no write-only (wo) entry")
    for entry in write_only:
        code = dut.abort_of(dut.read, entry.index, entry.subindex)
        assert code == ABORT_WRITE_ONLY, str(entry)


def test_2_5_read_missing_subindex_1000h_01(dut: Dut) -> None:
    """2.5 SDO 05: "Try to read non-existing sub-index 1000h:01h."

    Expected abort: 0x06090011 (sub-index does not exist).
    """
    assert dut.abort_of(dut.read, obj.DEVICE_TYPE, 1) == ABORT_NO_SUBINDEX


def test_2_6_read_missing_object_1004h(dut: Dut) -> None:
    """2.6 SDO 06: "Try to read non-existing object 1004h:00h"

    Expected abort: 0x06020000 (object does not exist).
    """
    assert dut.abort_of(dut.read, 0x1004, 0) == ABORT_NO_OBJECT


@pytest.mark.parametrize(
    "command", [0xE0, 0x60, 0x00], ids=["ccs7", "upload-segment", "download-segment"]
)
def test_2_7_read_with_wrong_command_specifier(dut: Dut, command: int) -> None:
    """2.7 SDO 07: "Read with wrong command specifier"

    A request with the undefined client command specifier 7, and segment
    requests while no transfer is in progress, are aborted with 0x05040001.
    The server keeps working afterwards.
    """
    reply = dut.sdo_request(struct.pack("<BHB4x", command, obj.DEVICE_TYPE, 0))
    assert abort_code(reply) == ABORT_COMMAND
    assert dut.read(obj.DEVICE_TYPE) == device_type(dut)


def test_2_8_write_u32_to_u16_and_u8(dut: Dut) -> None:
    """2.8 SDO 08: "Write u32 to u16 or u8 object."

    Four bytes to 1017h (UNSIGNED16) and to 1029h:01 (UNSIGNED8): aborted with
    0x06070012 (length too high) or 0x06070010 (length does not match) — CiA
    301 allows either — and the values stay.
    """
    for index, sub in ((obj.HEARTBEAT_PRODUCER_MS, 0), (obj.ERROR_BEHAVIOUR, 1)):
        before = dut.read(index, sub)
        assert dut.abort_of(dut.write, index, sub, b"\x01\x00\x00\x00") in TOO_LONG
        assert dut.read(index, sub) == before


def test_2_9_write_u8_to_u16_and_u32(dut: Dut) -> None:
    """2.9 SDO 09: "Write u8 to u16 or u32 object."

    One byte to 1017h (UNSIGNED16) and to 1016h:02 (UNSIGNED32): aborted with
    0x06070013 (length too low) or 0x06070010, and the values stay.
    """
    for index, sub in ((obj.HEARTBEAT_PRODUCER_MS, 0), (obj.HEARTBEAT_CONSUMER, 2)):
        before = dut.read(index, sub)
        assert dut.abort_of(dut.write, index, sub, b"\x01") in TOO_SHORT
        assert dut.read(index, sub) == before


def limited(dut: Dut, *, high: bool):
    """rw entries whose EDS limit is inside their data type's range."""
    out = []
    for entry in dut.entries:
        if entry.access != "rw" or entry.size is None:
            continue
        limit = entry.var.max if high else entry.var.min
        if limit is None:
            continue
        beyond = limit + 1 if high else limit - 1
        try:
            entry.encode(beyond)
        except Exception:
            continue
        out.append((entry, beyond))
    return out


def test_2_10_write_too_high_value(dut: Dut) -> None:
    """2.10 SDO 10: "Try write data with too high value."

    1029h:01 (HighLimit 2) and the first manufacturer/profile entry with a
    HighLimit get HighLimit+1: aborted with 0x06090031, value unchanged.
    """
    candidates = limited(dut, high=True)
    chosen = [c for c in candidates if c[0].index == obj.ERROR_BEHAVIOUR]
    chosen += [c for c in candidates if c[0].index >= 0x2000][:1]
    assert chosen
    for entry, value in chosen:
        before = dut.read(entry.index, entry.subindex)
        code = dut.abort_of(dut.write, entry.index, entry.subindex, entry.encode(value))
        assert code == ABORT_VALUE_HIGH, str(entry)
        assert dut.read(entry.index, entry.subindex) == before


def test_2_11_write_too_low_value(dut: Dut) -> None:
    """2.11 SDO 11: "Try write data with too low value."

    The first entry whose LowLimit is above its type's minimum gets
    LowLimit-1: aborted with 0x06090032, value unchanged.
    """
    candidates = limited(dut, high=False)
    assert candidates, f"{dut.kind}.eds has no LowLimit above a type minimum"
    entry, value = candidates[0]
    before = dut.read(entry.index, entry.subindex)
    assert (
        dut.abort_of(dut.write, entry.index, entry.subindex, entry.encode(value)) == ABORT_VALUE_LOW
    ), str(entry)
    assert dut.read(entry.index, entry.subindex) == before


def test_2_12_read_1200h_cob_ids(dut: Dut) -> None:
    """2.12 SDO 12: "Read 1200h:01h / 1200h:02h and compare with predefined value."

    The default SDO server uses 600h+node-ID (client to server) and
    580h+node-ID (server to client), as the EDS says.
    """
    assert dut.get(obj.SDO_SERVER, 1) == 0x600 + dut.node_id == dut.od[0x1200][1].default
    assert dut.get(obj.SDO_SERVER, 2) == 0x580 + dut.node_id == dut.od[0x1200][2].default


def test_2_13_read_1000h_segmented(dut: Dut) -> None:
    """2.13 SDO 13: "Read 1000h:00h with segmented transfer."

    The client's initiate upload request is the same for both transfer types;
    for 4 bytes the server may answer expedited (CiA 301 7.2.4.3.5, the server
    chooses). Accepted: expedited with the value, or segmented with size 4
    indicated and correctly toggled segments. Either way the value is the
    device type from the EDS.
    """
    upload = raw_upload(dut, obj.DEVICE_TYPE)
    assert upload.data == device_type(dut)
    if not upload.expedited:
        assert upload.size == 4


def test_2_15_write_1017h_segmented(dut: Dut) -> None:
    """2.15 SDO 15: "Write 1017h:00h segmented - if heartbeat is supported."

    A segmented download (s=1, size 2, one segment) of 1017h is accepted; the
    heartbeat then runs at the new period.
    """
    dut.write(obj.HEARTBEAT_PRODUCER_MS, 0, struct.pack("<H", 30), force_segment=True)
    assert dut.get(obj.HEARTBEAT_PRODUCER_MS) == 30
    beats = heartbeats_on_a_kept_grid(dut, 0.030, 5)
    assert len(beats) == 5
    gaps = [b.timestamp - a.timestamp for a, b in pairwise(beats)]
    assert median(gaps) == pytest.approx(0.030, abs=0.008)


def test_2_16_read_segmented_object(dut: Dut) -> None:
    """2.16 SDO 16: "Check read segmented object (size > 4)."

    1008h (manufacturer device name) is uploaded by python-canopen; the
    server indicates the size and the string equals the EDS default.
    """
    with dut.sdo.open(obj.DEVICE_NAME, 0, buffering=0) as fp:
        data = fp.read()
        size = fp.size
    assert data == string_default(dut, obj.DEVICE_NAME)
    assert size == len(data) > 4


def test_2_17_read_segmented_wrong_toggle_bit(dut: Dut) -> None:
    """2.17 SDO 17: "Read segmented object with wrong toggle bit."

    After the initiate upload of 1008h, the first segment request carries
    t=1 instead of 0: aborted with 0x05030000. A new upload then works.
    """
    reply = dut.sdo_request(upload_request(obj.DEVICE_NAME))
    assert reply is not None and reply[0] == 0x41  # segmented, size indicated
    assert abort_code(dut.sdo_request(bytes([0x70]))) == ABORT_TOGGLE
    # And mid-transfer: a correct first segment, then a repeated toggle 0.
    dut.sdo_request(upload_request(obj.DEVICE_NAME))
    first = dut.sdo_request(bytes([0x60]))
    assert abort_code(first) is None and not first[0] & 0x01
    assert abort_code(dut.sdo_request(bytes([0x60]))) == ABORT_TOGGLE
    assert raw_upload(dut, obj.DEVICE_NAME).data == string_default(dut, obj.DEVICE_NAME)


def test_2_18_read_object_segmented(dut: Dut) -> None:
    """2.18 SDO 18: "Read object segmented."

    1008h, 1009h and 100Ah read frame by frame: initiate response with the
    size indicated, segments with alternating toggle bits, the n field and
    the c bit in the last one; the strings equal the EDS defaults.
    """
    for index in STRING_OBJECTS:
        upload = raw_upload(dut, index)
        expected = string_default(dut, index)
        assert not upload.expedited and upload.size == len(expected)
        assert upload.data == expected
        assert len(upload.segments) == -(-len(expected) // 7)


def block_read(dut: Dut, index: int, crc: bool) -> tuple[bytes, bool]:
    fp = dut.sdo.open(index, 0, "rb", buffering=0, block_transfer=True, request_crc_support=crc)
    try:
        data = fp.read()
        return data, fp.crc_supported
    finally:
        fp.close()


def block_write(dut: Dut, index: int, data: bytes, crc: bool) -> None:
    with dut.sdo.open(
        index, 0, "wb", size=len(data), block_transfer=True, request_crc_support=crc
    ) as fp:
        fp.write(data)


def test_2_19_read_1000h_block_without_crc(dut: Dut) -> None:
    """2.19 SDO 19: "Read 1000h:00h with block transfer without CRC."

    python-canopen's block upload without CRC support: the server answers
    without CRC and sends the device type in one block.
    """
    data, crc = block_read(dut, obj.DEVICE_TYPE, crc=False)
    assert data == device_type(dut)
    assert crc is False


def test_2_21_write_1017h_block_without_crc(dut: Dut) -> None:
    """2.21 SDO 21: "Write 1017h:00h with block transfer without CRC - if heartbeat is supported."

    Block download of 1017h without CRC is accepted and read back.
    """
    block_write(dut, obj.HEARTBEAT_PRODUCER_MS, struct.pack("<H", 40), crc=False)
    assert dut.get(obj.HEARTBEAT_PRODUCER_MS) == 40


def test_2_22_read_segmented_object_block(dut: Dut) -> None:
    """2.22 SDO 22: "Read segmented object with block transfer."

    1008h (longer than 4 bytes) by block upload without CRC equals the EDS.
    """
    data, _ = block_read(dut, obj.DEVICE_NAME, crc=False)
    assert data == string_default(dut, obj.DEVICE_NAME)


def test_2_23_read_object_block_with_crc(dut: Dut) -> None:
    """2.23 SDO 23: "Read object with block transfer and CRC."

    The server agrees to the CRC (sc=1) and python-canopen verifies it for
    1008h, 1009h and 100Ah.
    """
    for index in STRING_OBJECTS:
        data, crc = block_read(dut, index, crc=True)
        assert crc is True
        assert data == string_default(dut, index)


def test_2_25_write_1017h_block_with_crc(dut: Dut) -> None:
    """2.25 SDO 25: "Write 1017h:00h with block transfer and CRC - if heartbeat is supported."

    Block download of 1017h with CRC is accepted (the server checks the CRC)
    and read back.
    """
    block_write(dut, obj.HEARTBEAT_PRODUCER_MS, struct.pack("<H", 60), crc=True)
    assert dut.get(obj.HEARTBEAT_PRODUCER_MS) == 60


def test_2_26_block_read_wrong_blocksize(dut: Dut) -> None:
    """2.26 SDO 26: "Perform block read with wrong blocksize (128)."

    Initiate block upload with blksize 128 (and 0): aborted with 0x05040002.
    """
    for blksize in (128, 0):
        request = struct.pack("<BHBBB2x", 0xA4, obj.DEVICE_NAME, 0, blksize, 0)
        assert abort_code(dut.sdo_request(request)) == ABORT_BLOCK_SIZE
    assert block_read(dut, obj.DEVICE_NAME, crc=True)[0] == string_default(dut, obj.DEVICE_NAME)


def test_2_27_block_read_wrong_sequence_number(dut: Dut) -> None:
    """2.27 SDO 27: "Perform block read with wrong sequence number (128)."

    Block upload of 1008h; after the sub-block the client confirms
    ackseq=128 (more than the segments sent, outside 0..127): aborted with
    0x05040003.
    """
    reply = dut.sdo_request(struct.pack("<BHBBB2x", 0xA0, obj.DEVICE_NAME, 0, 127, 0))
    assert reply is not None and reply[0] >> 5 == 6, reply
    size = struct.unpack_from("<I", reply, 4)[0]
    segments = -(-size // 7)
    mark = dut.log.mark()
    dut.send(dut.sdo_rx, bytes([0xA3]) + bytes(7))  # start upload
    frames = dut.log.wait_count(cob(dut.sdo_tx), segments, since=mark)
    assert [f.data[0] & 0x7F for f in frames] == list(range(1, segments + 1))
    assert frames[-1].data[0] & 0x80
    ack = dut.sdo_request(bytes([0xA2, 128, 127]))
    assert abort_code(ack) == ABORT_SEQUENCE

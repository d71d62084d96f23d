"""SDO server: byte-exact protocol tests, then interoperability with python-canopen's client."""

from __future__ import annotations

import struct
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import can
import canopen
import pytest
from canopen.objectdictionary import DOMAIN, UNSIGNED16, UNSIGNED32, VISIBLE_STRING, ODVariable
from canopen.sdo.base import CrcXmodem
from canopen.sdo.client import BlockUploadStream

from grasplink.core.frames import SDO_RX_BASE, SDO_TX_BASE
from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.devices.sdo_server import SdoServer, sdo_crc

DEVICE_TYPE = 0x1000
DEVICE_NAME = 0x1008
HEARTBEAT_TIME = 0x1017
BLOB = 0x2000
WRITE_ONLY = 0x2001
BROKEN = 0x2002
EMPTY = 0x2003
MISSING = 0x3000

DEVICE_TYPE_VALUE = bytes.fromhex("91010200")  # 0x00020191, little endian
NAME_VALUE = b"GraspLink sensate hand node, skin rev C.4"  # 41 bytes: 5 full segments + 6
BLOB_VALUE = bytes(range(256)) * 4  # 1 KiB: 146 full block segments + 2 bytes

T0 = 1_000  # an arbitrary start time in microseconds
TIMEOUT_US = 1_000_000


# -- a tiny in-memory object store (test double for ObjectAccess) ----------------------


@dataclass
class Entry:
    value: bytes
    readable: bool = True
    writable: bool = True
    fixed_size: bool = False  # numeric entries keep their length


class FakeStore:
    """Just enough of an object dictionary to drive the SDO server."""

    def __init__(self) -> None:
        self.entries = {
            (DEVICE_TYPE, 0): Entry(DEVICE_TYPE_VALUE, writable=False, fixed_size=True),
            (HEARTBEAT_TIME, 0): Entry(b"\x00\x00", fixed_size=True),
            (DEVICE_NAME, 0): Entry(NAME_VALUE, writable=False),
            (BLOB, 0): Entry(BLOB_VALUE),
            (WRITE_ONLY, 0): Entry(b"\x00" * 4, readable=False, fixed_size=True),
            (EMPTY, 0): Entry(b""),
        }
        self.writes: list[tuple[int, int, bytes]] = []

    def _entry(self, index: int, subindex: int) -> Entry:
        if index == BROKEN:
            raise RuntimeError("store bug")
        try:
            return self.entries[index, subindex]
        except KeyError:
            raise SdoAbort(AbortCode.NO_OBJECT) from None

    def sdo_read(self, index: int, subindex: int) -> bytes:
        entry = self._entry(index, subindex)
        if not entry.readable:
            raise SdoAbort(AbortCode.WRITE_ONLY)
        return entry.value

    def sdo_write(self, index: int, subindex: int, data: bytes) -> None:
        entry = self._entry(index, subindex)
        if not entry.writable:
            raise SdoAbort(AbortCode.READ_ONLY)
        if entry.fixed_size and len(data) > len(entry.value):
            raise SdoAbort(AbortCode.LENGTH_TOO_HIGH)
        if entry.fixed_size and len(data) < len(entry.value):
            raise SdoAbort(AbortCode.LENGTH_TOO_LOW)
        entry.value = bytes(data)
        self.writes.append((index, subindex, bytes(data)))


# -- helpers for raw frames ------------------------------------------------------------


def frame(*fields: int | bytes) -> bytes:
    """An 8-byte payload from ints (one byte each) and byte strings, zero padded."""
    out = b"".join(bytes((f,)) if isinstance(f, int) else f for f in fields)
    assert len(out) <= 8
    return out.ljust(8, b"\x00")


def mux(command: int, index: int, subindex: int = 0, body: bytes = b"") -> bytes:
    return frame(struct.pack("<BHB", command, index, subindex), body)


def u32(value: int) -> bytes:
    return struct.pack("<I", value)


def abort(index: int, subindex: int, code: int) -> bytes:
    return mux(0x80, index, subindex, u32(code))


def chunks(data: bytes, size: int = 7) -> list[bytes]:
    return [data[i : i + size] for i in range(0, len(data), size)] or [b""]


@pytest.fixture
def store() -> FakeStore:
    return FakeStore()


@pytest.fixture
def server(store: FakeStore) -> SdoServer:
    return SdoServer(store, timeout_us=TIMEOUT_US)


def test_crc_is_crc16_ccitt_as_python_canopen_computes_it() -> None:
    assert sdo_crc(b"123456789") == 0x31C3  # CRC-16/XMODEM check value
    reference = CrcXmodem()
    reference.process(BLOB_VALUE)
    assert sdo_crc(BLOB_VALUE) == reference.final()


@pytest.mark.parametrize(
    "kwargs", [{"max_block_size": 0}, {"max_block_size": 128}, {"timeout_us": 0}]
)
def test_constructor_rejects_invalid_settings(store: FakeStore, kwargs: dict[str, int]) -> None:
    with pytest.raises(ValueError):
        SdoServer(store, **kwargs)


# -- expedited and segmented upload ----------------------------------------------------


def test_expedited_upload_of_1000h(server: SdoServer) -> None:
    assert server.on_request(mux(0x40, DEVICE_TYPE), T0) == [
        mux(0x43, DEVICE_TYPE, 0, DEVICE_TYPE_VALUE)
    ]
    assert server.next_deadline_us() is None  # nothing left in progress


def test_expedited_upload_indicates_unused_bytes(server: SdoServer) -> None:
    # 2 bytes: e=1, s=1, n=2 -> 0x4B
    assert server.on_request(mux(0x40, HEARTBEAT_TIME), T0) == [
        mux(0x4B, HEARTBEAT_TIME, 0, b"\x00\x00")
    ]


def test_segmented_upload_with_alternating_toggle(server: SdoServer) -> None:
    assert server.on_request(mux(0x40, DEVICE_NAME), T0) == [
        mux(0x41, DEVICE_NAME, 0, u32(len(NAME_VALUE)))
    ]
    received = b""
    segments = chunks(NAME_VALUE)
    for i, chunk in enumerate(segments):
        toggle = 0x10 * (i % 2)
        last = i == len(segments) - 1
        expected_cmd = toggle | (7 - len(chunk)) << 1 | int(last)
        (response,) = server.on_request(frame(0x60 | toggle), T0)
        assert response == frame(expected_cmd, chunk)
        received += response[1 : 8 - ((response[0] >> 1) & 7)]
    assert received == NAME_VALUE
    assert server.next_deadline_us() is None


def test_segmented_upload_last_segment_byte_exact(server: SdoServer) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    for i in range(5):
        server.on_request(frame(0x60 | 0x10 * (i % 2)), T0)
    # sixth segment: toggle 1, n=1, c=1
    assert server.on_request(frame(0x70), T0) == [frame(0x13, NAME_VALUE[35:])]


def test_upload_of_empty_value_is_one_empty_segment(server: SdoServer) -> None:
    assert server.on_request(mux(0x40, EMPTY), T0) == [mux(0x41, EMPTY, 0, u32(0))]
    assert server.on_request(frame(0x60), T0) == [frame(0x0F)]  # n=7, c=1


def test_upload_wrong_toggle_aborts(server: SdoServer) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    assert server.on_request(frame(0x70), T0) == [abort(DEVICE_NAME, 0, AbortCode.TOGGLE_BIT)]
    # the transfer is gone
    assert server.on_request(frame(0x60), T0) == [
        abort(DEVICE_NAME, 0, AbortCode.COMMAND_SPECIFIER)
    ]


def test_upload_wrong_toggle_after_first_segment(server: SdoServer) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    server.on_request(frame(0x60), T0)
    assert server.on_request(frame(0x60), T0) == [abort(DEVICE_NAME, 0, AbortCode.TOGGLE_BIT)]


@pytest.mark.parametrize(
    ("index", "code"),
    [
        (MISSING, AbortCode.NO_OBJECT),
        (WRITE_ONLY, AbortCode.WRITE_ONLY),
        (BROKEN, AbortCode.GENERAL),  # any other exception -> general error, no crash
    ],
)
def test_upload_refused_by_store(server: SdoServer, index: int, code: int) -> None:
    assert server.on_request(mux(0x40, index), T0) == [abort(index, 0, code)]
    assert server.on_request(mux(0x40, DEVICE_TYPE), T0) == [
        mux(0x43, DEVICE_TYPE, 0, DEVICE_TYPE_VALUE)
    ]


# -- expedited and segmented download --------------------------------------------------


def test_expedited_download_size_indicated(server: SdoServer, store: FakeStore) -> None:
    # e=1, s=1, n=2: only the 2 indicated bytes reach the store
    assert server.on_request(mux(0x2B, HEARTBEAT_TIME, 0, b"\xe8\x03\xaa\xbb"), T0) == [
        mux(0x60, HEARTBEAT_TIME)
    ]
    assert store.writes == [(HEARTBEAT_TIME, 0, b"\xe8\x03")]


def test_expedited_download_without_size_passes_all_four_bytes(
    server: SdoServer, store: FakeStore
) -> None:
    # e=1, s=0: the store gets 4 bytes and judges them (too long for a U16)
    assert server.on_request(mux(0x22, HEARTBEAT_TIME, 0, b"\xe8\x03\x00\x00"), T0) == [
        abort(HEARTBEAT_TIME, 0, AbortCode.LENGTH_TOO_HIGH)
    ]
    assert store.writes == []


@pytest.mark.parametrize(
    ("index", "code"),
    [
        (DEVICE_TYPE, AbortCode.READ_ONLY),
        (MISSING, AbortCode.NO_OBJECT),
        (BROKEN, AbortCode.GENERAL),
    ],
)
def test_expedited_download_refused_by_store(server: SdoServer, index: int, code: int) -> None:
    assert server.on_request(mux(0x23, index, 0, b"\x01\x02\x03\x04"), T0) == [
        abort(index, 0, code)
    ]


@pytest.mark.parametrize("size_indicated", [True, False])
def test_segmented_download_writes_once_at_the_end(
    server: SdoServer, store: FakeStore, size_indicated: bool
) -> None:
    value = b"0123456789"
    initiate = mux(0x21, BLOB, 0, u32(len(value))) if size_indicated else mux(0x20, BLOB)
    assert server.on_request(initiate, T0) == [mux(0x60, BLOB)]
    assert server.on_request(frame(0x00, value[:7]), T0) == [frame(0x20)]
    assert store.writes == []  # nothing stored before the last segment
    # toggle 1, n=4, c=1
    assert server.on_request(frame(0x19, value[7:]), T0) == [frame(0x30)]
    assert store.writes == [(BLOB, 0, value)]
    assert server.next_deadline_us() is None


def test_segmented_download_value_checked_as_a_whole(server: SdoServer, store: FakeStore) -> None:
    server.on_request(mux(0x21, HEARTBEAT_TIME, 0, u32(3)), T0)
    assert server.on_request(frame(0x09, b"\x01\x02\x03"), T0) == [
        abort(HEARTBEAT_TIME, 0, AbortCode.LENGTH_TOO_HIGH)
    ]
    assert store.writes == []


def test_segmented_download_wrong_toggle_aborts(server: SdoServer, store: FakeStore) -> None:
    server.on_request(mux(0x21, BLOB, 0, u32(10)), T0)
    assert server.on_request(frame(0x10, b"1234567"), T0) == [abort(BLOB, 0, AbortCode.TOGGLE_BIT)]
    assert store.writes == []


def test_segmented_download_more_than_indicated_aborts(server: SdoServer) -> None:
    server.on_request(mux(0x21, BLOB, 0, u32(3)), T0)
    assert server.on_request(frame(0x00, b"1234567"), T0) == [
        abort(BLOB, 0, AbortCode.LENGTH_TOO_HIGH)
    ]


def test_segmented_download_less_than_indicated_aborts(server: SdoServer) -> None:
    server.on_request(mux(0x21, BLOB, 0, u32(10)), T0)
    assert server.on_request(frame(0x09, b"123"), T0) == [abort(BLOB, 0, AbortCode.LENGTH_TOO_LOW)]


def test_download_larger_than_memory_bound_aborts(store: FakeStore) -> None:
    server = SdoServer(store, max_download_bytes=8)
    assert server.on_request(mux(0x21, BLOB, 0, u32(9)), T0) == [
        abort(BLOB, 0, AbortCode.OUT_OF_MEMORY)
    ]
    server.on_request(mux(0x20, BLOB), T0)
    server.on_request(frame(0x00, b"1234567"), T0)
    assert server.on_request(frame(0x10, b"1234567"), T0) == [
        abort(BLOB, 0, AbortCode.OUT_OF_MEMORY)
    ]


# -- command specifiers, client abort, new initiate, junk ------------------------------


def test_unknown_command_specifier_aborts(server: SdoServer) -> None:
    assert server.on_request(mux(0xE0, DEVICE_TYPE), T0) == [
        abort(DEVICE_TYPE, 0, AbortCode.COMMAND_SPECIFIER)
    ]


def test_segment_without_transfer_aborts(server: SdoServer) -> None:
    assert server.on_request(frame(0x60), T0) == [abort(0, 0, AbortCode.COMMAND_SPECIFIER)]


@pytest.mark.parametrize("wrong", [frame(0x00, b"1234567"), frame(0xA3), frame(0xE0)])
def test_wrong_command_during_transfer_aborts_it(server: SdoServer, wrong: bytes) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    assert server.on_request(wrong, T0) == [abort(DEVICE_NAME, 0, AbortCode.COMMAND_SPECIFIER)]
    assert server.next_deadline_us() is None


def test_client_abort_drops_transfer_silently(server: SdoServer) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    assert server.on_request(abort(DEVICE_NAME, 0, AbortCode.GENERAL), T0) == []
    assert server.next_deadline_us() is None
    assert server.on_request(frame(0x60), T0) == [
        abort(DEVICE_NAME, 0, AbortCode.COMMAND_SPECIFIER)
    ]


def test_client_abort_when_idle_is_ignored(server: SdoServer) -> None:
    assert server.on_request(abort(DEVICE_NAME, 0, AbortCode.GENERAL), T0) == []


def test_new_initiate_replaces_transfer_silently(server: SdoServer) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    assert server.on_request(mux(0x40, DEVICE_TYPE), T0) == [
        mux(0x43, DEVICE_TYPE, 0, DEVICE_TYPE_VALUE)
    ]
    assert server.on_request(frame(0x60), T0) == [
        abort(DEVICE_TYPE, 0, AbortCode.COMMAND_SPECIFIER)
    ]


def test_payload_that_is_not_8_bytes_is_ignored(server: SdoServer) -> None:
    assert server.on_request(b"\x40\x00\x10\x00", T0) == []


# -- timeout and reset -----------------------------------------------------------------


def test_idle_transfer_times_out(server: SdoServer) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    assert server.next_deadline_us() == T0 + TIMEOUT_US
    assert server.advance(T0 + TIMEOUT_US - 1) == []
    assert server.advance(T0 + TIMEOUT_US) == [abort(DEVICE_NAME, 0, AbortCode.TIMEOUT)]
    assert server.next_deadline_us() is None
    assert server.advance(T0 + 2 * TIMEOUT_US) == []


def test_each_frame_restarts_the_timeout(server: SdoServer) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    server.on_request(frame(0x60), T0 + 900_000)
    assert server.next_deadline_us() == T0 + 900_000 + TIMEOUT_US
    assert server.advance(T0 + TIMEOUT_US) == []


def test_late_segment_sees_the_timeout_first(server: SdoServer) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    assert server.on_request(frame(0x60), T0 + TIMEOUT_US) == [
        abort(DEVICE_NAME, 0, AbortCode.TIMEOUT),
        abort(DEVICE_NAME, 0, AbortCode.COMMAND_SPECIFIER),
    ]


def test_reset_drops_transfer_without_a_frame(server: SdoServer) -> None:
    server.on_request(mux(0x40, DEVICE_NAME), T0)
    server.reset()
    assert server.next_deadline_us() is None
    assert server.advance(T0 + 10 * TIMEOUT_US) == []


# -- block download --------------------------------------------------------------------


def block_segments(data: bytes) -> list[bytes]:
    """7-byte chunks of a block transfer, the last one zero padded."""
    return [c.ljust(7, b"\x00") for c in chunks(data)]


@pytest.mark.parametrize(
    ("crc", "initiate_cmd", "response_cmd"), [(False, 0xC2, 0xA0), (True, 0xC6, 0xA4)]
)
def test_block_download_1017h(
    server: SdoServer, store: FakeStore, crc: bool, initiate_cmd: int, response_cmd: int
) -> None:
    value = b"\xe8\x03"
    assert server.on_request(mux(initiate_cmd, HEARTBEAT_TIME, 0, u32(2)), T0) == [
        mux(response_cmd, HEARTBEAT_TIME, 0, bytes((127,)))
    ]
    assert server.on_request(frame(0x81, value), T0) == [frame(0xA2, 1, 127)]
    crc_field = struct.pack("<H", sdo_crc(value) if crc else 0)
    # end: n=5 unused bytes in the last segment -> 0xC1 | 5 << 2
    assert server.on_request(frame(0xD5, crc_field), T0) == [frame(0xA1)]
    assert store.writes == [(HEARTBEAT_TIME, 0, value)]
    assert server.next_deadline_us() is None


def run_block_download(server: SdoServer, data: bytes, blksize: int) -> list[bytes]:
    """A minimal loss-free block download client; returns every server response."""
    responses = server.on_request(mux(0xC6, BLOB, 0, u32(len(data))), T0)
    segments = block_segments(data)
    for start in range(0, len(segments), blksize):
        sub = segments[start : start + blksize]
        for seqno, seg in enumerate(sub, 1):
            last = start + seqno == len(segments)
            responses += server.on_request(frame(seqno | (0x80 if last else 0), seg), T0)
    unused = 7 * len(segments) - len(data)
    end = frame(0xC1 | unused << 2, struct.pack("<H", sdo_crc(data)))
    return responses + server.on_request(end, T0)


def test_block_download_in_several_sub_blocks(store: FakeStore) -> None:
    server = SdoServer(store, max_block_size=4)
    data = bytes(range(30))  # 5 segments: 4 + 1
    assert run_block_download(server, data, blksize=4) == [
        mux(0xA4, BLOB, 0, bytes((4,))),
        frame(0xA2, 4, 4),
        frame(0xA2, 1, 4),
        frame(0xA1),
    ]
    assert store.writes == [(BLOB, 0, data)]


def test_block_download_1_kib(server: SdoServer, store: FakeStore) -> None:
    responses = run_block_download(server, BLOB_VALUE[::-1], blksize=127)
    assert responses[1:] == [frame(0xA2, 127, 127), frame(0xA2, 20, 127), frame(0xA1)]
    assert store.writes == [(BLOB, 0, BLOB_VALUE[::-1])]


def test_block_download_lost_segment_is_repeated(store: FakeStore) -> None:
    server = SdoServer(store, max_block_size=4)
    data = bytes(range(30))
    seg = block_segments(data)
    server.on_request(mux(0xC6, BLOB, 0, u32(30)), T0)
    assert server.on_request(frame(1, seg[0]), T0) == []
    assert server.on_request(frame(3, seg[2]), T0) == []  # segment 2 was lost
    # end of sub-block: confirm segment 1 only, so the client repeats from segment 2
    assert server.on_request(frame(4, seg[3]), T0) == [frame(0xA2, 1, 4)]
    for seqno, s in enumerate(seg[1:4], 1):
        assert server.on_request(frame(seqno, s), T0) == []
    assert server.on_request(frame(0x84, seg[4]), T0) == [frame(0xA2, 4, 4)]
    assert server.on_request(frame(0xC1 | 5 << 2, struct.pack("<H", sdo_crc(data))), T0) == [
        frame(0xA1)
    ]
    assert store.writes == [(BLOB, 0, data)]


def test_block_download_duplicate_segment_is_ignored(store: FakeStore) -> None:
    server = SdoServer(store, max_block_size=4)
    data = bytes(range(28))
    seg = block_segments(data)
    server.on_request(mux(0xC2, BLOB, 0, u32(28)), T0)
    for seqno in (1, 1, 2, 3):
        assert server.on_request(frame(seqno, seg[seqno - 1]), T0) == []
    assert server.on_request(frame(0x84, seg[3]), T0) == [frame(0xA2, 4, 4)]
    assert server.on_request(frame(0xC1), T0) == [frame(0xA1)]
    assert store.writes == [(BLOB, 0, data)]


def test_block_download_out_of_order_last_segment_ends_sub_block(store: FakeStore) -> None:
    server = SdoServer(store, max_block_size=4)
    data = bytes(range(14))
    seg = block_segments(data)
    server.on_request(mux(0xC2, BLOB, 0, u32(14)), T0)
    # segment 1 lost, segment 2 carries 'c': the client must repeat both
    assert server.on_request(frame(0x82, seg[1]), T0) == [frame(0xA2, 0, 4)]
    assert server.on_request(frame(1, seg[0]), T0) == []
    assert server.on_request(frame(0x82, seg[1]), T0) == [frame(0xA2, 2, 4)]
    assert server.on_request(frame(0xC1), T0) == [frame(0xA1)]
    assert store.writes == [(BLOB, 0, data)]


@pytest.mark.parametrize("seqno", [0, 5])
def test_block_download_invalid_sequence_number_aborts(store: FakeStore, seqno: int) -> None:
    server = SdoServer(store, max_block_size=4)
    server.on_request(mux(0xC2, BLOB, 0, u32(14)), T0)
    assert server.on_request(frame(seqno, b"1234567"), T0) == [
        abort(BLOB, 0, AbortCode.SEQUENCE_NUMBER)
    ]


def test_block_download_client_abort_during_sub_block(server: SdoServer, store: FakeStore) -> None:
    server.on_request(mux(0xC2, BLOB, 0, u32(14)), T0)
    server.on_request(frame(1, b"1234567"), T0)
    assert server.on_request(abort(BLOB, 0, AbortCode.GENERAL), T0) == []
    assert server.next_deadline_us() is None
    assert store.writes == []


def test_block_download_crc_mismatch_aborts(server: SdoServer, store: FakeStore) -> None:
    server.on_request(mux(0xC6, HEARTBEAT_TIME, 0, u32(2)), T0)
    server.on_request(frame(0x81, b"\xe8\x03"), T0)
    bad_crc = struct.pack("<H", sdo_crc(b"\xe8\x03") ^ 1)
    assert server.on_request(frame(0xD5, bad_crc), T0) == [abort(HEARTBEAT_TIME, 0, AbortCode.CRC)]
    assert store.writes == []


def test_block_download_without_crc_ignores_crc_field(server: SdoServer, store: FakeStore) -> None:
    server.on_request(mux(0xC2, HEARTBEAT_TIME, 0, u32(2)), T0)
    server.on_request(frame(0x81, b"\xe8\x03"), T0)
    assert server.on_request(frame(0xD5, b"\xde\xad"), T0) == [frame(0xA1)]
    assert store.writes == [(HEARTBEAT_TIME, 0, b"\xe8\x03")]


def test_block_download_size_mismatch_aborts(server: SdoServer, store: FakeStore) -> None:
    server.on_request(mux(0xC2, BLOB, 0, u32(3)), T0)
    server.on_request(frame(0x81, b"12"), T0)
    assert server.on_request(frame(0xD5), T0) == [abort(BLOB, 0, AbortCode.LENGTH_TOO_LOW)]
    assert store.writes == []


def test_block_download_refused_by_store_at_the_end(server: SdoServer) -> None:
    server.on_request(mux(0xC2, DEVICE_TYPE, 0, u32(4)), T0)
    assert server.on_request(frame(0x81, b"1234"), T0) == [frame(0xA2, 1, 127)]
    assert server.on_request(frame(0xCD), T0) == [abort(DEVICE_TYPE, 0, AbortCode.READ_ONLY)]


def test_block_download_wrong_end_command_aborts(server: SdoServer) -> None:
    server.on_request(mux(0xC2, HEARTBEAT_TIME, 0, u32(2)), T0)
    server.on_request(frame(0x81, b"\xe8\x03"), T0)
    assert server.on_request(frame(0x60), T0) == [
        abort(HEARTBEAT_TIME, 0, AbortCode.COMMAND_SPECIFIER)
    ]


# -- block upload ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("initiate_cmd", "response_cmd", "crc"),
    [(0xA0, 0xC2, 0), (0xA4, 0xC6, sdo_crc(DEVICE_TYPE_VALUE))],
)
def test_block_upload_1000h(
    server: SdoServer, initiate_cmd: int, response_cmd: int, crc: int
) -> None:
    assert server.on_request(mux(initiate_cmd, DEVICE_TYPE, 0, bytes((127, 0))), T0) == [
        mux(response_cmd, DEVICE_TYPE, 0, u32(4))
    ]
    assert server.on_request(frame(0xA3), T0) == [frame(0x81, DEVICE_TYPE_VALUE)]
    # end: n=3 -> 0xC1 | 3 << 2
    assert server.on_request(frame(0xA2, 1, 127), T0) == [frame(0xCD, struct.pack("<H", crc))]
    assert server.on_request(frame(0xA1), T0) == []
    assert server.next_deadline_us() is None


@pytest.mark.parametrize("blksize", [0, 128])
def test_block_upload_invalid_block_size_aborts(server: SdoServer, blksize: int) -> None:
    assert server.on_request(mux(0xA4, DEVICE_TYPE, 0, bytes((blksize, 0))), T0) == [
        abort(DEVICE_TYPE, 0, AbortCode.BLOCK_SIZE)
    ]
    assert server.next_deadline_us() is None


def test_block_upload_1_kib_in_two_sub_blocks(server: SdoServer) -> None:
    server.on_request(mux(0xA4, BLOB, 0, bytes((127, 0))), T0)
    first = server.on_request(frame(0xA3), T0)
    assert [f[0] for f in first] == list(range(1, 128))
    second = server.on_request(frame(0xA2, 127, 127), T0)
    assert [f[0] for f in second] == [*range(1, 20), 0x80 | 20]
    data = b"".join(f[1:] for f in first + second)
    assert data[: len(BLOB_VALUE)] == BLOB_VALUE
    # 147 segments * 7 - 1024 = 5 unused bytes
    assert server.on_request(frame(0xA2, 20, 127), T0) == [
        frame(0xC1 | 5 << 2, struct.pack("<H", sdo_crc(BLOB_VALUE)))
    ]


def test_block_upload_repeats_unacknowledged_segments(server: SdoServer) -> None:
    server.on_request(mux(0xA0, DEVICE_NAME, 0, bytes((4, 0))), T0)
    seg = block_segments(NAME_VALUE)  # 6 segments
    assert server.on_request(frame(0xA3), T0) == [frame(n, seg[n - 1]) for n in range(1, 5)]
    # client only got segments 1 and 2: the next sub-block starts with segment 3
    assert server.on_request(frame(0xA2, 2, 4), T0) == [
        frame(1, seg[2]),
        frame(2, seg[3]),
        frame(3, seg[4]),
        frame(0x84, seg[5]),
    ]
    assert server.on_request(frame(0xA2, 4, 4), T0) == [frame(0xC1 | 1 << 2)]
    assert server.on_request(frame(0xA1), T0) == []


def test_block_upload_ackseq_zero_repeats_whole_sub_block(server: SdoServer) -> None:
    server.on_request(mux(0xA0, DEVICE_NAME, 0, bytes((2, 0))), T0)
    first = server.on_request(frame(0xA3), T0)
    assert server.on_request(frame(0xA2, 0, 2), T0) == first


def test_block_upload_ackseq_beyond_sent_aborts(server: SdoServer) -> None:
    server.on_request(mux(0xA0, DEVICE_NAME, 0, bytes((4, 0))), T0)
    server.on_request(frame(0xA3), T0)
    assert server.on_request(frame(0xA2, 5, 4), T0) == [
        abort(DEVICE_NAME, 0, AbortCode.SEQUENCE_NUMBER)
    ]


def test_block_upload_invalid_block_size_in_ack_aborts(server: SdoServer) -> None:
    server.on_request(mux(0xA0, DEVICE_NAME, 0, bytes((4, 0))), T0)
    server.on_request(frame(0xA3), T0)
    assert server.on_request(frame(0xA2, 4, 128), T0) == [
        abort(DEVICE_NAME, 0, AbortCode.BLOCK_SIZE)
    ]


def test_block_upload_of_empty_value(server: SdoServer) -> None:
    assert server.on_request(mux(0xA0, EMPTY, 0, bytes((127, 0))), T0) == [
        mux(0xC2, EMPTY, 0, u32(0))
    ]
    assert server.on_request(frame(0xA3), T0) == [frame(0x81)]
    assert server.on_request(frame(0xA2, 1, 127), T0) == [frame(0xC1 | 7 << 2)]


def test_block_upload_expects_start_first(server: SdoServer) -> None:
    server.on_request(mux(0xA0, DEVICE_TYPE, 0, bytes((127, 0))), T0)
    assert server.on_request(frame(0xA2, 0, 127), T0) == [
        abort(DEVICE_TYPE, 0, AbortCode.COMMAND_SPECIFIER)
    ]


def test_block_upload_refused_by_store(server: SdoServer) -> None:
    assert server.on_request(mux(0xA0, WRITE_ONLY, 0, bytes((127, 0))), T0) == [
        abort(WRITE_ONLY, 0, AbortCode.WRITE_ONLY)
    ]


# -- interoperability with python-canopen's SDO client ---------------------------------

NODE_ID = 0x10
PUMP_POLL_S = 0.005


class SdoPump:
    """Runs an SdoServer behind a virtual CAN bus, the way a node's bus loop would.

    `drop_request` / `drop_response` get the 1-based number of each frame in that
    direction and may drop it, to exercise the retransmission paths.
    """

    def __init__(
        self,
        channel: str,
        server: SdoServer,
        drop_request: Callable[[int], bool] | None = None,
        drop_response: Callable[[int], bool] | None = None,
    ) -> None:
        self.server = server
        self.requests: list[bytes] = []
        self.responses: list[bytes] = []
        self._drop_request = drop_request or (lambda n: False)
        self._drop_response = drop_response or (lambda n: False)
        self._bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self._lock = threading.Lock()  # the server is only ever touched under it
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sdo-pump", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            msg = self._bus.recv(timeout=PUMP_POLL_S)
            with self._lock:
                out = self._handle(msg)
            for payload in out:
                self.responses.append(payload)
                if not self._drop_response(len(self.responses)):
                    self._bus.send(
                        can.Message(
                            arbitration_id=SDO_TX_BASE + NODE_ID, data=payload, is_extended_id=False
                        )
                    )

    def _handle(self, msg: can.Message | None) -> list[bytes]:
        now_us = time.monotonic_ns() // 1000
        out = self.server.advance(now_us)
        if msg is not None and msg.arbitration_id == SDO_RX_BASE + NODE_ID:
            data = bytes(msg.data)
            self.requests.append(data)
            if not self._drop_request(len(self.requests)):
                out += self.server.on_request(data, now_us)
        return out

    def wait_until_idle(self, timeout_s: float = 1.0) -> bool:
        """True once the server has no transfer in progress (client frames may lag)."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            with self._lock:
                if self.server.next_deadline_us() is None:
                    return True
            time.sleep(PUMP_POLL_S)
        return False

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2)
        self._bus.shutdown()


def client_od() -> canopen.ObjectDictionary:
    od = canopen.ObjectDictionary()
    for name, index, data_type, access in [
        ("Device type", DEVICE_TYPE, UNSIGNED32, "ro"),
        ("Manufacturer device name", DEVICE_NAME, VISIBLE_STRING, "const"),
        ("Producer heartbeat time", HEARTBEAT_TIME, UNSIGNED16, "rw"),
        ("Blob", BLOB, DOMAIN, "rw"),
    ]:
        var = ODVariable(name, index, 0)
        var.data_type = data_type
        var.access_type = access
        od.add_object(var)
    return od


@dataclass
class Link:
    node: canopen.RemoteNode
    store: FakeStore
    pump: SdoPump


@pytest.fixture
def make_link() -> Iterator[Callable[..., Link]]:
    cleanups: list[Callable[[], None]] = []

    def make(
        drop_request: Callable[[int], bool] | None = None,
        drop_response: Callable[[int], bool] | None = None,
    ) -> Link:
        channel = f"sdo-test-{uuid.uuid4().hex}"
        store = FakeStore()
        pump = SdoPump(channel, SdoServer(store), drop_request, drop_response)
        cleanups.append(pump.stop)
        network = canopen.Network()
        network.NOTIFIER_CYCLE = PUMP_POLL_S  # fast teardown
        network.connect(interface="virtual", channel=channel, receive_own_messages=False)
        cleanups.append(network.disconnect)
        node = canopen.RemoteNode(NODE_ID, client_od())
        network.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 0.5
        return Link(node, store, pump)

    yield make
    for cleanup in reversed(cleanups):
        cleanup()


@pytest.fixture
def link(make_link: Callable[..., Link]) -> Link:
    return make_link()


def test_canopen_expedited_upload(link: Link) -> None:
    assert link.node.sdo[DEVICE_TYPE].raw == 0x00020191
    assert link.node.sdo.upload(DEVICE_TYPE, 0) == DEVICE_TYPE_VALUE
    assert link.pump.responses[0][0] == 0x43


def test_canopen_segmented_upload(link: Link) -> None:
    assert link.node.sdo.upload(DEVICE_NAME, 0) == NAME_VALUE
    assert link.node.sdo[DEVICE_NAME].raw == NAME_VALUE.decode()
    assert link.pump.responses[0][0] == 0x41


def test_canopen_upload_with_buffered_stream(link: Link) -> None:
    with link.node.sdo.open(DEVICE_NAME, 0, "rb", buffering=16) as fp:
        assert fp.read() == NAME_VALUE
    with link.node.sdo.open(DEVICE_TYPE, 0, "rb") as fp:
        assert fp.read() == DEVICE_TYPE_VALUE


def test_canopen_expedited_download(link: Link) -> None:
    link.node.sdo[HEARTBEAT_TIME].raw = 1000
    assert link.store.entries[HEARTBEAT_TIME, 0].value == b"\xe8\x03"
    assert link.node.sdo[HEARTBEAT_TIME].raw == 1000
    assert link.pump.requests[0][0] == 0x2B


def test_canopen_segmented_download(link: Link) -> None:
    link.node.sdo.download(BLOB, 0, NAME_VALUE)
    link.node.sdo.download(HEARTBEAT_TIME, 0, b"\xd0\x07", force_segment=True)
    assert link.store.writes == [(BLOB, 0, NAME_VALUE), (HEARTBEAT_TIME, 0, b"\xd0\x07")]
    assert link.node.sdo.upload(BLOB, 0) == NAME_VALUE


@pytest.mark.parametrize(
    ("call", "code"),
    [
        (lambda sdo: sdo.upload(WRITE_ONLY, 0), AbortCode.WRITE_ONLY),
        (lambda sdo: sdo.upload(MISSING, 0), AbortCode.NO_OBJECT),
        (lambda sdo: sdo.upload(BROKEN, 0), AbortCode.GENERAL),
        (lambda sdo: sdo.download(DEVICE_TYPE, 0, b"\x00\x00\x00\x00"), AbortCode.READ_ONLY),
        (lambda sdo: sdo.download(DEVICE_NAME, 0, b"x" * 20), AbortCode.READ_ONLY),
        (lambda sdo: sdo.download(HEARTBEAT_TIME, 0, b"\x01\x02\x03"), AbortCode.LENGTH_TOO_HIGH),
    ],
)
def test_canopen_sees_abort_codes(
    link: Link, call: Callable[[canopen.sdo.SdoClient], object], code: int
) -> None:
    with pytest.raises(canopen.SdoAbortedError) as excinfo:
        call(link.node.sdo)
    assert excinfo.value.code == code
    assert link.node.sdo.upload(DEVICE_TYPE, 0) == DEVICE_TYPE_VALUE  # server still fine


def block_write(node: canopen.RemoteNode, index: int, data: bytes, crc: bool) -> None:
    with node.sdo.open(
        index, 0, "wb", size=len(data), block_transfer=True, request_crc_support=crc
    ) as fp:
        fp.write(data)


def block_read(node: canopen.RemoteNode, index: int, crc: bool) -> bytes:
    with node.sdo.open(index, 0, "rb", block_transfer=True, request_crc_support=crc) as fp:
        return fp.read()


@pytest.mark.parametrize("crc", [False, True])
def test_canopen_block_download(link: Link, crc: bool) -> None:
    block_write(link.node, HEARTBEAT_TIME, b"\xe8\x03", crc)
    block_write(link.node, BLOB, BLOB_VALUE[::-1], crc)
    assert link.store.writes == [(HEARTBEAT_TIME, 0, b"\xe8\x03"), (BLOB, 0, BLOB_VALUE[::-1])]
    assert link.pump.requests[0][0] == (0xC6 if crc else 0xC2)


@pytest.mark.parametrize("crc", [False, True])
def test_canopen_block_upload(link: Link, crc: bool) -> None:
    assert block_read(link.node, DEVICE_TYPE, crc) == DEVICE_TYPE_VALUE
    assert block_read(link.node, BLOB, crc) == BLOB_VALUE
    assert link.pump.requests[0][0] == (0xA4 if crc else 0xA0)
    assert link.pump.wait_until_idle()  # the client's end response closed the transfer


def test_canopen_block_upload_with_invalid_block_size(
    link: Link, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(BlockUploadStream, "blksize", 128)
    with pytest.raises(canopen.SdoAbortedError) as excinfo:
        block_read(link.node, DEVICE_TYPE, crc=True)
    assert excinfo.value.code == AbortCode.BLOCK_SIZE


def test_canopen_block_download_repeats_a_lost_segment(make_link: Callable[..., Link]) -> None:
    # request 1 is the initiate, so request 6 is segment 5 of the first sub-block
    link = make_link(drop_request=lambda n: n == 6)
    block_write(link.node, BLOB, BLOB_VALUE, crc=True)
    assert link.store.writes == [(BLOB, 0, BLOB_VALUE)]
    assert frame(0xA2, 4, 127) in link.pump.responses


def test_canopen_block_upload_repeats_a_lost_segment(make_link: Callable[..., Link]) -> None:
    # response 1 answers the initiate, so response 6 is segment 5 of the first sub-block
    link = make_link(drop_response=lambda n: n == 6)
    assert block_read(link.node, BLOB, crc=True) == BLOB_VALUE
    assert frame(0xA2, 4, 127) in link.pump.requests

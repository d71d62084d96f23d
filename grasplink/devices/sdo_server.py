"""Sans-IO CANopen SDO server (CiA 301 7.2.4): expedited, segmented and block transfers.

The server is a plain state machine. The node feeds it every 8-byte payload received on
COB-ID 0x600+id together with its own clock (`t_us`) and sends whatever payloads come
back on 0x580+id. Nothing here sleeps, spawns threads or touches a bus, so the same
object runs in a simulator, a unit test or a real node loop.

Choices where CiA 301 leaves room (all interoperate with python-canopen and CANopenNode):

* Uploads of 1..4 bytes are always answered expedited, everything else segmented with
  the size indicated (a server may choose; clients must accept either).
* Block upload never switches to segmented upload (the protocol switch threshold is
  ignored) and CRC is used exactly when the client asks for it.
* A new initiate request while a transfer is in progress silently drops the old one
  and starts the new one, as CANopenNode does. While receiving a block-download
  sub-block every frame but a client abort is a segment, so no initiate can be
  recognised there.
* Payloads whose length is not 8 are ignored, as CiA 301 SDOs always have DLC 8.
* Downloads are assembled and handed to the store in one `sdo_write`, so the store
  checks the whole value; a transfer whose length disagrees with the size the client
  indicated is aborted here (0x06070012 / 0x06070013), never written.
"""

from __future__ import annotations

import binascii
import logging
import struct
from collections.abc import Callable
from dataclasses import dataclass, field
from enum import Enum, IntEnum, auto

from grasplink.devices.access import ObjectAccess
from grasplink.devices.sdo_abort import AbortCode, SdoAbort

log = logging.getLogger(__name__)

SDO_PAYLOAD_SIZE = 8
EXPEDITED_DATA_SIZE = 4  # data bytes in an expedited initiate frame
SEGMENT_DATA_SIZE = 7  # data bytes in a (block) segment frame
MAX_BLOCK_SIZE = 127  # CiA 301: blksize is 1..127 segments per sub-block
DEFAULT_MAX_DOWNLOAD_BYTES = 1 << 20  # RAM bound for an assembled download

# Byte 0 of every SDO frame: command specifier in bits 7..5.
CS_SHIFT = 5
ABORT_COMMAND = 0x80  # client abort byte 0 (cs=4, rest zero); also never a valid segment

# Expedited / segmented field bits (byte 0).
SIZE_INDICATED = 0x01  # s
EXPEDITED = 0x02  # e
EXPEDITED_UNUSED_SHIFT = 2  # n: bytes of d without data, when e=1 and s=1
EXPEDITED_UNUSED_MASK = 0x03
TOGGLE = 0x10  # t
SEGMENT_UNUSED_SHIFT = 1  # n: bytes of the segment without data
SEGMENT_UNUSED_MASK = 0x07
NO_MORE_SEGMENTS = 0x01  # c

# Block transfer field bits (byte 0).
BLOCK_SIZE_INDICATED = 0x02  # s
CRC_SUPPORTED = 0x04  # cc (client) / sc (server)
BLOCK_UNUSED_SHIFT = 2  # n in the end frames
BLOCK_UNUSED_MASK = 0x07
LAST_BLOCK_SEGMENT = 0x80  # c in a block segment
SEQNO_MASK = 0x7F
BLOCK_UPLOAD_CS_MASK = 0x03  # client subcommand of block upload (cs)
BLOCK_DOWNLOAD_CS_MASK = 0x01  # client subcommand of block download (cs)

_MUX = struct.Struct("<BHB")  # command byte, index, subindex
_U32 = struct.Struct("<I")
_U16 = struct.Struct("<H")


class _Ccs(IntEnum):
    """Client command specifiers (client -> server, byte 0 bits 7..5)."""

    DOWNLOAD_SEGMENT = 0
    INITIATE_DOWNLOAD = 1
    INITIATE_UPLOAD = 2
    UPLOAD_SEGMENT = 3
    ABORT = 4
    BLOCK_UPLOAD = 5
    BLOCK_DOWNLOAD = 6


_KNOWN_CCS = frozenset(_Ccs)


class _Scs(IntEnum):
    """Server command specifiers (server -> client, byte 0 bits 7..5)."""

    UPLOAD_SEGMENT = 0
    DOWNLOAD_SEGMENT = 1
    INITIATE_UPLOAD = 2
    INITIATE_DOWNLOAD = 3
    ABORT = 4
    BLOCK_DOWNLOAD = 5
    BLOCK_UPLOAD = 6


class _BlockSub(IntEnum):
    """Block sub-commands (cs / ss), shared by both directions where they coincide."""

    INITIATE = 0
    END = 1
    ACK = 2  # block download response (ss) / block upload response (cs)
    START = 3  # start upload (cs, block upload only)


class _State(Enum):
    """What the server waits for next in a transfer in progress."""

    DOWNLOAD_SEGMENT = auto()
    UPLOAD_SEGMENT = auto()
    BLOCK_DOWNLOAD_SUBBLOCK = auto()
    BLOCK_DOWNLOAD_END = auto()
    BLOCK_UPLOAD_START = auto()
    BLOCK_UPLOAD_ACK = auto()
    BLOCK_UPLOAD_END = auto()


@dataclass
class _Transfer:
    """One segmented or block transfer in progress."""

    state: _State
    index: int
    subindex: int
    last_us: int  # time of the last frame, for the SDO timeout
    data: bytearray = field(default_factory=bytearray)  # assembled (down) / to send (up)
    size: int | None = None  # download: size the client indicated
    toggle: int = 0  # segmented: expected toggle bit
    offset: int = 0  # segmented upload: bytes sent so far
    crc: bool = False  # block: both sides use the CRC
    blksize: int = MAX_BLOCK_SIZE  # block: segments per sub-block
    seqno: int = 0  # block download: last good seqno; block upload: segments sent
    acked: int = 0  # block upload: segments the client confirmed
    tail: bytes | None = None  # block download: last segment, trimmed once n is known


def sdo_crc(data: bytes) -> int:
    """CiA 301 block-transfer CRC: CRC-16-CCITT, poly 0x1021, init 0, no reflection.

    Identical to CRC-16/XMODEM, which is what `binascii.crc_hqx` with seed 0 computes
    and what python-canopen's `CrcXmodem` uses.
    """
    return binascii.crc_hqx(data, 0)


def _payload(command: int, body: bytes = b"") -> bytes:
    """An SDO payload: command byte, body, zero padding to 8 bytes."""
    return bytes((command,)) + body.ljust(SDO_PAYLOAD_SIZE - 1, b"\x00")


def _mux_payload(command: int, index: int, subindex: int, body: bytes = b"") -> bytes:
    """An SDO payload carrying the multiplexer (index, subindex) in bytes 1..3."""
    return _MUX.pack(command, index, subindex) + body.ljust(EXPEDITED_DATA_SIZE, b"\x00")


def _segment_count(length: int) -> int:
    """Block segments needed for `length` bytes; an empty value still takes one."""
    return max(1, -(-length // SEGMENT_DATA_SIZE))


class SdoServer:
    """CiA 301 SDO server for one SDO channel, driven by payloads and timestamps."""

    def __init__(
        self,
        access: ObjectAccess,
        *,
        timeout_us: int = 1_000_000,
        max_block_size: int = MAX_BLOCK_SIZE,
        max_download_bytes: int = DEFAULT_MAX_DOWNLOAD_BYTES,
    ):
        """`max_block_size` is the blksize announced for block downloads (block uploads
        use the client's); `max_download_bytes` bounds what a download may buffer."""
        if not 1 <= max_block_size <= MAX_BLOCK_SIZE:
            raise ValueError(f"max_block_size must be 1..{MAX_BLOCK_SIZE}, not {max_block_size}")
        if timeout_us <= 0:
            raise ValueError(f"timeout_us must be positive, not {timeout_us}")
        self._access = access
        self._timeout_us = timeout_us
        self._max_block_size = max_block_size
        self._max_download_bytes = max_download_bytes
        self._transfer: _Transfer | None = None
        # Multiplexer reported in abort frames: the current (or last) transfer's.
        self._mux: tuple[int, int] = (0, 0)
        self._handlers: dict[_State, Callable[[_Transfer, bytes], list[bytes]]] = {
            _State.DOWNLOAD_SEGMENT: self._on_download_segment,
            _State.UPLOAD_SEGMENT: self._on_upload_segment,
            _State.BLOCK_DOWNLOAD_SUBBLOCK: self._on_block_download_segment,
            _State.BLOCK_DOWNLOAD_END: self._on_block_download_end,
            _State.BLOCK_UPLOAD_START: self._on_block_upload_start,
            _State.BLOCK_UPLOAD_ACK: self._on_block_upload_ack,
            _State.BLOCK_UPLOAD_END: self._on_block_upload_end,
        }

    # -- public API ---------------------------------------------------------------------

    def on_request(self, data: bytes, t_us: int) -> list[bytes]:
        """One client->server frame payload in; zero or more server->client payloads out.

        A transfer that went stale before this frame is timed out first, so the result
        does not depend on how often the caller runs `advance`.
        """
        out = self.advance(t_us)
        if len(data) != SDO_PAYLOAD_SIZE:
            return out
        data = bytes(data)
        if self._transfer is not None:
            self._transfer.last_us = t_us
        try:
            out += self._dispatch(data, t_us)
        except SdoAbort as exc:
            out.append(self._abort(exc.code))
        except Exception:
            # A store bug must not take the node down; the client gets a general error.
            log.exception("SDO access to 0x%04X:%02X failed", *self._mux)
            out.append(self._abort(AbortCode.GENERAL))
        return out

    def advance(self, t_us: int) -> list[bytes]:
        """Abort (0x05040000) a transfer idle for `timeout_us` or longer."""
        deadline = self.next_deadline_us()
        if deadline is None or t_us < deadline:
            return []
        return [self._abort(AbortCode.TIMEOUT)]

    def next_deadline_us(self) -> int | None:
        """When the transfer in progress times out, or None when idle."""
        if self._transfer is None:
            return None
        return self._transfer.last_us + self._timeout_us

    def reset(self) -> None:
        """Drop any transfer in progress without a frame (NMT reset communication)."""
        self._transfer = None

    # -- dispatch -----------------------------------------------------------------------

    def _dispatch(self, data: bytes, t_us: int) -> list[bytes]:
        """Sub-block segments first (they reuse every command byte but 0x80), then the
        abort and initiate requests valid in any state, then the state's own handler."""
        transfer = self._transfer
        if (
            transfer is not None
            and transfer.state is _State.BLOCK_DOWNLOAD_SUBBLOCK
            and data[0] != ABORT_COMMAND
        ):
            return self._on_block_download_segment(transfer, data)
        ccs = data[0] >> CS_SHIFT
        if ccs == _Ccs.ABORT:
            self._transfer = None  # the client gave up; an abort is never answered
            return []
        initiate = self._initiate_handler(data[0])
        if initiate is not None:
            self._transfer = None
            _, index, subindex = _MUX.unpack_from(data)
            self._mux = (index, subindex)
            return initiate(data, t_us)
        if transfer is None:
            if ccs not in _KNOWN_CCS:  # report it against the object it names
                _, index, subindex = _MUX.unpack_from(data)
                self._mux = (index, subindex)
            raise SdoAbort(AbortCode.COMMAND_SPECIFIER, "no transfer in progress")
        return self._handlers[transfer.state](transfer, data)

    def _initiate_handler(self, command: int) -> Callable[[bytes, int], list[bytes]] | None:
        """The handler for an initiate request, or None if `command` is no initiate."""
        ccs = command >> CS_SHIFT
        if ccs == _Ccs.INITIATE_DOWNLOAD:
            return self._initiate_download
        if ccs == _Ccs.INITIATE_UPLOAD:
            return self._initiate_upload
        if ccs == _Ccs.BLOCK_DOWNLOAD and command & BLOCK_DOWNLOAD_CS_MASK == _BlockSub.INITIATE:
            return self._initiate_block_download
        if ccs == _Ccs.BLOCK_UPLOAD and command & BLOCK_UPLOAD_CS_MASK == _BlockSub.INITIATE:
            return self._initiate_block_upload
        return None

    def _abort(self, code: int) -> bytes:
        """Drop the transfer and build the abort frame for it."""
        self._transfer = None
        index, subindex = self._mux
        return _mux_payload(_Scs.ABORT << CS_SHIFT, index, subindex, _U32.pack(code))

    @staticmethod
    def _expect(data: bytes, ccs: _Ccs, sub_mask: int = 0, sub: int = 0) -> None:
        """Abort with 0x05040001 unless `data` is the command the state waits for."""
        if data[0] >> CS_SHIFT != ccs or data[0] & sub_mask != sub:
            raise SdoAbort(AbortCode.COMMAND_SPECIFIER, f"unexpected command 0x{data[0]:02X}")

    # -- expedited and segmented download ----------------------------------------------

    def _initiate_download(self, data: bytes, t_us: int) -> list[bytes]:
        command, index, subindex = _MUX.unpack_from(data)
        response = _mux_payload(_Scs.INITIATE_DOWNLOAD << CS_SHIFT, index, subindex)
        if command & EXPEDITED:
            unused = 0
            if command & SIZE_INDICATED:
                unused = (command >> EXPEDITED_UNUSED_SHIFT) & EXPEDITED_UNUSED_MASK
            body = data[_MUX.size : SDO_PAYLOAD_SIZE - unused]
            self._access.sdo_write(index, subindex, body)
            return [response]
        size = _U32.unpack_from(data, _MUX.size)[0] if command & SIZE_INDICATED else None
        self._check_download_size(size)
        self._transfer = _Transfer(_State.DOWNLOAD_SEGMENT, index, subindex, t_us, size=size)
        return [response]

    def _on_download_segment(self, transfer: _Transfer, data: bytes) -> list[bytes]:
        self._expect(data, _Ccs.DOWNLOAD_SEGMENT)
        command = data[0]
        if command & TOGGLE != transfer.toggle:
            raise SdoAbort(AbortCode.TOGGLE_BIT)
        unused = (command >> SEGMENT_UNUSED_SHIFT) & SEGMENT_UNUSED_MASK
        self._append(transfer, data[1 : 1 + SEGMENT_DATA_SIZE - unused])
        response = _payload(_Scs.DOWNLOAD_SEGMENT << CS_SHIFT | transfer.toggle)
        if command & NO_MORE_SEGMENTS:
            self._finish_download(transfer)
        else:
            transfer.toggle ^= TOGGLE
        return [response]

    def _check_download_size(self, size: int | None) -> None:
        if size is not None and size > self._max_download_bytes:
            raise SdoAbort(AbortCode.OUT_OF_MEMORY, f"{size} bytes announced")

    def _append(self, transfer: _Transfer, chunk: bytes) -> None:
        """Add received data, refusing more than announced or than RAM allows."""
        length = len(transfer.data) + len(chunk)
        if transfer.size is not None and length > transfer.size:
            raise SdoAbort(AbortCode.LENGTH_TOO_HIGH, f"more than the {transfer.size} announced")
        if length > self._max_download_bytes:
            raise SdoAbort(AbortCode.OUT_OF_MEMORY, f"more than {self._max_download_bytes} bytes")
        transfer.data += chunk

    def _finish_download(self, transfer: _Transfer) -> None:
        """Hand the assembled value to the store in one write, so it checks the whole."""
        if transfer.size is not None and len(transfer.data) < transfer.size:
            raise SdoAbort(AbortCode.LENGTH_TOO_LOW, f"less than the {transfer.size} announced")
        self._transfer = None
        self._access.sdo_write(transfer.index, transfer.subindex, bytes(transfer.data))

    # -- expedited and segmented upload ------------------------------------------------

    def _initiate_upload(self, data: bytes, t_us: int) -> list[bytes]:
        _, index, subindex = _MUX.unpack_from(data)
        value = bytes(self._access.sdo_read(index, subindex))
        command = _Scs.INITIATE_UPLOAD << CS_SHIFT | SIZE_INDICATED
        if 0 < len(value) <= EXPEDITED_DATA_SIZE:
            unused = EXPEDITED_DATA_SIZE - len(value)
            command |= EXPEDITED | unused << EXPEDITED_UNUSED_SHIFT
            return [_mux_payload(command, index, subindex, value)]
        self._transfer = _Transfer(
            _State.UPLOAD_SEGMENT, index, subindex, t_us, data=bytearray(value)
        )
        return [_mux_payload(command, index, subindex, _U32.pack(len(value)))]

    def _on_upload_segment(self, transfer: _Transfer, data: bytes) -> list[bytes]:
        self._expect(data, _Ccs.UPLOAD_SEGMENT)
        if data[0] & TOGGLE != transfer.toggle:
            raise SdoAbort(AbortCode.TOGGLE_BIT)
        chunk = bytes(transfer.data[transfer.offset : transfer.offset + SEGMENT_DATA_SIZE])
        transfer.offset += len(chunk)
        command = _Scs.UPLOAD_SEGMENT << CS_SHIFT | transfer.toggle
        command |= (SEGMENT_DATA_SIZE - len(chunk)) << SEGMENT_UNUSED_SHIFT
        if transfer.offset >= len(transfer.data):
            command |= NO_MORE_SEGMENTS
            self._transfer = None
        else:
            transfer.toggle ^= TOGGLE
        return [_payload(command, chunk)]

    # -- block download ----------------------------------------------------------------

    def _initiate_block_download(self, data: bytes, t_us: int) -> list[bytes]:
        command, index, subindex = _MUX.unpack_from(data)
        size = _U32.unpack_from(data, _MUX.size)[0] if command & BLOCK_SIZE_INDICATED else None
        self._check_download_size(size)
        crc = bool(command & CRC_SUPPORTED)
        self._transfer = _Transfer(
            _State.BLOCK_DOWNLOAD_SUBBLOCK,
            index,
            subindex,
            t_us,
            size=size,
            crc=crc,
            blksize=self._max_block_size,
        )
        response = _Scs.BLOCK_DOWNLOAD << CS_SHIFT | (CRC_SUPPORTED if crc else 0)
        return [_mux_payload(response, index, subindex, bytes((self._max_block_size,)))]

    def _on_block_download_segment(self, transfer: _Transfer, data: bytes) -> list[bytes]:
        """Keep in-order segments; at the sub-block's end confirm the last good one.

        Out-of-order or repeated segments are dropped. The sub-block ends with segment
        number blksize or with the 'c' bit; the confirmation then carries ackseq = last
        segment received in sequence, and the client repeats everything after it.
        """
        seqno = data[0] & SEQNO_MASK
        last = bool(data[0] & LAST_BLOCK_SEGMENT)
        if not 1 <= seqno <= transfer.blksize:
            raise SdoAbort(AbortCode.SEQUENCE_NUMBER, f"segment {seqno} of {transfer.blksize}")
        if seqno == transfer.seqno + 1:
            transfer.seqno = seqno
            if last:
                transfer.tail = data[1:]
            else:
                self._append(transfer, data[1:])
        if not last and seqno != transfer.blksize:
            return []
        ack = _payload(
            _Scs.BLOCK_DOWNLOAD << CS_SHIFT | _BlockSub.ACK,
            bytes((transfer.seqno, self._max_block_size)),
        )
        transfer.seqno = 0
        if transfer.tail is not None:
            transfer.state = _State.BLOCK_DOWNLOAD_END
        return [ack]

    def _on_block_download_end(self, transfer: _Transfer, data: bytes) -> list[bytes]:
        self._expect(data, _Ccs.BLOCK_DOWNLOAD, BLOCK_DOWNLOAD_CS_MASK, _BlockSub.END)
        unused = (data[0] >> BLOCK_UNUSED_SHIFT) & BLOCK_UNUSED_MASK
        tail = transfer.tail or b""
        self._append(transfer, tail[: SEGMENT_DATA_SIZE - unused])
        if transfer.crc:
            (client_crc,) = _U16.unpack_from(data, 1)
            if client_crc != sdo_crc(bytes(transfer.data)):
                raise SdoAbort(AbortCode.CRC)
        self._finish_download(transfer)
        return [_payload(_Scs.BLOCK_DOWNLOAD << CS_SHIFT | _BlockSub.END)]

    # -- block upload ------------------------------------------------------------------

    def _initiate_block_upload(self, data: bytes, t_us: int) -> list[bytes]:
        command, index, subindex = _MUX.unpack_from(data)
        blksize = data[_MUX.size]
        self._check_client_blksize(blksize)
        value = bytes(self._access.sdo_read(index, subindex))
        crc = bool(command & CRC_SUPPORTED)
        self._transfer = _Transfer(
            _State.BLOCK_UPLOAD_START,
            index,
            subindex,
            t_us,
            data=bytearray(value),
            crc=crc,
            blksize=blksize,
        )
        response = _Scs.BLOCK_UPLOAD << CS_SHIFT | BLOCK_SIZE_INDICATED
        response |= CRC_SUPPORTED if crc else 0
        return [_mux_payload(response, index, subindex, _U32.pack(len(value)))]

    @staticmethod
    def _check_client_blksize(blksize: int) -> None:
        if not 1 <= blksize <= MAX_BLOCK_SIZE:
            raise SdoAbort(AbortCode.BLOCK_SIZE, f"blksize {blksize}")

    def _on_block_upload_start(self, transfer: _Transfer, data: bytes) -> list[bytes]:
        self._expect(data, _Ccs.BLOCK_UPLOAD, BLOCK_UPLOAD_CS_MASK, _BlockSub.START)
        return self._send_subblock(transfer)

    def _send_subblock(self, transfer: _Transfer) -> list[bytes]:
        """All segments of the next sub-block, starting at the first unconfirmed one."""
        total = _segment_count(len(transfer.data))
        count = min(transfer.blksize, total - transfer.acked)
        frames = []
        for seqno in range(1, count + 1):
            segment = transfer.acked + seqno - 1
            start = segment * SEGMENT_DATA_SIZE
            chunk = bytes(transfer.data[start : start + SEGMENT_DATA_SIZE])
            command = seqno | (LAST_BLOCK_SEGMENT if segment == total - 1 else 0)
            frames.append(_payload(command, chunk))
        transfer.seqno = count
        transfer.state = _State.BLOCK_UPLOAD_ACK
        return frames

    def _on_block_upload_ack(self, transfer: _Transfer, data: bytes) -> list[bytes]:
        """Advance past the confirmed segments, then resend/continue or end."""
        self._expect(data, _Ccs.BLOCK_UPLOAD, BLOCK_UPLOAD_CS_MASK, _BlockSub.ACK)
        ackseq, blksize = data[1], data[2]
        if ackseq > transfer.seqno:
            raise SdoAbort(AbortCode.SEQUENCE_NUMBER, f"ackseq {ackseq} > {transfer.seqno} sent")
        transfer.acked += ackseq
        total = _segment_count(len(transfer.data))
        if transfer.acked < total:
            self._check_client_blksize(blksize)
            transfer.blksize = blksize
            return self._send_subblock(transfer)
        transfer.state = _State.BLOCK_UPLOAD_END
        unused = total * SEGMENT_DATA_SIZE - len(transfer.data)
        command = _Scs.BLOCK_UPLOAD << CS_SHIFT | unused << BLOCK_UNUSED_SHIFT | _BlockSub.END
        crc = sdo_crc(bytes(transfer.data)) if transfer.crc else 0
        return [_payload(command, _U16.pack(crc))]

    def _on_block_upload_end(self, transfer: _Transfer, data: bytes) -> list[bytes]:
        self._expect(data, _Ccs.BLOCK_UPLOAD, BLOCK_UPLOAD_CS_MASK, _BlockSub.END)
        self._transfer = None
        return []

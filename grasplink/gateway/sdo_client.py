"""Sans-IO CANopen SDO client (CiA 301 7.2.4): expedited and segmented transfers.

The gateway configures nodes over SDO while the bus keeps running, so SDO
must never block a bus callback: a transfer is a small state machine fed
the server's responses and the caller's clock, returning request payloads
to send. One client talks to one server (0x600+id / 0x580+id) and runs its
queued transfers one after another, as CiA 301 allows one transfer per SDO
channel at a time. A response that is late by `timeout_us` aborts the
transfer with 0x05040000 (and tells the server so).
"""

from __future__ import annotations

import struct
from collections import deque
from dataclasses import dataclass, field
from enum import Enum, auto

from grasplink.core.frames import SDO_RX_BASE, SDO_TX_BASE, Frame
from grasplink.devices.sdo_abort import AbortCode

DEFAULT_TIMEOUT_US = 500_000
MAX_QUEUED = 256  # transfers waiting per server: a configuration is a few dozen writes
MAX_UPLOAD_BYTES = 1 << 16

_MUX = struct.Struct("<BHB")
_U32 = struct.Struct("<I")

# Command specifiers, byte 0 bits 7..5.
CCS_DOWNLOAD_SEGMENT, CCS_INITIATE_DOWNLOAD, CCS_INITIATE_UPLOAD, CCS_UPLOAD_SEGMENT = 0, 1, 2, 3
SCS_UPLOAD_SEGMENT, SCS_DOWNLOAD_SEGMENT, SCS_INITIATE_UPLOAD, SCS_INITIATE_DOWNLOAD = 0, 1, 2, 3
CS_ABORT = 4
EXPEDITED, SIZE_INDICATED, TOGGLE, NO_MORE_SEGMENTS = 0x02, 0x01, 0x10, 0x01


class Phase(Enum):
    QUEUED = auto()
    RUNNING = auto()
    DONE = auto()
    FAILED = auto()


@dataclass
class Transfer:
    """One SDO read or write; `done`/`ok` tell how it ended, `abort_code` why not."""

    index: int
    subindex: int
    upload: bool
    data: bytes = b""  # to write, or what was read
    phase: Phase = Phase.QUEUED
    abort_code: int | None = None
    detail: str = ""
    _initiated: bool = False
    _toggle: int = 0
    _offset: int = 0
    _buffer: bytearray = field(default_factory=bytearray)

    @property
    def done(self) -> bool:
        return self.phase in (Phase.DONE, Phase.FAILED)

    @property
    def ok(self) -> bool:
        return self.phase is Phase.DONE

    def describe(self) -> str:
        what = "read" if self.upload else "write"
        where = f"0x{self.index:04X}:{self.subindex:02X}"
        if self.ok or self.abort_code is None:
            return f"{what} {where}"
        try:
            name = AbortCode(self.abort_code).name
        except ValueError:
            name = "UNKNOWN"
        return f"{what} {where} aborted 0x{self.abort_code:08X} ({name}){self.detail}"


class SdoClient:
    """Queued SDO transfers to one server node; see module docstring."""

    def __init__(self, server_id: int, *, timeout_us: int = DEFAULT_TIMEOUT_US):
        if not 1 <= server_id <= 127:
            raise ValueError(f"SDO server node-ID {server_id} is outside 1..127")
        self.server_id = server_id
        self.timeout_us = timeout_us
        self.rx_can_id = SDO_TX_BASE + server_id  # what the server sends
        self._tx_can_id = SDO_RX_BASE + server_id
        self._queue: deque[Transfer] = deque()
        self._current: Transfer | None = None
        self._deadline_us: int | None = None
        self.stale_responses = 0

    # -- queueing ---------------------------------------------------------------------
    def download(self, index: int, subindex: int, data: bytes) -> Transfer:
        """Queue a write of `data` (already encoded in the object's type)."""
        if not data:
            raise ValueError("an SDO download needs at least one byte")
        return self._enqueue(Transfer(index, subindex, upload=False, data=bytes(data)))

    def upload(self, index: int, subindex: int) -> Transfer:
        return self._enqueue(Transfer(index, subindex, upload=True))

    def _enqueue(self, transfer: Transfer) -> Transfer:
        if len(self._queue) >= MAX_QUEUED:
            raise OverflowError(
                f"more than {MAX_QUEUED} SDO transfers queued for 0x{self.server_id:02X}"
            )
        self._queue.append(transfer)
        return transfer

    @property
    def idle(self) -> bool:
        return self._current is None and not self._queue

    def cancel(self) -> None:
        """Drop every queued and running transfer (the server rebooted or was lost)."""
        for transfer in [*([self._current] if self._current else []), *self._queue]:
            transfer.phase, transfer.detail = Phase.FAILED, ": cancelled"
        self._queue.clear()
        self._current = None
        self._deadline_us = None

    # -- sans-IO -------------------------------------------------------------------------
    def advance(self, t_us: int) -> list[Frame]:
        """Start the next transfer when idle; abort one whose response is overdue."""
        if (
            self._current is not None
            and self._deadline_us is not None
            and t_us >= self._deadline_us
        ):
            return self._abort(
                AbortCode.TIMEOUT, f": no answer after {self.timeout_us / 1000:g} ms"
            )
        if self._current is None and self._queue:
            self._current = self._queue.popleft()
            self._current.phase = Phase.RUNNING
            return self._send(self._initiate(self._current), t_us)
        return []

    def next_deadline_us(self) -> int | None:
        if self._current is None and self._queue:
            return 0  # start at once
        return self._deadline_us

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        """A frame from the server (others are ignored)."""
        transfer = self._current
        if frame.can_id != self.rx_can_id or frame.rtr or transfer is None:
            return []
        data = bytes(frame.data)
        if len(data) != 8:
            return self._abort(AbortCode.COMMAND_SPECIFIER, ": response not 8 bytes")
        scs = data[0] >> 5
        if scs == CS_ABORT:
            transfer.abort_code = _U32.unpack_from(data, 4)[0]
            return self._finish(Phase.FAILED)
        try:
            reply = (self._on_upload if transfer.upload else self._on_download)(transfer, data)
        except _StaleResponse:
            self.stale_responses += 1  # answers a transfer cancelled before: not ours
            return []
        except _ProtocolError as exc:
            return self._abort(exc.code, f": {exc}")
        if reply is None:
            return self._finish(Phase.DONE) + self.advance(t_us)
        return self._send(reply, t_us)

    # -- protocol ----------------------------------------------------------------------------
    @staticmethod
    def _initiate(t: Transfer) -> bytes:
        if t.upload:
            return _MUX.pack(CCS_INITIATE_UPLOAD << 5, t.index, t.subindex) + bytes(4)
        if len(t.data) <= 4:
            unused = 4 - len(t.data)
            command = (CCS_INITIATE_DOWNLOAD << 5) | (unused << 2) | EXPEDITED | SIZE_INDICATED
            return _MUX.pack(command, t.index, t.subindex) + t.data.ljust(4, b"\0")
        command = (CCS_INITIATE_DOWNLOAD << 5) | SIZE_INDICATED
        return _MUX.pack(command, t.index, t.subindex) + _U32.pack(len(t.data))

    def _on_download(self, t: Transfer, data: bytes) -> bytes | None:
        scs = data[0] >> 5
        if not t._initiated:
            if scs != SCS_INITIATE_DOWNLOAD:
                raise _ProtocolError(AbortCode.COMMAND_SPECIFIER, f"unexpected 0x{data[0]:02X}")
            self._check_mux(t, data)
            t._initiated = True
            if len(t.data) <= 4:
                return None
            return self._next_segment(t)
        if scs != SCS_DOWNLOAD_SEGMENT:
            raise _ProtocolError(AbortCode.COMMAND_SPECIFIER, f"unexpected 0x{data[0]:02X}")
        if (data[0] & TOGGLE) >> 4 != t._toggle:
            raise _ProtocolError(AbortCode.TOGGLE_BIT, "toggle bit")
        t._toggle ^= 1
        return None if t._offset >= len(t.data) else self._next_segment(t)

    @staticmethod
    def _next_segment(t: Transfer) -> bytes:
        chunk = t.data[t._offset : t._offset + 7]
        t._offset += len(chunk)
        last = NO_MORE_SEGMENTS if t._offset >= len(t.data) else 0
        command = (CCS_DOWNLOAD_SEGMENT << 5) | (t._toggle << 4) | ((7 - len(chunk)) << 1) | last
        return bytes([command]) + chunk.ljust(7, b"\0")

    def _on_upload(self, t: Transfer, data: bytes) -> bytes | None:
        scs = data[0] >> 5
        if not t._initiated:
            if scs != SCS_INITIATE_UPLOAD:
                raise _ProtocolError(AbortCode.COMMAND_SPECIFIER, f"unexpected 0x{data[0]:02X}")
            self._check_mux(t, data)
            t._initiated = True
            if data[0] & EXPEDITED:
                size = 4 - ((data[0] >> 2) & 0x03) if data[0] & SIZE_INDICATED else 4
                t.data = data[4 : 4 + size]
                return None
            return bytes([(CCS_UPLOAD_SEGMENT << 5) | (t._toggle << 4)]) + bytes(7)
        if scs != SCS_UPLOAD_SEGMENT:
            raise _ProtocolError(AbortCode.COMMAND_SPECIFIER, f"unexpected 0x{data[0]:02X}")
        if (data[0] & TOGGLE) >> 4 != t._toggle:
            raise _ProtocolError(AbortCode.TOGGLE_BIT, "toggle bit")
        unused = (data[0] >> 1) & 0x07
        t._buffer += data[1 : 8 - unused]
        if len(t._buffer) > MAX_UPLOAD_BYTES:
            raise _ProtocolError(AbortCode.OUT_OF_MEMORY, "upload too long")
        if data[0] & NO_MORE_SEGMENTS:
            t.data = bytes(t._buffer)
            return None
        t._toggle ^= 1
        return bytes([(CCS_UPLOAD_SEGMENT << 5) | (t._toggle << 4)]) + bytes(7)

    @staticmethod
    def _check_mux(t: Transfer, data: bytes) -> None:
        """An initiate response for another object answers an earlier, cancelled request."""
        _, index, subindex = _MUX.unpack_from(data)
        if (index, subindex) != (t.index, t.subindex):
            raise _StaleResponse

    def _send(self, payload: bytes, t_us: int) -> list[Frame]:
        self._deadline_us = t_us + self.timeout_us
        return [Frame(self._tx_can_id, payload)]

    def _abort(self, code: int, detail: str) -> list[Frame]:
        t = self._current
        assert t is not None
        t.abort_code, t.detail = int(code), detail
        payload = _MUX.pack(CS_ABORT << 5, t.index, t.subindex) + _U32.pack(int(code))
        self._finish(Phase.FAILED)
        return [Frame(self._tx_can_id, payload)]

    def _finish(self, phase: Phase) -> list[Frame]:
        assert self._current is not None
        self._current.phase = phase
        self._current = None
        self._deadline_us = None
        return []


class _StaleResponse(Exception):
    pass


class _ProtocolError(Exception):
    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.code = code

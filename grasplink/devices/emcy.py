"""EMCY producer: error register (1001h), error history (1003h), inhibit (1015h).

An error is *raised* with its CiA 301 error code and the error-register bit
it belongs to, and *cleared* when the condition goes away; when the last
active error clears the device sends the "error reset" EMCY (code 0000h).
Messages that fall inside the inhibit time wait in a small bounded queue.
"""

from __future__ import annotations

import struct
from collections import deque

from grasplink.core.frames import Frame
from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.devices.store import ObjectStore, Value
from grasplink.profiles import objects as obj

# Error codes the grasplink devices use (CiA 301 table 21, CiA 402).
ERROR_RESET = 0x0000
HEARTBEAT_TIMEOUT = 0x8130
CAN_ID_COLLISION = 0x8150  # another node transmits on this node's heartbeat COB-ID
PDO_LENGTH_ERROR = 0x8210
PDO_LENGTH_EXCEEDED = 0x8220
RPDO_TIMEOUT = 0x8250
SENSOR_SATURATED = 0xFF01  # manufacturer-specific: FSR at full scale

# Error register bits (1001h).
REG_GENERIC = 0x01
REG_CURRENT = 0x02
REG_VOLTAGE = 0x04
REG_TEMPERATURE = 0x08
REG_COMMUNICATION = 0x10
REG_PROFILE = 0x20
REG_MANUFACTURER = 0x80

COB_ID_INVALID = 0x80000000
QUEUE_LIMIT = 8

# What each code means, as docs/devices.md declares it: a receiver trusts these names only.
DESCRIPTIONS = {
    ERROR_RESET: "error reset",
    HEARTBEAT_TIMEOUT: "heartbeat of a monitored node lost",
    CAN_ID_COLLISION: "CAN-ID collision: another node uses this node-ID",
    PDO_LENGTH_ERROR: "RPDO shorter than mapped",
    PDO_LENGTH_EXCEEDED: "RPDO longer than mapped",
    RPDO_TIMEOUT: "RPDO deadline expired",
    SENSOR_SATURATED: "FSR at full scale",
}
# Codes every node can send, and those of a node with RPDOs (the kind's set: factory.DEVICES).
EVERY_NODE_CODES = frozenset({ERROR_RESET, HEARTBEAT_TIMEOUT, CAN_ID_COLLISION})
RPDO_CODES = frozenset({PDO_LENGTH_ERROR, PDO_LENGTH_EXCEEDED, RPDO_TIMEOUT})


class EmcyProducer:
    def __init__(self, store: ObjectStore):
        self.store = store
        self._active: dict[int, int] = {}  # code -> register bit
        self._queue: deque[bytes] = deque(maxlen=QUEUE_LIMIT)
        self._last_sent_us: int | None = None
        self.dropped = 0
        # 1003h is optional (CiA 301): a device without it keeps no history
        history = (
            store.entry(obj.ERROR_HISTORY, 0).var.parent
            if store.has(obj.ERROR_HISTORY, 0)
            else None
        )
        self._history_len = max(history.subindices) if history is not None else 0
        store.add_command(obj.ERROR_HISTORY, self._on_history_write)

    # -- error state -------------------------------------------------------
    def raise_error(self, code: int, register_bit: int, t_us: int, info: bytes = b"") -> None:
        """Record an error and queue its EMCY (once per occurrence)."""
        self._active[code] = register_bit
        self._push_history(code, info)
        self._enqueue(code, info)

    def clear_error(self, code: int, t_us: int) -> None:
        if self._active.pop(code, None) is None:
            return
        self._update_register()
        if not self._active:
            self._enqueue(ERROR_RESET, b"")

    def is_active(self, code: int) -> bool:
        return code in self._active

    def reset(self) -> None:
        """Reset communication: forget pending messages and active errors."""
        self._active.clear()
        self._queue.clear()
        self._last_sent_us = None
        self.store.set(obj.ERROR_REGISTER, 0, 0)

    # -- transmission --------------------------------------------------------
    def poll(self, t_us: int) -> list[Frame]:
        """Frames due now, honouring the inhibit time."""
        if not self._queue:  # the common case, asked on every tick: nothing to send
            return []
        if not self.store.has(obj.COB_ID_EMCY):  # 1014h is optional: a device without EMCY
            self._queue.clear()
            return []
        cob_id = int(self.store.get(obj.COB_ID_EMCY))
        if cob_id & COB_ID_INVALID:
            self._queue.clear()
            return []
        frames = []
        while self._queue:
            if self._last_sent_us is not None and t_us < self._last_sent_us + self.inhibit_us:
                break
            frames.append(Frame(cob_id & 0x7FF, self._queue.popleft()))
            self._last_sent_us = t_us
            if self.inhibit_us:
                break
        return frames

    def next_deadline_us(self) -> int | None:
        if not self._queue:
            return None
        if self._last_sent_us is None:
            return 0
        return self._last_sent_us + self.inhibit_us

    @property
    def inhibit_us(self) -> int:
        if not self.store.has(obj.EMCY_INHIBIT_100US):
            return 0
        return int(self.store.get(obj.EMCY_INHIBIT_100US)) * 100

    # -- internals -----------------------------------------------------------
    def _enqueue(self, code: int, info: bytes) -> None:
        self._update_register()
        if len(self._queue) == self._queue.maxlen:
            self.dropped += 1
        register = int(self.store.get(obj.ERROR_REGISTER))
        payload = struct.pack("<HB", code, register) + info[:5].ljust(5, b"\0")
        self._queue.append(payload)

    def _update_register(self) -> None:
        register = 0
        for bit in self._active.values():
            register |= bit | REG_GENERIC
        self.store.set(obj.ERROR_REGISTER, 0, register)

    def _push_history(self, code: int, info: bytes) -> None:
        """Newest error at sub-index 1 (CiA 301 1003h); older ones shift down."""
        if not self._history_len:
            return
        extra = int.from_bytes(info[:2].ljust(2, b"\0"), "little")
        for sub in range(self._history_len, 1, -1):
            self.store.set(obj.ERROR_HISTORY, sub, self.store.get(obj.ERROR_HISTORY, sub - 1))
        self.store.set(obj.ERROR_HISTORY, 1, (extra << 16) | code)
        count = min(int(self.store.get(obj.ERROR_HISTORY, 0)) + 1, self._history_len)
        self.store.set(obj.ERROR_HISTORY, 0, count)

    def _on_history_write(self, subindex: int, value: Value) -> None:
        """Only 1003h:00 = 0 is writable: it clears the history."""
        if subindex != 0:
            raise SdoAbort(AbortCode.READ_ONLY)
        if value != 0:
            raise SdoAbort(AbortCode.INVALID_VALUE, "1003h:00 accepts only 0 (clear history)")
        for sub in range(self._history_len, 0, -1):
            self.store.set(obj.ERROR_HISTORY, sub, 0)
        self.store.set(obj.ERROR_HISTORY, 0, 0)

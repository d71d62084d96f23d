"""The CAN frame the sans-IO core speaks, and CANopen's predefined COB-IDs."""

from __future__ import annotations

from dataclasses import dataclass

NMT_COB_ID = 0x000
SYNC_COB_ID_DEFAULT = 0x080
EMCY_BASE = 0x080
TPDO_BASES = (0x180, 0x280, 0x380, 0x480)
RPDO_BASES = (0x200, 0x300, 0x400, 0x500)
SDO_TX_BASE = 0x580  # server -> client
SDO_RX_BASE = 0x600  # client -> server
HEARTBEAT_BASE = 0x700


@dataclass(frozen=True, slots=True)
class Frame:
    """An 11-bit CAN 2.0A data or remote frame (CANopen uses no extended IDs)."""

    can_id: int
    data: bytes = b""
    rtr: bool = False
    dlc: int | None = None  # for remote frames, the requested length

    def __post_init__(self) -> None:
        if not 0 <= self.can_id <= 0x7FF:
            raise ValueError(f"CAN-ID 0x{self.can_id:X} is not an 11-bit identifier")
        if len(self.data) > 8:
            raise ValueError(f"CAN frame 0x{self.can_id:03X} carries {len(self.data)} > 8 bytes")

    @property
    def length(self) -> int:
        return self.dlc if self.rtr and self.dlc is not None else len(self.data)

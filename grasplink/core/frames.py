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
LSS_SLAVE_COB_ID = 0x7E4  # LSS slave -> master (CiA 305)
LSS_MASTER_COB_ID = 0x7E5  # LSS master -> slaves
NODE_ID_MASK = 0x7F
CAN_ID_MASK = 0x7FF  # an 11-bit CAN-ID (the COB-ID objects' low bits)
SYNC_TYPE_MAX = 240  # PDO transmission types 0..240 are SYNC-synchronous (CiA 301)
UNCONFIGURED_NODE_ID = 0xFF  # no node-ID yet: the node answers only LSS (CiA 305)

# CAN-IDs no PDO, SYNC or EMCY may use (CiA 301 7.3.5, "restricted CAN-IDs").
RESTRICTED_CAN_IDS = (
    (0x000, 0x000),
    (0x001, 0x07F),
    (0x101, 0x180),
    (0x581, 0x5FF),
    (0x601, 0x67F),
    (0x6E0, 0x6FF),
    (0x701, 0x77F),
    (0x780, 0x7FF),
)

# Function code (CAN-ID without the node-ID) -> the service it carries, as an analyser names it.
FUNCTION_NAMES = {
    NMT_COB_ID: "NMT",
    EMCY_BASE: "EMCY",  # SYNC shares 080h with node-ID 0
    **{base: f"TPDO{n}" for n, base in enumerate(TPDO_BASES, start=1)},
    **{base: f"RPDO{n}" for n, base in enumerate(RPDO_BASES, start=1)},
    SDO_TX_BASE: "SDO tx",
    SDO_RX_BASE: "SDO rx",
    HEARTBEAT_BASE: "heartbeat",
}


def function_of(can_id: int) -> tuple[str, int]:
    """(service name, node-ID) of a predefined-connection-set CAN-ID; ("SYNC", 0) for 080h,
    ("LSS master", 0) and ("LSS slave", 0) for 7E5h and 7E4h."""
    base, node_id = can_id & ~NODE_ID_MASK, can_id & NODE_ID_MASK
    if can_id == SYNC_COB_ID_DEFAULT:
        return "SYNC", 0
    if can_id in (LSS_MASTER_COB_ID, LSS_SLAVE_COB_ID):
        return ("LSS master" if can_id == LSS_MASTER_COB_ID else "LSS slave"), 0
    return FUNCTION_NAMES.get(base, f"0x{base:03X}"), node_id


def is_restricted_can_id(can_id: int) -> bool:
    """Whether CiA 301 reserves `can_id` for NMT, SDO, heartbeat or future use."""
    return any(lo <= can_id <= hi for lo, hi in RESTRICTED_CAN_IDS)


def node_cob_ids(node_id: int) -> tuple[int, ...]:
    """Every CAN-ID a node with `node_id` transmits on in the predefined connection set."""
    return (
        EMCY_BASE + node_id,
        HEARTBEAT_BASE + node_id,
        SDO_TX_BASE + node_id,
        *(base + node_id for base in TPDO_BASES),
    )


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

"""NMT states and commands (CiA 301, 7.3.2)."""

from __future__ import annotations

from enum import IntEnum


class NmtState(IntEnum):
    """The value a heartbeat carries for each state."""

    INITIALISING = 0x00  # only ever seen as the boot-up frame
    STOPPED = 0x04
    OPERATIONAL = 0x05
    PRE_OPERATIONAL = 0x7F


class NmtCommand(IntEnum):
    START = 0x01
    STOP = 0x02
    ENTER_PRE_OPERATIONAL = 0x80
    RESET_NODE = 0x81
    RESET_COMMUNICATION = 0x82


# What each state lets through (CiA 301, table 79).
SDO_ALLOWED = frozenset({NmtState.PRE_OPERATIONAL, NmtState.OPERATIONAL})
EMCY_ALLOWED = SDO_ALLOWED
SYNC_ALLOWED = SDO_ALLOWED
PDO_ALLOWED = frozenset({NmtState.OPERATIONAL})

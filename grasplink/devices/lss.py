"""LSS slave (CiA 305): a master finds a node by its identity and gives it a node-ID.

A node's LSS address is its identity object 1018h (vendor-ID, product code,
revision, serial number). The master addresses one node (switch state
selective, or fastscan for nodes without a node-ID), puts it in the LSS
*configuration* state and configures it there. The node-ID it sets is only
*pending*: the node takes it at its next NMT reset (reset communication or
reset node), and "store configuration" keeps it over a power cycle. A node
whose active node-ID is FFh takes part in no NMT, SDO or heartbeat: it waits
for LSS, and boots as soon as the master switches it back to *waiting* with a
valid pending node-ID.

Sans-IO: `LssSlave.on_request` takes the 8 bytes of one 7E5h frame and returns
the 7E4h reply, if any, and whether the node must boot now; `DeviceNode` does
the NMT part. Layouts and error codes follow CiA 305 as CANopenNode's
CO_LSSslave.c and python-canopen's LssMaster encode them (docs/devices.md, LSS).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from enum import IntEnum

from grasplink.core.frames import UNCONFIGURED_NODE_ID
from grasplink.devices.store import ObjectStore
from grasplink.profiles import objects as obj

LSS_FRAME_LENGTH = 8  # every LSS frame carries 8 bytes; shorter ones are not LSS (CiA 305)


class LssState(IntEnum):
    WAITING = 0x00
    CONFIGURATION = 0x01


class Cs(IntEnum):
    """LSS command specifiers (byte 0 of every LSS frame)."""

    SWITCH_STATE_GLOBAL = 0x04
    CONFIGURE_NODE_ID = 0x11
    CONFIGURE_BIT_TIMING = 0x13
    ACTIVATE_BIT_TIMING = 0x15
    STORE_CONFIGURATION = 0x17
    SWITCH_SELECTIVE_VENDOR = 0x40
    SWITCH_SELECTIVE_PRODUCT = 0x41
    SWITCH_SELECTIVE_REVISION = 0x42
    SWITCH_SELECTIVE_SERIAL = 0x43
    SWITCH_SELECTIVE_RESPONSE = 0x44
    IDENTIFY_VENDOR = 0x46
    IDENTIFY_PRODUCT = 0x47
    IDENTIFY_REVISION_LOW = 0x48
    IDENTIFY_REVISION_HIGH = 0x49
    IDENTIFY_SERIAL_LOW = 0x4A
    IDENTIFY_SERIAL_HIGH = 0x4B
    IDENTIFY_NON_CONFIGURED = 0x4C
    IDENTIFY_SLAVE = 0x4F  # slave -> master: identify remote slave and fastscan answer
    IDENTIFY_NON_CONFIGURED_SLAVE = 0x50  # slave -> master
    FASTSCAN = 0x51
    INQUIRE_VENDOR = 0x5A
    INQUIRE_PRODUCT = 0x5B
    INQUIRE_REVISION = 0x5C
    INQUIRE_SERIAL = 0x5D
    INQUIRE_NODE_ID = 0x5E


# Error codes of the configure and store services (byte 1 of their answer).
ERROR_NONE = 0
NODE_ID_OUT_OF_RANGE = 1
BIT_TIMING_NOT_SUPPORTED = 1
STORE_NOT_SUPPORTED = 1

# CiA 301/305 bit timing table (table selector 0): index -> kbit/s. Index 5 is reserved
# and 9 (automatic bit rate detection) is not something a simulated node can do.
BIT_TIMINGS_KBIT_S = {0: 1000, 1: 800, 2: 500, 3: 250, 4: 125, 6: 50, 7: 20, 8: 10}
STANDARD_TABLE = 0

FASTSCAN_RESET = 0x80  # BitChecked of the first fastscan frame: every candidate answers
IDENTITY_PARTS = 4  # vendor-ID, product code, revision, serial: 1018h sub 1..4

_SELECTIVE = (
    Cs.SWITCH_SELECTIVE_VENDOR,
    Cs.SWITCH_SELECTIVE_PRODUCT,
    Cs.SWITCH_SELECTIVE_REVISION,
    Cs.SWITCH_SELECTIVE_SERIAL,
)
_IDENTIFY = (
    Cs.IDENTIFY_VENDOR,
    Cs.IDENTIFY_PRODUCT,
    Cs.IDENTIFY_REVISION_LOW,
    Cs.IDENTIFY_REVISION_HIGH,
    Cs.IDENTIFY_SERIAL_LOW,
    Cs.IDENTIFY_SERIAL_HIGH,
)
_INQUIRE_PART: dict[int, int] = {
    Cs.INQUIRE_VENDOR: 0,
    Cs.INQUIRE_PRODUCT: 1,
    Cs.INQUIRE_REVISION: 2,
    Cs.INQUIRE_SERIAL: 3,
}


def valid_node_id(node_id: int) -> bool:
    """A node-ID LSS may configure: 1..127, or FFh to make the node unconfigured."""
    return 1 <= node_id <= 127 or node_id == UNCONFIGURED_NODE_ID


def answer(cs: int, *payload: int) -> bytes:
    """An 8-byte LSS frame: the command specifier, `payload` bytes, zeros."""
    return bytes([cs, *payload]).ljust(LSS_FRAME_LENGTH, b"\0")


def _with_u32(cs: int, value: int) -> bytes:
    return struct.pack("<BI3x", cs, value)


@dataclass(frozen=True, slots=True)
class LssOutcome:
    """What one LSS request asks of the node: a reply to send, and whether to boot now."""

    reply: bytes | None = None
    boot: bool = False


NOTHING = LssOutcome()


class LssSlave:
    """The LSS state machine of one node; see the module docstring.

    `stored_node_id` and `stored_bit_timing` are the node's non-volatile LSS
    configuration: they survive a power cycle, like the 1010h values in
    `ObjectStore.nvm` (CiA 305 keeps them apart from 1010h, so 1011h does not
    forget them). `can_store` False makes "store configuration" answer error 1
    (not supported), as a device without non-volatile memory does.
    """

    def __init__(self, store: ObjectStore, node_id: int, *, can_store: bool = True):
        self.store = store
        self.builtin_node_id = node_id  # what the firmware boots with when nothing is stored
        self.can_store = can_store
        self.stored_node_id: int | None = None
        self.stored_bit_timing: int | None = None
        self.pending_node_id = node_id
        self.pending_bit_timing: int | None = None
        self.active_bit_timing: int | None = None
        self.switch_delay_ms: int | None = None  # of the last "activate bit timing"
        self.state = LssState.WAITING
        self._selected: list[int] = []  # switch state selective: the parts received so far
        self._identify: list[int] = []  # identify remote slave: the bounds received so far
        self._fastscan_part = 0  # LSSPos: the identity part fastscan is checking

    # -- life cycle ----------------------------------------------------------------
    def power_on(self) -> None:
        """Power on: the pending configuration is what was stored, else the firmware's."""
        self.pending_node_id = (
            self.builtin_node_id if self.stored_node_id is None else self.stored_node_id
        )
        self.pending_bit_timing = self.active_bit_timing = self.stored_bit_timing
        self.reset()

    def reset(self) -> None:
        """An NMT reset of the node: LSS starts over in the waiting state."""
        self.state = LssState.WAITING
        self._selected.clear()
        self._identify.clear()
        self._fastscan_part = 0

    def identity(self) -> tuple[int, int, int, int]:
        """The LSS address, from 1018h (a sub-index the EDS lacks reads 0)."""
        vendor, product, revision, serial = (
            int(self.store.get(obj.IDENTITY, sub)) if self.store.has(obj.IDENTITY, sub) else 0
            for sub in range(1, IDENTITY_PARTS + 1)
        )
        return vendor, product, revision, serial

    @staticmethod
    def unconfigured(active_node_id: int, pending_node_id: int) -> bool:
        return active_node_id == pending_node_id == UNCONFIGURED_NODE_ID

    # -- requests ------------------------------------------------------------------
    def on_request(self, data: bytes, active_node_id: int) -> LssOutcome:
        """Handle one frame the master sent on 7E5h; `active_node_id` is the node's now."""
        if len(data) != LSS_FRAME_LENGTH:
            return NOTHING
        cs = data[0]
        if cs == Cs.SWITCH_STATE_GLOBAL:
            return self._switch_global(data[1], active_node_id)
        if cs in _IDENTIFY:
            return self._identify_remote(cs, data)
        if cs == Cs.IDENTIFY_NON_CONFIGURED:
            if self.unconfigured(active_node_id, self.pending_node_id):
                return LssOutcome(answer(Cs.IDENTIFY_NON_CONFIGURED_SLAVE))
            return NOTHING
        if self.state == LssState.WAITING:
            if cs in _SELECTIVE:
                return self._switch_selective(cs, data)
            if cs == Cs.FASTSCAN:
                return self._fastscan(data, active_node_id)
            return NOTHING
        return self._configure(cs, data, active_node_id)

    def _switch_global(self, mode: int, active_node_id: int) -> LssOutcome:
        if mode == LssState.CONFIGURATION:
            self.state = LssState.CONFIGURATION
            return NOTHING
        if mode != LssState.WAITING:
            return NOTHING
        boot = (
            self.state == LssState.CONFIGURATION
            and active_node_id == UNCONFIGURED_NODE_ID
            and self.pending_node_id != UNCONFIGURED_NODE_ID
        )
        self.state = LssState.WAITING
        self._selected.clear()
        return LssOutcome(boot=boot)

    def _switch_selective(self, cs: int, data: bytes) -> LssOutcome:
        """Vendor, product, revision, serial in this order; a frame out of order starts over."""
        step = _SELECTIVE.index(cs)
        if step != len(self._selected):
            self._selected.clear()
            if step != 0:
                return NOTHING
        self._selected.append(struct.unpack_from("<I", data, 1)[0])
        if len(self._selected) < IDENTITY_PARTS:
            return NOTHING
        selected, self._selected = tuple(self._selected), []
        if selected != self.identity():
            return NOTHING
        self.state = LssState.CONFIGURATION
        return LssOutcome(answer(Cs.SWITCH_SELECTIVE_RESPONSE))

    def _identify_remote(self, cs: int, data: bytes) -> LssOutcome:
        """Vendor, product, revision low/high, serial low/high; in both LSS states."""
        step = _IDENTIFY.index(cs)
        if step != len(self._identify):
            self._identify.clear()
            if step != 0:
                return NOTHING
        self._identify.append(struct.unpack_from("<I", data, 1)[0])
        if len(self._identify) < len(_IDENTIFY):
            return NOTHING
        (vendor, product, rev_low, rev_high, serial_low, serial_high), self._identify = (
            tuple(self._identify),
            [],
        )
        my_vendor, my_product, revision, serial = self.identity()
        if (
            (vendor, product) == (my_vendor, my_product)
            and rev_low <= revision <= rev_high
            and serial_low <= serial <= serial_high
        ):
            return LssOutcome(answer(Cs.IDENTIFY_SLAVE))
        return NOTHING

    def _fastscan(self, data: bytes, active_node_id: int) -> LssOutcome:
        """Fastscan (CiA 305): only unconfigured nodes in the waiting state take part.

        Frame: IDNumber (u32), BitChecked, LSSSub, LSSNext. A node answers when the
        bits BitChecked..31 of its identity part LSSSub equal IDNumber's and LSSSub is
        the part it is at (LSSPos), then moves to LSSNext; BitChecked 0 with LSSNext
        below LSSSub is the full match that puts it in the configuration state.
        """
        if not self.unconfigured(active_node_id, self.pending_node_id):
            return NOTHING
        id_number, bit_checked, sub, following = struct.unpack_from("<IBBB", data, 1)
        if bit_checked == FASTSCAN_RESET:
            self._fastscan_part = 0
            return LssOutcome(answer(Cs.IDENTIFY_SLAVE))
        if bit_checked > 31 or sub >= IDENTITY_PARTS or following >= IDENTITY_PARTS:
            return NOTHING
        if sub != self._fastscan_part:
            return NOTHING
        mask = (0xFFFFFFFF << bit_checked) & 0xFFFFFFFF
        if (self.identity()[sub] ^ id_number) & mask:
            return NOTHING
        self._fastscan_part = following
        if bit_checked == 0 and following < sub:
            self.state = LssState.CONFIGURATION
        return LssOutcome(answer(Cs.IDENTIFY_SLAVE))

    def _configure(self, cs: int, data: bytes, active_node_id: int) -> LssOutcome:
        """The services of the configuration state."""
        if cs == Cs.CONFIGURE_NODE_ID:
            node_id = data[1]
            if not valid_node_id(node_id):
                return LssOutcome(answer(cs, NODE_ID_OUT_OF_RANGE))
            self.pending_node_id = node_id
            return LssOutcome(answer(cs, ERROR_NONE))
        if cs == Cs.CONFIGURE_BIT_TIMING:
            selector, index = data[1], data[2]
            if selector != STANDARD_TABLE or index not in BIT_TIMINGS_KBIT_S:
                return LssOutcome(answer(cs, BIT_TIMING_NOT_SUPPORTED))
            self.pending_bit_timing = index
            return LssOutcome(answer(cs, ERROR_NONE))
        if cs == Cs.ACTIVATE_BIT_TIMING:
            # A simulated bus has no bit rate to switch: the node only records it.
            if self.pending_bit_timing is not None:
                self.active_bit_timing = self.pending_bit_timing
                self.switch_delay_ms = struct.unpack_from("<H", data, 1)[0]
            return NOTHING
        if cs == Cs.STORE_CONFIGURATION:
            if not self.can_store:
                return LssOutcome(answer(cs, STORE_NOT_SUPPORTED))
            self.stored_node_id = self.pending_node_id
            self.stored_bit_timing = self.pending_bit_timing
            return LssOutcome(answer(cs, ERROR_NONE))
        if cs == Cs.INQUIRE_NODE_ID:
            return LssOutcome(answer(cs, active_node_id))
        part = _INQUIRE_PART.get(cs)
        if part is not None:
            return LssOutcome(_with_u32(cs, self.identity()[part]))
        return NOTHING

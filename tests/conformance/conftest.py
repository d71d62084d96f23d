"""Shared harness of the CiA conformance suite: a device under test on a virtual bus.

Every test gets a fresh `Dut`: one grasplink node (built by `build_node`) running
in a `NodeRunner` on its own python-can ``virtual`` bus handle, and an independent
master on a second handle of the same (unique) channel — a ``canopen.Network`` with
a ``canopen.RemoteNode`` built from the shipped EDS, the way the CiA conformance
test tool talks to a device. A `FrameLog` listener on the master's notifier sees
every frame the device sends, so tests can wait for an expected frame with a
bounded timeout instead of sleeping, and send raw frames where python-canopen
cannot produce the protocol error a case needs.
"""

from __future__ import annotations

import configparser
import functools
import struct
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import can
import canopen
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.sdo.exceptions import SdoAbortedError

from grasplink.bus.runner import NodeRunner
from grasplink.devices.factory import build_node
from grasplink.devices.node import DeviceNode
from grasplink.profiles import eds_path
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import KINDS

RPDO_KINDS = frozenset({"belt", "hand"})
NO_RPDO_REASON = "{kind} has no RPDOs (NrOfRXPDO=0, 1400h-17FFh absent in its EDS)"

# NMT (CiA 301 7.2.8.3.1)
NMT_START, NMT_STOP, NMT_PRE_OP = 0x01, 0x02, 0x80
NMT_RESET_NODE, NMT_RESET_COMM = 0x81, 0x82
STATE_BOOTUP, STATE_STOPPED, STATE_OPERATIONAL, STATE_PRE_OP = 0x00, 0x04, 0x05, 0x7F

# SDO abort codes (CiA 301 7.2.4.3.17)
ABORT_TOGGLE = 0x05030000
ABORT_COMMAND = 0x05040001
ABORT_BLOCK_SIZE = 0x05040002
ABORT_SEQUENCE = 0x05040003
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_NO_OBJECT = 0x06020000
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_TOO_LONG = 0x06040042
ABORT_PARAMETER_INCOMPATIBLE = 0x06040043
ABORT_LENGTH_MISMATCH = 0x06070010
ABORT_LENGTH_HIGH = 0x06070012
ABORT_LENGTH_LOW = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_INVALID_VALUE = 0x06090030
ABORT_VALUE_HIGH = 0x06090031
ABORT_VALUE_LOW = 0x06090032
ABORT_CANNOT_TRANSFER = 0x08000020
ABORT_NO_DATA = 0x08000024
ABORT_DEVICE_STATE = 0x08000022
# A mapping write outside the CiA 301 mapping procedure (PDO valid, or sub-index 0
# not 0) must be refused; CiA 301 names no single code for it.
MAPPING_LOCKED = frozenset(
    {ABORT_UNSUPPORTED_ACCESS, ABORT_DEVICE_STATE, ABORT_PARAMETER_INCOMPATIBLE}
)

COB_INVALID = 0x80000000
COB_NO_RTR = 0x40000000
SAVE = obj.STORE_SIGNATURE  # "save"
LOAD = obj.RESTORE_SIGNATURE  # "load"

# CiA 301 7.3.5, table 31: CAN-IDs no PDO, SYNC or EMCY may use.
RESTRICTED_CAN_IDS = (
    0x000,
    0x001,
    0x07F,
    0x101,
    0x180,
    0x581,
    0x5FF,
    0x601,
    0x67F,
    0x6E0,
    0x6FF,
    0x701,
    0x77F,
    0x780,
    0x7FF,
)

FAST_HEARTBEAT_MS = 20
FRAME_TIMEOUT_S = 1.0  # bounded wait for a frame that must come
SILENCE_S = 0.1  # how long "nothing comes" is watched (the device answers in ~1 ms)

# An application parameter per kind (rw, not mappable, 2000h-9FFFh) and a valid
# non-default value for it: for store/restore and reset tests.
APP_PARAMETER: dict[str, tuple[int, int, int]] = {
    "skin": (obj.SKIN_SAMPLE_RATE_HZ, 0, 1000),
    "emg": (obj.EMG_WINDOW_MS, 0, 250),
    "belt": (obj.BELT_NUB_COUNT, 0, 12),
    "hand": (obj.HAND_CRUSH_LIMIT_MN, 0, 30000),
}


@functools.cache
def _master_od(kind: str, node_id: int) -> canopen.ObjectDictionary:
    """The master's view of the EDS ($NODEID resolved); read-only, so shared by tests."""
    return canopen.import_od(str(eds_path(kind)), node_id)


# -- the EDS, as the conformance tool reads it ----------------------------------------
@dataclass(frozen=True)
class EdsEntry:
    """One sub-index as the EDS describes it (canopen resolves $NODEID in defaults)."""

    index: int
    subindex: int
    var: ODVariable
    section: str
    obj_flags: int
    object_type: int  # of the object (7 VAR, 8 ARRAY, 9 RECORD)

    @property
    def access(self) -> str:
        return self.var.access_type

    @property
    def readable(self) -> bool:
        return self.access in ("ro", "rw", "rwr", "rww", "const")

    @property
    def writable(self) -> bool:
        return self.access in ("wo", "rw", "rwr", "rww")

    @property
    def size(self) -> int | None:
        return len(self.var) // 8 if self.var.fixed_size else None

    @property
    def refuse_write_on_download(self) -> bool:  # CiA 306 ObjFlags bit 0
        return bool(self.obj_flags & 0x1)

    @property
    def refuse_read_on_scan(self) -> bool:  # CiA 306 ObjFlags bit 1
        return bool(self.obj_flags & 0x2)

    @property
    def has_default(self) -> bool:
        return self.var.default is not None

    @property
    def is_process_input(self) -> bool:
        """ro + PDO-mappable: live data the device updates itself (no fixed default)."""
        return self.access == "ro" and self.var.pdo_mappable

    def encode(self, value) -> bytes:
        return self.var.encode_raw(value)

    def __str__(self) -> str:
        return f"{self.index:04X}h:{self.subindex:02X}h ({self.var.name}, {self.access})"


def _parse_int(text: str) -> int:
    return int(text, 0)


def eds_entries(kind: str, od: canopen.ObjectDictionary) -> list[EdsEntry]:
    """Every sub-index the EDS file lists (only those: not canopen's synthetic dummies)."""
    parser = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    parser.optionxform = str
    parser.read(eds_path(kind))
    entries = []
    for section in parser.sections():
        head = section[:4]
        if len(head) != 4 or not all(c in "0123456789ABCDEFabcdef" for c in head):
            continue
        index = int(head, 16)
        subindex = None
        if len(section) == 4:
            item = od[index]
            if isinstance(item, ODVariable):
                subindex = 0
            else:
                continue
        elif section[4:7].lower() == "sub":
            subindex = int(section[7:], 16)
        else:
            continue
        var = od.get_variable(index, subindex)
        assert var is not None, f"canopen lost [{section}]"
        flags = parser.get(section, "ObjFlags", fallback="0") or "0"
        object_type = _parse_int(parser.get(f"{index:04X}", "ObjectType", fallback="0x7"))
        entries.append(EdsEntry(index, subindex, var, section, _parse_int(flags), object_type))
    return sorted(entries, key=lambda e: (e.index, e.subindex))


@functools.cache
def _entries(kind: str, node_id: int) -> list[EdsEntry]:
    return eds_entries(kind, _master_od(kind, node_id))


def eds_device_info(kind: str) -> configparser.SectionProxy:
    parser = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    parser.optionxform = str
    parser.read(eds_path(kind))
    return parser["DeviceInfo"]


# -- frames seen by the master -----------------------------------------------------------
class FrameLog(can.Listener):
    """Every frame the master's bus receives, with a condition to wait on."""

    def __init__(self) -> None:
        self._frames: list[can.Message] = []
        self._cond = threading.Condition()

    def on_message_received(self, msg: can.Message) -> None:
        with self._cond:
            self._frames.append(msg)
            self._cond.notify_all()

    def mark(self) -> int:
        """A position: frames after it are 'new'."""
        with self._cond:
            return len(self._frames)

    def since(
        self, mark: int = 0, predicate: Callable[[can.Message], bool] | None = None
    ) -> list[can.Message]:
        with self._cond:
            frames = self._frames[mark:]
        return [m for m in frames if predicate is None or predicate(m)]

    def wait_for(
        self,
        predicate: Callable[[can.Message], bool],
        timeout: float = FRAME_TIMEOUT_S,
        since: int | None = None,
    ) -> can.Message | None:
        """The first frame after `since` (default: now) matching, or None after `timeout`."""
        found = self.wait_count(predicate, 1, timeout, since)
        return found[0] if found else None

    def wait_count(
        self,
        predicate: Callable[[can.Message], bool],
        count: int,
        timeout: float = FRAME_TIMEOUT_S,
        since: int | None = None,
    ) -> list[can.Message]:
        """Up to `count` matching frames after `since`; fewer if the timeout expires."""
        start = self.mark() if since is None else since
        self._wait(predicate, count, timeout, start)
        return self.since(start, predicate)[:count]

    def _wait(self, predicate, count: int, timeout: float, since: int | None) -> bool:
        start = self.mark() if since is None else since
        deadline = time.monotonic() + timeout
        with self._cond:
            while True:
                if sum(1 for m in self._frames[start:] if predicate(m)) >= count:
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)

    def collect(
        self, predicate: Callable[[can.Message], bool], duration: float, since: int | None = None
    ) -> list[can.Message]:
        """Matching frames seen during the next `duration` seconds."""
        start = self.mark() if since is None else since
        time.sleep(duration)
        return self.since(start, predicate)


def cob(can_id: int) -> Callable[[can.Message], bool]:
    return lambda m: m.arbitration_id == can_id and not m.is_remote_frame


class SdoAbort(AssertionError):
    def __init__(self, code: int):
        self.code = code
        super().__init__(f"SDO abort 0x{code:08X}")


# -- the device under test ------------------------------------------------------------------
class Dut:
    """One grasplink node on the bus plus the master that tests it."""

    def __init__(self, kind: str, channel: str):
        self.kind = kind
        self.channel = channel
        self.log = FrameLog()
        self.master_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.network = canopen.Network(self.master_bus)
        self.network.NOTIFIER_CYCLE = 0.01  # quick teardown
        self.network.listeners.append(self.log)
        self.device: DeviceNode = build_node(kind)
        self.node_id = self.device.node_id
        self.node = canopen.RemoteNode(self.node_id, _master_od(kind, self.node_id))
        self.network.add_node(self.node)
        self.od = self.node.object_dictionary
        self.sdo = self.node.sdo
        # No test waits for an SDO that never comes, so a generous bound costs nothing and
        # keeps a loaded 2-core machine (CI beside other jobs) from failing a scan.
        self.sdo.RESPONSE_TIMEOUT = 3.0
        self.network.connect()
        self.device_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.runner = NodeRunner(
            self.device_bus, [self.device], max_wait_s=0.01, name=f"dut-{kind}"
        )
        self.bootup_mark = self.log.mark()
        self.runner.start()

    def close(self) -> None:
        self.runner.stop()
        self.network.disconnect()
        self.device_bus.shutdown()

    # -- ids -------------------------------------------------------------------------------
    @property
    def has_rpdos(self) -> bool:
        return self.kind in RPDO_KINDS

    def require_rpdos(self) -> None:
        if not self.has_rpdos:
            pytest.skip(NO_RPDO_REASON.format(kind=self.kind))

    @property
    def heartbeat_id(self) -> int:
        return 0x700 + self.node_id

    @property
    def emcy_id(self) -> int:
        return 0x80 + self.node_id

    @property
    def sdo_tx(self) -> int:
        return 0x580 + self.node_id

    @property
    def sdo_rx(self) -> int:
        return 0x600 + self.node_id

    @property
    def entries(self) -> list[EdsEntry]:
        return _entries(self.kind, self.node_id)

    def entry(self, index: int, subindex: int = 0) -> EdsEntry:
        return next(e for e in self.entries if (e.index, e.subindex) == (index, subindex))

    # -- SDO through python-canopen -----------------------------------------------------------
    def read(self, index: int, subindex: int = 0) -> bytes:
        """Upload the raw bytes (no truncation to the EDS size)."""
        try:
            with self.sdo.open(index, subindex, buffering=0) as fp:
                data = fp.read()
                size = fp.size
        except SdoAbortedError as exc:
            raise SdoAbort(exc.code) from None
        assert size is None or size == len(data), f"indicated {size}, got {len(data)} bytes"
        return bytes(data)

    def write(self, index: int, subindex: int, data: bytes, force_segment: bool = False) -> None:
        try:
            self.sdo.download(index, subindex, data, force_segment=force_segment)
        except SdoAbortedError as exc:
            raise SdoAbort(exc.code) from None

    def get(self, index: int, subindex: int = 0):
        var = self.od.get_variable(index, subindex)
        return var.decode_raw(self.read(index, subindex))

    def set(self, index: int, subindex: int, value) -> None:
        var = self.od.get_variable(index, subindex)
        self.write(index, subindex, var.encode_raw(value))

    def barrier(self) -> None:
        """An SDO round trip: the device handles frames in order, so once its answer is
        here every frame caused by what was sent before is in the log too."""
        self.read(obj.DEVICE_TYPE)

    def abort_of(self, fn: Callable, *args, **kwargs) -> int:
        """The abort code `fn` ends with; fails if it succeeds."""
        try:
            fn(*args, **kwargs)
        except SdoAbort as exc:
            return exc.code
        raise AssertionError(f"{fn.__name__}{args} succeeded; an SDO abort was expected")

    # -- raw frames ----------------------------------------------------------------------------
    def send(
        self, can_id: int, data: bytes = b"", *, rtr: bool = False, dlc: int | None = None
    ) -> None:
        msg = can.Message(
            arbitration_id=can_id,
            is_extended_id=False,
            is_remote_frame=rtr,
            data=None if rtr else data,
            dlc=dlc if dlc is not None else (0 if rtr else len(data)),
        )
        self.master_bus.send(msg)

    def sdo_request(self, payload: bytes, timeout: float = FRAME_TIMEOUT_S) -> bytes | None:
        """Send one raw SDO request (padded to 8 bytes); the server's reply payload or None."""
        mark = self.log.mark()
        self.send(self.sdo_rx, payload.ljust(8, b"\0"))
        reply = self.log.wait_for(cob(self.sdo_tx), timeout, since=mark)
        return None if reply is None else bytes(reply.data)

    def sdo_silence(self, payload: bytes, duration: float = SILENCE_S) -> bool:
        """True if a raw SDO request gets no answer within `duration`."""
        return self.sdo_request(payload, duration) is None

    # -- NMT, heartbeat, SYNC ------------------------------------------------------------------
    def nmt(self, command: int, node_id: int | None = None) -> None:
        """An NMT command via python-canopen: to the device, broadcast (0) or another node."""
        if node_id is None or node_id == self.node_id:
            self.node.nmt.send_command(command)
        elif node_id == 0:
            self.network.nmt.send_command(command)
        else:
            self.send(0x000, bytes([command, node_id]))

    def set_heartbeat(self, ms: int = FAST_HEARTBEAT_MS) -> None:
        self.set(obj.HEARTBEAT_PRODUCER_MS, 0, ms)

    def wait_heartbeat(
        self, state: int | None = None, timeout: float = FRAME_TIMEOUT_S, since: int | None = None
    ) -> can.Message | None:
        def match(m: can.Message) -> bool:
            return (
                m.arbitration_id == self.heartbeat_id
                and not m.is_remote_frame
                and len(m.data) == 1
                and (state is None or m.data[0] == state)
            )

        return self.log.wait_for(match, timeout, since)

    def wait_bootup(self, since: int, timeout: float = FRAME_TIMEOUT_S) -> can.Message | None:
        return self.wait_heartbeat(STATE_BOOTUP, timeout, since)

    def enter(self, command: int, state: int) -> None:
        """Send an NMT state command and wait until a heartbeat reports `state`."""
        mark = self.log.mark()
        self.nmt(command)
        assert self.wait_heartbeat(state, since=mark) is not None, (
            f"no heartbeat with state 0x{state:02X} after NMT 0x{command:02X}"
        )

    def start(self) -> None:
        """NMT start; the barrier returns once the device has handled it."""
        self.nmt(NMT_START)
        self.barrier()

    def enter_pre_operational(self) -> None:
        self.nmt(NMT_PRE_OP)
        self.barrier()

    def sync(self, counter: int | None = None) -> None:
        self.send(0x080, b"" if counter is None else bytes([counter]))

    # -- PDOs -------------------------------------------------------------------------------
    def tpdo_numbers(self) -> list[int]:
        return [n for n in range(1, 513) if 0x1800 + n - 1 in self.od]

    def rpdo_numbers(self) -> list[int]:
        return [n for n in range(1, 513) if 0x1400 + n - 1 in self.od]

    def default_cob_id(self, comm_index: int) -> int:
        return int(self.od[comm_index][1].default)

    def invalidate(self, comm_index: int) -> int:
        """Set bit 31 of a PDO's COB-ID; returns the previous COB-ID."""
        cob_id = self.get(comm_index, 1)
        if not cob_id & COB_INVALID:
            self.set(comm_index, 1, cob_id | COB_INVALID)
        return cob_id

    def remap(self, map_index: int, entries: list[int]) -> None:
        """Write a mapping with the CiA 301 procedure (the PDO must be invalid)."""
        self.set(map_index, 0, 0)
        for sub, value in enumerate(entries, start=1):
            self.set(map_index, sub, value)
        self.set(map_index, 0, len(entries))

    def configure_tpdo(
        self,
        number: int,
        *,
        transmission_type: int,
        inhibit_100us: int = 0,
        event_timer_ms: int = 0,
        sync_start: int = 0,
        rtr: bool = False,
        mapping: list[int] | None = None,
    ) -> tuple[int, int]:
        """Configure TPDO `number` with the PDO invalid, then validate it.

        Returns (CAN-ID, mapped length in bytes). A TPDO without any mapping gets
        1001h (error register, 8 bit), which every node can map.
        """
        comm, mapping_index = 0x1800 + number - 1, 0x1A00 + number - 1
        cob_id = self.invalidate(comm)
        self.set(comm, 2, transmission_type)
        self.set(comm, 3, inhibit_100us)
        self.set(comm, 5, event_timer_ms)
        self.set(comm, 6, sync_start)
        if mapping is None and self.get(mapping_index, 0) == 0:
            mapping = [0x10010008]
        if mapping is not None:
            self.remap(mapping_index, mapping)
        can_id = cob_id & 0x7FF
        new = can_id | (0 if rtr else COB_NO_RTR)
        self.set(comm, 1, new)
        count = self.get(mapping_index, 0)
        length = sum(self.get(mapping_index, s) & 0xFF for s in range(1, count + 1)) // 8
        return can_id, length

    def disable_tpdos(self, keep: tuple[int, ...] = ()) -> None:
        for number in self.tpdo_numbers():
            if number not in keep:
                self.invalidate(0x1800 + number - 1)

    # -- EMCY -----------------------------------------------------------------------------------
    def force_emcy(self) -> can.Message:
        """Make the device send an EMCY: a short RPDO (8210h) where the node has RPDOs,
        else a heartbeat-consumer timeout (8130h). Returns the EMCY frame."""
        if self.has_rpdos:
            self.start()
            mark = self.log.mark()
            self.send(0x200 + self.node_id, b"\x06")  # RPDO1 maps 6 bytes; 1 sent
        else:
            self.set(obj.HEARTBEAT_CONSUMER, 2, (0x05 << 16) | 30)  # node 5, 30 ms
            mark = self.log.mark()
            self.send(0x705, bytes([STATE_OPERATIONAL]))  # its first heartbeat arms the monitor
        emcy = self.log.wait_for(cob(self.emcy_id), since=mark)
        assert emcy is not None, "the device sent no EMCY"
        return emcy


# -- process-data events per kind ---------------------------------------------------------
# A mapping entry whose value changes on events: the skin's sample counter and the
# EMG's envelope sequence change on their own (sampling); the drives' statusword
# changes when the master writes the controlword.
EVENT_MAPPING = {"skin": 0x21020020, "emg": 0x22020008, "belt": 0x60410010, "hand": 0x60410010}
SELF_CHANGING = frozenset({"skin", "emg"})
# TPDOs the application triggers itself (transmission type 254 events).
APP_TRIGGERED = {
    "skin": frozenset({1}),
    "emg": frozenset({1, 2}),
    "belt": frozenset(),
    "hand": frozenset(),
}
# Slow the application's own TPDO triggers down (skin: 80 Hz / 3 samples = 37.5 ms,
# EMG: one envelope per second), so event timers can be seen.
SLOW_APP = {"skin": (obj.SKIN_SAMPLE_RATE_HZ, 0, 80), "emg": (obj.EMG_ENVELOPE_PERIOD_MS, 0, 1000)}


def cause_event(dut: Dut) -> int | None:
    """Change the drive's statusword by a controlword write; returns the new statusword.
    Skin and EMG data change on their own: nothing to do, None."""
    if dut.kind in SELF_CHANGING:
        return None
    before = dut.get(obj.STATUSWORD)
    for controlword in (0x06, 0x00):
        dut.set(obj.CONTROLWORD, 0, controlword)
        after = dut.get(obj.STATUSWORD)
        if after != before:
            return after
    raise AssertionError("the controlword did not change the statusword")


def slow_app(dut: Dut) -> None:
    if dut.kind in SLOW_APP:
        dut.set(*SLOW_APP[dut.kind])


@pytest.fixture(params=KINDS)
def kind(request: pytest.FixtureRequest) -> str:
    return request.param


@pytest.fixture
def dut(kind: str) -> Iterator[Dut]:
    device = Dut(kind, f"conformance-{kind}-{uuid.uuid4().hex}")
    try:
        assert device.wait_bootup(device.bootup_mark) is not None, "no boot-up message"
        yield device
    finally:
        device.close()


def emcy_code(msg: can.Message) -> int:
    return struct.unpack_from("<H", bytes(msg.data))[0]


def mappable_objects(dut: Dut, *, accesses: tuple[str, ...]) -> list[EdsEntry]:
    return [
        e for e in dut.entries if e.var.pdo_mappable and e.access in accesses and e.size is not None
    ]


def mapping_locked(dut: Dut, index: int, subindex: int) -> bool:
    """True for a PDO mapping entry that CiA 301 lets change only inside the mapping
    procedure at this moment: the PDO is valid, or sub-index 0 is not 0."""
    if not (0x1600 <= index <= 0x17FF or 0x1A00 <= index <= 0x1BFF):
        return False
    if not dut.get(index - 0x200, 1) & COB_INVALID:
        return True
    return subindex != 0 and dut.get(index, 0) != 0


def records(dut: Dut) -> list[int]:
    return sorted(
        i for i in {e.index for e in dut.entries} if isinstance(dut.od[i], ODRecord | ODArray)
    )


# -- raw SDO frames (CiA 301 7.2.4.3) ------------------------------------------------------
def upload_request(index: int, subindex: int = 0) -> bytes:
    return struct.pack("<BHB4x", 0x40, index, subindex)


def abort_code(reply: bytes | None) -> int | None:
    """The abort code of a server reply, None if it is no abort."""
    assert reply is not None, "no SDO reply"
    return struct.unpack_from("<I", reply, 4)[0] if reply[0] == 0x80 else None


@dataclass
class RawUpload:
    expedited: bool
    data: bytes
    size: int | None  # size the server indicated
    segments: list[int]  # command bytes of the upload segment responses


def raw_upload(dut: Dut, index: int, subindex: int = 0) -> RawUpload:
    """Read an object with raw initiate/segment frames, checking the protocol bits."""
    mux = struct.pack("<HB", index, subindex)
    reply = dut.sdo_request(upload_request(index, subindex))
    code = abort_code(reply)
    if code is not None:
        raise SdoAbort(code)
    assert reply[0] >> 5 == 2, f"scs {reply[0] >> 5} is no initiate upload response"
    assert reply[1:4] == mux, "multiplexer of the response differs"
    sized = bool(reply[0] & 0x01)
    if reply[0] & 0x02:  # expedited
        unused = (reply[0] >> 2) & 0x03 if sized else 0
        data = bytes(reply[4 : 8 - unused])
        return RawUpload(True, data, len(data) if sized else None, [])
    size = struct.unpack_from("<I", reply, 4)[0] if sized else None
    data, toggle, commands = b"", 0, []
    while True:
        seg = dut.sdo_request(bytes([0x60 | toggle << 4]))
        code = abort_code(seg)
        if code is not None:
            raise SdoAbort(code)
        commands.append(seg[0])
        assert seg[0] >> 5 == 0, f"segment response 0x{seg[0]:02X} has scs {seg[0] >> 5}"
        assert (seg[0] >> 4) & 1 == toggle, "toggle bit of the segment response is wrong"
        unused = (seg[0] >> 1) & 0x07
        data += bytes(seg[1 : 8 - unused])
        toggle ^= 1
        if seg[0] & 0x01:
            break
        assert len(commands) < 10_000
    if size is not None:
        assert len(data) == size, f"indicated {size} bytes, sent {len(data)}"
    return RawUpload(False, data, size, commands)

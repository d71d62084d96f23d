"""The network's PDO maps as a DBC file, for CAN analysers (CANalyzer, SavvyCAN, cantools...).

Bit positions are never written here: every PDO's layout is read from the
node's object dictionary through python-canopen's PDO maps (as `PdoCodec`
reads it), so the DBC, the devices and the gateway agree by construction.
Values stay in the object dictionary's own integer units (mN, mrad/s, µV,
ADC counts): a DBC value is then the same number SDO, docs/profiles.md and
`PdoCodec` show, exactly, with no rounding from a scale factor.

Besides the PDOs the file holds the frames every CANopen node shares: NMT,
SYNC, each node's heartbeat (state as a value table), EMCY (error code as a
value table) and expedited SDO request/response fields.
"""

from __future__ import annotations

import re
from collections import OrderedDict
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import canopen
import cantools
from canopen.objectdictionary import ODVariable
from cantools.database.can import Database, Message, Node, Signal
from cantools.database.can.formats.dbc.dbc_specifics import DbcSpecifics
from cantools.database.conversion import BaseConversion
from cantools.typechecking import Choices

from grasplink.core.frames import (
    EMCY_BASE,
    HEARTBEAT_BASE,
    NMT_COB_ID,
    SDO_RX_BASE,
    SDO_TX_BASE,
    SYNC_COB_ID_DEFAULT,
)
from grasplink.core.nmt import NmtCommand, NmtState
from grasplink.errors import ConfigError
from grasplink.profiles import load_profile, od_default
from grasplink.profiles import objects as obj
from grasplink.profiles.eds import DATA_TYPES
from grasplink.profiles.kinds import BY_NODE_ID, KINDS, node_kind, unknown_kind
from grasplink.profiles.objects import DEFAULT_NODE_IDS

MASTER = "gateway"
GATEWAY_HEARTBEAT_MS = 100  # the gateway's default heartbeat ([gateway] heartbeat_ms)
NODE_NAMES = {k: node_kind(k).title for k in KINDS} | {MASTER: "Gateway"}
DBC_NAME_MAX = 32  # longer names need a DBC long-name attribute some analysers ignore
_UNIT_RE = re.compile(r"\s*\[([^\]]+)\]\s*$")
_Value = TypeVar("_Value", bound=int)  # an int or an IntEnum (NmtState, NmtCommand)

# Enumerations the EDS cannot express (it has no value descriptions), from profiles.objects.
OBJECT_CHOICES: dict[tuple[int, int], dict[int, str]] = {
    (obj.BELT_ACTIVE, 0): {0: "none", 1: "force belt", 2: "slip belt"},
    (obj.EMG_LEVEL, 0): {level: f"e{level}" for level in range(6)},
}
# CiA 301 table 21 error codes the grasplink devices send (devices/emcy.py), and 0xFF01.
EMCY_CODES = {
    0x0000: "error reset or no error",
    0x8130: "life guard or heartbeat error",
    0x8150: "CAN-ID collision",
    0x8210: "PDO not processed: length error",
    0x8220: "PDO length exceeded",
    0x8250: "RPDO timeout",
    0xFF01: "sensor saturated (manufacturer-specific)",
}
NMT_STATE_NAMES = {
    NmtState.INITIALISING: "boot-up",
    NmtState.STOPPED: "stopped",
    NmtState.OPERATIONAL: "operational",
    NmtState.PRE_OPERATIONAL: "pre-operational",
}
NMT_COMMAND_NAMES = {
    NmtCommand.START: "start",
    NmtCommand.STOP: "stop",
    NmtCommand.ENTER_PRE_OPERATIONAL: "enter pre-operational",
    NmtCommand.RESET_NODE: "reset node",
    NmtCommand.RESET_COMMUNICATION: "reset communication",
}
TRANSMISSION_TYPES = {
    0: "synchronous, acyclic",
    252: "RTR, synchronous",
    253: "RTR, event",
    254: "event-driven, manufacturer-specific",
    255: "event-driven, device profile",
}


@dataclass(frozen=True)
class PdoSignal:
    """One mapped object of a PDO: where it sits in the frame and what it is."""

    name: str  # DBC-safe, unique in its message
    index: int
    subindex: int
    object_name: str
    start_bit: int  # from the mapping (canopen PdoVariable.offset), little endian
    length_bits: int
    data_type: int
    low: int | float  # the EDS limits, else the data type's range
    high: int | float
    unit: str  # from the object name's [unit], "" if none

    @property
    def key(self) -> tuple[int, int]:
        return (self.index, self.subindex)


@dataclass(frozen=True)
class PdoMessage:
    """One PDO of one node at its default COB-ID, as the EDS maps it."""

    kind: str
    node_id: int
    direction: str  # "TPDO" (the node sends) or "RPDO" (the node receives)
    number: int
    can_id: int
    length_bytes: int
    enabled: bool  # COB-ID valid bit in the EDS default
    transmission_type: int
    event_timer_ms: int
    inhibit_time_100us: int
    signals: tuple[PdoSignal, ...]

    @property
    def name(self) -> str:
        return f"{NODE_NAMES[self.kind]}_{self.direction}{self.number}"


def dbc_name(text: str) -> str:
    """An object name as a DBC identifier: "Target grip force [mN]" -> "TargetGripForce"."""
    words = re.findall(r"[A-Za-z0-9]+", _UNIT_RE.sub("", text))
    name = "".join(w[:1].upper() + w[1:] for w in words) or "Object"
    if name[0].isdigit():
        name = "_" + name
    return name[:DBC_NAME_MAX]


def pdo_messages(kind: str, node_id: int) -> list[PdoMessage]:
    """Every mapped TPDO and RPDO of a shipped profile at `node_id`, read from its EDS."""
    od = load_profile(kind, node_id)
    node = canopen.RemoteNode(node_id, od)
    canopen.Network().add_node(node)  # never connected: the maps only need a network object
    node.tpdo.read(from_od=True)
    node.rpdo.read(from_od=True)
    messages = []
    for direction, maps in (("TPDO", node.tpdo), ("RPDO", node.rpdo)):
        for number, pdo in sorted(maps.map.items() if maps.map is not None else ()):
            if not len(pdo.map):
                continue
            signals: list[PdoSignal] = []
            taken: set[str] = set()
            for var in pdo.map:
                signals.append(_pdo_signal(var.od, var.offset, var.length, taken))
            messages.append(
                PdoMessage(
                    kind=kind,
                    node_id=node_id,
                    direction=direction,
                    number=number,
                    can_id=pdo.cob_id,
                    length_bytes=(pdo.length + 7) // 8,
                    enabled=bool(pdo.enabled),
                    transmission_type=int(pdo.trans_type or 0),
                    event_timer_ms=int(pdo.event_timer or 0),
                    inhibit_time_100us=int(pdo.inhibit_time or 0),
                    signals=tuple(signals),
                )
            )
    return messages


def _pdo_signal(od: ODVariable, offset: int, length: int, taken: set[str]) -> PdoSignal:
    data_type = od.data_type or 0
    dtype = DATA_TYPES[data_type]
    name = dbc_name(od.name)
    suffix = 2
    while name in taken:
        name = f"{name[: DBC_NAME_MAX - 3]}_{suffix}"
        suffix += 1
    taken.add(name)
    unit = _UNIT_RE.search(od.name)
    return PdoSignal(
        name=name,
        index=od.index,
        subindex=od.subindex,
        object_name=od.name,
        start_bit=offset,
        length_bits=length,
        data_type=data_type,
        low=od.min if od.min is not None else dtype.low,
        high=od.max if od.max is not None else dtype.high,
        unit=unit.group(1) if unit else "",
    )


def node_ids_with(overrides: Mapping[str, int] | None = None) -> dict[str, int]:
    """The profile's default node-IDs (and the gateway's), with `overrides` by kind."""
    ids = dict(DEFAULT_NODE_IDS) | {MASTER: obj.GATEWAY_NODE_ID}
    for kind, node_id in (overrides or {}).items():
        if kind not in ids:
            raise ConfigError(f"--node-id {kind}=...: {unknown_kind(kind)} (or {MASTER})")
        if not 1 <= node_id <= 127:
            raise ConfigError(f"--node-id {kind}={node_id}: node-ID is outside 1..127")
        ids[kind] = node_id
    clashes = sorted({i for i in ids.values() if list(ids.values()).count(i) > 1})
    if clashes:
        names = [f"{k}={v:#04x}" for k, v in ids.items() if v in clashes]
        raise ConfigError(f"two nodes share a node-ID: {', '.join(names)}")
    return ids


def build_database(overrides: Mapping[str, int] | None = None) -> Database:
    """The whole network (four nodes and the gateway) as a cantools `Database`."""
    ids = node_ids_with(overrides)
    master = NODE_NAMES[MASTER]
    kinds = list(BY_NODE_ID)
    nodes = [Node(master, comment=f"NMT master and gateway, node-ID 0x{ids[MASTER]:02X}")]
    nodes += [
        Node(NODE_NAMES[k], comment=f"{k} node, node-ID 0x{ids[k]:02X} ({k}.eds)") for k in kinds
    ]
    messages = [_nmt(ids), _sync(), _heartbeat(MASTER, ids[MASTER], GATEWAY_HEARTBEAT_MS, kinds)]
    for kind in kinds:
        node_id = ids[kind]
        messages += [_pdo_message(m) for m in pdo_messages(kind, node_id)]
        od = load_profile(kind, node_id)
        heartbeat_ms = od_default(od, obj.HEARTBEAT_PRODUCER_MS)
        messages += [
            _heartbeat(kind, node_id, heartbeat_ms, [MASTER]),
            _emcy(kind, node_id),
            *_sdo(kind, node_id),
        ]
    messages.sort(key=lambda m: m.frame_id)
    used = [m.frame_id for m in messages]
    clash = sorted({f for f in used if used.count(f) > 1})
    if clash:
        raise ConfigError(
            "these node-IDs put two frames on one CAN-ID: " + ", ".join(f"0x{f:03X}" for f in clash)
        )
    tables = OrderedDict(
        (
            ("NmtState", _choices(NMT_STATE_NAMES)),
            ("NmtCommand", _choices(NMT_COMMAND_NAMES)),
            ("EmcyErrorCode", _choices(EMCY_CODES)),
        )
    )
    return Database(
        messages=messages,
        nodes=nodes,
        version="grasplink profiles",
        dbc_specifics=DbcSpecifics(value_tables=tables),
        sort_signals=None,  # keep each message's signals in mapping order
    )


def write_dbc(path: Path, overrides: Mapping[str, int] | None = None) -> Path:
    """Write the network's DBC to `path` (cantools' encoding for DBC: cp1252, CRLF)."""
    try:
        cantools.database.dump_file(build_database(overrides), str(path), database_format="dbc")
    except OSError as exc:
        raise ConfigError(f"cannot write {path}: {exc.strerror or exc}") from None
    return Path(path)


def dbc_text(overrides: Mapping[str, int] | None = None) -> str:
    return build_database(overrides).as_dbc_string()


# -- messages -----------------------------------------------------------------------------
def _pdo_message(pdo: PdoMessage) -> Message:
    node = NODE_NAMES[pdo.kind]
    sender, receiver = (
        (node, NODE_NAMES[MASTER])
        if pdo.direction == "TPDO"
        else (
            NODE_NAMES[MASTER],
            node,
        )
    )
    signals = []
    for s in pdo.signals:
        dtype = DATA_TYPES[s.data_type]
        choices = OBJECT_CHOICES.get(s.key)
        signals.append(
            Signal(
                name=s.name,
                start=s.start_bit,
                length=s.length_bits,
                byte_order="little_endian",
                is_signed=dtype.signed,
                conversion=BaseConversion.factory(
                    scale=1,
                    offset=0,
                    choices=_choices(choices) if choices is not None else None,
                    is_float=dtype.kind == "float",
                ),
                minimum=s.low,
                maximum=s.high,
                unit=s.unit or None,
                comment=f"object {s.index:04X}h:{s.subindex:02X} {s.object_name} ({dtype.name})",
                receivers=[receiver],
            )
        )
    comm, mapping = (
        (obj.TPDO_COMM, obj.TPDO_MAP)
        if pdo.direction == "TPDO"
        else (
            obj.RPDO_COMM,
            obj.RPDO_MAP,
        )
    )
    what = TRANSMISSION_TYPES.get(pdo.transmission_type, "synchronous, cyclic")
    comment = (
        f"{pdo.direction}{pdo.number} of the {pdo.kind} node 0x{pdo.node_id:02X}: "
        f"communication {comm + pdo.number - 1:04X}h, mapping {mapping + pdo.number - 1:04X}h; "
        f"transmission type {pdo.transmission_type} ({what})"
    )
    if pdo.direction == "TPDO":
        comment += (
            f", inhibit {pdo.inhibit_time_100us / 10:g} ms, event timer {pdo.event_timer_ms} ms"
        )
    if not pdo.enabled:
        comment += "; disabled in the EDS default (COB-ID bit 31 set)"
    return Message(
        frame_id=pdo.can_id,
        name=pdo.name,
        length=pdo.length_bytes,
        signals=signals,
        comment=comment,
        senders=[sender],
        cycle_time=pdo.event_timer_ms or None,
    )


def _nmt(ids: Mapping[str, int]) -> Message:
    targets = {0: "all nodes"} | {ids[k]: k for k in BY_NODE_ID}
    nodes = [NODE_NAMES[k] for k in BY_NODE_ID]
    return Message(
        frame_id=NMT_COB_ID,
        name="NMT",
        length=2,
        signals=[
            _field(
                "Command",
                0,
                8,
                choices=NMT_COMMAND_NAMES,
                comment="NMT command",
                receivers=nodes,
            ),
            _field(
                "NodeID",
                8,
                8,
                choices=targets,
                comment="addressed node-ID (0: all)",
                receivers=nodes,
            ),
        ],
        comment="NMT node control from the master (CiA 301 7.2.8.3.1)",
        senders=[NODE_NAMES[MASTER]],
    )


def _sync() -> Message:
    return Message(
        frame_id=SYNC_COB_ID_DEFAULT,
        name="SYNC",
        length=0,
        signals=[],
        comment="SYNC (no counter): triggers PDOs of transmission type 0..240",
        senders=[NODE_NAMES[MASTER]],
    )


def _heartbeat(kind: str, node_id: int, period_ms: int, consumers: list[str]) -> Message:
    receivers = [NODE_NAMES[c] for c in consumers]
    return Message(
        frame_id=HEARTBEAT_BASE + node_id,
        name=f"{NODE_NAMES[kind]}_Heartbeat",
        length=1,
        signals=[
            _field(
                "State",
                0,
                7,
                choices=NMT_STATE_NAMES,
                comment="NMT state; 0 is the boot-up message",
                receivers=receivers,
            ),
            _field(
                "Toggle",
                7,
                1,
                comment="node-guarding toggle bit; 0 in a heartbeat",
                receivers=receivers,
            ),
        ],
        comment=f"heartbeat of the {kind} node 0x{node_id:02X} (producer time 1017h)",
        senders=[NODE_NAMES[kind]],
        cycle_time=period_ms or None,
    )


def _emcy(kind: str, node_id: int) -> Message:
    receivers = [NODE_NAMES[MASTER]]
    return Message(
        frame_id=EMCY_BASE + node_id,
        name=f"{NODE_NAMES[kind]}_EMCY",
        length=8,
        signals=[
            _field(
                "ErrorCode",
                0,
                16,
                choices=EMCY_CODES,
                comment="CiA 301 emergency error code",
                receivers=receivers,
            ),
            _field(
                "ErrorRegister",
                16,
                8,
                comment="1001h: bit 0 generic, 1 current, 2 voltage, 3 temperature, "
                "4 communication, 5 device profile, 7 manufacturer-specific",
                receivers=receivers,
            ),
            _field(
                "ManufacturerData",
                24,
                40,
                comment="manufacturer-specific bytes 3..7 (heartbeat error: the lost node-ID; "
                "RPDO timeout: the RPDO number)",
                receivers=receivers,
            ),
        ],
        comment=f"emergency messages of the {kind} node 0x{node_id:02X} (COB-ID 1014h)",
        senders=[NODE_NAMES[kind]],
    )


def _sdo(kind: str, node_id: int) -> list[Message]:
    node, master = NODE_NAMES[kind], NODE_NAMES[MASTER]
    messages = []
    for base, suffix, sender, receiver, what in (
        (SDO_RX_BASE, "SDO_Request", master, node, "client (gateway) to server"),
        (SDO_TX_BASE, "SDO_Response", node, master, "server to client (gateway)"),
    ):
        fields = [
            ("Command", 0, 8, "SDO command specifier byte"),
            ("Index", 8, 16, "object index (initiate and abort frames)"),
            ("SubIndex", 24, 8, "object sub-index (initiate and abort frames)"),
            ("Data", 32, 32, "expedited data or abort code; segments carry data in bytes 1..7"),
        ]
        messages.append(
            Message(
                frame_id=base + node_id,
                name=f"{node}_{suffix}",
                length=8,
                signals=[
                    _field(name, start, length, comment=text, receivers=[receiver])
                    for name, start, length, text in fields
                ],
                comment=f"SDO of the {kind} node 0x{node_id:02X}, {what}",
                senders=[sender],
            )
        )
    return messages


def _field(
    name: str,
    start: int,
    length: int,
    *,
    choices: Mapping[_Value, str] | None = None,
    comment: str,
    receivers: list[str],
) -> Signal:
    return Signal(
        name=name,
        start=start,
        length=length,
        byte_order="little_endian",
        is_signed=False,
        conversion=BaseConversion.factory(choices=_choices(choices) if choices else None),
        minimum=0,
        maximum=(1 << length) - 1,
        comment=comment,
        receivers=receivers,
    )


def _choices(names: Mapping[_Value, str]) -> Choices:
    """A value table as cantools types it (an OrderedDict of plain ints)."""
    return OrderedDict((int(value), text) for value, text in names.items())


def load_dbc(path: Path) -> Database:
    """Read a DBC back with cantools (strict: overlapping signals are an error)."""
    database = cantools.database.load_file(str(path), database_format="dbc")
    if not isinstance(database, Database):  # only a .cdd is a diagnostics database
        raise ConfigError(f"{path}: not a CAN database")
    return database

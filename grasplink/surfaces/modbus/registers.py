"""The Modbus register map: plain data and pure encode/decode functions, no IO.

Built once from the gateway's snapshot layout and the node profiles: a register
that carries a profile object's value (grip forces, belt velocity, EMG
envelope and level, calibration) takes its word type, raw unit and limits
from that object in the EDS, so the map cannot disagree with the nodes. Node
blocks are generated per node kind the gateway masters.

- **Input registers** (function 04): read-only state, encoded from
  `Gateway.latest` (the 20 Hz snapshot, `grasplink.gateway.snapshot`). Which values
  the map carries, at which address, scale and encoding, is this table's decision;
  every `path` must name a field of the snapshot (checked as the map is built, so a
  misspelt path fails naming its register). Contiguous from address 0 and small
  enough (`MAX_READ`) for one request to read the whole map.
- **Holding registers** (03, 06, 16, 23): the run-time commands of
  `gateway/commands.py`. A write must cover exactly one command group (one
  register, or the e_min/e_max pair): values are range-checked here first
  (`ILLEGAL_VALUE`), addresses and groups too (`ILLEGAL_ADDRESS`), so a
  refused write posts nothing.

A configuration may add device objects (`[[modbus.registers]]`, `config.ModbusRegister`):
each at its own input registers, at or above `MODBUS_DEVICE_BASE` (`DeviceRegister`,
`register_map_for`); a read must lie inside the fixed map or on configured registers.
Likewise `[[modbus.holding]]`: a device's RPDO-mapped objects at holding registers, a
write of one becoming the command `write_object` (the gateway sends it in the RPDO).

Conventions (docs/modbus.md): 32-bit values take two registers, high word
first; signed values are two's complement; engineering value = raw × scale;
an unknown value reads as the type's sentinel (0xFFFF, 0x8000, 0xFFFFFFFF,
0x80000000) and a known value saturates one step short of it; counters wrap.
"""

from __future__ import annotations

import functools
import math
import numbers
import re
import struct
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

from grasplink.core.nmt import NmtState
from grasplink.gateway.commands import (
    CALIBRATION_PHASES,
    MAX_THRESHOLD_MM_S,
    MIN_THRESHOLD_MM_S,
    Command,
)
from grasplink.gateway.config import MODBUS_DEVICE_BASE, GatewayConfig, ModbusRegister
from grasplink.gateway.edge import GatewayEdge
from grasplink.gateway.feedback import FeedbackMode, Reason
from grasplink.gateway.levels import Belt
from grasplink.gateway.reflex import GripSource, ReflexState
from grasplink.gateway.service import Gateway
from grasplink.gateway.snapshot import NodePhase, NodeSnapshot, Snapshot, check_path
from grasplink.profiles import load_profile, object_limits
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import KINDS

#: Bumped whenever an address, type, scale or a value's meaning changes, or registers are
#: added (at the end of a table: no address moves); readable at input register 0.
MAP_VERSION = 2
#: What each map version changed, for docs/modbus.md (a client checks `map_version`).
MAP_CHANGES: tuple[tuple[int, str], ...] = (
    (1, "the first map"),
    (
        2,
        "`skin.slip_speed_mm_s` (address unchanged, still i16) is the slip speed's "
        "magnitude, never negative: the direction is no longer its sign but "
        "`skin.slip_direction`. Added at the end of the input table (no address moved): "
        "`skin.slip_speed_low_mm_s`, `skin.slip_speed_high_mm_s` (the range of speeds the "
        "decoder still allows: a bound while the speed is unknown), `skin.slip_direction` "
        "(+1, -1, sentinel: not told) and `skin.slip_direction_confidence`; belt reason "
        "code 9, `slip, at least this speed` (the belt shows a bound's lower end).",
    ),
)
#: Registers one read (function 03/04) may ask for, by the Modbus specification.
MAX_READ = 125
#: How long a write waits for the gateway's CommandResult (its runner wakes every 20 ms).
COMMAND_TIMEOUT_S = 0.5
#: Alarm categories per node (the gateway's alarm keys are "KIND.CATEGORY").
ALARM_CATEGORIES = ("lost", "provisioning", "emcy", "clamped")
OTHER_ALARM_BIT = 31
_UNIT_RE = re.compile(r"\[([^\]]+)\]\s*$")
# Raw unit (the EDS's) -> engineering unit (the snapshot's): scale.
_UNIT_SCALES = {("mN", "N"): 0.001}


class ExceptionCode(IntEnum):
    """Modbus exception codes the server answers with."""

    ILLEGAL_FUNCTION = 0x01
    ILLEGAL_ADDRESS = 0x02
    ILLEGAL_VALUE = 0x03
    DEVICE_FAILURE = 0x04
    DEVICE_BUSY = 0x06
    GATEWAY_NO_RESPONSE = 0x0B  # a unit id no gateway of this process is served at


class RegisterError(Exception):
    """A request the map refuses; carries the Modbus exception code and why (sans-IO)."""

    def __init__(self, code: ExceptionCode, message: str):
        super().__init__(message)
        self.code = code


@dataclass(frozen=True, slots=True)
class WordType:
    """u16, i16, u32 or i32: how many registers, signed or not, and the sentinel.

    `sentinel` is the word pattern of an unknown value (the most negative, or all ones);
    `low..high` the known values, which stop one step short of it. Precomputed: the
    encoder runs for every snapshot a client polls.
    """

    name: str
    words: int
    signed: bool
    bits: int = field(init=False)
    mask: int = field(init=False)
    sentinel: int = field(init=False)
    low: int = field(init=False)
    high: int = field(init=False)

    def __post_init__(self) -> None:
        bits = 16 * self.words
        half = 1 << (bits - 1)
        values = {
            "bits": bits,
            "mask": (1 << bits) - 1,
            "sentinel": half if self.signed else (1 << bits) - 1,
            "low": -half + 1 if self.signed else 0,
            "high": half - 1 if self.signed else (1 << bits) - 2,
        }
        for name, value in values.items():
            object.__setattr__(self, name, value)


U16 = WordType("u16", 1, False)
I16 = WordType("i16", 1, True)
U32 = WordType("u32", 2, False)
I32 = WordType("i32", 2, True)

# CiA 301 data type codes (python-canopen's) -> the register type that carries them.
_EDS_TYPES = {1: U16, 2: I16, 3: I16, 4: I32, 5: U16, 6: U16, 7: U32}


@dataclass(frozen=True, slots=True)
class ProfileSource:
    """The EDS object a register carries: type, raw unit and limits come from it."""

    kind: str
    index: int
    subindex: int
    name: str
    raw_unit: str
    type: WordType
    low: int
    high: int

    def __str__(self) -> str:
        return f"{self.kind} {self.index:04X}h:{self.subindex:02X} {self.name}"


@functools.lru_cache(maxsize=64)
def profile_source(kind: str, index: int, subindex: int = 0) -> ProfileSource:
    """The shipped profile's object `kind index:subindex` as a register source."""
    entry = load_profile(kind, obj.DEFAULT_NODE_IDS[kind])[index]
    if not hasattr(entry, "data_type"):
        entry = entry[subindex]
    unit = _UNIT_RE.search(entry.name)
    if not isinstance(entry.data_type, int) or entry.data_type not in _EDS_TYPES:
        raise ValueError(f"{kind} {index:04X}h:{subindex:02X}: no register type for it")
    low, high = object_limits(kind, index, subindex)
    return ProfileSource(
        kind,
        index,
        subindex,
        _UNIT_RE.sub("", entry.name).strip(),
        unit.group(1) if unit else "",
        _EDS_TYPES[entry.data_type],
        low,
        high,
    )


@dataclass(frozen=True, slots=True)
class Register:
    """One value in the map, at `address` (0-based PDU address) and the next for 32 bits.

    Engineering value = raw × `scale`, in `unit`. `codes`: an enumeration (name ->
    code); `bits`: a bit field (bit i means `bits[i]`); `counter`: wraps modulo 2^bits
    and has no sentinel. `path` locates the value in the snapshot's JSON-ready form
    (input) or the settings (holding); `derive` computes it instead, from the typed
    `Snapshot` (input) or the settings, when it is not one value there.
    Holding registers accept raw values `low..high` (or the codes).
    """

    name: str
    address: int
    type: WordType
    description: str
    unit: str = ""
    scale: float = 1.0
    section: str = ""
    path: tuple[str, ...] = ()
    derive: Callable[[Any], Any] | None = None
    source: str = ""  # where the value comes from, for the docs (default: "snapshot PATH")
    profile: ProfileSource | None = None
    codes: Mapping[str, int] | None = None
    bits: tuple[str, ...] = ()
    counter: bool = False
    low: int | None = None
    high: int | None = None
    default: int | None = None  # raw value read while the value is absent (else the sentinel)

    @property
    def words(self) -> int:
        return self.type.words

    @property
    def end(self) -> int:
        """One past the last address."""
        return self.address + self.type.words

    @property
    def has_sentinel(self) -> bool:
        return not self.counter and self.default is None

    def value_of(self, data: Snapshot | Mapping[str, Any] | None) -> Any:
        """The engineering value in a snapshot or settings mapping (None if absent)."""
        if data is None:
            return None
        if self.derive is not None:
            return self.derive(data)
        return _lookup(data.to_dict() if isinstance(data, Snapshot) else data, self.path)

    def to_raw(self, value: Any) -> int | None:
        """Engineering value -> raw integer (saturated, or wrapped for counters);
        None when unknown (None, NaN, a name not in the codes)."""
        kind = type(value)
        raw: int
        if kind is float:
            if not math.isfinite(value):
                return None
            raw = round(value / self.scale)
        elif kind is int:
            raw = int(value) if self.scale == 1 else round(value / self.scale)
        elif kind is bool:
            return int(value)
        elif kind is str:
            return None if self.codes is None else self.codes.get(value)
        elif isinstance(value, numbers.Real):  # numpy scalars and other numbers
            return self.to_raw(float(value))
        else:
            return None
        word_type = self.type
        if self.counter:
            return raw & word_type.mask
        return word_type.high if raw > word_type.high else max(word_type.low, raw)

    def encode(self, value: Any) -> list[int]:
        """Engineering value -> register words (high word first)."""
        raw = self.to_raw(value)
        if raw is None:
            # Absent: the default if it has one, a counter reads 0, anything else is unknown.
            raw = self.default if self.default is not None else (0 if self.counter else None)
        return to_words(self.type, raw)

    def decode(self, words: Sequence[int]) -> int | None:
        """Register words -> raw integer; None for the sentinel."""
        return from_words(self.type, words, sentinel=self.has_sentinel)

    def engineering(self, words: Sequence[int]) -> float | int | None:
        """Register words -> engineering value (raw × scale); None for the sentinel."""
        raw = self.decode(words)
        if raw is None or self.scale == 1:
            return raw
        return raw * self.scale


def to_words(word_type: WordType, raw: int | None) -> list[int]:
    """Raw integer -> words, two's complement, high word first; None -> the sentinel."""
    pattern = word_type.sentinel if raw is None else raw & word_type.mask
    if word_type.words == 1:
        return [pattern]
    return [pattern >> 16, pattern & 0xFFFF]


def from_words(word_type: WordType, words: Sequence[int], *, sentinel: bool = True) -> int | None:
    """Words (high first) -> raw integer; None for the sentinel pattern."""
    if sentinel and _pattern(word_type, words) == word_type.sentinel:
        return None
    return words_to_int(word_type, words)


def words_to_int(word_type: WordType, words: Sequence[int]) -> int:
    """Words (high first) -> raw integer, the sentinel pattern read as a number (writes)."""
    pattern = _pattern(word_type, words)
    if word_type.signed and pattern >= 1 << (word_type.bits - 1):
        pattern -= 1 << word_type.bits
    return pattern


def _pattern(word_type: WordType, words: Sequence[int]) -> int:
    if len(words) != word_type.words or any(not 0 <= w <= 0xFFFF for w in words):
        raise ValueError(f"{word_type.name} takes {word_type.words} words of 0..0xFFFF")
    pattern = 0
    for word in words:
        pattern = pattern << 16 | word
    return pattern


@dataclass(frozen=True, slots=True)
class CommandGroup:
    """Holding registers written together as one command (`gateway/commands.py`)."""

    command: str
    registers: tuple[Register, ...]
    build: Callable[[tuple[int, ...]], Any]  # checked raw values -> the command's value
    description: str

    @property
    def address(self) -> int:
        return self.registers[0].address

    @property
    def end(self) -> int:
        return self.registers[-1].end


@dataclass(frozen=True)
class RegisterMap:
    """Input registers, holding registers and the command groups over the holding ones."""

    inputs: tuple[Register, ...]
    holding: tuple[Register, ...]
    groups: tuple[CommandGroup, ...]
    _by_name: dict[str, Register] = field(default_factory=dict, repr=False)
    # "inputs", "holding" -> the table's registers as the encoder reads them (`_Plan`)
    _compiled: dict[str, tuple[_Plan, ...]] = field(default_factory=dict, repr=False, compare=False)
    # a configuration's device objects (`register_map_for`), by address, above the fixed map
    device_registers: tuple[DeviceRegister, ...] = ()
    # its device objects a client writes (`[[modbus.holding]]`), by address
    device_holding: tuple[DeviceRegister, ...] = ()
    source: str = ""  # the configuration they come from

    def __post_init__(self) -> None:
        for table in (self.inputs, self.holding):
            _check_contiguous(table)
        for register in self.inputs + self.holding:
            if register.name in self._by_name:
                raise ValueError(f"register name {register.name} used twice")
            self._by_name[register.name] = register
        self._compiled["inputs"] = tuple(_plan(register) for register in self.inputs)
        self._compiled["holding"] = tuple(_plan(register) for register in self.holding)
        if self.input_count > MAX_READ or self.holding_count > MAX_READ:
            raise ValueError(f"a table longer than {MAX_READ} registers cannot be read at once")

    def __getitem__(self, name: str) -> Register:
        return self._by_name[name]

    @property
    def input_count(self) -> int:
        return self.inputs[-1].end if self.inputs else 0

    @property
    def holding_count(self) -> int:
        return self.holding[-1].end if self.holding else 0

    def encode_inputs(self, snapshot: Snapshot | None) -> list[int]:
        """The whole input table for one snapshot (None: before the first one)."""
        data = None if snapshot is None else snapshot.to_dict()
        return _encode_table(self._compiled["inputs"], data, snapshot)

    def encode_holding(self, settings: Mapping[str, Any] | None) -> list[int]:
        """The whole holding table for the gateway's current settings."""
        return _encode_table(self._compiled["holding"], settings, settings)

    @property
    def input_span(self) -> int:
        """One past the last input register served: the fixed map's, or a device object's."""
        return max((r.end for r in self.device_registers), default=self.input_count)

    def encode_served_inputs(self, snapshot: Snapshot | None) -> list[int]:
        """Every input register served (0..input_span): the fixed map, then the device
        objects at their addresses (0 between them: never read, `read_inputs` refuses it)."""
        table = self.encode_inputs(snapshot)
        if not self.device_registers:
            return table
        table += [0] * (self.input_span - len(table))
        for register in self.device_registers:
            table[register.address : register.end] = register.encode(snapshot)
        return table

    def read_inputs(self, table: list[int], address: int, count: int) -> list[int]:
        """`read` of the served input table: ILLEGAL_ADDRESS also for a span that is not
        all in the fixed map or all on configured registers."""
        return self._read_served(
            "input", table, address, count, self.input_count, self.device_registers
        )

    @property
    def holding_span(self) -> int:
        """One past the last holding register served: the fixed map's, or a device's."""
        return max((r.end for r in self.device_holding), default=self.holding_count)

    def encode_served_holding(self, settings: Mapping[str, Any] | None) -> list[int]:
        """Every holding register served: the fixed map, then each device object's value
        as last sent to it (`settings[register name]`; the sentinel before any)."""
        table = self.encode_holding(settings)
        if not self.device_holding:
            return table
        table += [0] * (self.holding_span - len(table))
        for register in self.device_holding:
            value = None if settings is None else settings.get(register.name)
            table[register.address : register.end] = register.encode_value(value)
        return table

    def read_holding(self, table: list[int], address: int, count: int) -> list[int]:
        """`read` of the served holding table, as `read_inputs` reads the input one."""
        return self._read_served(
            "holding", table, address, count, self.holding_count, self.device_holding
        )

    def _read_served(
        self,
        what: str,
        table: list[int],
        address: int,
        count: int,
        fixed: int,
        devices: tuple[DeviceRegister, ...],
    ) -> list[int]:
        words = self.read(table, address, count)
        end = address + count
        if end > fixed and (address < fixed or not _covered(devices, address, end)):
            raise RegisterError(
                ExceptionCode.ILLEGAL_ADDRESS,
                f"{what} registers {address}..{end - 1} are not all mapped (fixed map "
                f"0..{fixed - 1}; device objects: "
                + ", ".join(f"{r.address}..{r.end - 1}" for r in devices)
                + ")",
            )
        return words

    def read(self, table: list[int], address: int, count: int) -> list[int]:
        """`count` words from `address` of an encoded table; ILLEGAL_ADDRESS outside it."""
        if not 1 <= count <= MAX_READ:
            raise RegisterError(ExceptionCode.ILLEGAL_VALUE, f"count {count} outside 1..125")
        if address < 0 or address + count > len(table):
            raise RegisterError(
                ExceptionCode.ILLEGAL_ADDRESS,
                f"registers {address}..{address + count - 1} outside 0..{len(table) - 1}",
            )
        return table[address : address + count]

    def command_for_write(self, address: int, words: Sequence[int]) -> Command:
        """The command a holding-register write asks for, every value checked.

        ILLEGAL_ADDRESS: not exactly one command group (an address outside the table, a
        write starting inside a group or covering part of one, or several groups).
        ILLEGAL_VALUE: a value outside its range or codes, or e_min >= e_max; a device
        object's value outside what the object accepts.
        """
        end = address + len(words)
        device = next((r for r in self.device_holding if r.address == address), None)
        if device is not None and end == device.end:
            return device.command(words)
        group = next((g for g in self.groups if g.address == address), None)
        if group is None or end != group.end:
            span = f"{address}..{end - 1}" if len(words) > 1 else str(address)
            raise RegisterError(
                ExceptionCode.ILLEGAL_ADDRESS,
                f"holding registers {span} are not one command; commands: "
                + ", ".join(f"{g.command} {_span(g)}" for g in self.groups)
                + "".join(
                    f", write_object {r.name} {r.address}..{r.end - 1}" for r in self.device_holding
                ),
            )
        raws: list[int] = []
        offset = 0
        for register in group.registers:
            chunk = words[offset : offset + register.words]
            offset += register.words
            raw = words_to_int(register.type, chunk)
            if not _accepts(register, raw):
                raise RegisterError(
                    ExceptionCode.ILLEGAL_VALUE,
                    f"{register.name}: {_describe_raw(register, chunk)} outside "
                    f"{_accepted(register)}",
                )
            raws.append(raw)
        try:
            value = group.build(tuple(raws))
        except ValueError as exc:
            raise RegisterError(ExceptionCode.ILLEGAL_VALUE, f"{group.command}: {exc}") from None
        return Command(group.command, value)


def _covered(devices: Sequence[DeviceRegister], address: int, end: int) -> bool:
    """Whether address..end-1 lies on consecutive configured registers."""
    for register in devices:  # by address: a gap ends the run
        if register.end <= address:
            continue
        if register.address > address:
            return False
        address = register.end
        if address >= end:
            return True
    return False


def _span(group: CommandGroup) -> str:
    return (
        str(group.address)
        if group.end - group.address == 1
        else (f"{group.address}..{group.end - 1}")
    )


def _accepts(register: Register, raw: int) -> bool:
    if register.codes is not None:
        return raw in register.codes.values()
    low = register.type.low if register.low is None else register.low
    high = register.type.high if register.high is None else register.high
    return low <= raw <= high


def _accepted(register: Register) -> str:
    if register.codes is not None:
        return "codes " + ", ".join(f"{c} {n}" for n, c in register.codes.items())
    return f"{register.low}..{register.high}"


def _describe_raw(register: Register, words: Sequence[int]) -> str:
    return " ".join(f"0x{w:04X}" for w in words) if register.words > 1 else str(words[0])


def _check_contiguous(table: tuple[Register, ...]) -> None:
    expected = 0
    for register in table:
        if register.address != expected:
            raise ValueError(f"{register.name} at {register.address}, expected {expected}")
        expected = register.end


# One register as the table encoder reads it: (path, derive, scale, codes, counter, mask,
# low, high, raw when absent (None: the sentinel), sentinel pattern, two words, register).
_Plan = tuple[
    tuple[str, ...],
    Callable[[Any], Any] | None,
    float,
    Mapping[str, int] | None,
    bool,
    int,
    int,
    int,
    int | None,
    int,
    bool,
    Register,
]


def _plan(register: Register) -> _Plan:
    word_type = register.type
    absent = register.default if register.default is not None else (0 if register.counter else None)
    return (
        register.path,
        register.derive,
        register.scale,
        register.codes,
        register.counter,
        word_type.mask,
        word_type.low,
        word_type.high,
        absent,
        word_type.sentinel,
        word_type.words == 2,
        register,
    )


def _encode_table(
    plans: tuple[_Plan, ...], data: Mapping[str, Any] | None, source: Any
) -> list[int]:
    """`Register.value_of` and `Register.encode` for every register of a table, in one loop
    with their common cases inlined: the server encodes a snapshot for every poll it
    answers, and per-register method calls were most of that cost. Anything unusual (a
    numpy scalar, a value of another type) takes the register's own path. Paths read
    `data` (the JSON-ready form), `derive` reads `source` (the typed snapshot)."""
    words: list[int] = []
    append = words.append
    for plan in plans:
        path, derive, scale, codes, counter, mask, low, high, absent, sentinel, double, reg = plan
        value: Any
        if data is None:
            value = None
        elif derive is not None:
            value = derive(source)
        else:
            value = data
            try:
                for key in path:
                    value = value[key]
            except (KeyError, TypeError, IndexError):
                value = None
        kind = type(value)
        raw: int | None
        if kind is float:
            if math.isfinite(value):
                known: int = round(value / scale)
                raw = known & mask if counter else high if known > high else max(low, known)
            else:
                raw = absent
        elif kind is int:
            known = value if scale == 1 else round(value / scale)
            raw = known & mask if counter else high if known > high else max(low, known)
        elif kind is bool:
            raw = int(value)
        elif kind is str:
            raw = None if codes is None else codes.get(value)
            if raw is None:
                raw = absent
        elif value is None:
            raw = absent
        else:
            words += reg.encode(value)
            continue
        pattern = sentinel if raw is None else raw & mask
        if double:
            append(pattern >> 16)
            append(pattern & 0xFFFF)
        else:
            append(pattern)
    return words


def _lookup(data: Any, path: tuple[str, ...]) -> Any:
    try:
        for key in path:
            data = data[key]
    except (KeyError, TypeError, IndexError):  # absent, or a value where a table was expected
        return None
    return data


# -- derived values (from the typed snapshot) -----------------------------------------------
def _node_bits(test: Callable[[NodeSnapshot], bool]) -> Callable[[Snapshot], int]:
    bits = tuple((1 << i, kind) for i, kind in enumerate(KINDS))

    def derive(snapshot: Snapshot) -> int:
        nodes = snapshot.nodes
        value = 0
        for bit, kind in bits:
            node = nodes.get(kind)
            if node is not None and test(node):
                value |= bit
        return value

    return derive


def _live(node: NodeSnapshot) -> bool:
    return node.nmt_state is not None and node.phase is not NodePhase.LOST


def alarm_bit(key: str) -> int:
    """The bit of the `alarms` register an alarm key ("belt.lost") sets."""
    kind, _, category = key.partition(".")
    if kind in KINDS and category in ALARM_CATEGORIES:
        return KINDS.index(kind) * len(ALARM_CATEGORIES) + ALARM_CATEGORIES.index(category)
    return OTHER_ALARM_BIT


def _alarms(snapshot: Snapshot) -> int:
    return functools.reduce(lambda bits, key: bits | 1 << alarm_bit(key), snapshot.alarms, 0)


def _alarm_count(snapshot: Snapshot) -> int:
    return len(snapshot.alarms)


def _emcy_code(kind: str) -> Callable[[Snapshot], int | None]:
    def derive(snapshot: Snapshot) -> int | None:
        node = snapshot.nodes.get(kind)
        if node is None:
            return None
        return 0 if node.last_emcy is None else node.last_emcy

    return derive


def _uptime_ms(snapshot: Snapshot) -> float:
    return snapshot.uptime_s * 1000


def _map_version(_: object) -> int:
    return MAP_VERSION


# -- building the map ----------------------------------------------------------------------
class _Table:
    """Allocates consecutive addresses in declaration order."""

    def __init__(self, *, of_snapshot: bool = False) -> None:
        self.registers: list[Register] = []
        self.section = ""
        self.of_snapshot = of_snapshot  # paths name snapshot fields (the input table)

    def add(self, name: str, word_type: WordType | None, description: str, **kw: Any) -> Register:
        if self.of_snapshot and kw.get("path"):
            try:
                check_path(kw["path"])
            except ValueError as exc:
                raise ValueError(f"input register {name}: {exc}") from None
            # the docs' source column: the path, unless the register says more
            kw.setdefault("source", "snapshot " + ".".join(kw["path"]))
        profile: ProfileSource | None = kw.get("profile")
        if word_type is None:
            assert profile is not None
            word_type = profile.type
            if "unit" in kw and kw["unit"] != profile.raw_unit:
                kw["scale"] = _UNIT_SCALES[(profile.raw_unit, kw["unit"])]
            kw.setdefault("unit", profile.raw_unit)
        address = self.registers[-1].end if self.registers else 0
        register = Register(name, address, word_type, description, section=self.section, **kw)
        self.registers.append(register)
        return register


def _codes(names: Sequence[str], start: int = 0) -> dict[str, int]:
    return {name: start + i for i, name in enumerate(names)}


FEEDBACK_CODES = {m.value: m.code for m in FeedbackMode}
BELT_CODES = _codes([b.value for b in Belt])  # none, force, slip: as the belt's 2302h
REASON_CODES = _codes([r.value for r in Reason])
REFLEX_CODES = _codes([s.value for s in ReflexState])
SOURCE_CODES = _codes([s.value for s in GripSource])
PHASE_CODES = _codes([p.value for p in NodePhase])
NMT_CODES = {s.name: s.value for s in NmtState}
CALIBRATE_CODES = _codes(CALIBRATION_PHASES, start=1)
RESTART_CODES = _codes(KINDS, start=1)  # restart_node: the registry's order
BOOL_CODES = {"false": 0, "true": 1}
THRESHOLD_SCALE = 0.1


def _inputs() -> tuple[Register, ...]:
    t = _Table(of_snapshot=True)
    node_bits = tuple(f"{kind}" for kind in KINDS)
    t.section = "gateway"
    t.add(
        "map_version",
        U16,
        "register map layout version",
        derive=_map_version,
        default=MAP_VERSION,  # known before the first snapshot too
        source=f"constant {MAP_VERSION}",
    )
    t.add(
        "uptime_ms",
        U32,
        "time since the gateway started; changes with every snapshot "
        "(20 Hz), so a value that stops changing means a stalled gateway",
        unit="ms",
        derive=_uptime_ms,
        counter=True,
        source="snapshot uptime_s × 1000",
    )
    t.add(
        "nodes_configured",
        U16,
        "nodes the gateway masters (its configuration)",
        derive=_node_bits(lambda n: True),
        bits=node_bits,
        source="snapshot nodes",
    )
    t.add(
        "nodes_live",
        U16,
        "live list: the node's heartbeat is heard and not overdue",
        derive=_node_bits(_live),
        bits=node_bits,
        source="snapshot nodes.KIND: nmt_state known and phase not lost",
    )
    t.add(
        "nodes_operational",
        U16,
        "the node is provisioned and OPERATIONAL",
        derive=_node_bits(lambda n: n.phase is NodePhase.OPERATIONAL),
        bits=node_bits,
        source="snapshot nodes.KIND.phase == operational",
    )
    alarm_bits = [""] * 32
    for kind in KINDS:
        for category in ALARM_CATEGORIES:
            alarm_bits[alarm_bit(f"{kind}.{category}")] = f"{kind}.{category}"
    alarm_bits[OTHER_ALARM_BIT] = "any other alarm"
    t.add(
        "alarms",
        U32,
        "active alarms, one bit per alarm key (docs/gateway.md, degraded "
        "states); their text is in the gateway's status line and snapshot",
        derive=_alarms,
        bits=tuple(alarm_bits),
        source="snapshot alarms",
    )
    t.add(
        "alarm_count", U16, "number of active alarms", derive=_alarm_count, source="snapshot alarms"
    )
    for kind in KINDS:
        t.section = f"nodes.{kind}"
        base = ("nodes", kind)
        t.add(
            f"nodes.{kind}.node_id",
            U16,
            f"{kind} node-ID; 0 when not configured",
            path=(*base, "node_id"),
            default=0,
        )
        t.add(
            f"nodes.{kind}.nmt_state",
            U16,
            "NMT state from its last heartbeat (CANopen state byte)",
            path=(*base, "nmt_state"),
            codes=NMT_CODES,
        )
        t.add(
            f"nodes.{kind}.phase",
            U16,
            "what the gateway is doing with the node",
            path=(*base, "phase"),
            codes=PHASE_CODES,
        )
        t.add(
            f"nodes.{kind}.boots",
            U16,
            "boot-ups seen",
            path=(*base, "boots"),
            counter=True,
        )
        t.add(
            f"nodes.{kind}.pdos_rx",
            U32,
            "TPDOs received and decoded",
            path=(*base, "pdos_rx"),
            counter=True,
        )
        t.add(
            f"nodes.{kind}.pdos_dropped",
            U32,
            "TPDOs dropped (did not fit the mapping)",
            path=(*base, "pdos_dropped"),
            counter=True,
        )
        t.add(
            f"nodes.{kind}.last_emcy_code",
            U16,
            "error code of its last EMCY (0: none "
            "since the gateway started; 0x0000 is also error reset)",
            derive=_emcy_code(kind),
            source=f"snapshot nodes.{kind}.last_emcy",
        )

    t.section = "skin"
    t.add(
        "skin.grip_force_n",
        None,
        "grip force decoded from the skin",
        unit="N",
        path=("skin", "grip_force_n"),
        profile=profile_source("skin", obj.SKIN_STATIC_FORCE_MN),
    )
    t.add(
        "skin.slip",
        U16,
        "the decoder reports slip (0 no, 1 yes)",
        path=("skin", "slip"),
    )
    t.add(
        "skin.slip_speed_mm_s",
        I16,
        "slip speed, a magnitude (>= 0 since map version 2; sentinel: slip of unknown "
        "speed, or no slip; its range and direction: the registers at the end)",
        unit="mm/s",
        scale=0.1,
        path=("skin", "slip_speed_mm_s"),
    )
    t.add(
        "skin.position_mm",
        I32,
        "object position along the skin",
        unit="mm",
        scale=0.001,
        path=("skin", "position_mm"),
    )
    t.add(
        "skin.confidence",
        U16,
        "decoder confidence 0..1",
        scale=0.001,
        path=("skin", "confidence"),
    )
    t.add(
        "skin.lost_packets",
        U32,
        "skin sample packets lost (sequence gaps)",
        path=("nodes", "skin", "lost_packets"),
        counter=True,
    )

    t.section = "emg"
    t.add(
        "emg.envelope_uv",
        None,
        "EMG envelope the intent was decoded from",
        path=("emg", "envelope_uv"),
        profile=profile_source("emg", obj.EMG_ENVELOPE_UV),
    )
    t.add(
        "emg.level",
        None,
        "contraction level e0..e5 (through the gateway's calibration)",
        path=("emg", "level"),
        profile=profile_source("emg", obj.EMG_LEVEL),
    )
    t.add(
        "emg.grip_intent_n",
        None,
        "grip the wearer asks for",
        unit="N",
        path=("emg", "grip_intent_n"),
        profile=profile_source("hand", obj.HAND_TARGET_GRIP_MN),
    )
    t.add(
        "emg.saturated",
        U16,
        "the envelope is saturated (0 no, 1 yes)",
        path=("emg", "saturated"),
    )

    t.section = "belt"
    t.add(
        "belt.mode",
        U16,
        "feedback mode",
        path=("belt", "mode"),
        codes=FEEDBACK_CODES,
    )
    t.add(
        "belt.belt",
        None,
        "which belt the motor turns",
        path=("belt", "belt"),
        codes=BELT_CODES,
        profile=profile_source("belt", obj.BELT_ACTIVE),
    )
    t.add(
        "belt.level",
        U16,
        "display level shown, 1..n (0: none, stopped or a slip of "
        "unknown speed at the occurrence speed)",
        path=("belt", "level"),
        default=0,
    )
    t.add(
        "belt.velocity_mrad_s",
        None,
        "belt velocity commanded (> 0 force belt, < 0 slip belt, 0 stopped)",
        path=("belt", "velocity_mrad_s"),
        profile=profile_source("belt", obj.BELT_TARGET_VELOCITY_MRAD_S),
    )
    t.add(
        "belt.reason",
        U16,
        "why the belt does what it does",
        path=("belt", "reason"),
        codes=REASON_CODES,
    )

    t.section = "hand"
    t.add(
        "hand.grip_n",
        None,
        "grip force the hand reports",
        unit="N",
        path=("hand", "grip_n"),
        profile=profile_source("hand", obj.HAND_ACTUAL_GRIP_MN),
    )
    t.add(
        "hand.setpoint_n",
        None,
        "grip force commanded",
        unit="N",
        path=("hand", "setpoint_n"),
        profile=profile_source("hand", obj.HAND_TARGET_GRIP_MN),
    )
    t.add(
        "hand.reflex",
        U16,
        "grip reflex state",
        path=("hand", "reflex"),
        codes=REFLEX_CODES,
    )
    t.add(
        "hand.source",
        U16,
        "where the commanded grip comes from",
        path=("hand", "source"),
        codes=SOURCE_CODES,
    )

    t.section = "loop"
    t.add(
        "loop.latency_p50_us",
        U32,
        "gateway processing time from a skin TPDO to the RPDOs it causes, median of recent",
        unit="us",
        path=("loop", "latency_p50_us"),
    )
    t.add(
        "loop.latency_p99_us",
        U32,
        "the same, 99th percentile",
        unit="us",
        path=("loop", "latency_p99_us"),
    )
    t.add(
        "loop.percepts",
        U32,
        "skin decoder updates the loop acted on",
        path=("loop", "percepts"),
        counter=True,
    )

    # map version 2: added after the rest, so no earlier address moved
    t.section = "skin speed range and direction (map version 2)"
    for end, what in (("low", "slowest"), ("high", "fastest")):
        t.add(
            f"skin.slip_speed_{end}_mm_s",
            U16,
            f"the {what} slip speed the decoder still allows (sentinel: not bounded; "
            f"while the speed is unknown a bound, which the belt and reflex act on at "
            f"its low end)",
            unit="mm/s",
            scale=0.1,
            path=("skin", f"slip_speed_{end}_mm_s"),
        )
    t.add(
        "skin.slip_direction",
        I16,
        "slip direction: +1 from the first ridge towards the last, -1 back "
        "(sentinel: not told, e.g. a uniform skin)",
        path=("skin", "slip_direction"),
    )
    t.add(
        "skin.slip_direction_confidence",
        U16,
        "P(the object moves that way) 0..1 (sentinel: no direction)",
        scale=0.001,
        path=("skin", "slip_direction_confidence"),
    )
    return tuple(t.registers)


def _threshold(raws: tuple[int, ...]) -> float:
    return round(raws[0] * THRESHOLD_SCALE, 1)


def _calibration(raws: tuple[int, ...]) -> dict[str, float]:
    e_min, e_max = raws
    if not e_min < e_max:
        raise ValueError(f"e_min ({e_min} uV) must be below e_max ({e_max} uV)")
    return {"e_min_uv": float(e_min), "e_max_uv": float(e_max)}


def _holding() -> tuple[tuple[Register, ...], tuple[CommandGroup, ...]]:
    t = _Table()
    t.section = "commands"
    groups = []
    mode = t.add(
        "feedback_mode",
        U16,
        "feedback mode",
        path=("feedback_mode",),
        codes=FEEDBACK_CODES,
        source="gateway feedback controller mode",
    )
    groups.append(
        CommandGroup("feedback_mode", (mode,), lambda r: r[0], "switch the belt's feedback mode")
    )
    reflex = t.add(
        "reflex_enabled",
        U16,
        "grip reflex on (1) or off (0)",
        path=("reflex_enabled",),
        codes=BOOL_CODES,
        source="gateway reflex",
    )
    groups.append(
        CommandGroup(
            "reflex_enabled",
            (reflex,),
            lambda r: bool(r[0]),
            "switch the reflex; off while acting releases at the release rate",
        )
    )
    low = round(MIN_THRESHOLD_MM_S / THRESHOLD_SCALE)
    high = round(MAX_THRESHOLD_MM_S / THRESHOLD_SCALE)
    threshold = t.add(
        "reflex_threshold_mm_s",
        U16,
        "slip speed above which the reflex acts",
        unit="mm/s",
        scale=THRESHOLD_SCALE,
        low=low,
        high=high,
        path=("reflex_threshold_mm_s",),
        source="gateway reflex configuration",
    )
    groups.append(
        CommandGroup(
            "reflex_threshold_mm_s",
            (threshold,),
            _threshold,
            "set the reflex threshold (its hysteresis is kept below half of it)",
        )
    )
    pair = []
    for sub, name in ((1, "e_min"), (2, "e_max")):
        profile = profile_source("emg", obj.EMG_CALIBRATION, sub)
        # One short of the sentinel, so what is written reads back unchanged.
        high = min(profile.high, profile.type.high)
        pair.append(
            t.add(
                f"emg_{name}_uv",
                None,
                f"EMG calibration {name}",
                low=profile.low,
                high=high,
                path=(f"emg_{name}_uv",),
                profile=profile,
                source="gateway EMG calibration",
            )
        )
    groups.append(
        CommandGroup(
            "emg_calibration",
            tuple(pair),
            _calibration,
            "set the EMG calibration: used at once and written to the EMG node (2220h) over SDO",
        )
    )
    phase = t.add(
        "emg_calibrate",
        U16,
        "EMG calibration phase (reads the last one asked for, 0 none)",
        path=("emg_calibrate",),
        codes=CALIBRATE_CODES,
        default=0,
        source="last accepted write",
    )
    groups.append(
        CommandGroup(
            "emg_calibrate",
            (phase,),
            lambda r: CALIBRATION_PHASES[r[0] - 1],
            "record the rest or maximum phase, finish (derive e_min/e_max) or cancel",
        )
    )
    restart = t.add(
        "restart_node",
        U16,
        "NMT reset of one node (reads the last one asked for, 0 none)",
        path=("restart_node",),
        codes=RESTART_CODES,
        default=0,
        source="last accepted write",
    )
    groups.append(
        CommandGroup(
            "restart_node",
            (restart,),
            lambda r: KINDS[r[0] - 1],
            "reset the node; the gateway provisions and starts it again (a device node: "
            "by its name over MQTT, docs/telemetry.md)",
        )
    )
    return tuple(t.registers), tuple(groups)


@dataclass(frozen=True, slots=True)
class DeviceRegister:
    """A device node's object at configured input registers (`[[modbus.registers]]`).

    The object's value as the register type carries it: integers exact (one short of the
    sentinel at most: an UNSIGNED16 of 65535 in a uint16 reads 65534), float32 as IEEE 754
    high word first; unknown (not received yet, or the node not operational: no stale
    value is served as live) reads the sentinel, float32 a quiet NaN."""

    config: ModbusRegister
    type: WordType | None  # None: float32

    @property
    def name(self) -> str:
        return f"{self.config.node}.{self.config.key}"

    @property
    def address(self) -> int:
        return self.config.address

    @property
    def end(self) -> int:
        return self.config.end

    def value_of(self, snapshot: Snapshot | None) -> Any:
        """The object's value in `snapshot` (None: unknown, or the node not operational)."""
        if snapshot is None:
            return None
        node = snapshot.nodes.get(self.config.node)
        device = snapshot.devices.get(self.config.node)
        if node is None or device is None or node.phase is not NodePhase.OPERATIONAL:
            return None
        for obj_, value in zip(device.objects, device.values, strict=True):
            if obj_.key == self.config.key:
                return value
        return None

    def encode(self, snapshot: Snapshot | None) -> list[int]:
        return self.encode_value(self.value_of(snapshot))

    def encode_value(self, value: Any) -> list[int]:
        """`value` (None: unknown) in the register's type."""
        if self.type is None:
            return float32_words(value)
        if isinstance(value, int):  # (a BOOLEAN too)
            word_type = self.type
            return to_words(word_type, min(word_type.high, max(word_type.low, int(value))))
        return to_words(self.type, None)

    def command(self, words: Sequence[int]) -> Command:
        """A client's write (a holding register): `write_object` with the value the words
        carry, checked against what the object accepts (ILLEGAL_VALUE otherwise)."""
        entry = self.config
        real = entry.data_type.startswith("REAL")
        value: int | float
        if self.type is None:
            number = float(struct.unpack(">f", struct.pack(">HH", *words))[0])
            whole = math.isfinite(number) and number.is_integer()
            value = int(number) if whole and not real else number
        else:
            value = words_to_int(self.type, words)
        low, high = entry.limits
        why = ""
        if isinstance(value, float) and not math.isfinite(value):
            why = "not a finite number"
        elif isinstance(value, float) and not real:
            why = f"not an integer ({entry.data_type})"
        elif not low <= value <= high:
            why = f"outside {low:g}..{high:g}"
        if why:
            raise RegisterError(
                ExceptionCode.ILLEGAL_VALUE, f"{self.name} ({entry.name}): {value} is {why}"
            )
        return Command("write_object", {"node": entry.node, "object": entry.key, "value": value})


def float32_words(value: Any) -> list[int]:
    """A number as IEEE 754 single precision, high word first; None (unknown): quiet NaN,
    beyond its range: ±infinity."""
    if value is None or isinstance(value, str):
        value = math.nan
    number = float(value)
    if math.isfinite(number) and abs(number) > FLOAT32_MAX:
        number = math.copysign(math.inf, number)
    bits = int.from_bytes(struct.pack(">f", number), "big")
    return [bits >> 16, bits & 0xFFFF]


FLOAT32_MAX = 3.4028234663852886e38
_DEVICE_WORD_TYPES: dict[str, WordType | None] = {
    "int16": I16,
    "uint16": U16,
    "int32": I32,
    "uint32": U32,
    "float32": None,
}


def register_map_for(config: GatewayConfig) -> RegisterMap:
    """The map a gateway with `config` serves: the fixed map, and the configuration's
    device objects (the fixed map itself when it names none)."""
    if not config.modbus_registers and not config.modbus_holding:
        return register_map()
    fixed = register_map()
    if max(fixed.input_count, fixed.holding_count) > MODBUS_DEVICE_BASE:  # never: one read
        raise ValueError(f"the fixed map reaches past {MODBUS_DEVICE_BASE}")
    return RegisterMap(
        fixed.inputs,
        fixed.holding,
        fixed.groups,
        device_registers=tuple(
            DeviceRegister(e, _DEVICE_WORD_TYPES[e.type]) for e in config.modbus_registers
        ),
        device_holding=tuple(
            DeviceRegister(e, _DEVICE_WORD_TYPES[e.type]) for e in config.modbus_holding
        ),
        source=config.source,
    )


@functools.lru_cache(maxsize=1)
def register_map() -> RegisterMap:
    """The map (built once: the shipped profiles do not change while a process runs)."""
    holding, groups = _holding()
    return RegisterMap(_inputs(), holding, groups)


def settings_of(
    gateway: Gateway | GatewayEdge, last_actions: Mapping[str, str] | None = None
) -> dict[str, Any]:
    """The gateway's current settings for the holding registers.

    Read from another thread without locks: each is one attribute holding an
    immutable value (enum, bool, frozen dataclass) that the gateway's thread
    replaces whole, so a write is visible as soon as its CommandResult arrives.
    """
    if isinstance(gateway, GatewayEdge):
        gateway = gateway.gateway
    reflex = gateway.arbiter.reflex
    settings: dict[str, Any] = {
        "feedback_mode": gateway.feedback.mode.value,
        "reflex_enabled": reflex.enabled,
        "reflex_threshold_mm_s": reflex.config.threshold_mm_s,
    }
    decoder = gateway.emg_decoder
    if decoder is not None:
        calibration = decoder.calibration
        settings["emg_e_min_uv"] = calibration.e_min_uv
        settings["emg_e_max_uv"] = calibration.e_max_uv
    for entry in gateway.config.modbus_holding:  # a device object: the value last sent to it
        link = gateway.links[gateway.config.nodes[entry.node].node_id]
        settings[f"{entry.node}.{entry.key}"] = link.written.get((entry.index, entry.subindex))
    settings.update(last_actions or {})
    return settings

"""The object-dictionary store a device's SDO server, PDOs and behaviour share.

One store per device keeps the current value of every entry. The SDO path
(`sdo_read`/`sdo_write`) enforces what a bus client may do: existence,
access type, length, value limits from the EDS, then object-specific checks
registered by the protocol engines and the application. The device side
(`get`/`set`) bypasses the access checks, as firmware writing its own
process data does, and notifies listeners so mapped TPDOs see changes.

"Non-volatile memory" (objects 1010h/1011h) is a dict that survives resets
of this object, which is what a reset node / reset communication must honour.

Defaults written `$NODEID+...` in the EDS (COB-IDs) follow `node_id`: a node
whose node-ID LSS changed gets its new COB-IDs at the next reset, and 1010h
stores such an entry only when it differs from that default, so a stored
default keeps following the node-ID (as CANopenNode does).
"""

from __future__ import annotations

from collections.abc import Callable, Container, Iterator
from dataclasses import dataclass

import canopen.objectdictionary as cod
from canopen.objectdictionary import ODArray, ODRecord, ODVariable
from canopen.objectdictionary import datatypes as dt

from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.profiles import objects as obj

Key = tuple[int, int]
Value = int | float | str | bytes
# (index, subindex, new value) -> None; raise SdoAbort to refuse a write.
Validator = Callable[[int, int, Value], None]
Listener = Callable[[int, int, Value], None]
# The indices a listener on every index cares about; None: all of them.
Interest = Container[int] | None
# A command object acts on a write instead of storing it (1010h "save", 1003h:00 = 0).
Command = Callable[[int, Value], None]

DATA_TYPE_AREA_END = 0x0020  # 0001h..001Fh: static data types
COMMUNICATION_AREA = range(0x1000, 0x2000)
APPLICATION_AREA = range(0x2000, 0xA000)
_STORE_SUB_AREAS = {
    1: (COMMUNICATION_AREA, APPLICATION_AREA),
    2: (COMMUNICATION_AREA,),
    3: (APPLICATION_AREA,),
}


@dataclass(slots=True)
class Entry:
    """One sub-index: its EDS description and current value."""

    var: ODVariable
    value: Value

    @property
    def readable(self) -> bool:
        return self.var.access_type in ("ro", "rw", "rwr", "rww", "const")

    @property
    def writable(self) -> bool:
        return self.var.access_type in ("wo", "rw", "rwr", "rww")

    @property
    def is_parameter(self) -> bool:
        """Stored by 1010h: configuration, not process data."""
        return self.writable and not self.var.pdo_mappable


def _default_of(var: ODVariable) -> Value:
    if var.default is not None:
        return var.default
    if var.data_type in dt.INTEGER_TYPES or var.data_type in dt.FLOAT_TYPES:
        return 0
    if var.data_type in (dt.VISIBLE_STRING, dt.UNICODE_STRING):
        return ""
    return b""


def _iter_variables(od: cod.ObjectDictionary) -> Iterator[ODVariable]:
    for index in sorted(od.indices):
        item = od[index]
        if isinstance(item, ODVariable):
            yield item
        elif isinstance(item, (ODRecord, ODArray)):
            for sub in sorted(item.subindices):
                yield item.subindices[sub]


class ObjectStore:
    """Current values of a device's object dictionary, with CiA 301 write checks."""

    def __init__(self, od: cod.ObjectDictionary, node_id: int = 0):
        """`node_id`: the one `od`'s `$NODEID` defaults were resolved for."""
        self.od = od
        self._entries: dict[Key, Entry] = {}
        self._objects: set[int] = set()
        for var in _iter_variables(od):
            self._entries[(var.index, var.subindex)] = Entry(var, _default_of(var))
            self._objects.add(var.index)
        self._validators: dict[int, list[Validator]] = {}
        self._listeners: list[tuple[Listener, Interest]] = []
        self._listeners_by_index: dict[int, list[Listener]] = {}
        self._commands: dict[int, Command] = {}
        self.nvm: dict[Key, Value] = {}
        # How many writes changed a value (or re-wrote one as a command): a cache of
        # anything derived from the dictionary is valid while this count stays the same.
        self.changes = 0
        self._od_node_id = node_id
        self.node_id = node_id  # the one `default` computes `$NODEID` defaults for
        self.add_command(obj.STORE_PARAMETERS, self._on_store)
        self.add_command(obj.RESTORE_DEFAULTS, self._on_restore)

    # -- structure ---------------------------------------------------------
    def has(self, index: int, subindex: int = 0) -> bool:
        return (index, subindex) in self._entries

    def entry(self, index: int, subindex: int = 0) -> Entry:
        try:
            return self._entries[(index, subindex)]
        except KeyError:
            if index not in self._objects:
                raise SdoAbort(AbortCode.NO_OBJECT, f"object 0x{index:04X}") from None
            raise SdoAbort(AbortCode.NO_SUBINDEX, f"0x{index:04X}:{subindex:02X}") from None

    def keys(self) -> Iterator[Key]:
        return iter(self._entries)

    def indices(self) -> list[int]:
        return sorted(self._objects)

    # -- device side -------------------------------------------------------
    def get(self, index: int, subindex: int = 0) -> Value:
        # The dictionary lookup inline: a node reads its objects many times per packet.
        entry = self._entries.get((index, subindex))
        return (entry or self.entry(index, subindex)).value

    def set(self, index: int, subindex: int, value: Value) -> None:
        """Write from the device itself: no access check, listeners notified on change."""
        entry = self._entries.get((index, subindex)) or self.entry(index, subindex)
        if entry.value == value:
            return
        entry.value = value
        self._notify(index, subindex, value)

    def _notify(self, index: int, subindex: int, value: Value) -> None:
        self.changes += 1
        for listener, interest in self._listeners:
            if interest is None or index in interest:
                listener(index, subindex, value)
        for listener in self._listeners_by_index.get(index, ()):
            listener(index, subindex, value)

    def encode(self, index: int, subindex: int = 0) -> bytes:
        entry = self.entry(index, subindex)
        return entry.var.encode_raw(entry.value)

    def size_bits(self, index: int, subindex: int = 0) -> int:
        return len(self.entry(index, subindex).var)

    def add_validator(self, index: int, validator: Validator) -> None:
        self._validators.setdefault(index, []).append(validator)

    def add_listener(
        self,
        listener: Listener,
        indices: tuple[int, ...] | None = None,
        *,
        interest: Interest = None,
    ) -> None:
        """Call `listener` on every change, or only on changes of `indices`.

        `interest` (with no `indices`): a container the caller keeps up to date, of the
        indices whose changes the listener acts on; the store skips the call for the
        others. Unlike `indices` the set may change, and the listener keeps its place
        among the listeners of every change (they are called in the order they came).
        """
        if indices is None:
            self._listeners.append((listener, interest))
        else:
            for index in indices:
                self._listeners_by_index.setdefault(index, []).append(listener)

    def add_command(self, index: int, command: Command) -> None:
        """Writes to `index` call `command(subindex, value)` and are not stored."""
        self._commands[index] = command

    # -- bus side (SDO) ----------------------------------------------------
    def sdo_read(self, index: int, subindex: int) -> bytes:
        entry = self.entry(index, subindex)
        if index < DATA_TYPE_AREA_END:
            # Static data types (dummies for mapping): CiA 301 answers their length
            # in bits as UNSIGNED32.
            return len(entry.var).to_bytes(4, "little")
        if not entry.readable:
            raise SdoAbort(AbortCode.WRITE_ONLY, f"0x{index:04X}:{subindex:02X} is write-only")
        return entry.var.encode_raw(entry.value)

    def sdo_write(self, index: int, subindex: int, data: bytes) -> None:
        entry = self.entry(index, subindex)
        if not entry.writable:
            raise SdoAbort(AbortCode.READ_ONLY, f"0x{index:04X}:{subindex:02X} is read-only")
        value = self.decode(entry, data)
        self.check_limits(entry, value)
        for validator in self._validators.get(index, ()):
            validator(index, subindex, value)
        command = self._commands.get(index)
        if command is not None:
            command(subindex, value)
        elif entry.value == value:
            # Writing the current value is accepted and still notifies: writing
            # a signature twice or re-writing 6040h are meaningful commands.
            self._notify(index, subindex, value)
        else:
            self.set(index, subindex, value)

    @staticmethod
    def decode(entry: Entry, data: bytes) -> Value:
        var = entry.var
        if var.fixed_size:
            expected = len(var) // 8
            if len(data) != expected:
                raise SdoAbort(
                    AbortCode.LENGTH_MISMATCH,
                    f"0x{var.index:04X}:{var.subindex:02X} takes {expected} bytes, got {len(data)}",
                )
        value = var.decode_raw(data)
        if isinstance(value, float) and value != value:  # NaN never enters the dictionary
            raise SdoAbort(AbortCode.INVALID_VALUE, "NaN")
        return value

    @staticmethod
    def check_limits(entry: Entry, value: Value) -> None:
        var = entry.var
        if not isinstance(value, int | float):
            return
        if var.max is not None and value > var.max:
            raise SdoAbort(AbortCode.VALUE_TOO_HIGH, f"{value} > {var.max}")
        if var.min is not None and value < var.min:
            raise SdoAbort(AbortCode.VALUE_TOO_LOW, f"{value} < {var.min}")

    # -- defaults and non-volatile memory ------------------------------------
    def default(self, entry: Entry) -> Value:
        """The EDS default of `entry`, a `$NODEID` one for the current `node_id`."""
        value = _default_of(entry.var)
        if entry.var.relative and isinstance(value, int):
            return value - self._od_node_id + self.node_id
        return value

    def load_defaults(self, area: range) -> None:
        """Reset an area to EDS defaults overlaid with what 1010h stored."""
        for (index, sub), entry in self._entries.items():
            if index in area:
                key = (index, sub)
                value = self.nvm.get(key, self.default(entry))
                self.set(index, sub, value)

    def _on_store(self, subindex: int, value: Value) -> None:
        self._check_signature(subindex, value, obj.STORE_SIGNATURE)
        for (index, sub), entry in self._entries.items():
            if (
                entry.is_parameter
                and self._in(index, subindex)
                and index not in (obj.STORE_PARAMETERS, obj.RESTORE_DEFAULTS)
            ):
                if entry.var.relative and entry.value == self.default(entry):
                    self.nvm.pop((index, sub), None)  # keeps following the node-ID
                else:
                    self.nvm[(index, sub)] = entry.value

    def _on_restore(self, subindex: int, value: Value) -> None:
        """Forget stored values; the defaults take effect at the next reset (CiA 301)."""
        self._check_signature(subindex, value, obj.RESTORE_SIGNATURE)
        for key in [k for k in self.nvm if self._in(k[0], subindex)]:
            del self.nvm[key]

    @staticmethod
    def _in(index: int, subindex: int) -> bool:
        return any(index in area for area in _STORE_SUB_AREAS[subindex])

    @staticmethod
    def _check_signature(subindex: int, value: Value, signature: int) -> None:
        if subindex not in _STORE_SUB_AREAS:
            raise SdoAbort(AbortCode.NO_SUBINDEX)
        if value != signature:
            raise SdoAbort(AbortCode.CANNOT_TRANSFER, "wrong signature for store/restore")

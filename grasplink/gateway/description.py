"""The bus description's per-node keys: the file a node is built from, what it must be,
whether the network waits for it, and what is written to it before it starts.

A `[nodes.NAME]` table (docs/gateway.md, "Bus description"):

    node_id = 0x30
    dcf = "vendor/gripper.dcf"            # or eds = "..."; relative to the config file
    identity = { vendor_id = 0x360, product_code = 0x1 }   # checked from 1018h first
    mandatory = true                      # the network is not started without it
    [nodes.NAME.sdo]                      # written after the DCF values, before the start
    "6060sub0" = 3

Every object the table names is checked against the node's dictionary here, before
the bus is touched: it exists, it is writable, the value fits its type and limits.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import canopen
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, datatypes

from grasplink.core.frames import CAN_ID_MASK
from grasplink.core.params import Params
from grasplink.errors import ConfigError
from grasplink.profiles import find_variable, object_key

#: identity keys -> their 1018h sub-index (CiA 301 identity object)
IDENTITY_SUBS = {"vendor_id": 1, "product_code": 2, "revision": 3, "serial": 4}
_WRITABLE = ("rw", "wo", "rww", "rwr")


@dataclass(frozen=True)
class Identity:
    """What 1018h must read: (sub-index, value) for each key the description gives."""

    expected: tuple[tuple[int, int], ...]

    def mismatch(self, read: Mapping[int, int]) -> str | None:
        """Why `read` (sub-index -> value) is not this identity; None when it is."""
        names = {sub: name for name, sub in IDENTITY_SUBS.items()}
        wrong = [
            f"{names[sub]} 0x{read.get(sub, 0):X}, expected 0x{value:X}"
            for sub, value in self.expected
            if read.get(sub) != value
        ]
        return "; ".join(wrong) or None


@dataclass(frozen=True)
class SdoWrite:
    """One value written to a node over SDO before it starts, encoded by its dictionary."""

    index: int
    subindex: int
    data: bytes
    what: str


def dictionary(
    p: Params, key: str, path: Path, node_id: int
) -> tuple[canopen.ObjectDictionary, tuple[str, ...]]:
    """The node's object dictionary as the field loader builds it, and its warnings (the
    quirks it repaired, `file:line: what`); a file no dictionary comes from is reported
    at `key`."""
    from grasplink.profiles.field import load_object_dictionary

    try:
        od, warnings = load_object_dictionary(path, node_id)
    except ConfigError as exc:
        raise p.error(key, str(exc)) from None
    return od, tuple(str(w) for w in warnings)


def identity(p: Params) -> Identity | None:
    if not p.has("identity"):
        return None
    t = p.table_of("identity")
    expected = tuple(
        (sub, t.integer(name, low=0, high=0xFFFFFFFF))
        for name, sub in IDENTITY_SUBS.items()
        if t.has(name)
    )
    t.finish()
    if not expected:
        raise p.error("identity", f"name at least one of {', '.join(IDENTITY_SUBS)}")
    return Identity(expected)


def sdo_writes(p: Params, od_of: Callable[[], canopen.ObjectDictionary]) -> tuple[SdoWrite, ...]:
    """The `[sdo]` table's writes in the order given, each checked against the dictionary."""
    t = p.table_of("sdo")
    od = od_of()
    out = []
    for key in t.table:
        value = t.raw(key)
        try:
            index, subindex = object_key(key)
            var = _variable(od, index, subindex)
            data = encode(var, value)
        except ConfigError as exc:
            raise t.error(key, str(exc)) from None
        out.append(SdoWrite(index, subindex, data, f"{var.name} = {value!r}"))
    t.finish()
    return tuple(out)


PDO_COMM = ((0x1400, 0x1600), (0x1800, 0x1A00))  # (first communication, first mapping) objects
PDO_COUNT = 512  # PDOs of each direction (CiA 301)
COB_ID_INVALID = 0x80000000


def dcf_writes(od: canopen.ObjectDictionary) -> tuple[SdoWrite, ...]:
    """A DCF's configured values (ParameterValue) as a CiA 302 master writes its concise
    DCF: every writable object the file gives one, in index order; a PDO's by the CiA 301
    mapping procedure (COB-ID invalid, count 0, entries, count, parameters, COB-ID), as a
    device refuses a mapping changed while its PDO is valid."""
    out: list[SdoWrite] = []
    pdo_objects = {base + n for bases in PDO_COMM for base in bases for n in range(PDO_COUNT)}
    for index in sorted(od.indices):
        if index in pdo_objects:
            continue
        out += [_dcf_write(var) for var in _configured(od, index)]
    for comm_base, map_base in PDO_COMM:
        for n in range(PDO_COUNT):
            out += _pdo_writes(od, comm_base + n, map_base + n)
    return tuple(out)


def tpdo_transmission_type(
    od: canopen.ObjectDictionary, can_id: int, writes: tuple[SdoWrite, ...]
) -> int | None:
    """The transmission type the TPDO at `can_id` has once configured: its file's (a DCF's
    value, else the default), then the description's last `[sdo]` write of it; None when
    no TPDO of the file goes at that COB-ID."""
    for n in range(PDO_COUNT):
        comm = PDO_COMM[1][0] + n
        if comm not in od or not isinstance(od[comm], ODRecord | ODArray):
            continue
        params = od[comm]
        if 1 not in params.subindices or 2 not in params.subindices:  # type: ignore[union-attr]
            continue
        cob = _current(params[1])  # type: ignore[index]
        if cob is None or int(cob) & CAN_ID_MASK != can_id:
            continue
        kind = _current(params[2])  # type: ignore[index]
        for write in writes:
            if (write.index, write.subindex) == (comm, 2):
                kind = write.data[0]
        return None if kind is None else int(kind)
    return None


def _current(var: ODVariable) -> Any:
    return var.value if var.value is not None else var.default


def _configured(od: canopen.ObjectDictionary, index: int) -> list[ODVariable]:
    """The writable variables of `index` the DCF gives a ParameterValue."""
    if index not in od:
        return []
    entry = od[index]
    variables = [entry] if isinstance(entry, ODVariable) else list(entry.values())
    return [v for v in variables if v.value is not None and v.access_type in _WRITABLE]


def _dcf_write(var: ODVariable, value: Any = None, what: str = "") -> SdoWrite:
    value = var.value if value is None else value
    return SdoWrite(var.index, var.subindex, var.encode_raw(value), what or f"{var.name} (DCF)")


def _pdo_writes(od: canopen.ObjectDictionary, comm: int, mapping: int) -> list[SdoWrite]:
    comm_vars = {v.subindex: v for v in _configured(od, comm)}
    map_vars = {v.subindex: v for v in _configured(od, mapping)}
    if not comm_vars and not map_vars:
        return []
    if comm not in od or 1 not in od[comm]:  # type: ignore[operator]
        return [_dcf_write(v) for v in (*comm_vars.values(), *map_vars.values())]
    cob = od[comm][1]  # type: ignore[index]
    final_cob = cob.value if cob.value is not None else cob.default
    out = []
    label = f"PDO 0x{comm:04X}"
    if final_cob is not None and cob.access_type in _WRITABLE:
        out.append(_dcf_write(cob, int(final_cob) | COB_ID_INVALID, f"{label} off (DCF)"))
    count = od[mapping][0] if mapping in od else None  # type: ignore[index]
    if map_vars and count is not None and count.access_type in _WRITABLE:
        # (a read-only count is a static mapping: the device's, never written)
        map_vars.pop(0, None)
        final_count = count.value if count.value is not None else count.default
        out.append(_dcf_write(count, 0, f"{label} mapping cleared (DCF)"))
        out += [_dcf_write(v) for _, v in sorted(map_vars.items())]
        if final_count is not None:
            out.append(_dcf_write(count, int(final_count), f"{label} maps {final_count} (DCF)"))
    out += [_dcf_write(v) for sub, v in sorted(comm_vars.items()) if sub != 1]
    if final_cob is not None and cob.access_type in _WRITABLE:
        out.append(_dcf_write(cob, int(final_cob), f"{label} on (DCF)"))
    return out


def _variable(od: canopen.ObjectDictionary, index: int, subindex: int) -> ODVariable:
    var = find_variable(od, index, subindex)
    if var.access_type not in _WRITABLE:
        raise ConfigError(f"{var.name} (0x{index:04X}sub{subindex:X}) is {var.access_type}")
    return var


def encode(var: ODVariable, value: Any) -> bytes:
    """`value` in `var`'s data type, within its limits; ConfigError naming why not."""
    integer = var.data_type in datatypes.INTEGER_TYPES
    if integer and (isinstance(value, bool) or not isinstance(value, int)):
        raise ConfigError(f"{var.name} takes an integer, got {value!r}")
    if var.data_type in datatypes.FLOAT_TYPES and (
        isinstance(value, bool) or not isinstance(value, int | float)
    ):
        raise ConfigError(f"{var.name} takes a number, got {value!r}")
    if var.data_type == datatypes.VISIBLE_STRING and not isinstance(value, str):
        raise ConfigError(f"{var.name} takes a string, got {value!r}")
    low, high = var.min, var.max
    if isinstance(value, int | float) and (
        (low is not None and value < low) or (high is not None and value > high)
    ):
        raise ConfigError(f"{var.name} = {value} is outside {low}..{high}")
    try:
        return var.encode_raw(value)
    except (ValueError, OverflowError, TypeError, struct.error) as exc:
        raise ConfigError(f"{var.name} = {value!r} does not fit its type: {exc}") from None

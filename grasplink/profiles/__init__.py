"""Device profiles: the shipped EDS files and how to load them.

The .eds files next to this module (one per node kind, `kinds.py`) are the
source of truth for every object a grasplink node has (type, access, limits,
default, unit). Devices and the gateway load them through `load_profile`,
which validates first so a broken file fails with an EdsError naming file,
section and key instead of canopen silently dropping a default.

canopen is imported lazily: `grasplink.profiles.objects` is imported by
almost everything and should stay cheap.
"""

from __future__ import annotations

import functools
import re
from pathlib import Path
from typing import TYPE_CHECKING

from grasplink.errors import ConfigError, EdsError
from grasplink.profiles.eds import validate_eds
from grasplink.profiles.kinds import KINDS, node_kind, unknown_kind

if TYPE_CHECKING:
    import canopen
    from canopen.objectdictionary import ODVariable

__all__ = [
    "eds_path",
    "find_variable",
    "load_profile",
    "object_limits",
    "shipped_profile",
    "validate_eds",
]

_PROFILE_DIR = Path(__file__).resolve().parent


def eds_path(kind: str) -> Path:
    """Path of the shipped EDS of a node kind (`kinds.py`)."""
    return _PROFILE_DIR / node_kind(kind).eds


def load_profile(kind_or_path: str | Path, node_id: int) -> canopen.ObjectDictionary:
    """An object dictionary, $NODEID resolved to `node_id`: a shipped profile validated
    strictly and imported with canopen; any other file through the field loader
    (`field.py`: its quirks repaired, warnings dropped here: `field.load_object_dictionary`
    returns them).

    `kind_or_path` is a device kind or a path to an .eds/.dcf file (a Path, or
    a string containing a path separator or ending in .eds/.dcf).
    """
    if isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise ConfigError(f"node-ID {node_id!r} is outside 1..127")
    path = _resolve(kind_or_path)
    if path.resolve().parent != _PROFILE_DIR:  # a vendor's file: as it is in the field
        from grasplink.profiles.field import load_object_dictionary

        return load_object_dictionary(path, node_id)[0]
    validate_eds(path)
    from canopen.objectdictionary import import_od

    try:
        return import_od(str(path), node_id=node_id)
    except Exception as exc:  # canopen raises bare KeyError/ValueError/configparser errors
        raise EdsError(str(path), None, None, f"canopen cannot import it: {exc!r}") from exc


# "6060sub0", "2100sub1A" (sub-index in hex, as EDS section names spell it), or "6060"
_OBJECT_KEY = re.compile(r"(?:0x)?([0-9A-Fa-f]{4})(?:sub([0-9A-Fa-f]{1,2}))?")


def object_key(text: str) -> tuple[int, int]:
    """(index, subindex) of "6060sub0" / "6060" (sub-index 0); ConfigError otherwise."""
    match = _OBJECT_KEY.fullmatch(text.strip())
    if match is None:
        raise ConfigError(f"{text!r} is not an object: write it as 6060sub0 (index, sub in hex)")
    return int(match[1], 16), int(match[2] or "0", 16)


def od_variable(od: canopen.ObjectDictionary, index: int, subindex: int = 0) -> ODVariable:
    """The variable at index:subindex (a plain VAR's own entry when it has no sub-indices)."""
    from canopen.objectdictionary import ODArray, ODRecord

    entry = od[index]
    if isinstance(entry, ODArray | ODRecord):
        return entry[subindex]
    return entry


def find_variable(od: canopen.ObjectDictionary, index: int, subindex: int = 0) -> ODVariable:
    """The variable at index:subindex; ConfigError saying which of the two the file lacks."""
    from canopen.objectdictionary import ODArray, ODRecord

    if index not in od:
        raise ConfigError(f"the node's dictionary has no object 0x{index:04X}")
    entry = od[index]
    # (canopen makes up any sub-index of an ARRAY from its first: the file's are the real ones)
    declared = entry.subindices if isinstance(entry, ODArray | ODRecord) else {0: entry}
    if subindex not in declared:
        raise ConfigError(f"object 0x{index:04X} has no sub-index {subindex}")
    return od_variable(od, index, subindex)


def od_default(od: canopen.ObjectDictionary, index: int, subindex: int = 0) -> int:
    """An integer entry's default; the loader guarantees one (EdsError otherwise)."""
    value = od_variable(od, index, subindex).default
    if value is None:
        raise EdsError("<profile>", f"{index:04X}sub{subindex}", "DefaultValue", "is missing")
    return int(value)


@functools.lru_cache(maxsize=64)
def shipped_profile(kind: str, node_id: int) -> canopen.ObjectDictionary:
    """A shipped profile parsed once per process and node-ID, shared: read it, never write
    it (a device's own store is built from `load_profile`'s fresh copy).

    Bounded: four kinds at a handful of node-IDs each.
    """
    if kind not in KINDS:  # a vendor's file may change between two loads: never cached
        raise ConfigError(unknown_kind(kind))
    return load_profile(kind, node_id)


@functools.lru_cache(maxsize=256)
def object_limits(kind: str, index: int, subindex: int = 0) -> tuple[int, int]:
    """(low, high) a shipped profile's object accepts: its EDS limits, else its type's range.

    Cached: the shipped profiles do not change while a process runs.
    """
    entry = od_variable(shipped_profile(kind, node_kind(kind).node_id), index, subindex)
    low, high = variable_limits(entry)
    return int(low), int(high)


def variable_limits(entry: ODVariable) -> tuple[float, float]:
    """(low, high) an object accepts: its file's LowLimit/HighLimit, else its type's range."""
    from grasplink.profiles.eds import _types

    dtype = _types()[int(entry.data_type or 0)]
    low = entry.min if entry.min is not None else dtype.low
    high = entry.max if entry.max is not None else dtype.high
    return low, high


def _resolve(kind_or_path: str | Path) -> Path:
    if isinstance(kind_or_path, Path):
        return kind_or_path
    text = str(kind_or_path)
    if text in KINDS:
        return eds_path(text)
    if "/" in text or "\\" in text or text.lower().endswith((".eds", ".dcf")):
        return Path(text)
    raise ConfigError(f"{unknown_kind(text)} (or a path to an .eds file)")

"""EDS and DCF files as they are found in the field (CiA 306), loaded the way canopen and Lely do.

Our own EDS files go through the strict `eds.validate_eds`; a vendor's file
or one written by another open-source stack does not pass it, and canopen's
importer crashes on some of its quirks (an empty VendorNumber, a missing
Dummy0001, a duplicate key, a byte-order mark) and silently drops others (an
empty or octal DefaultValue, a `[1018SUB1]` section, a lower-case
`defaultvalue`, the sub-indices of a CompactSubObj array without a [Name]
section). So `load_object_dictionary` reads the file itself, line by line,
and hands canopen's importer (`canopen.objectdictionary.import_od`) a
normalised copy it cannot misread: every quirk it repairs becomes a
`LoadWarning` naming file and line, and only a file from which no object
dictionary can be built raises an `EdsError` naming file and line.

What is read as Lely reads it where canopen has no answer: CompactSubObj
arrays and records get every sub-index (names from [xxxxName], DCF values
from [xxxxValue], sub-index 0 = the count, read-only); a REAL given as an
integer is its IEEE 754 bit pattern; a number with a leading zero is octal
(CiA 306); Dummy entries beyond 0007h in [DummyUsage] become dummy objects
too. docs/eds_files.md lists every repair and every error.
"""

from __future__ import annotations

import codecs
import io
import re
import struct
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, NoReturn

from grasplink.errors import ConfigError, EdsError
from grasplink.profiles.eds import (
    ACCESS_TYPES,
    DATA_TYPES,
    DEVICE_INFO_NUMBERS,
    OBJECT_KEYS,
    OBJECT_LISTS,
)

if TYPE_CHECKING:
    from canopen.objectdictionary import ObjectDictionary

    from grasplink.core.params import Params

__all__ = ["LoadWarning", "load_object_dictionary", "node_file"]

_VAR, _ARRAY, _RECORD, _DOMAIN = 0x7, 0x8, 0x9, 0x2
_DEFINITIONS = {0x0: "NULL", 0x5: "DEFTYPE", 0x6: "DEFSTRUCT"}
_UNSIGNED8, _DOMAIN_TYPE = 0x0005, 0x000F
_MANDATORY_NAMES = {0x1000: "device type", 0x1001: "error register", 0x1018: "identity"}
_REQUIRED_SECTIONS = ("FileInfo", "DeviceInfo", "DummyUsage")

_FILE_INFO_KEYS = (
    "FileName",
    "FileVersion",
    "FileRevision",
    "EDSVersion",
    "Description",
    "CreationTime",
    "CreationDate",
    "CreatedBy",
    "ModificationTime",
    "ModificationDate",
    "ModifiedBy",
    "LastEDS",
)
_DEVICE_INFO_STRINGS = ("VendorName", "ProductName", "OrderCode")
_DEVICE_INFO_NUMBERS = (*DEVICE_INFO_NUMBERS, "CompactPDO")  # (read, and dropped: see below)
_COMMISSIONING_KEYS = (
    "NodeID",
    "NodeName",
    "Baudrate",
    "NetNumber",
    "NetworkName",
    "CANopenManager",
    "LSS_SerialNumber",
)
_OBJECT_KEYS = (
    *OBJECT_KEYS,
    # not CiA 306, but canopen reads them
    "Factor",
    "Description",
    "Unit",
)
_KEYS = {
    "FileInfo": _FILE_INFO_KEYS,
    "DeviceInfo": (*_DEVICE_INFO_STRINGS, *_DEVICE_INFO_NUMBERS),
    "DeviceComissioning": _COMMISSIONING_KEYS,
    "object": _OBJECT_KEYS,
    "list": ("SupportedObjects",),
    "entries": ("NrOfEntries",),
    "Comments": ("Lines",),
}
_NAMED_SECTIONS = {
    name.lower(): name
    for name in ("FileInfo", "DeviceInfo", "DummyUsage", "Comments", *OBJECT_LISTS)
}
_OBJECT_RE = re.compile(r"([0-9A-Fa-f]{4})")
_SUB_RE = re.compile(r"([0-9A-Fa-f]{4})sub([0-9A-Fa-f]{1,2})", re.IGNORECASE)
_EXTRA_RE = re.compile(r"([0-9A-Fa-f]{4})(name|value|denotation)", re.IGNORECASE)
_INT_RE = re.compile(r"([+-]?)(0[xX][0-9A-Fa-f]+|[0-9]+)")
_CONTROL_RE = re.compile(r"[\x00-\x08\x0b-\x1f\x7f]")
_COMMENT_RE = re.compile(r"\s;")  # canopen's inline comment: ';' after white space
_DIGITS_RE = re.compile(r"[0-9]+")
_LINE_KEY_RE = re.compile(r"line([0-9]+)", re.IGNORECASE)
_NODEID = "$NODEID"


@dataclass(frozen=True)
class LoadWarning:
    """A quirk the loader repaired: where it is and what was made of it."""

    path: str
    line: int
    message: str

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.message}"


def load_object_dictionary(
    path: str | Path, node_id: int | None = None
) -> tuple[ObjectDictionary, list[LoadWarning]]:
    """Load any CiA 306 EDS or DCF: (object dictionary, warnings in line order).

    `node_id` resolves $NODEID; without it a DCF's [DeviceComissioning] NodeID
    does, and without either node-relative values stay unresolved (canopen
    leaves their `default` None and keeps `default_raw`). The dictionary's
    `node_id` is the one used. A DCF's ParameterValue is each entry's `value`
    beside its `default`, which is what canopen's LocalNode serves first.
    Raises EdsError (file and line) only where no dictionary can be built.
    """
    if node_id is not None and (
        isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127
    ):
        raise ConfigError(f"node-ID {node_id!r} is outside 1..127")
    return _Loader(Path(path), node_id).run()


def node_file(p: Params, base: Path) -> Path | None:
    """The `eds` or `dcf` a table names (one of them), resolved against `base` (the
    folder of the file the table is in); None when it names neither."""
    eds, dcf = p.string("eds", None), p.string("dcf", None)
    if eds is not None and dcf is not None:
        raise p.error("dcf", "give eds or dcf, not both")
    name, text = ("dcf", dcf) if dcf is not None else ("eds", eds)
    if text is None:
        return None
    path = Path(text).expanduser()
    path = path if path.is_absolute() else base / path
    if not path.is_file():
        raise p.error(name, f"no such file: {path}")
    suffix = path.suffix.lower()
    if (name == "dcf") != (suffix == ".dcf") or suffix not in (".eds", ".dcf"):
        raise p.error(name, f"expected a .{name} file, got {path.name}")
    return path


# --- numbers -----------------------------------------------------------------
def _int(text: str) -> tuple[int, str | None] | None:
    """A CiA 306 integer (decimal, 0x hex, leading-0 octal): (value, note) or None."""
    match = _INT_RE.fullmatch(text.replace(" ", ""))
    if match is None:
        return None
    sign, body = match.groups()
    note = None
    if body[:2] in ("0x", "0X"):
        value = int(body, 16)
    elif len(body) > 1 and body[0] == "0":
        if set(body) <= set("01234567"):
            value = int(body, 8)
            if value != int(body, 10):
                note = f"{text!r} is read as octal {value} (CiA 306; canopen would drop it)"
        else:
            value = int(body, 10)
            note = f"{text!r} has a leading zero but is not octal: read as decimal {value}"
    else:
        value = int(body, 10)
    return (-value if sign == "-" else value), note


def _node_relative(text: str) -> tuple[int, bool, str | None] | None:
    """An integer that may be `$NODEID+n` or `n+$NODEID`: (n, relative, note) or None."""
    compact = text.replace(" ", "")
    upper = compact.upper()
    if _NODEID not in upper:
        parsed = _int(compact)
        return None if parsed is None else (parsed[0], False, parsed[1])
    if upper == _NODEID:
        rest = "0"
    elif upper.startswith(_NODEID + "+"):
        rest = compact[len(_NODEID) + 1 :]
    elif upper.endswith("+" + _NODEID):
        rest = compact[: -len(_NODEID) - 1]
    else:
        return None
    parsed = _int(rest)
    return None if parsed is None else (parsed[0], True, parsed[1])


def _collapsed(warnings: list[LoadWarning]) -> list[LoadWarning]:
    """In line order, one warning per message: a quirk on 17 lines is one line of output."""
    lines: dict[str, list[int]] = {}
    first: dict[str, LoadWarning] = {}
    for warning in sorted(warnings, key=lambda w: w.line):
        lines.setdefault(warning.message, []).append(warning.line)
        first.setdefault(warning.message, warning)
    out = []
    for message, warning in first.items():
        more = lines[message][1:]
        if more:
            shown = ", ".join(str(n) for n in more[:4]) + (", ..." if len(more) > 4 else "")
            warning = replace(warning, message=f"{message} (and {len(more)} more: lines {shown})")
        out.append(warning)
    return sorted(out, key=lambda w: w.line)


def _numbered(section: _Section) -> dict[int, _Line]:
    """A list section's numbered entries ("1=0x1000"), by number."""
    return {int(k): v for k, v in section.values.items() if _DIGITS_RE.fullmatch(k)}


class _NamedText(io.StringIO):
    """The repaired file for import_od, which picks its parser by the name's suffix."""

    name = "repaired.eds"


def _is_hex(text: str) -> bool:
    return "0x" in text.lower()


# --- the file as read ----------------------------------------------------------
@dataclass
class _Line:
    """One `key=value` line: the key as written, its value and where it is."""

    key: str
    text: str
    line: int


@dataclass
class _Section:
    """A section under its canonical name, with canonical keys."""

    name: str
    kind: str  # a named section, "object", "sub", "name", "value", "denotation", "other"
    line: int
    index: int = -1
    subindex: int = -1
    values: dict[str, _Line] = field(default_factory=dict)

    def get(self, key: str) -> _Line | None:
        return self.values.get(key)


@dataclass
class _Var:
    """One entry as canopen should see it: canonical texts, limits set afterwards."""

    name: str
    subindex: int
    line: int
    data_type: int
    access: str
    pdo: bool
    default: str | None = None
    value: str | None = None
    low: float | None = None
    high: float | None = None
    extras: dict[str, str] = field(default_factory=dict)  # StorageLocation, Factor, ...


@dataclass
class _Object:
    index: int
    name: str
    object_type: int
    line: int
    var: _Var | None = None
    subs: dict[int, _Var] = field(default_factory=dict)
    storage: str | None = None


class _Loader:
    """One load: read, repair with warnings, emit, import, finish."""

    def __init__(self, path: Path, node_id: int | None) -> None:
        self.path = path
        self.name = str(path)
        self.node_id = node_id
        self.warnings: list[LoadWarning] = []
        self.sections: dict[str, _Section] = {}
        self.raw_sections: dict[str, _Section] = {}  # unknown sections by lower-case name
        self.compact_tables: set[str] = set()  # [xxxxName]/[xxxxValue] used by a CompactSubObj

    def warn(self, line: int, message: str) -> None:
        self.warnings.append(LoadWarning(self.name, line, message))

    def fail(self, line: int, section: str | None, key: str | None, problem: str) -> NoReturn:
        raise EdsError(self.name, section, key, problem, line=line)

    def run(self) -> tuple[ObjectDictionary, list[LoadWarning]]:
        self._parse(self._lines())
        if not any(s.kind in ("object", "DeviceInfo", "list") for s in self.sections.values()):
            self.fail(1, None, None, "not a CiA 306 EDS or DCF: no [DeviceInfo] and no objects")
        for name in _REQUIRED_SECTIONS:
            if name not in self.sections:
                self.warn(1, f"no [{name}] section (CiA 306 requires it)")
        objects = self._objects()
        if not objects:
            self.fail(1, None, None, "no objects: no object dictionary can be built")
        self._check_lists(objects)
        for index, what in _MANDATORY_NAMES.items():
            if index not in objects:
                self.warn(1, f"no object {index:04X}h ({what}), which CiA 301 makes mandatory")
        text = "\n".join(self._emit(objects))
        od = self._import(text)
        self._finish(od, objects)
        return od, _collapsed(self.warnings)

    # --- reading ----------------------------------------------------------
    def _lines(self) -> list[str]:
        try:
            data = self.path.read_bytes()
        except OSError as exc:
            self.fail(1, None, None, f"cannot read file: {exc.strerror or exc}")
        text = self._decode(data)
        lines = [line.rstrip("\r") for line in text.split("\n")]
        stray = [n for n, line in enumerate(lines, 1) if _CONTROL_RE.search(line)]
        if stray:
            self.warn(
                stray[0],
                f"control characters removed on {len(stray)} line(s), the first here",
            )
            lines = [_CONTROL_RE.sub("", line) for line in lines]
        return lines

    def _decode(self, data: bytes) -> str:
        for bom, codec in ((codecs.BOM_UTF16_LE, "utf-16-le"), (codecs.BOM_UTF16_BE, "utf-16-be")):
            if data.startswith(bom):
                self.warn(1, f"{codec.upper()[:6]} file: read as text (canopen would not)")
                return data[len(bom) :].decode(codec, errors="replace")
        if data.startswith(codecs.BOM_UTF8):
            self.warn(1, "UTF-8 byte-order mark removed (canopen would not find the first section)")
            data = data[len(codecs.BOM_UTF8) :]
        try:
            return data.decode("utf-8")
        except UnicodeDecodeError as exc:
            line = data[: exc.start].count(b"\n") + 1
            self.warn(line, "not UTF-8 from this line on: the file is read as Latin-1")
            return data.decode("latin-1")

    def _parse(self, lines: list[str]) -> None:
        current: _Section | None = None
        skipping = False  # after a broken header: its keys belong to no section
        for number, raw in enumerate(lines, 1):
            line = raw.strip()
            if not line or line[0] in ";#":
                continue
            if line.startswith("["):
                end = line.find("]")
                if end < 0:
                    self.warn(number, f"broken section header {line[:40]!r}: its lines are ignored")
                    current, skipping = None, True
                    continue
                current, skipping = self._open_section(line[1:end].strip(), number), False
                continue
            cut = min((i for i in (line.find("="), line.find(":")) if i >= 0), default=-1)
            if cut <= 0:
                self.warn(number, f"line ignored: {line[:40]!r} is not key=value")
                continue
            if current is None:
                if not skipping:
                    self.warn(number, "line ignored: it is before the first section")
                    skipping = True
                continue
            value = line[cut + 1 :]
            comment = _COMMENT_RE.search(value)
            if comment:
                value = value[: comment.start()]
            self._add_key(current, line[:cut].strip(), value.strip(), number)

    def _open_section(self, raw: str, number: int) -> _Section:
        section = self._classify(raw, number)
        table = self.raw_sections if section.kind == "other" else self.sections
        key = section.name.lower() if section.kind == "other" else section.name
        previous = table.get(key)
        if previous is not None:
            self.warn(
                number,
                f"duplicate section [{raw}] (first on line {previous.line}): "
                "its keys are merged, later values win",
            )
            return previous
        table[key] = section
        return section

    def _classify(self, raw: str, number: int) -> _Section:
        lower = raw.lower()
        if lower in _NAMED_SECTIONS:
            name = _NAMED_SECTIONS[lower]
            if raw != name:
                self.warn(number, f"section [{raw}] read as [{name}]")
            kind = "list" if name in OBJECT_LISTS else name
            return _Section(name, kind, number)
        if lower in ("devicecomissioning", "devicecommissioning"):
            if raw != "DeviceComissioning":
                self.warn(
                    number, f"section [{raw}] read as [DeviceComissioning] (CiA 306 spelling)"
                )
            return _Section("DeviceComissioning", "DeviceComissioning", number)
        if match := _OBJECT_RE.fullmatch(raw):
            index = int(match.group(1), 16)
            return _Section(f"{index:04X}", "object", number, index)
        if match := _SUB_RE.fullmatch(raw):
            index, sub = int(match.group(1), 16), int(match.group(2), 16)
            if "sub" not in raw and "Sub" not in raw:
                self.warn(number, f"section [{raw}] read as [{index:04X}sub{sub:X}]")
            return _Section(f"{index:04X}sub{sub:X}", "sub", number, index, sub)
        if match := _EXTRA_RE.fullmatch(raw):
            index, kind = int(match.group(1), 16), match.group(2).lower()
            return _Section(f"{index:04X}{kind.capitalize()}", kind, number, index)
        return _Section(raw, "other", number)

    def _add_key(self, section: _Section, raw: str, text: str, number: int) -> None:
        key = self._canonical_key(section.kind, raw, number)
        previous = section.values.get(key)
        if previous is not None:
            self.warn(
                number,
                f"duplicate key {raw} in [{section.name}] (first on line {previous.line}): "
                "the later value is used",
            )
        section.values[key] = _Line(raw, text, number)

    def _canonical_key(self, kind: str, raw: str, number: int) -> str:
        loose = raw.replace(" ", "").lower()
        if kind in ("list", "name", "value") and _DIGITS_RE.fullmatch(loose):
            return str(int(loose))
        if kind == "Comments" and (match := _LINE_KEY_RE.fullmatch(loose)):
            canonical = f"Line{int(match.group(1))}"
        elif kind == "DummyUsage" and re.fullmatch(r"dummy[0-9a-f]{4}", loose):
            canonical = f"Dummy{int(loose[5:], 16):04X}"
        else:
            keys = _KEYS.get("object" if kind == "sub" else kind, ())
            if kind in ("name", "value"):
                keys = _KEYS["entries"]
            canonical = next((k for k in keys if k.lower() == loose), raw)
        if canonical != raw:
            self.warn(number, f"key {raw!r} read as {canonical!r} (canopen matches keys exactly)")
        return canonical

    # --- objects ----------------------------------------------------------
    def _objects(self) -> dict[int, _Object]:
        subs: dict[int, dict[int, _Section]] = {}
        for section in self.sections.values():
            if section.kind == "sub":
                subs.setdefault(section.index, {})[section.subindex] = section
        objects: dict[int, _Object] = {}
        for section in self.sections.values():
            if section.kind != "object":
                continue
            own = subs.pop(section.index, {})
            if section.index < 0x1000:
                self.warn(section.line, f"[{section.name}] is in the data type area: ignored")
                continue
            built = self._object(section, own)
            if built is not None:
                objects[built.index] = built
        for index, orphans in sorted(subs.items()):
            first = min(orphans.values(), key=lambda s: s.line)
            if index >= 0x1000:
                self.warn(
                    first.line, f"[{first.name}] has no object section [{index:04X}]: ignored"
                )
        for section in self.sections.values():
            if section.kind in ("name", "value"):
                owner = objects.get(section.index)
                if owner is None or section.name not in self.compact_tables:
                    self.warn(
                        section.line,
                        f"[{section.name}] ignored: [{section.index:04X}] has no CompactSubObj",
                    )
        return objects

    def _object(self, section: _Section, subs: dict[int, _Section]) -> _Object | None:
        compact = section.get("CompactSubObj")
        object_type = self._object_type(section, bool(subs) or compact is not None)
        if object_type is None:
            return None
        name = self._name(section, f"Object {section.name}")
        obj = _Object(section.index, name, object_type, section.line)
        storage = section.get("StorageLocation")
        obj.storage = storage.text if storage else None
        if object_type in (_VAR, _DOMAIN):
            if subs:
                first = min(subs.values(), key=lambda s: s.line)
                self.warn(
                    first.line,
                    f"[{section.name}] is a VAR: its {len(subs)} sub-index section(s) are ignored",
                )
            obj.var = self._var(section, 0, name, object_type == _DOMAIN)
            return obj
        count = self._compact_count(section, compact, bool(subs))
        if count:
            obj.subs = self._expand(section, name, count)
            return obj
        self._check_sub_number(section, subs)
        for subindex, sub in sorted(subs.items()):
            obj.subs[subindex] = self._var(sub, subindex, self._name(sub, f"Sub-index {subindex}"))
        if not obj.subs:
            kind = "an ARRAY" if object_type == _ARRAY else "a RECORD"
            self.warn(section.line, f"[{section.name}] is {kind} without sub-indices: loaded empty")
        elif 0 not in obj.subs:
            highest = max(obj.subs)
            self.warn(
                section.line,
                f"[{section.name}] has no sub-index 0: added as UNSIGNED8 ro = {highest}",
            )
            obj.subs[0] = _Var(
                "Highest sub-index supported",
                0,
                section.line,
                _UNSIGNED8,
                "ro",
                False,
                str(highest),
            )
        return obj

    def _object_type(self, section: _Section, has_subs: bool) -> int | None:
        entry = section.get("ObjectType")
        if entry is not None and entry.text:
            parsed = _int(entry.text)
            if parsed is None:
                self.fail(
                    entry.line,
                    section.name,
                    "ObjectType",
                    f"{entry.text!r} is not a number: the object cannot be typed",
                )
            value = parsed[0]
            if value in _DEFINITIONS:
                self.warn(
                    entry.line,
                    f"[{section.name}] is a {_DEFINITIONS[value]}, not an object: ignored",
                )
                return None
            if value not in (_VAR, _ARRAY, _RECORD, _DOMAIN):
                self.fail(
                    entry.line,
                    section.name,
                    "ObjectType",
                    f"{entry.text!r} is not VAR, ARRAY, RECORD or DOMAIN: "
                    "the object cannot be typed",
                )
            return value
        if entry is not None:
            self.warn(entry.line, f"[{section.name}] ObjectType is empty")
        if has_subs:
            self.warn(section.line, f"[{section.name}] has no ObjectType but sub-indices: a RECORD")
            return _RECORD
        return _VAR  # CiA 306: a missing ObjectType means VAR

    def _name(self, section: _Section, fallback: str) -> str:
        for key in ("ParameterName", "Denotation"):
            entry = section.get(key)
            if entry is not None and entry.text:
                if key == "Denotation":
                    self.warn(entry.line, f"[{section.name}] has no ParameterName: its Denotation")
                return entry.text
        self.warn(section.line, f"[{section.name}] has no ParameterName: named {fallback!r}")
        return fallback

    def _compact_count(self, section: _Section, compact: _Line | None, has_subs: bool) -> int:
        if compact is None:
            return 0
        parsed = _int(compact.text) if compact.text else None
        if parsed is None or not 0 <= parsed[0] <= 0xFE:
            self.warn(compact.line, f"CompactSubObj {compact.text!r} is not 0..254: ignored")
            return 0
        if has_subs and parsed[0]:
            self.warn(
                compact.line,
                f"[{section.name}] has CompactSubObj and sub-index sections: the sections are used",
            )
            return 0
        return parsed[0]

    def _check_sub_number(self, section: _Section, subs: dict[int, _Section]) -> None:
        entry = section.get("SubNumber")
        if entry is None:
            return
        parsed = _int(entry.text) if entry.text else None
        if parsed is None:
            self.warn(entry.line, f"SubNumber {entry.text!r} is not a number: ignored")
        elif parsed[0] != len(subs):
            self.warn(
                entry.line,
                f"SubNumber={entry.text} but {len(subs)} sub-index section(s): those are used",
            )

    def _expand(self, section: _Section, name: str, count: int) -> dict[int, _Var]:
        """CompactSubObj: sub-index 0 is the count, 1..count are copies of the object's entry."""
        template = self._var(section, 1, name)
        names = self._entries(section, "Name", count)
        values = self._entries(section, "Value", count)
        subs = {0: _Var("Number of entries", 0, section.line, _UNSIGNED8, "ro", False, str(count))}
        for subindex in range(1, count + 1):
            entry_name = names.get(subindex)
            var = replace(
                template,
                name=entry_name.text if entry_name and entry_name.text else f"{name}{subindex}",
                subindex=subindex,
                extras=dict(template.extras),
            )
            value = values.get(subindex)
            if value is not None:
                var.value = self._convert(value, "value", var.data_type)
            subs[subindex] = var
        return subs

    def _entries(self, section: _Section, kind: str, count: int) -> dict[int, _Line]:
        table = self.sections.get(f"{section.name}{kind}")
        if table is None:
            return {}
        self.compact_tables.add(table.name)
        declared = table.get("NrOfEntries")
        entries = _numbered(table)
        if declared is not None:
            parsed = _int(declared.text) if declared.text else None
            if parsed is None or parsed[0] != len(entries):
                self.warn(
                    declared.line,
                    f"NrOfEntries={declared.text} but {len(entries)} entries in [{table.name}]",
                )
        for subindex, entry in sorted(entries.items()):
            if not 1 <= subindex <= count:
                self.warn(
                    entry.line,
                    f"[{table.name}] entry {subindex} is beyond CompactSubObj={count}: ignored",
                )
        return {k: v for k, v in entries.items() if 1 <= k <= count}

    def _var(self, section: _Section, subindex: int, name: str, domain: bool = False) -> _Var:
        data_type = self._data_type(section, domain)
        var = _Var(
            name, subindex, section.line, data_type, self._access(section), self._pdo(section)
        )
        default = section.get("DefaultValue")
        if default is not None:
            var.default = self._convert(default, "default", data_type)
        value = section.get("ParameterValue")
        if value is not None:
            var.value = self._convert(value, "value", data_type)
        var.low = self._limit(section, "LowLimit", data_type)
        var.high = self._limit(section, "HighLimit", data_type)
        if var.low is not None and var.high is not None and var.low > var.high:
            entry = section.get("LowLimit")
            assert entry is not None
            self.warn(entry.line, f"LowLimit {var.low} is above HighLimit {var.high}: both ignored")
            var.low = var.high = None
        self._check_default_limits(section, var)
        for key in ("StorageLocation", "Factor", "Description", "Unit"):
            entry = section.get(key)
            if entry is not None and entry.text:
                var.extras[key] = entry.text
        return var

    def _data_type(self, section: _Section, domain: bool) -> int:
        entry = section.get("DataType")
        if entry is None or not entry.text:
            if domain:
                self.warn(section.line, f"[{section.name}] is a DOMAIN without DataType: 000Fh")
                return _DOMAIN_TYPE
            line = entry.line if entry else section.line
            what = "is empty" if entry else "is missing"
            self.fail(line, section.name, "DataType", f"{what}: the entry cannot be typed")
        parsed = _int(entry.text)
        if parsed is None:
            self.fail(
                entry.line,
                section.name,
                "DataType",
                f"{entry.text!r} is not a number: the entry cannot be typed",
            )
        code = parsed[0]
        if code in DATA_TYPES:
            return code
        base = self._complex_base(code)
        if base is not None:
            return base
        self.warn(
            entry.line,
            f"DataType {entry.text} is not a CiA 301 basic type: read as DOMAIN (as canopen does)",
        )
        return _DOMAIN_TYPE

    def _complex_base(self, code: int) -> int | None:
        """CANFestival's sub-range types: [A0sub1] DefaultValue names the base type (canopen)."""
        section = self.raw_sections.get(f"{code:x}sub1")
        entry = section.get("DefaultValue") if section else None
        parsed = _int(entry.text) if entry and entry.text else None
        return parsed[0] if parsed and parsed[0] in DATA_TYPES else None

    def _access(self, section: _Section) -> str:
        entry = section.get("AccessType")
        if entry is not None and entry.text.lower() in ACCESS_TYPES:
            return entry.text.lower()
        if entry is None:
            self.warn(section.line, f"[{section.name}] has no AccessType: read as rw")
        else:
            self.warn(
                entry.line,
                f"AccessType {entry.text!r} is not ro, wo, rw, rwr, rww or const: read as rw",
            )
        return "rw"

    def _pdo(self, section: _Section) -> bool:
        entry = section.get("PDOMapping")
        if entry is None:
            return False
        parsed = _int(entry.text) if entry.text else None
        if parsed is None or parsed[0] not in (0, 1):
            self.warn(entry.line, f"PDOMapping {entry.text!r} is not 0 or 1: read as 0")
            return False
        return bool(parsed[0])

    def _convert(self, entry: _Line, what: str, code: int) -> str | None:
        """A DefaultValue or ParameterValue as canopen parses it, or None (warned)."""
        dtype = DATA_TYPES[code]
        text, key = entry.text, entry.key
        lost = "the entry has no default" if what == "default" else "the entry keeps its default"
        if dtype.kind == "str":
            return text
        if dtype.kind == "hex":
            try:
                bytes.fromhex(text)
            except ValueError:
                self.warn(entry.line, f"{key} {text!r} is not hex bytes: {lost}")
                return None
            return text
        if not text:
            self.warn(entry.line, f"{key} is empty: {lost}")
            return None
        if dtype.kind == "float":
            number = self._float(entry, dtype.bits or 32)
            if number is None:
                self.warn(entry.line, f"{key} {text!r} is not a number: {lost}")
                return None
            return repr(number)
        parsed = _node_relative(text)
        if parsed is None:
            self.warn(entry.line, f"{key} {text!r} is not a number: {lost}")
            return None
        value, relative, note = parsed
        if note:
            self.warn(entry.line, note)
        if relative:
            return f"{_NODEID}+{value}"
        in_range = self._in_range(entry, value, code)
        if in_range is None:
            self.warn(
                entry.line,
                f"{key} {text} is outside the {dtype.name} range {dtype.low}..{dtype.high}: {lost}",
            )
            return None
        return str(in_range)

    def _float(self, entry: _Line, bits: int) -> float | None:
        try:
            return float(entry.text)
        except ValueError:
            pass
        parsed = _int(entry.text)
        if parsed is None or not 0 <= parsed[0] < (1 << bits):
            return None
        fmt = ">f" if bits == 32 else ">d"
        number = float(struct.unpack(fmt, parsed[0].to_bytes(bits // 8, "big"))[0])
        self.warn(
            entry.line,
            f"{entry.key} {entry.text} is read as the IEEE 754 bit pattern of {number!r} "
            "(as Lely does)",
        )
        return number

    def _in_range(self, entry: _Line, value: int, code: int) -> int | None:
        """The value within its type's range (hex two's complement for signed types), or None."""
        dtype = DATA_TYPES[code]
        if not dtype.bits:
            return value
        if dtype.signed and _is_hex(entry.text) and dtype.high < value < (1 << dtype.bits):
            value -= 1 << dtype.bits
        return value if dtype.low <= value <= dtype.high else None

    def _limit(self, section: _Section, key: str, code: int) -> float | None:
        entry = section.get(key)
        dtype = DATA_TYPES[code]
        if entry is None or not entry.text or dtype.kind not in ("int", "float", "time"):
            return None
        if dtype.kind == "float":
            number = self._float(entry, dtype.bits or 32)
        else:
            parsed = _int(entry.text)
            number = self._in_range(entry, parsed[0], code) if parsed else None
            if parsed and parsed[1]:
                self.warn(entry.line, parsed[1])
        if number is None:
            self.warn(entry.line, f"{key} {entry.text!r} is not a {dtype.name}: ignored")
        return number

    def _check_default_limits(self, section: _Section, var: _Var) -> None:
        entry = section.get("DefaultValue")
        if entry is None or var.default is None or DATA_TYPES[var.data_type].kind != "int":
            return
        if var.default.startswith(_NODEID):
            return
        value = int(var.default)
        if var.low is not None and value < var.low:
            self.warn(entry.line, f"DefaultValue {entry.text} is below LowLimit {var.low}")
        if var.high is not None and value > var.high:
            self.warn(entry.line, f"DefaultValue {entry.text} is above HighLimit {var.high}")

    # --- object lists -----------------------------------------------------
    def _check_lists(self, objects: dict[int, _Object]) -> None:
        lists = [self.sections[name] for name in OBJECT_LISTS if name in self.sections]
        if not lists:
            self.warn(1, "no object lists ([MandatoryObjects] ...): every object section is loaded")
            return
        listed: dict[int, int] = {}
        for section in lists:
            entries = _numbered(section)
            declared = section.get("SupportedObjects")
            parsed = _int(declared.text) if declared and declared.text else None
            if declared is None or parsed is None:
                line = declared.line if declared else section.line
                self.warn(line, f"[{section.name}] SupportedObjects is missing or not a number")
            elif parsed[0] != len(entries):
                self.warn(
                    declared.line,
                    f"SupportedObjects={declared.text} but [{section.name}] lists {len(entries)}",
                )
            for _, entry in sorted(entries.items()):
                index = _int(entry.text) if entry.text else None
                if index is None:
                    self.warn(entry.line, f"{entry.text!r} is not an object index: ignored")
                elif index[0] in listed:
                    self.warn(
                        entry.line,
                        f"{index[0]:04X}h is listed twice (first on line {listed[index[0]]})",
                    )
                else:
                    listed[index[0]] = entry.line
                    if f"{index[0]:04X}" not in self.sections:
                        self.warn(
                            entry.line,
                            f"{index[0]:04X}h is listed but has no [{index[0]:04X}] section: "
                            "not loaded",
                        )
        unlisted = [obj for index, obj in sorted(objects.items()) if index not in listed]
        if unlisted:
            names = ", ".join(f"[{obj.index:04X}]" for obj in unlisted[:6])
            more = ", ..." if len(unlisted) > 6 else ""
            self.warn(
                min(obj.line for obj in unlisted),
                f"{len(unlisted)} object section(s) in no object list ({names}{more}): "
                "loaded all the same",
            )

    # --- emitting, importing ----------------------------------------------
    def _emit(self, objects: dict[int, _Object]) -> Iterable[str]:
        """The normalised file canopen reads: canonical names, keys and values only."""
        yield from self._emit_file_info()
        yield from self._emit_device_info()
        yield from self._emit_commissioning()
        yield from self._emit_dummies()
        yield from self._emit_comments()
        for index, obj in sorted(objects.items()):
            yield f"[{index:04X}]"
            yield f"ParameterName={obj.name}"
            yield f"ObjectType=0x{obj.object_type:X}"
            if obj.var is not None:
                yield from self._emit_var(obj.var)  # its StorageLocation among the extras
                continue
            if obj.storage:
                yield f"StorageLocation={obj.storage}"
            yield f"SubNumber={len(obj.subs)}"
            for subindex, var in sorted(obj.subs.items()):
                yield f"[{index:04X}sub{subindex:X}]"
                yield f"ParameterName={var.name}"
                yield from self._emit_var(var)

    @staticmethod
    def _emit_var(var: _Var) -> Iterable[str]:
        yield f"DataType=0x{var.data_type:04X}"
        yield f"AccessType={var.access}"
        yield f"PDOMapping={int(var.pdo)}"
        if var.default is not None:
            yield f"DefaultValue={var.default}"
        if var.value is not None:
            yield f"ParameterValue={var.value}"
        for key, text in var.extras.items():
            yield f"{key}={text}"

    def _emit_file_info(self) -> Iterable[str]:
        section = self.sections.get("FileInfo")
        if section is None:
            return
        yield "[FileInfo]"
        for key, entry in section.values.items():
            if re.fullmatch(r"[A-Za-z0-9_]+", key):
                yield f"{key}={entry.text}"

    def _emit_device_info(self) -> Iterable[str]:
        yield "[DeviceInfo]"  # even empty: canopen logs its own warning without one
        section = self.sections.get("DeviceInfo")
        if section is None:
            return
        for key in _DEVICE_INFO_STRINGS:
            entry = section.get(key)
            if entry is not None:
                yield f"{key}={entry.text}"
        for key in _DEVICE_INFO_NUMBERS:
            entry = section.get(key)
            if entry is None:
                continue
            parsed = _int(entry.text) if entry.text else None
            if parsed is None or parsed[0] < 0:
                what = "is empty" if not entry.text else f"{entry.text!r} is not a number"
                self.warn(entry.line, f"{key} {what}: ignored")
            elif key != "CompactPDO":
                yield f"{key}={parsed[0]}"
        self._check_compact_pdo(section)

    def _check_compact_pdo(self, section: _Section) -> None:
        entry = section.get("CompactPDO")
        parsed = _int(entry.text) if entry and entry.text else None
        if entry is None or not parsed or not parsed[0]:
            return
        for key, base in (("NrOfRXPDO", 0x1400), ("NrOfTXPDO", 0x1800)):
            declared = section.get(key)
            count = _int(declared.text) if declared and declared.text else None
            explicit = sum(f"{base + n:04X}" in self.sections for n in range(512))
            if count and count[0] > explicit:
                self.warn(
                    entry.line,
                    f"CompactPDO={entry.text}: {key}={count[0]} but {explicit} defined; "
                    "the implicit PDOs are not created",
                )

    def _emit_commissioning(self) -> Iterable[str]:
        section = self.sections.get("DeviceComissioning")
        if section is None:
            return
        yield "[DeviceComissioning]"
        entry = section.get("NodeID")
        parsed = _int(entry.text) if entry and entry.text else None
        if entry is not None and parsed is not None and 1 <= parsed[0] <= 127:
            yield f"NodeID={parsed[0]}"
            if self.node_id is None:
                self.node_id = parsed[0]
        elif entry is not None and not (parsed and parsed[0] == 255):  # 255: unconfigured (LSS)
            self.warn(entry.line, f"NodeID {entry.text!r} is not 1..127: ignored")
        entry = section.get("Baudrate")
        parsed = _int(entry.text) if entry and entry.text else None
        if entry is not None and parsed is not None and parsed[0] > 0:
            yield f"Baudrate={parsed[0]}"
        elif entry is not None:
            self.warn(entry.line, f"Baudrate {entry.text!r} is not a bit rate in kbit/s: ignored")

    def _emit_dummies(self) -> Iterable[str]:
        section = self.sections.get("DummyUsage")
        if section is None:
            return
        yield "[DummyUsage]"
        missing = []
        for n in range(1, 8):
            key = f"Dummy{n:04X}"
            entry = section.get(key)
            if entry is None:
                missing.append(key)
                yield f"{key}=0"
            elif (parsed := _int(entry.text)) is not None and parsed[0] in (0, 1):
                yield f"{key}={parsed[0]}"
            else:
                self.warn(entry.line, f"{key}={entry.text!r} is not 0 or 1: read as 0")
                yield f"{key}=0"
        if missing:
            self.warn(section.line, f"[DummyUsage] lacks {', '.join(missing)}: read as 0")

    def _emit_comments(self) -> Iterable[str]:
        section = self.sections.get("Comments")
        if section is None:
            return
        lines = sorted(
            (int(match.group(1)), entry)
            for key, entry in section.values.items()
            if (match := _LINE_KEY_RE.fullmatch(key))
        )
        declared = section.get("Lines")
        parsed = _int(declared.text) if declared and declared.text else None
        if declared is None or parsed is None or parsed[0] != len(lines):
            line = declared.line if declared else section.line
            text = declared.text if declared else "(missing)"
            self.warn(line, f"[Comments] Lines={text} but {len(lines)} Line keys: those are kept")
        yield "[Comments]"
        yield f"Lines={len(lines)}"
        for n, (_, entry) in enumerate(lines, 1):
            yield f"Line{n}={entry.text}"

    def _import(self, text: str) -> ObjectDictionary:
        from canopen.objectdictionary import import_od

        source = _NamedText(text)
        try:
            return import_od(source, node_id=self.node_id)
        except Exception as exc:  # a repair this module missed: still one clear error
            raise EdsError(
                self.name, None, None, f"canopen cannot import the repaired file: {exc!r}"
            ) from exc

    def _finish(self, od: ObjectDictionary, objects: dict[int, _Object]) -> None:
        """What canopen cannot take from the text: limits it misparses, node-ID, Lely's dummies."""
        from canopen.objectdictionary import ODVariable

        od.node_id = self.node_id
        for index, obj in objects.items():
            for var in [obj.var] if obj.var is not None else obj.subs.values():
                target = od.get_variable(index, var.subindex)
                if target is not None:  # canopen types limits as int; REAL limits are floats
                    target.min = var.low  # type: ignore[assignment]
                    target.max = var.high  # type: ignore[assignment]
        section = self.sections.get("DummyUsage")
        for key, entry in section.values.items() if section else ():
            match = re.fullmatch(r"Dummy([0-9A-F]{4})", key)
            code = int(match.group(1), 16) if match else 0
            if code > 7 and code in DATA_TYPES and entry.text == "1" and code not in od:
                dummy = ODVariable(key, code, 0)
                dummy.data_type, dummy.access_type = code, "const"
                od.add_object(dummy)

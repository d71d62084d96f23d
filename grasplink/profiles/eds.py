"""Validation of EDS files before canopen imports them.

canopen's importer silently drops a DefaultValue or limit it cannot parse,
crashes with a bare KeyError/NoOptionError on a missing [Comments] line or
[DummyUsage] entry, and never checks limits or PDO maps. dcfchk is a
development tool, not a run-time dependency. So every EDS (shipped or given
by a user) goes through `validate_eds` first, and every problem surfaces as
an `EdsError` naming file, section and key.

CiA 306 makes DefaultValue optional, and canopen leaves a missing one as
None, which the device store turns into 0. For most process data that is
harmless (the application publishes it, an RPDO writes it), but for the
entries the device configures itself from it silently changes behaviour:
1017h = 0 switches the heartbeat off, 1016h = 0 stops monitoring, 1800h:02 = 0
makes a TPDO synchronous, a sample rate of 0 Hz. So a DefaultValue is required
(`_default_required`) on every readable entry of

- the mandatory objects 1000h, 1001h, 1018h (device type, error register,
  identity: what a master checks before it trusts a node);
- the communication area 1000h-1FFFh (heartbeat 1016h/1017h, SYNC 1005h,
  EMCY 1014h/1015h, 1029h, SDO and PDO parameters): the runtime reloads these
  at every reset communication and 0 is a meaningful setting for nearly all;
- the application area when the entry is not PDO-mappable: a parameter or
  constant (sample rates, limits, quick-stop option, sub-index 0 counts) that
  the application reads at reset rather than produces.

Write-only entries have no value to read, and PDO-mappable application
entries are process data, so those may omit it. An empty DefaultValue on a
numeric entry counts as missing (canopen drops it the same way); an empty
string or byte string is a value.
"""

from __future__ import annotations

import configparser
import re
from dataclasses import dataclass
from pathlib import Path
from typing import NoReturn

from grasplink.errors import EdsError


@dataclass(frozen=True)
class DataType:
    """A CiA 301 basic data type: code, name, size and value kind."""

    code: int
    name: str
    bits: int | None  # None: variable length (strings, domain)
    kind: str  # "int", "float", "str", "hex", "time"

    @property
    def signed(self) -> bool:
        return self.name.startswith("INTEGER")

    @property
    def low(self) -> int:
        return -(1 << (self.bits - 1)) if self.signed and self.bits else 0

    @property
    def high(self) -> int:
        assert self.bits is not None
        return (1 << (self.bits - 1)) - 1 if self.signed else (1 << self.bits) - 1


def _types() -> dict[int, DataType]:
    ints = {
        0x01: ("BOOLEAN", 1),
        0x02: ("INTEGER8", 8),
        0x03: ("INTEGER16", 16),
        0x04: ("INTEGER32", 32),
        0x05: ("UNSIGNED8", 8),
        0x06: ("UNSIGNED16", 16),
        0x07: ("UNSIGNED32", 32),
        0x10: ("INTEGER24", 24),
        0x12: ("INTEGER40", 40),
        0x13: ("INTEGER48", 48),
        0x14: ("INTEGER56", 56),
        0x15: ("INTEGER64", 64),
        0x16: ("UNSIGNED24", 24),
        0x18: ("UNSIGNED40", 40),
        0x19: ("UNSIGNED48", 48),
        0x1A: ("UNSIGNED56", 56),
        0x1B: ("UNSIGNED64", 64),
    }
    table = {code: DataType(code, name, bits, "int") for code, (name, bits) in ints.items()}
    table[0x08] = DataType(0x08, "REAL32", 32, "float")
    table[0x11] = DataType(0x11, "REAL64", 64, "float")
    table[0x09] = DataType(0x09, "VISIBLE_STRING", None, "str")
    table[0x0B] = DataType(0x0B, "UNICODE_STRING", None, "str")
    table[0x0A] = DataType(0x0A, "OCTET_STRING", None, "hex")
    table[0x0F] = DataType(0x0F, "DOMAIN", None, "hex")
    table[0x0C] = DataType(0x0C, "TIME_OF_DAY", 48, "time")
    table[0x0D] = DataType(0x0D, "TIME_DIFFERENCE", 48, "time")
    return table


DATA_TYPES: dict[int, DataType] = _types()
ACCESS_TYPES = ("ro", "wo", "rw", "rwr", "rww", "const")
OBJECT_TYPES = {0x2: "DOMAIN", 0x7: "VAR", 0x8: "ARRAY", 0x9: "RECORD"}
OBJECT_LISTS = ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects")
MANDATORY_OBJECTS = (0x1000, 0x1001, 0x1018)
COMMUNICATION_AREA = range(0x1000, 0x2000)
REQUIRED_SECTIONS = ("FileInfo", "DeviceInfo", "DummyUsage", "Comments", *OBJECT_LISTS)
_OTHER_SECTIONS = {"DeviceComissioning"}
#: the [DeviceInfo] keys whose values are numbers (CiA 306)
DEVICE_INFO_NUMBERS = (
    *(f"BaudRate_{r}" for r in (10, 20, 50, 125, 250, 500, 800, 1000)),
    "VendorNumber",
    "ProductNumber",
    "RevisionNumber",
    "SimpleBootUpMaster",
    "SimpleBootUpSlave",
    "Granularity",
    "DynamicChannelsSupported",
    "GroupMessaging",
    "NrOfRXPDO",
    "NrOfTXPDO",
    "LSS_Supported",
)
#: the keys CiA 306 defines for an object's section (field.py adds what canopen reads)
OBJECT_KEYS = (
    "ParameterName",
    "ObjectType",
    "DataType",
    "AccessType",
    "DefaultValue",
    "LowLimit",
    "HighLimit",
    "PDOMapping",
    "SubNumber",
    "ObjFlags",
    "CompactSubObj",
    "ParameterValue",
    "Denotation",
    "StorageLocation",
    "UploadFile",
    "DownloadFile",
    "ParamRefd",
)
_OBJECT_KEYS_LOWER = {key.lower(): key for key in OBJECT_KEYS}
_OBJECT_RE = re.compile(r"^([0-9A-Fa-f]{4})$")
_SUB_RE = re.compile(r"^([0-9A-Fa-f]{4})sub([0-9A-Fa-f]{1,2})$", re.IGNORECASE)
_NUMBER_RE = re.compile(r"^-?(0[xX][0-9A-Fa-f]+|[0-9]+)$")
_NODEID = "$NODEID"


def parse_int(text: str) -> tuple[int, bool]:
    """Parse an EDS integer ("0x1A", "-3", "$NODEID+0x180"): (value, node-relative).

    Stricter than canopen's int(x, 0) on purpose: forms canopen would silently
    drop (e.g. "010", "1_000") or dcfchk rejects raise ValueError.
    """
    text = text.replace(" ", "")
    if _NODEID.lower() in text.lower() and _NODEID not in text:
        raise ValueError("write $NODEID in upper case")
    relative = _NODEID in text
    if relative:
        if text == _NODEID:
            return 0, True
        if text.startswith(_NODEID + "+"):
            text = text[len(_NODEID) + 1 :]
        elif text.endswith("+" + _NODEID):
            text = text[: -len(_NODEID) - 1]
        else:
            raise ValueError("expected $NODEID+value")
    if not _NUMBER_RE.match(text):
        raise ValueError("not an integer")
    return int(text, 0), relative


def _default_required(index: int, access: str, mappable: bool) -> str | None:
    """Why an entry must carry a DefaultValue, or None when it may omit it (module docstring)."""
    if access == "wo":
        return None
    if index in MANDATORY_OBJECTS:
        return "a mandatory object (CiA 301) needs a value"
    if index in COMMUNICATION_AREA:
        return "the device sets up its communication from this entry at every reset"
    if not mappable:
        return "the application reads this parameter at reset"
    return None


def validate_eds(path: str | Path) -> None:
    """Raise EdsError for the first problem found in the EDS at `path`."""
    _Checker(Path(path)).run()


class _Checker:
    """One validation pass; `fail` raises with file/section/key filled in."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.name = str(path)
        self.cfg = configparser.RawConfigParser(
            strict=False, interpolation=None, inline_comment_prefixes=(";",)
        )
        self.cfg.optionxform = str  # type: ignore[assignment,method-assign]
        self.subs: dict[str, dict[int, str]] = {}  # object section -> {sub-index: section}

    def fail(self, section: str | None, key: str | None, problem: str) -> NoReturn:
        raise EdsError(self.name, section, key, problem)

    def run(self) -> None:
        text = self._read()
        self._check_duplicates(text)
        try:
            self.cfg.read_string(text, source=self.name)
        except configparser.Error as exc:
            self.fail(None, None, f"not an INI file: {exc}")
        for name in self.cfg.sections():
            if match := _SUB_RE.match(name):
                subs = self.subs.setdefault(match.group(1).upper(), {})
                subs[int(match.group(2), 16)] = name
        for section in REQUIRED_SECTIONS:
            if not self.cfg.has_section(section):
                self.fail(section, None, "required section is missing")
        self._check_info_sections()
        listed = self._check_object_lists()
        for section in self.cfg.sections():
            self._check_section_known(section, listed)
        for index in sorted(listed):
            self._check_object(f"{index:04X}")
        self._check_pdos(listed)

    # --- file level -------------------------------------------------------
    def _read(self) -> str:
        try:
            data = self.path.read_bytes()
        except OSError as exc:
            self.fail(None, None, f"cannot read file: {exc.strerror or exc}")
        try:
            return data.decode("ascii")
        except UnicodeDecodeError as exc:
            line = data[: exc.start].count(b"\n") + 1
            self.fail(
                None,
                None,
                f"non-ASCII byte on line {line} (canopen reads the file "
                "with the locale encoding; write 'u' for micro)",
            )

    def _check_duplicates(self, text: str) -> None:
        """Duplicates make canopen's strict parser crash; report them by name."""
        sections: set[str] = set()
        keys: set[str] = set()
        section = None
        for line in text.splitlines():
            stripped = line.strip()
            if not stripped or stripped[0] in ";#" or line[0].isspace():
                continue
            if stripped.startswith("[") and stripped.endswith("]"):
                section = stripped[1:-1]
                if section.lower() in sections:
                    self.fail(section, None, "duplicate section")
                sections.add(section.lower())
                keys = set()
            elif "=" in stripped:
                key = stripped.split("=", 1)[0].strip()
                if key.lower() in keys:
                    self.fail(section, key, "duplicate key")
                keys.add(key.lower())

    def _check_info_sections(self) -> None:
        for key in DEVICE_INFO_NUMBERS:
            self._int_option("DeviceInfo", key, required=False)
        lines = self._int_option("Comments", "Lines", required=True)
        for n in range(1, (lines or 0) + 1):
            if not self.cfg.has_option("Comments", f"Line{n}"):
                self.fail("Comments", f"Line{n}", f"missing (Lines={lines})")
        for n in range(1, 8):
            value = self.cfg.get("DummyUsage", f"Dummy{n:04d}", fallback=None)
            if value not in ("0", "1"):
                self.fail("DummyUsage", f"Dummy{n:04d}", f"must be 0 or 1, got {value!r}")

    def _int_option(self, section: str, key: str, required: bool) -> int | None:
        value = self.cfg.get(section, key, fallback=None)
        if value is None:
            if required:
                self.fail(section, key, "required key is missing")
            return None
        try:
            number, relative = parse_int(value)
        except ValueError:
            number, relative = 0, True
        if relative:
            self.fail(section, key, f"{value!r} is not an integer")
        return number

    # --- object lists -----------------------------------------------------
    def _check_object_lists(self) -> set[int]:
        listed: set[int] = set()
        for section in OBJECT_LISTS:
            count = self._int_option(section, "SupportedObjects", required=True) or 0
            keys = set(self.cfg.options(section)) - {"SupportedObjects"}
            expected = {str(n) for n in range(1, count + 1)}
            for key in sorted(keys - expected):
                self.fail(section, key, f"unexpected entry (SupportedObjects={count})")
            for n in range(1, count + 1):
                index = self._int_option(section, str(n), required=True)
                assert index is not None
                self._check_list_membership(section, str(n), index)
                if index in listed:
                    self.fail(section, str(n), f"0x{index:04X} is listed twice")
                if not self.cfg.has_section(f"{index:04X}"):
                    self.fail(section, str(n), f"0x{index:04X} has no [{index:04X}] section")
                listed.add(index)
        return listed

    def _check_list_membership(self, section: str, key: str, index: int) -> None:
        if section == "MandatoryObjects":
            ok = index in MANDATORY_OBJECTS
        elif section == "ManufacturerObjects":
            ok = 0x2000 <= index < 0x6000
        else:
            ok = 0x1000 <= index < 0x2000 or 0x6000 <= index <= 0xFFFF
        if not ok:
            self.fail(section, key, f"0x{index:04X} does not belong in [{section}]")

    def _check_section_known(self, section: str, listed: set[int]) -> None:
        if section in REQUIRED_SECTIONS or section in _OTHER_SECTIONS:
            return
        if match := _OBJECT_RE.match(section):
            if int(match.group(1), 16) not in listed:
                self.fail(section, None, "object is not listed in any *Objects section")
            return
        if match := _SUB_RE.match(section):
            parent = match.group(1).upper()
            if not self.cfg.has_section(parent):
                self.fail(section, None, f"sub-index without object section [{parent}]")
            return
        self.fail(section, None, "unknown section (CompactSubObj/Name/Value are not supported)")

    # --- objects ----------------------------------------------------------
    def _check_object(self, section: str) -> None:
        self._check_keys(section)
        if not self.cfg.get(section, "ParameterName", fallback=""):
            self.fail(section, "ParameterName", "required key is missing")
        object_type = self._int_option(section, "ObjectType", required=True)
        if object_type not in OBJECT_TYPES:
            self.fail(section, "ObjectType", f"{object_type} is not VAR, ARRAY, RECORD or DOMAIN")
        if self.cfg.has_option(section, "CompactSubObj"):
            self.fail(section, "CompactSubObj", "not supported; write explicit sub-sections")
        subs = self.subs.get(section, {})
        if object_type in (0x7, 0x2):
            if subs:
                self.fail(section, "ObjectType", "a VAR must not have sub-index sections")
            self._check_variable(section)
            return
        sub_number = self._int_option(section, "SubNumber", required=True)
        if sub_number != len(subs):
            self.fail(section, "SubNumber", f"{sub_number} but {len(subs)} sub-index sections")
        if 0 not in subs:
            self.fail(section, "SubNumber", f"sub-index 0 section [{section}sub0] is missing")
        for sub_section in subs.values():
            self._check_keys(sub_section)
            if not self.cfg.get(sub_section, "ParameterName", fallback=""):
                self.fail(sub_section, "ParameterName", "required key is missing")
            self._check_variable(sub_section)
        self._check_sub0(subs)

    def _check_keys(self, section: str) -> None:
        for key in self.cfg.options(section):
            if key not in OBJECT_KEYS and key.lower() in _OBJECT_KEYS_LOWER:
                spelling = _OBJECT_KEYS_LOWER[key.lower()]
                self.fail(section, key, f"spell it {spelling!r} (canopen is case-sensitive)")

    def _check_sub0(self, subs: dict[int, str]) -> None:
        sub0 = subs[0]
        if self._int_option(sub0, "DataType", required=True) != 0x0005:
            self.fail(sub0, "DataType", "sub-index 0 must be UNSIGNED8 (0x0005)")
        if self.cfg.get(sub0, "AccessType").lower() in ("ro", "const"):
            highest = max(subs)
            value = self._value(sub0, "DefaultValue")
            if value is not None and value != highest:
                self.fail(sub0, "DefaultValue", f"{value} but the highest sub-index is {highest}")

    def _check_variable(self, section: str) -> None:
        code = self._int_option(section, "DataType", required=True)
        if code not in DATA_TYPES:
            self.fail(section, "DataType", f"0x{code:04X} is not a known CiA 301 data type")
        access = self.cfg.get(section, "AccessType", fallback=None)
        if access is None:
            self.fail(section, "AccessType", "required key is missing")
        elif access.lower() not in ACCESS_TYPES:
            self.fail(section, "AccessType", f"{access!r} is not one of {', '.join(ACCESS_TYPES)}")
        mapping = self.cfg.get(section, "PDOMapping", fallback="0")
        if mapping not in ("0", "1"):
            self.fail(section, "PDOMapping", f"{mapping!r} must be 0 or 1")
        dtype = DATA_TYPES[code]
        self._check_default_present(section, dtype, access.lower(), mapping == "1")
        if dtype.kind == "int":
            self._check_int_values(section, dtype)
        elif dtype.kind == "float":
            for key in ("DefaultValue", "LowLimit", "HighLimit"):
                raw = self.cfg.get(section, key, fallback="")
                try:
                    float(raw or 0)
                except ValueError:
                    self.fail(section, key, f"{raw!r} is not a number")
        elif dtype.kind == "hex":
            raw = self.cfg.get(section, "DefaultValue", fallback="")
            try:
                bytes.fromhex(raw)
            except ValueError:
                self.fail(section, "DefaultValue", f"{raw!r} is not a hex byte string")

    def _check_default_present(
        self, section: str, dtype: DataType, access: str, mappable: bool
    ) -> None:
        reason = _default_required(int(section[:4], 16), access, mappable)
        if reason is None:
            return
        raw = self.cfg.get(section, "DefaultValue", fallback=None)
        if raw is None:
            problem = "required key is missing"
        elif not raw.strip() and dtype.kind in ("int", "float", "time"):
            problem = "is empty"
        else:
            return
        self.fail(
            section, "DefaultValue", f"{problem}: {reason}; without it the node starts with 0"
        )

    def _check_int_values(self, section: str, dtype: DataType) -> None:
        low = self._value(section, "LowLimit", dtype)
        high = self._value(section, "HighLimit", dtype)
        if low is not None and high is not None and low > high:
            self.fail(section, "LowLimit", f"{low} is above HighLimit {high}")
        raw = self.cfg.get(section, "DefaultValue", fallback="")
        if not raw:
            return
        base, relative = self._parse(section, "DefaultValue", raw)
        for value in (base + 1, base + 127) if relative else (base,):
            at = " at node-ID " + str(value - base) if relative else ""
            if not dtype.low <= value <= dtype.high:
                self.fail(
                    section,
                    "DefaultValue",
                    f"{raw}{at} is outside the {dtype.name} range {dtype.low}..{dtype.high}",
                )
            if low is not None and value < low:
                self.fail(section, "DefaultValue", f"{raw}{at} is below LowLimit {low}")
            if high is not None and value > high:
                self.fail(section, "DefaultValue", f"{raw}{at} is above HighLimit {high}")

    def _value(self, section: str, key: str, dtype: DataType | None = None) -> int | None:
        """A plain (not node-relative) integer entry, range-checked against dtype."""
        raw = self.cfg.get(section, key, fallback="")
        if not raw:
            return None
        value, relative = self._parse(section, key, raw)
        if relative:
            self.fail(section, key, f"{raw!r}: $NODEID is only supported in DefaultValue")
        if dtype is not None and not dtype.low <= value <= dtype.high:
            self.fail(
                section, key, f"{raw} is outside the {dtype.name} range {dtype.low}..{dtype.high}"
            )
        return value

    def _parse(self, section: str, key: str, raw: str) -> tuple[int, bool]:
        try:
            return parse_int(raw)
        except ValueError as exc:
            self.fail(section, key, f"{raw!r} is not an integer ({exc})")

    # --- PDOs -------------------------------------------------------------
    def _check_pdos(self, listed: set[int]) -> None:
        """Default maps must point at mappable entries and fit in 8 bytes."""
        for comm_base, key in ((0x1400, "NrOfRXPDO"), (0x1800, "NrOfTXPDO")):
            comms = [i for i in listed if comm_base <= i < comm_base + 0x200]
            declared = self._int_option("DeviceInfo", key, required=False)
            if declared is not None and declared != len(comms):
                self.fail("DeviceInfo", key, f"{declared} but {len(comms)} PDO sections")
            for comm in comms:
                if comm + 0x200 not in listed:
                    self.fail(f"{comm:04X}", None, f"no mapping object 0x{comm + 0x200:04X}")
                self._check_map(f"{comm + 0x200:04X}")

    def _check_map(self, section: str) -> None:
        if not self.cfg.has_section(f"{section}sub0"):
            self.fail(section, "ObjectType", "a PDO mapping object must be a RECORD")
        count = self._value(f"{section}sub0", "DefaultValue") or 0
        bits = 0
        for n in range(1, count + 1):
            sub = f"{section}sub{n:X}"
            if not self.cfg.has_section(sub):
                self.fail(f"{section}sub0", "DefaultValue", f"{count} mapped but no [{sub}]")
            entry = self._value(sub, "DefaultValue") or 0
            index, subindex, length = entry >> 16, (entry >> 8) & 0xFF, entry & 0xFF
            bits += length
            if index < 0x1000:
                usage = self.cfg.get("DummyUsage", f"Dummy{index:04d}", fallback="0")
                if index not in DATA_TYPES or usage != "1":
                    self.fail(sub, "DefaultValue", f"dummy 0x{index:04X} is not enabled")
                target_bits = DATA_TYPES[index].bits
            else:
                target = self._mapped_section(index, subindex)
                if target is None:
                    self.fail(
                        sub, "DefaultValue", f"maps 0x{index:04X}:{subindex} which does not exist"
                    )
                if self.cfg.get(target, "PDOMapping", fallback="0") != "1":
                    self.fail(sub, "DefaultValue", f"maps [{target}] which has PDOMapping=0")
                code = self._int_option(target, "DataType", required=True)
                target_bits = DATA_TYPES[code or 0].bits
            if target_bits != length:
                self.fail(sub, "DefaultValue", f"length {length} bits, object has {target_bits}")
        if bits > 64:
            self.fail(f"{section}sub0", "DefaultValue", f"default map is {bits} bits (max 64)")

    def _mapped_section(self, index: int, subindex: int) -> str | None:
        section = f"{index:04X}"
        if not self.cfg.has_section(section):
            return None
        subs = self.subs.get(section)
        if subs:
            return subs.get(subindex)
        return section if subindex == 0 else None

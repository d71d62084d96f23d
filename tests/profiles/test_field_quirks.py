"""Each field quirk loads with a warning naming file and line; only an unbuildable file fails.

Every test starts from a small, clean EDS (`_BASE`, which loads without a
warning) and changes one thing about it.
"""

from __future__ import annotations

from pathlib import Path

import canopen
import pytest
from canopen.objectdictionary import ODArray, ODVariable, import_od

from grasplink.errors import ConfigError, EdsError
from grasplink.profiles import eds_path, load_profile
from grasplink.profiles.field import LoadWarning, load_object_dictionary
from grasplink.profiles.kinds import KINDS, node_kind

_BASE = """\
[FileInfo]
FileName=t.eds
EDSVersion=4.0

[DeviceInfo]
VendorName=Test
VendorNumber=0x360
ProductNumber=1
NrOfRXPDO=0
NrOfTXPDO=0

[DummyUsage]
Dummy0001=0
Dummy0002=1
Dummy0003=1
Dummy0004=1
Dummy0005=1
Dummy0006=1
Dummy0007=1

[Comments]
Lines=1
Line1=a test file

[MandatoryObjects]
SupportedObjects=3
1=0x1000
2=0x1001
3=0x1018

[OptionalObjects]
SupportedObjects=1
1=0x1017

[ManufacturerObjects]
SupportedObjects=1
1=0x2000

[1000]
ParameterName=Device type
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=0x00000191

[1001]
ParameterName=Error register
ObjectType=0x7
DataType=0x0005
AccessType=ro
DefaultValue=0

[1017]
ParameterName=Producer heartbeat time
ObjectType=0x7
DataType=0x0006
AccessType=rw
DefaultValue=100

[1018]
ParameterName=Identity
ObjectType=0x9
SubNumber=2

[1018sub0]
ParameterName=Highest sub-index supported
ObjectType=0x7
DataType=0x0005
AccessType=const
DefaultValue=1

[1018sub1]
ParameterName=Vendor-ID
ObjectType=0x7
DataType=0x0007
AccessType=ro
DefaultValue=0x360

[2000]
ParameterName=Value
ObjectType=0x7
DataType=0x0003
AccessType=rw
PDOMapping=1
DefaultValue=5
"""


def _line(text: str, needle: str) -> int:
    """1-based line number of the first line containing `needle` (or equal to it, with a $)."""
    lines = text.split("\n")
    if needle.endswith("$"):
        return lines.index(needle[:-1]) + 1
    return next(n for n, line in enumerate(lines, 1) if needle in line)


def _load(
    tmp_path: Path, text: str | bytes, node_id: int | None = None, name: str = "t.eds"
) -> tuple[canopen.ObjectDictionary, list[LoadWarning]]:
    path = tmp_path / name
    if isinstance(text, str):
        path.write_text(text, encoding="utf-8")
    else:
        path.write_bytes(text)
    return load_object_dictionary(path, node_id)


def _messages(warnings: list[LoadWarning]) -> list[tuple[int, str]]:
    return [(w.line, w.message) for w in warnings]


def _var(od: canopen.ObjectDictionary, index: int, subindex: int = 0) -> ODVariable:
    var = od.get_variable(index, subindex)
    assert var is not None
    return var


def _add(text: str, section: str, lines: str) -> str:
    """`text` with `lines` added at the end of `section`'s header line."""
    return text.replace(f"[{section}]\n", f"[{section}]\n{lines}\n", 1)


def _add_object(text: str, listing: str, body: str) -> str:
    """An extra manufacturer object (listed as the 2nd) with its sections."""
    text = text.replace(
        "[ManufacturerObjects]\nSupportedObjects=1\n1=0x2000",
        f"[ManufacturerObjects]\nSupportedObjects=2\n1=0x2000\n2={listing}",
    )
    return text + "\n" + body


# --- the clean file and our own ------------------------------------------------------
def test_the_clean_base_file_loads_without_warnings(tmp_path: Path) -> None:
    od, warnings = _load(tmp_path, _BASE, node_id=5)
    assert warnings == []
    assert (od.node_id, _var(od, 0x1017).default, _var(od, 0x1018, 1).default) == (5, 100, 0x360)


@pytest.mark.parametrize("kind", KINDS)
def test_our_own_eds_files_load_without_warnings_exactly_as_the_strict_loader_does(
    kind: str,
) -> None:
    node_id = node_kind(kind).node_id
    od, warnings = load_object_dictionary(eds_path(kind), node_id)
    assert warnings == []
    strict = load_profile(kind, node_id)
    assert list(od) == list(strict)
    for index in strict:
        ours, theirs = od[index], strict[index]
        entries = (
            [(ours, theirs)]
            if isinstance(theirs, ODVariable)
            else [
                (ours[s], theirs[s])
                for s in theirs.subindices  # type: ignore[index]
            ]
        )
        for a, b in entries:
            assert (
                a.name,
                a.data_type,
                a.access_type,
                a.default,
                a.min,
                a.max,
                a.pdo_mappable,
            ) == (
                b.name,
                b.data_type,
                b.access_type,
                b.default,
                b.min,
                b.max,
                b.pdo_mappable,
            ), f"{index:04X}:{a.subindex}"


# --- reading the text ------------------------------------------------------------
def test_lower_case_keys_and_line5_style_comments_are_read_with_a_warning(tmp_path: Path) -> None:
    text = _BASE.replace("Line1=a test file", "line1=a test file").replace(
        "[1017]\nParameterName", "[1017]\nparametername"
    )
    text = text.replace("DefaultValue=100", "defaultvalue=100")
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (_line(text, "line1="), "key 'line1' read as 'Line1' (canopen matches keys exactly)"),
        (
            _line(text, "parametername"),
            "key 'parametername' read as 'ParameterName' (canopen matches keys exactly)",
        ),
        (
            _line(text, "defaultvalue"),
            "key 'defaultvalue' read as 'DefaultValue' (canopen matches keys exactly)",
        ),
    ]
    assert od.comments == "a test file"
    assert _var(od, 0x1017).default == 100


def test_an_empty_vendor_number_is_ignored_where_canopen_raises(tmp_path: Path) -> None:
    text = _BASE.replace("VendorNumber=0x360", "VendorNumber=")
    (tmp_path / "raw.eds").write_text(text)
    with pytest.raises(ValueError):
        import_od(str(tmp_path / "raw.eds"))
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [(_line(text, "VendorNumber="), "VendorNumber is empty: ignored")]
    assert od.device_information.vendor_number is None
    assert od.device_information.product_number == 1


def test_missing_file_and_device_info_and_dummy_usage_are_warnings(tmp_path: Path) -> None:
    start = _BASE.index("[MandatoryObjects]")
    text = _BASE[start:]
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (1, "no [FileInfo] section (CiA 306 requires it)"),
        (1, "no [DeviceInfo] section (CiA 306 requires it)"),
        (1, "no [DummyUsage] section (CiA 306 requires it)"),
    ]
    assert len(od) == 5


def test_a_duplicate_key_keeps_the_later_value_where_canopen_raises(tmp_path: Path) -> None:
    text = _BASE.replace("DefaultValue=100", "DefaultValue=100\nDefaultValue=250")
    (tmp_path / "raw.eds").write_text(text)
    with pytest.raises(Exception, match="already exists"):
        import_od(str(tmp_path / "raw.eds"))
    od, warnings = _load(tmp_path, text)
    first = _line(text, "DefaultValue=100")
    assert _messages(warnings) == [
        (
            first + 1,
            f"duplicate key DefaultValue in [1017] (first on line {first}): "
            "the later value is used",
        )
    ]
    assert _var(od, 0x1017).default == 250


def test_a_duplicate_section_is_merged(tmp_path: Path) -> None:
    text = _BASE + "\n[1017]\nHighLimit=1000\n"
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (
            _line(text, "HighLimit=1000") - 1,
            f"duplicate section [1017] (first on line {_line(text, '[1017]')}): "
            "its keys are merged, later values win",
        )
    ]
    assert (_var(od, 0x1017).default, _var(od, 0x1017).max) == (100, 1000)


def test_byte_order_mark_latin1_bytes_and_control_characters_are_repaired(
    tmp_path: Path,
) -> None:
    text = _BASE.replace("VendorName=Test", "VendorName=M\xfcller\x00")
    data = b"\xef\xbb\xbf" + text.encode("latin-1")
    od, warnings = _load(tmp_path, data)
    line = _line(text, "VendorName")
    assert _messages(warnings) == [
        (1, "UTF-8 byte-order mark removed (canopen would not find the first section)"),
        (line, "not UTF-8 from this line on: the file is read as Latin-1"),
        (line, "control characters removed on 1 line(s), the first here"),
    ]
    assert od.device_information.vendor_name == "M\xfcller"


def test_a_utf16_file_is_decoded(tmp_path: Path) -> None:
    od, warnings = _load(tmp_path, b"\xff\xfe" + _BASE.encode("utf-16-le"))
    assert _messages(warnings) == [(1, "UTF-16 file: read as text (canopen would not)")]
    assert _var(od, 0x1017).default == 100


def test_section_names_are_read_in_any_case(tmp_path: Path) -> None:
    text = _BASE.replace("[1018sub1]", "[1018SUB1]").replace("[DeviceInfo]", "[deviceinfo]")
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (_line(text, "[deviceinfo]"), "section [deviceinfo] read as [DeviceInfo]"),
        (_line(text, "[1018SUB1]"), "section [1018SUB1] read as [1018sub1]"),
    ]
    assert _var(od, 0x1018, 1).default == 0x360
    assert od.device_information.vendor_number == 0x360


def test_lines_that_are_not_key_value_are_ignored_with_a_warning(tmp_path: Path) -> None:
    text = "stray=1\n" + _BASE.replace("[1017]\n", "[1017]\nno delimiter here\n")
    _, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (1, "line ignored: it is before the first section"),
        (_line(text, "no delimiter"), "line ignored: 'no delimiter here' is not key=value"),
    ]


# --- numbers -------------------------------------------------------------------
def test_a_leading_zero_is_octal_as_cia306_says(tmp_path: Path) -> None:
    text = _BASE.replace("DefaultValue=100", "DefaultValue=0144")
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (_line(text, "0144"), "'0144' is read as octal 100 (CiA 306; canopen would drop it)")
    ]
    assert _var(od, 0x1017).default == 100


def test_an_empty_or_garbage_default_leaves_the_entry_without_one(tmp_path: Path) -> None:
    text = _BASE.replace("DefaultValue=100", "DefaultValue=").replace(
        "DefaultValue=5", "DefaultValue=five"
    )
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (_line(text, "DefaultValue=$"), "DefaultValue is empty: the entry has no default"),
        (_line(text, "=five"), "DefaultValue 'five' is not a number: the entry has no default"),
    ]
    assert _var(od, 0x1017).default is None and _var(od, 0x2000).default is None


def test_signed_hex_is_twos_complement_and_out_of_range_is_dropped(tmp_path: Path) -> None:
    text = _BASE.replace("DefaultValue=5", "DefaultValue=0xFFFE\nLowLimit=0x8000")
    text = text.replace("DefaultValue=100", "DefaultValue=70000")
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (
            _line(text, "70000"),
            "DefaultValue 70000 is outside the UNSIGNED16 range 0..65535: the entry has no default",
        )
    ]
    assert (_var(od, 0x2000).default, _var(od, 0x2000).min) == (-2, -32768)
    assert _var(od, 0x1017).default is None


def test_a_real_written_as_an_integer_is_its_bit_pattern_as_lely_reads_it(tmp_path: Path) -> None:
    body = (
        "[2001]\nParameterName=Gain\nObjectType=0x7\nDataType=0x0008\nAccessType=rw\n"
        "DefaultValue=0x3FC00000\nLowLimit=0.5\n"
    )
    text = _add_object(_BASE, "0x2001", body)
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (
            _line(text, "0x3FC00000"),
            "DefaultValue 0x3FC00000 is read as the IEEE 754 bit pattern of 1.5 (as Lely does)",
        )
    ]
    assert (_var(od, 0x2001).default, _var(od, 0x2001).min) == (1.5, 0.5)


# --- $NODEID, DCF values ------------------------------------------------------------
_NODE_RELATIVE = (
    "[1014]\nParameterName=COB-ID EMCY\nObjectType=0x7\nDataType=0x0007\nAccessType=rw\n"
    "DefaultValue=$NODEID+0x80\n\n"
    "[1200]\nParameterName=SDO server\nObjectType=0x9\nSubNumber=3\n\n"
    "[1200sub0]\nParameterName=Highest\nDataType=0x0005\nAccessType=const\nDefaultValue=2\n\n"
    "[1200sub1]\nParameterName=COB-ID rx\nDataType=0x0007\nAccessType=ro\n"
    "DefaultValue=0x600+$NODEID\n\n"
    "[1200sub2]\nParameterName=COB-ID tx\nDataType=0x0007\nAccessType=ro\n"
    "DefaultValue=$nodeid + 0x580\n\n"
    "[2001]\nParameterName=Own ID\nDataType=0x0005\nAccessType=ro\nDefaultValue=$NODEID\n"
)


def _with_node_relative(text: str) -> str:
    text = text.replace(
        "[OptionalObjects]\nSupportedObjects=1\n1=0x1017",
        "[OptionalObjects]\nSupportedObjects=3\n1=0x1017\n2=0x1014\n3=0x1200",
    )
    return _add_object(text, "0x2001", _NODE_RELATIVE)


def test_nodeid_expressions_resolve_for_the_node_id_given(tmp_path: Path) -> None:
    od, warnings = _load(tmp_path, _with_node_relative(_BASE), node_id=0x22)
    assert warnings == []
    assert _var(od, 0x1014).default == 0xA2
    assert (_var(od, 0x1200, 1).default, _var(od, 0x1200, 2).default) == (0x622, 0x5A2)
    assert _var(od, 0x2001).default == 0x22
    assert _var(od, 0x1014).relative


def test_without_a_node_id_nodeid_values_stay_unresolved_as_canopen_leaves_them(
    tmp_path: Path,
) -> None:
    od, _ = _load(tmp_path, _with_node_relative(_BASE))
    assert od.node_id is None
    assert _var(od, 0x1014).default is None
    assert _var(od, 0x1014).relative


def test_a_dcf_node_id_resolves_nodeid_unless_one_is_given(tmp_path: Path) -> None:
    text = _with_node_relative(_BASE) + "\n[DeviceComissioning]\nNodeID=0x10\nBaudrate=250\n"
    od, warnings = _load(tmp_path, text, name="t.dcf")
    assert warnings == []
    assert (od.node_id, od.bitrate, _var(od, 0x1014).default) == (0x10, 250_000, 0x90)
    od, _ = _load(tmp_path, text, node_id=0x20, name="t.dcf")
    assert (od.node_id, _var(od, 0x1014).default) == (0x20, 0xA0)


def test_a_dcf_parameter_value_is_what_a_local_node_serves(tmp_path: Path) -> None:
    text = _BASE.replace("DefaultValue=100", "DefaultValue=100\nParameterValue=0x1F4")
    od, _ = _load(tmp_path, text, name="t.dcf")
    assert (_var(od, 0x1017).default, _var(od, 0x1017).value) == (100, 500)
    assert canopen.LocalNode(5, od).sdo.upload(0x1017, 0) == (500).to_bytes(2, "little")


# --- sub-indices ------------------------------------------------------------------
def test_compact_sub_objects_get_every_entry_with_names_and_dcf_values(tmp_path: Path) -> None:
    body = (
        "[2001]\nParameterName=Channel\nObjectType=0x8\nDataType=0x0006\nAccessType=rw\n"
        "PDOMapping=1\nDefaultValue=7\nCompactSubObj=3\n\n"
        "[2001Name]\nNrOfEntries=2\n1=Left\n2=Right\n\n"
        "[2001Value]\nNrOfEntries=1\n3=0x10\n"
    )
    od, warnings = _load(tmp_path, _add_object(_BASE, "0x2001", body))
    assert warnings == []
    array = od[0x2001]
    assert isinstance(array, ODArray)
    got = [(v.subindex, v.name, v.default, v.value, v.access_type) for v in array.values()]
    assert got == [
        (0, "Number of entries", 3, None, "ro"),
        (1, "Left", 7, None, "rw"),
        (2, "Right", 7, None, "rw"),
        (3, "Channel3", 7, 16, "rw"),
    ]
    assert all(v.pdo_mappable for v in list(array.values())[1:])


def test_miscounted_sub_numbers_and_object_lists_load_what_the_sections_say(
    tmp_path: Path,
) -> None:
    text = _BASE.replace("SubNumber=2", "SubNumber=4").replace(
        "[OptionalObjects]\nSupportedObjects=1\n1=0x1017",
        "[OptionalObjects]\nSupportedObjects=3\n1=0x1017\n2=0x1800",
    )
    text += "\n[2100]\nParameterName=Unlisted\nDataType=0x0005\nAccessType=ro\nDefaultValue=1\n"
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (_line(text, "2=0x1800") - 2, "SupportedObjects=3 but [OptionalObjects] lists 2"),
        (
            _line(text, "2=0x1800"),
            "1800h is listed but has no [1800] section: not loaded",
        ),
        (_line(text, "SubNumber=4"), "SubNumber=4 but 2 sub-index section(s): those are used"),
        (
            _line(text, "[2100]"),
            "1 object section(s) in no object list ([2100]): loaded all the same",
        ),
    ]
    assert 0x1800 not in od and _var(od, 0x2100).default == 1
    assert len(od[0x1018]) == 2


def test_an_object_without_object_type_but_with_sub_indices_is_a_record(tmp_path: Path) -> None:
    text = _BASE.replace(
        "[1018]\nParameterName=Identity\nObjectType=0x9", "[1018]\nParameterName=Identity"
    )
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (_line(text, "[1018]"), "[1018] has no ObjectType but sub-indices: a RECORD")
    ]
    assert _var(od, 0x1018, 1).default == 0x360


def test_a_missing_sub_index_0_is_added_with_the_highest_sub_index(tmp_path: Path) -> None:
    start = _BASE.index("[1018sub0]")
    end = _BASE.index("[1018sub1]")
    text = _BASE[:start] + _BASE[end:]
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (_line(text, "[1018]"), "[1018] has no sub-index 0: added as UNSIGNED8 ro = 1"),
        (_line(text, "SubNumber=2"), "SubNumber=2 but 1 sub-index section(s): those are used"),
    ]
    assert (_var(od, 0x1018, 0).default, _var(od, 0x1018, 0).access_type) == (1, "ro")


def test_lely_dummies_beyond_0007_become_dummy_objects_and_a_missing_one_is_0(
    tmp_path: Path,
) -> None:
    text = _BASE.replace("Dummy0001=0\n", "").replace("Dummy0007=1", "Dummy0007=1\nDummy0010=1")
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (_line(text, "[DummyUsage]"), "[DummyUsage] lacks Dummy0001: read as 0")
    ]
    assert (_var(od, 0x10).name, _var(od, 0x10).data_type) == ("Dummy0010", 0x10)
    assert 0x0001 not in od and _var(od, 0x0002).name == "Dummy0002"


def test_an_unknown_data_type_is_a_domain_as_canopen_makes_it(tmp_path: Path) -> None:
    text = _BASE.replace("DataType=0x0003", "DataType=0x0040")
    od, warnings = _load(tmp_path, text)
    assert _messages(warnings) == [
        (
            _line(text, "0x0040"),
            "DataType 0x0040 is not a CiA 301 basic type: read as DOMAIN (as canopen does)",
        ),
        (
            _line(text, "DefaultValue=5"),
            "DefaultValue '5' is not hex bytes: the entry has no default",
        ),
    ]
    assert _var(od, 0x2000).data_type == 0x000F


# --- errors ---------------------------------------------------------------------
def _error(tmp_path: Path, text: str | bytes) -> EdsError:
    with pytest.raises(EdsError) as info:
        _load(tmp_path, text)
    return info.value


def test_a_file_that_is_no_eds_is_one_error(tmp_path: Path) -> None:
    error = _error(tmp_path, b"\x89PNG\r\n\x1a\n\x00\x00 binary")
    assert (
        str(error)
        == f"{tmp_path / 't.eds'}:1: not a CiA 306 EDS or DCF: no [DeviceInfo] and no objects"
    )


def test_a_file_without_objects_is_one_error(tmp_path: Path) -> None:
    error = _error(tmp_path, _BASE[: _BASE.index("[MandatoryObjects]")])
    assert error.line == 1 and "no objects" in str(error)


def test_an_entry_without_a_data_type_is_one_error_naming_file_line_section_and_key(
    tmp_path: Path,
) -> None:
    text = _BASE.replace("DataType=0x0006\n", "")
    error = _error(tmp_path, text)
    assert (error.line, error.section, error.key) == (_line(text, "[1017]"), "1017", "DataType")
    assert str(error) == (
        f"{tmp_path / 't.eds'}:{error.line} [1017] DataType: is missing: the entry cannot be typed"
    )


def test_an_object_type_that_is_no_object_is_one_error(tmp_path: Path) -> None:
    text = _BASE.replace(
        "[1017]\nParameterName=Producer heartbeat time\nObjectType=0x7",
        "[1017]\nParameterName=Producer heartbeat time\nObjectType=0xA",
    )
    error = _error(tmp_path, text)
    assert (error.line, error.key) == (_line(text, "ObjectType=0xA"), "ObjectType")


def test_an_unreadable_file_is_one_error(tmp_path: Path) -> None:
    with pytest.raises(EdsError, match="cannot read file"):
        load_object_dictionary(tmp_path / "missing.eds")


@pytest.mark.parametrize("node_id", [0, 128, True, "5"])
def test_a_node_id_outside_1_to_127_is_a_config_error(tmp_path: Path, node_id: object) -> None:
    (tmp_path / "t.eds").write_text(_BASE)
    with pytest.raises(ConfigError):
        load_object_dictionary(tmp_path / "t.eds", node_id)  # type: ignore[arg-type]

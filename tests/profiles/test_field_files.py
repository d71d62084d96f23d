"""EDS and DCF files written by other projects load, with the warnings pinned here.

The files under field/ come from CANopenNode, CANopenDemo, python-canopen and
Lely core (field/README.md: where, which commit, licence). Each test names the
quirk or feature of the file it checks.
"""

from __future__ import annotations

from pathlib import Path

import canopen
import pytest
from canopen.objectdictionary import ODArray, ODRecord, ODVariable, import_od

from grasplink.profiles.field import LoadWarning, load_object_dictionary

FIELD = Path(__file__).resolve().parent / "field"

EXPECTED_WARNINGS = {
    "canopendemo_demoDevice.eds": [
        (
            177,
            "DefaultValue is empty: the entry has no default "
            "(and 17 more: lines 186, 195, 204, 213, ...)",
        ),
    ],
    "canopennode_DS301_profile.eds": [
        (17, "VendorNumber is empty: ignored"),
        (19, "ProductNumber is empty: ignored"),
        (
            171,
            "DefaultValue is empty: the entry has no default "
            "(and 16 more: lines 180, 189, 198, 207, ...)",
        ),
    ],
    "lely_co-nmt-slave.dcf": [
        (1, "no [FileInfo] section (CiA 306 requires it)"),
        (1, "no [DummyUsage] section (CiA 306 requires it)"),
    ],
    "lely_coapp-fiber-slave.dcf": [
        (1, "no [FileInfo] section (CiA 306 requires it)"),
        (13, "key 'NrOfRxPDO' read as 'NrOfRXPDO' (canopen matches keys exactly)"),
        (14, "key 'NrOfTxPDO' read as 'NrOfTXPDO' (canopen matches keys exactly)"),
        (15, "CompactPDO=0x3f: NrOfRXPDO=4 but 1 defined; the implicit PDOs are not created"),
        (15, "CompactPDO=0x3f: NrOfTXPDO=4 but 2 defined; the implicit PDOs are not created"),
        (17, "[DummyUsage] lacks Dummy0001: read as 0"),
    ],
    "python-canopen_e35.eds": [
        (116, "SupportedObjects=105 but [ManufacturerObjects] lists 104"),
        (6662, "1 object section(s) in no object list ([2FFF]): loaded all the same"),
        (6775, "6505h is listed but has no [6505] section: not loaded"),
    ],
    "python-canopen_sample.eds": [
        (77, "SubNumber=5 but 4 sub-index section(s): those are used"),
        (121, "SubNumber=9 but 6 sub-index section(s): those are used"),
        (
            194,
            "33 object section(s) in no object list "
            "([1400], [1401], [1402], [1403], [1600], [1601], ...): loaded all the same",
        ),
        (835, "SupportedObjects=0 but [ManufacturerObjects] lists 1"),
        (891, "DataType 0x40 is not a CiA 301 basic type: read as DOMAIN (as canopen does)"),
        (892, "DefaultValue '0x0' is not hex bytes: the entry has no default"),
        (907, "[3003] is an ARRAY without sub-indices: loaded empty"),
        (936, "DefaultValue is empty: the entry has no default"),
        (990, "SubNumber=0x7 but 3 sub-index section(s): those are used"),
    ],
}


def _flat(od: canopen.ObjectDictionary) -> dict[tuple[int, int], tuple[object, ...]]:
    """Every entry's (name, type, access, default, value, mappable, limits, relative)."""
    out = {}
    for obj in od.values():
        entries = [obj] if isinstance(obj, ODVariable) else list(obj.values())
        for v in entries:
            out[(v.index, v.subindex)] = (
                v.name,
                v.data_type,
                v.access_type,
                v.default,
                v.value,
                v.pdo_mappable,
                v.min,
                v.max,
                v.relative,
            )
    return out


def _entry(od: canopen.ObjectDictionary, index: int, subindex: int = 0) -> ODVariable:
    var = od.get_variable(index, subindex)
    assert var is not None, f"{index:04X}:{subindex}"
    return var


def test_the_field_files_are_all_here_with_a_readme() -> None:
    files = sorted(p.name for p in FIELD.iterdir() if p.suffix in (".eds", ".dcf"))
    assert files == sorted(EXPECTED_WARNINGS)
    readme = (FIELD / "README.md").read_text(encoding="utf-8")
    for name in files:
        assert name in readme


@pytest.mark.parametrize("name", sorted(EXPECTED_WARNINGS))
def test_each_field_file_loads_with_its_pinned_warnings(name: str) -> None:
    path = FIELD / name
    _, warnings = load_object_dictionary(path)
    assert [(w.line, w.message) for w in warnings] == EXPECTED_WARNINGS[name]
    assert all(isinstance(w, LoadWarning) and w.path == str(path) for w in warnings)
    if warnings:
        assert str(warnings[0]) == f"{path}:{warnings[0].line}: {warnings[0].message}"


@pytest.mark.parametrize(
    "name", ["canopendemo_demoDevice.eds", "python-canopen_e35.eds", "lely_co-nmt-slave.dcf"]
)
def test_where_canopen_imports_a_file_itself_every_entry_is_the_same(name: str) -> None:
    path = FIELD / name
    od, _ = load_object_dictionary(path, node_id=0x22)
    assert _flat(od) == _flat(import_od(str(path), node_id=0x22))


def test_canopennode_ds301_profile_loads_though_canopen_refuses_its_empty_vendor_number() -> None:
    path = FIELD / "canopennode_DS301_profile.eds"
    with pytest.raises(ValueError):
        import_od(str(path), node_id=0x22)
    od, _ = load_object_dictionary(path, node_id=0x22)
    assert od.node_id == 0x22
    assert od.device_information.vendor_number is None
    assert _entry(od, 0x1014).default == 0x80 + 0x22  # $NODEID+0x80
    assert _entry(od, 0x1003, 1).default is None  # the empty DefaultValue (warned)
    assert _entry(od, 0x1800, 1).default == 0xC00001A2  # $NODEID+0xC0000180
    assert _entry(od, 0x1017).name == "Producer heartbeat time"


def test_canopendemo_is_a_cia401_module_with_analogue_inputs_in_its_tpdo() -> None:
    od, _ = load_object_dictionary(FIELD / "canopendemo_demoDevice.eds", node_id=4)
    assert _entry(od, 0x1000).default == 0x000F0191  # CiA 401, digital + analogue in/out
    inputs = od[0x6401]
    assert isinstance(inputs, ODArray) and inputs.name == "Read analog input 16-bit"
    assert _entry(od, 0x6401, 0).default == 16
    assert _entry(od, 0x6401, 1).pdo_mappable and _entry(od, 0x6401, 1).data_type == 0x0003
    assert _entry(od, 0x1A01, 0).default == 4
    assert _entry(od, 0x1A01, 1).default == 0x64010110  # 6401h:01, 16 bits
    assert _entry(od, 0x1801, 1).default == 0x40000284  # $NODEID+0x40000280, RTR not allowed


def test_python_canopen_e35_is_a_cia402_drive_whose_dcf_values_win() -> None:
    od, _ = load_object_dictionary(FIELD / "python-canopen_e35.eds", node_id=0x30)
    assert _entry(od, 0x1000).default == 0x00020192  # CiA 402
    control = _entry(od, 0x6040)
    assert (control.name, control.data_type, control.access_type) == ("Controlword", 6, "rww")
    assert control.pdo_mappable
    assert _entry(od, 0x6060).data_type == 0x0002  # modes of operation: INTEGER8
    assert 0x6505 not in od  # listed, but the file has no section for it (warned)
    rpdo_map_count = _entry(od, 0x1600, 0)
    assert (rpdo_map_count.default, rpdo_map_count.value) == (None, 2)  # ParameterValue only
    assert _entry(od, 0x1600, 2).value == 0x60400010  # controlword in RPDO1
    assert _entry(od, 0x1A00, 1).default == 0x606C0020  # velocity actual value in TPDO1
    node = canopen.LocalNode(0x30, od)
    assert node.sdo.upload(0x1600, 0) == bytes([2])  # what a device serves: the DCF value


def test_python_canopen_sample_expands_compact_arrays_and_takes_its_node_id() -> None:
    od, _ = load_object_dictionary(FIELD / "python-canopen_sample.eds")
    assert od.node_id == 0x10  # [DeviceComissioning] NodeID
    assert od.bitrate == 500_000
    assert _entry(od, 0x1400, 1).default == 0x200 + 0x10  # $NODEID+512
    assert _entry(od, 0x1403, 1).default == 1280 + 0x10  # 1280+$NODEID
    status = od[0x3004]
    assert isinstance(status, ODArray)
    assert [status[n].name for n in range(1, 4)] == [f"Sensor Status {n}" for n in (1, 2, 3)]
    assert _entry(od, 0x3004, 0).default == 3
    assert _entry(od, 0x3004, 2).default == 3  # every entry takes the object's DefaultValue
    valves = od[0x3006]
    assert isinstance(valves, ODArray) and len(valves) == 25  # canopen alone makes 2
    assert _entry(od, 0x3006, 24).name == "Valve 1 % Open24"
    assert _entry(od, 0x3002).min == 4.5  # a REAL limit canopen alone drops
    assert _entry(od, 0x3030).max == -1  # INTEGER32 HighLimit=0xFFFFFFFF
    assert _entry(od, 0x1017).value == 0  # ParameterValue beside DefaultValue


def test_python_canopen_sample_resolves_nodeid_for_the_node_id_given() -> None:
    od, _ = load_object_dictionary(FIELD / "python-canopen_sample.eds", node_id=3)
    assert od.node_id == 3
    assert _entry(od, 0x1400, 1).default == 0x203
    assert _entry(od, 0x1400, 1).relative


def test_lely_nmt_slave_dcf_takes_node_id_and_parameter_values_from_the_dcf() -> None:
    od, _ = load_object_dictionary(FIELD / "lely_co-nmt-slave.dcf")
    assert od.node_id == 2
    heartbeat = _entry(od, 0x1017)
    assert (heartbeat.default, heartbeat.value) == (0, 100)
    assert canopen.LocalNode(2, od).sdo.upload(0x1017, 0) == (100).to_bytes(2, "little")
    assert od.device_information.vendor_number == 0x360


def test_lely_fiber_slave_expands_compact_records_with_their_value_sections() -> None:
    od, _ = load_object_dictionary(FIELD / "lely_coapp-fiber-slave.dcf", node_id=5)
    assert _entry(od, 0x1014).default == 0x85  # $NODEID+0x80
    heartbeat = od[0x1016]
    assert isinstance(heartbeat, ODArray)
    assert _entry(od, 0x1016, 0).default == 1
    assert _entry(od, 0x1016, 1).value == 0x00010400  # [1016Value] 1=
    rpdo_map = od[0x1600]
    assert isinstance(rpdo_map, ODRecord)  # CompactSubObj on a RECORD: Lely reads it, canopen not
    assert _entry(od, 0x1600, 1).value == 0x20010020
    assert _entry(od, 0x1A00, 1).value == 0x20020020
    assert _entry(od, 0x1800, 1).default == 0x185
    assert _entry(od, 0x1F80).value == 4
    dummy = _entry(od, 0x0010)  # Dummy0010=1: an INTEGER24 dummy, as Lely allows
    assert (dummy.name, dummy.data_type) == ("Dummy0010", 0x0010)
    assert _entry(od, 0x0002).name == "Dummy0002"
    assert 0x0001 not in od  # Dummy0001 missing: not a dummy (warned)

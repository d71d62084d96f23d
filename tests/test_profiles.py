"""The shipped EDS files, their validator, the generated docs and ridge layouts."""

from __future__ import annotations

import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

from grasplink.errors import ConfigError, EdsError
from grasplink.profiles import eds_path, load_profile, objects, validate_eds
from grasplink.profiles.docgen import render_profiles_markdown
from grasplink.profiles.edsgen import DEVICES, render_eds
from grasplink.profiles.kinds import KINDS
from grasplink.profiles.layouts import LAYOUTS_MM, PRESET_CODES, parse_layout, spacings_um

REPO = Path(__file__).resolve().parents[1]
DCFCHK = Path(sys.executable).parent / "dcfchk"
DRIVES = ("belt", "hand")
COMMON_NAMES = (
    "DEVICE_TYPE",
    "ERROR_REGISTER",
    "ERROR_HISTORY",
    "COB_ID_SYNC",
    "DEVICE_NAME",
    "HARDWARE_VERSION",
    "SOFTWARE_VERSION",
    "STORE_PARAMETERS",
    "RESTORE_DEFAULTS",
    "COB_ID_EMCY",
    "EMCY_INHIBIT_100US",
    "HEARTBEAT_CONSUMER",
    "HEARTBEAT_PRODUCER_MS",
    "IDENTITY",
    "ERROR_BEHAVIOUR",
    "SDO_SERVER",
    "TPDO_COMM",
    "TPDO_MAP",
)
CIA402_NAMES = (
    "ERROR_CODE",
    "CONTROLWORD",
    "STATUSWORD",
    "QUICK_STOP_OPTION",
    "MODES_OF_OPERATION",
    "MODES_OF_OPERATION_DISPLAY",
    "SUPPORTED_DRIVE_MODES",
)


# --- shipped files -----------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("node_id", ["default", 127])
def test_shipped_eds_passes_dcfchk_without_errors(kind: str, node_id: int | str) -> None:
    # dcfchk 2.4.2 needs -n: without it, it crashes on any $NODEID PDO COB-ID.
    assert DCFCHK.exists(), "dcfchk missing: install the dev extras (dcf-tools)"
    node = objects.DEFAULT_NODE_IDS[kind] if node_id == "default" else node_id
    result = subprocess.run(
        [str(DCFCHK), "-n", str(node), "-p", str(eds_path(kind))],
        capture_output=True,
        text=True,
        timeout=60,
    )
    output = result.stdout + result.stderr
    assert result.returncode == 0, output
    assert "error" not in output.lower(), output
    assert "warning" not in output.lower(), output


@pytest.mark.parametrize("kind", KINDS)
def test_shipped_eds_imports_with_cob_ids_resolved_to_node_id(kind: str) -> None:
    node_id = 0x22
    od = load_profile(kind, node_id)
    assert od[0x1200][1].default == 0x600 + node_id
    assert od[0x1200][2].default == 0x580 + node_id
    assert od[0x1014].default == 0x80 + node_id
    for n in range(4):
        cob = od[objects.TPDO_COMM + n][1].default
        assert cob & 0x7FF == 0x180 + 0x100 * n + node_id
        assert cob & 0x40000000  # RTR not allowed
        assert od[objects.TPDO_COMM + n][0].default == 6
    has_rpdos = kind in DRIVES
    assert (objects.RPDO_COMM in od) == has_rpdos
    if has_rpdos:
        for n in range(4):
            cob = od[objects.RPDO_COMM + n][1].default
            assert cob & 0x7FF == 0x200 + 0x100 * n + node_id
            assert bool(cob & 0x80000000) == (n != 0)
            assert od[objects.RPDO_COMM + n][2].default == 255


# 1018h sub 2 of each shipped EDS (edsgen.DEVICES): one code per kind, never reused.
PRODUCT_CODES = {kind: description[0] for kind, description in DEVICES.items()}


def test_product_codes_are_todays_and_distinct() -> None:
    assert {k: PRODUCT_CODES[k] for k in ("skin", "belt", "emg", "hand")} == {
        "skin": 1,
        "belt": 2,
        "emg": 3,
        "hand": 4,
    }
    assert len(set(PRODUCT_CODES.values())) == len(PRODUCT_CODES)


@pytest.mark.parametrize("kind", KINDS)
def test_shipped_eds_common_values(kind: str) -> None:
    od = load_profile(kind, objects.DEFAULT_NODE_IDS[kind])
    expected_type = 0x00020192 if kind in DRIVES else 0x00000194
    assert od[objects.DEVICE_TYPE].default == expected_type
    assert od[objects.IDENTITY][1].default == 0x00000ABC
    assert od[objects.IDENTITY][2].default == PRODUCT_CODES[kind]
    assert od[objects.IDENTITY][3].default == 0x00010000
    assert od[objects.HEARTBEAT_CONSUMER][1].default == 0x000101F4
    assert od[objects.HEARTBEAT_PRODUCER_MS].default == 100
    assert len(od[objects.DEVICE_NAME].default) > 4  # segmented upload
    assert od[objects.ERROR_BEHAVIOUR][1].max == 2
    assert od[objects.STORE_PARAMETERS][1].default == 1
    dummies = sorted(i for i in od if i < 0x1000)
    assert dummies == ([2, 3, 4, 5, 6, 7] if kind in DRIVES else [])


def test_shipped_device_specific_values() -> None:
    belt = load_profile("belt", 0x20)
    target = belt[objects.BELT_TARGET_VELOCITY_MRAD_S]
    assert (target.min, target.max, target.pdo_mappable) == (-7400, 8000, True)
    assert belt[objects.MODES_OF_OPERATION].default == objects.MODE_PROFILE_VELOCITY
    assert belt[objects.TPDO_COMM][3].default == 100
    assert belt[objects.TPDO_COMM][5].default == 50
    hand = load_profile("hand", 0x40)
    assert hand[objects.MODES_OF_OPERATION].default == objects.MODE_GRIP_FORCE
    assert hand[objects.MODES_OF_OPERATION].min == -1
    assert hand[objects.HAND_MAX_GRIP_MN].access_type == "const"
    assert hand[objects.RPDO_MAP][2].default == 0x24000020
    skin = load_profile("skin", 0x10)
    assert skin[objects.TPDO_MAP][4].default == 0x21010008
    assert skin[objects.TPDO_COMM + 1][5].default == 20
    emg = load_profile("emg", 0x30)
    assert emg[objects.TPDO_COMM + 1][1].default & 0x80000000  # raw stream off by default
    assert emg[objects.EMG_SAMPLE_RATE_HZ].default == 1500


def test_ridge_spacing_defaults_are_the_alpha01_layout() -> None:
    od = load_profile("skin", 0x10)
    spacing = od[objects.SKIN_RIDGE_SPACING_UM]
    alpha = spacings_um(LAYOUTS_MM["alpha0.1"])
    assert spacing[0].default == len(alpha)
    assert tuple(spacing[n].default for n in range(1, len(alpha) + 1)) == alpha
    assert all(spacing[n].default == 4000 for n in range(len(alpha) + 1, 13))
    assert PRESET_CODES[od[objects.SKIN_LAYOUT_PRESET].default] == "alpha0.1"
    assert od[objects.SKIN_LAYOUT_PRESET].max == len(PRESET_CODES)


def _expected_indices(kind: str) -> dict[str, int]:
    """objects.py names that must exist in this kind's EDS."""
    prefix = f"{kind.upper()}_"
    names = [*COMMON_NAMES, *(("RPDO_COMM", "RPDO_MAP", *CIA402_NAMES) if kind in DRIVES else ())]
    names += [name for name in vars(objects) if name.startswith(prefix)]
    return {name: getattr(objects, name) for name in names}


@pytest.mark.parametrize("kind", KINDS)
def test_every_named_index_exists_in_its_eds(kind: str) -> None:
    od = load_profile(kind, objects.DEFAULT_NODE_IDS[kind])
    expected = _expected_indices(kind)
    assert len(expected) > len(COMMON_NAMES) + 4
    missing = {name: hex(index) for name, index in expected.items() if index not in od}
    assert not missing


@pytest.mark.parametrize("kind", KINDS)
def test_shipped_eds_is_ascii_and_matches_generator(kind: str) -> None:
    text = eds_path(kind).read_bytes().decode("ascii")
    assert text == render_eds(kind), "run: python -m grasplink.profiles.edsgen"


@pytest.mark.parametrize("kind", KINDS)
def test_every_parameter_name_unit_is_bracketed(kind: str) -> None:
    text = eds_path(kind).read_text(encoding="ascii")
    for name in re.findall(r"^ParameterName=(.*)$", text, re.MULTILINE):
        assert name.count("[") == name.count("]") <= 1, name
        assert "[" not in name or name.endswith("]"), name


def test_docs_profiles_md_is_up_to_date() -> None:
    committed = (REPO / "docs" / "profiles.md").read_text(encoding="utf-8")
    assert committed == render_profiles_markdown(), "run: grasplink profiles doc / make docs"


# --- load_profile arguments ----------------------------------------------------
def test_load_profile_unknown_kind_lists_valid_kinds() -> None:
    with pytest.raises(ConfigError, match="the kinds are skin, emg, belt, hand"):
        load_profile("glove", 0x10)


@pytest.mark.parametrize("node_id", [0, 128, -1, True])
def test_load_profile_rejects_node_id_outside_1_127(node_id: int) -> None:
    with pytest.raises(ConfigError, match=r"1\.\.127"):
        load_profile("skin", node_id)


def test_load_profile_accepts_a_path(tmp_path: Path) -> None:
    copy = tmp_path / "mine.eds"
    copy.write_text(eds_path("emg").read_text(encoding="ascii"), encoding="ascii")
    assert load_profile(copy, 5)[objects.TPDO_COMM][1].default == 0x40000185
    assert load_profile(str(copy), 5)[objects.SDO_SERVER][1].default == 0x605


def test_load_profile_wraps_canopen_errors(monkeypatch: pytest.MonkeyPatch) -> None:
    def broken(*_args: object, **_kwargs: object) -> None:
        raise KeyError("boom")

    monkeypatch.setattr("canopen.objectdictionary.import_od", broken)
    with pytest.raises(EdsError, match=r"skin\.eds.*canopen"):
        load_profile("skin", 0x10)


# --- validator ---------------------------------------------------------------
def _edit(kind: str, section: str, key: str, value: str | None) -> str:
    """The shipped EDS text with one key of one section replaced (None: dropped)."""
    return _edit_text(eds_path(kind).read_text(encoding="ascii"), section, key, value)


def _edit_text(text: str, section: str, key: str, value: str | None) -> str:
    out: list[str] = []
    current = None
    for line in text.splitlines():
        if line.startswith("["):
            current = line[1:-1]
        elif current == section and line.startswith(key + "="):
            if value is not None:
                out.append(f"{key}={value}")
            continue
        out.append(line)
    return "\n".join(out) + "\n"


def _drop_section(kind: str, section: str) -> str:
    blocks = eds_path(kind).read_text(encoding="ascii").split("\n\n")
    return "\n\n".join(b for b in blocks if not b.startswith(f"[{section}]\n"))


def _error(tmp_path: Path, text: str, name: str = "belt.eds") -> EdsError:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    with pytest.raises(EdsError) as info:
        validate_eds(path)
    assert name in str(info.value)
    return info.value


def test_validator_accepts_every_shipped_eds() -> None:
    for kind in KINDS:
        validate_eds(eds_path(kind))


def test_validator_reports_missing_required_section(tmp_path: Path) -> None:
    err = _error(tmp_path, _drop_section("belt", "Comments"))
    assert (err.section, err.key) == ("Comments", None)
    assert "missing" in str(err)


def test_validator_reports_listed_object_without_section(tmp_path: Path) -> None:
    err = _error(tmp_path, _drop_section("belt", "2310"))
    assert err.section == "ManufacturerObjects"
    assert "0x2310" in str(err)


def test_validator_reports_default_above_high_limit(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("belt", "60FF", "DefaultValue", "9000"))
    assert (err.section, err.key) == ("60FF", "DefaultValue")
    assert str(err).endswith("belt.eds [60FF] DefaultValue: 9000 is above HighLimit 8000")


def test_validator_reports_default_below_low_limit(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("belt", "60FF", "DefaultValue", "-8000"))
    assert "below LowLimit -7400" in str(err)


def test_validator_reports_unknown_data_type(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("belt", "2310", "DataType", "0x0017"))
    assert (err.section, err.key) == ("2310", "DataType")
    assert "0x0017" in str(err)


def test_validator_reports_bad_access_type(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("belt", "6040", "AccessType", "readwrite"))
    assert (err.section, err.key) == ("6040", "AccessType")
    assert "readwrite" in str(err)


def test_validator_reports_sub_number_mismatch(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("belt", "1018", "SubNumber", "6"))
    assert (err.section, err.key) == ("1018", "SubNumber")
    assert "5 sub-index sections" in str(err)


def test_validator_reports_non_numeric_default(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("belt", "2311", "DefaultValue", "twelve"))
    assert (err.section, err.key) == ("2311", "DefaultValue")
    assert "'twelve' is not an integer" in str(err)


def test_validator_reports_sub_index_problems_by_sub_section(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("belt", "1600sub2", "DefaultValue", "0x60FF0010"))
    assert err.section == "1600sub2"
    assert "32" in str(err)


def test_validator_reports_missing_parameter_name(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("skin", "2120", "ParameterName", None), "skin.eds")
    assert (err.section, err.key) == ("2120", "ParameterName")


def test_validator_reports_bad_pdo_mapping_flag(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("skin", "2120", "PDOMapping", "yes"), "skin.eds")
    assert (err.section, err.key) == ("2120", "PDOMapping")


def test_validator_reports_duplicates(tmp_path: Path) -> None:
    text = eds_path("emg").read_text(encoding="ascii")
    err = _error(tmp_path, text.replace("[2210]\n", "[2210]\nDataType=0x0006\n"), "emg.eds")
    assert (err.section, err.key) == ("2210", "DataType")
    assert "duplicate" in str(err)
    err = _error(tmp_path, text + "\n[1000]\nParameterName=again\n", "emg.eds")
    assert err.section == "1000"


def test_validator_reports_unlisted_object_section(tmp_path: Path) -> None:
    text = eds_path("emg").read_text(encoding="ascii")
    extra = "\n[2299]\nParameterName=Stray\nObjectType=0x7\nDataType=0x0005\nAccessType=ro\n"
    err = _error(tmp_path, text + extra, "emg.eds")
    assert err.section == "2299"
    assert "not listed" in str(err)


def test_validator_reports_non_ascii(tmp_path: Path) -> None:
    text = _edit("emg", "2200", "ParameterName", "EMG envelope [µV]")
    err = _error(tmp_path, text, "emg.eds")
    assert "non-ASCII" in str(err)


def test_validator_reports_unreadable_file(tmp_path: Path) -> None:
    with pytest.raises(EdsError, match=r"missing\.eds.*cannot read"):
        validate_eds(tmp_path / "missing.eds")


@pytest.mark.parametrize(
    ("kind", "section"),
    [
        ("skin", "1017"),  # producer heartbeat: 0 would switch the heartbeat off
        ("belt", "1016sub1"),  # consumer of the gateway: 0 would stop monitoring it
        ("skin", "1000"),  # mandatory: device type
        ("emg", "1001"),  # mandatory: error register
        ("hand", "1018sub1"),  # mandatory: vendor-ID
        ("skin", "1800sub2"),  # TPDO transmission type: 0 would make it synchronous
        ("belt", "1A00sub0"),  # number of mapped objects
        ("skin", "2120"),  # application parameter: a sample rate of 0 Hz
        ("belt", "605A"),  # quick stop option code (the safe state's ramp)
        ("hand", "2403"),  # a const the application reads
    ],
)
def test_validator_requires_default_on_entries_the_device_configures_itself_from(
    tmp_path: Path, kind: str, section: str
) -> None:
    err = _error(tmp_path, _edit(kind, section, "DefaultValue", None), f"{kind}.eds")
    assert (err.section, err.key) == (section, "DefaultValue")
    assert f"{kind}.eds [{section}] DefaultValue: required key is missing" in str(err)


def test_validator_treats_an_empty_numeric_default_as_missing(tmp_path: Path) -> None:
    err = _error(tmp_path, _edit("skin", "1017", "DefaultValue", ""), "skin.eds")
    assert (err.section, err.key) == ("1017", "DefaultValue")
    assert "is empty" in str(err)


def test_validator_accepts_process_data_without_default(tmp_path: Path) -> None:
    # PDO-mappable application entries are produced by the application or written by an RPDO.
    path = tmp_path / "belt.eds"
    text = _edit("belt", "606C", "DefaultValue", None)
    path.write_text(_edit_text(text, "60FF", "DefaultValue", None), encoding="ascii")
    validate_eds(path)
    assert load_profile(path, 0x20)[0x606C].default is None


def test_a_missing_heartbeat_default_is_refused_strictly_and_loads_in_the_field(
    tmp_path: Path,
) -> None:
    """Our own files are held to the strict validator; a file elsewhere (a vendor's) loads
    as it is in the field, where CiA 306 makes DefaultValue optional (docs/eds_files.md)."""
    path = tmp_path / "skin.eds"
    path.write_text(_edit("skin", "1017", "DefaultValue", None), encoding="ascii")
    with pytest.raises(EdsError) as info:
        validate_eds(path)
    assert (info.value.path, info.value.section, info.value.key) == (
        str(path),
        "1017",
        "DefaultValue",
    )
    od = load_profile(path, 0x10)
    assert od[0x1017].default is None


def test_profiles_check_names_a_missing_default_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from grasplink.cli import main

    path = tmp_path / "skin.eds"
    path.write_text(_edit("skin", "1017", "DefaultValue", None), encoding="ascii")
    assert main(["profiles", "check", "--strict", str(path)]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1
    assert f"{path} [1017] DefaultValue: required key is missing" in err


# --- ridge layouts -------------------------------------------------------------
def test_layouts_cover_an_84_mm_skin_and_presets_are_in_order() -> None:
    for name, spacings in LAYOUTS_MM.items():
        assert math.isclose(sum(spacings), 84.0), name
    assert list(PRESET_CODES.values()) == list(LAYOUTS_MM)
    assert list(PRESET_CODES) == [1, 2, 3, 4, 5, 6, 7]
    assert LAYOUTS_MM["uniform4"] == (4.0,) * 21


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("alpha0.1", (19.0, 12.0, 5.0, 8.0, 4.0, 3.0, 33.0)),
        (" fibonacci ", (5.0, 34.0, 21.0, 8.0, 3.0, 13.0)),
        ("4, 3,48 ,29", (4.0, 3.0, 48.0, 29.0)),
        ("2.5", (2.5,)),
        (",".join(["4"] * 21), (4.0,) * 21),
    ],
)
def test_parse_layout_accepts_names_and_spacings(text: str, expected: tuple[float, ...]) -> None:
    assert parse_layout(text) == expected


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty"),
        ("   ", "empty"),
        ("alpha0.2", "valid names: alpha0.1, alpha0.3"),
        ("4,0,5", "'0' must be 0.1..1000 mm"),
        ("4,-3", "'-3' must be 0.1..1000 mm"),
        ("4,nan", "'nan' is not a finite"),
        ("4,inf", "'inf' is not a finite"),
        ("4,x,5", "'x' is not a number"),
        ("4,,5", "#2 is empty"),
        ("0", "must be 0.1..1000 mm"),
        ("1e300,1", "'1e300' must be 0.1..1000 mm"),
    ],
)
def test_parse_layout_rejects_bad_input_naming_the_value(text: str, message: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_layout(text)

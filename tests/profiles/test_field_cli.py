"""`grasplink profiles check`: field files with their warnings; --strict for our own files."""

from __future__ import annotations

from pathlib import Path

import pytest

from grasplink.cli import main
from grasplink.profiles import eds_path
from grasplink.profiles.kinds import KINDS

FIELD = Path(__file__).resolve().parent / "field"


def test_check_prints_each_warning_with_file_and_line_and_exits_0(
    capsys: pytest.CaptureFixture[str],
) -> None:
    path = FIELD / "canopennode_DS301_profile.eds"
    assert main(["profiles", "check", str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out == [
        f"{path}:17: VendorNumber is empty: ignored",
        f"{path}:19: ProductNumber is empty: ignored",
        f"{path}:171: DefaultValue is empty: the entry has no default "
        "(and 16 more: lines 180, 189, 198, 207, ...)",
        f"{path}: ok (39 objects, 3 warnings)",
    ]


def test_check_goes_through_every_file_and_exits_1_if_one_cannot_be_loaded(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    bad = tmp_path / "bad.eds"
    bad.write_text("not an EDS\n", encoding="ascii")
    good = FIELD / "lely_co-nmt-slave.dcf"
    assert main(["profiles", "check", str(bad), str(good)]) == 1
    captured = capsys.readouterr()
    assert captured.err == (
        f"grasplink: error: {bad}:1: not a CiA 306 EDS or DCF: no [DeviceInfo] and no objects\n"
    )
    assert captured.out.splitlines()[-1] == f"{good}: ok (9 objects, 2 warnings)"


def test_strict_refuses_a_field_file_as_before(capsys: pytest.CaptureFixture[str]) -> None:
    path = FIELD / "canopennode_DS301_profile.eds"
    assert main(["profiles", "check", "--strict", str(path)]) == 1
    err = capsys.readouterr().err
    assert err == f"grasplink: error: {path} [DeviceInfo] VendorNumber: '' is not an integer\n"


def test_our_own_eds_files_pass_both_modes_without_a_warning(
    capsys: pytest.CaptureFixture[str],
) -> None:
    paths = [str(eds_path(kind)) for kind in KINDS]
    assert main(["profiles", "check", "--strict", *paths]) == 0
    assert capsys.readouterr().out.splitlines() == [f"{p}: ok" for p in paths]
    assert main(["profiles", "check", *paths]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(paths)
    assert all(line.endswith(" warnings)") and ", 0 warnings)" in line for line in lines)

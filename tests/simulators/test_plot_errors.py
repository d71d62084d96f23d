"""`grasplink plot` on a broken recording: one line naming the file and the problem, exit 1."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from grasplink.cli import main as cli_main

ROOT = Path(__file__).resolve().parents[2]

SCENE = """
[scene]
seed = 1
duration_s = 0.5

[nodes.skin]
[nodes.belt]

[controller]
type = "scripted"
belt_mrad_s = [[0.1, 5000]]

[[effects]]
type = "grip.scripted"
grip_n = [[0.0, 5.0]]

[[effects]]
type = "load.scripted"
mass_kg = 0.2

[[effects]]
type = "object.scripted"
speed_mm_s = [[0.0, 60.0]]

[[effects]]
type = "skin.fsr"

[[effects]]
type = "belt.motor"
"""


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("recording")
    scene = folder / "scene.toml"
    scene.write_text(SCENE)
    out = folder / "out"
    assert cli_main(["run", str(scene), "--out", str(out)]) == 0
    assert {p.name for p in out.iterdir()} == {"summary.json", "truth.csv", "skin.csv", "can.asc"}
    return out


def _half(data: bytes) -> bytes:
    """Cut in the middle of a line, as a copy or a write interrupted half-way would."""
    cut = len(data) // 2
    while data[cut - 1 : cut] in (b"\n", b" "):
        cut += 1
    return data[:cut]


def _lines(keep: int) -> Callable[[bytes], bytes]:
    return lambda data: b"".join(data.splitlines(keepends=True)[:keep])


def _drop_line(number: int) -> Callable[[bytes], bytes]:
    def edit(data: bytes) -> bytes:
        lines = data.splitlines(keepends=True)
        return b"".join(lines[: number - 1] + lines[number:])

    return edit


GARBAGE = b"\x89PNG\r\n\x1a\n\x00\xff\xfe binary"
Edit = Callable[[bytes], bytes]
CASES: list[tuple[str, Edit, str]] = [
    ("summary.json", _half, "not valid JSON"),
    ("summary.json", lambda _d: GARBAGE, "not a text file"),
    ("summary.json", lambda _d: b"", "empty file"),
    ("summary.json", lambda _d: b"[1, 2]", "expected a JSON object"),
    ("summary.json", lambda d: d.replace(b'"duration_s": 0.5', b'"duration_s": "x"'), "duration_s"),
    ("summary.json", lambda d: d.replace(b'"node_id": 32', b'"node_id": "belt"'), "node_id"),
    ("summary.json", lambda d: d.replace(b'"layout": "alpha0.1"', b'"layout": 7'), "layout"),
    ("can.asc", _half, "truncated"),
    ("can.asc", _lines(40), "truncated"),
    ("can.asc", lambda _d: GARBAGE, "not a text file"),
    ("can.asc", lambda _d: b"", "empty file"),
    ("can.asc", lambda d: d.replace(b"Rx   d 1 00", b"Rx   d 1 ZZ", 1), "not a CAN log line"),
    ("can.asc", lambda d: d.replace(b"Rx   d 1 00", b"Rx   d 4 00", 1), "DLC 4 but 1 data bytes"),
    ("can.asc", _drop_line(20), "summary.json counts"),
    ("truth.csv", _half, "cut off"),
    ("truth.csv", _lines(100), "summary.json counts"),
    ("truth.csv", lambda _d: GARBAGE, "not a text file"),
    ("truth.csv", lambda _d: b"", "empty file"),
    ("truth.csv", lambda _d: b"time,x\n0,1\n", "header must be t_s"),
    ("truth.csv", lambda d: d.replace(b"\n0.001,", b"\nabc,", 1), "t_s 'abc' is not a number"),
    ("skin.csv", _half, "cut off"),
    ("skin.csv", lambda _d: GARBAGE, "not a text file"),
    ("skin.csv", lambda _d: b"", "empty file"),
    ("skin.csv", lambda _d: b"t_s,other\n0,1\n", "no column skin.force_n"),
    ("skin.csv", lambda d: d.replace(b"\n0.0025,", b"\n0.0025,1,", 1), "3 values"),
    ("skin.csv", lambda d: d.replace(b"\n0.0025,", b"\nnan,", 1), "not finite"),
    ("skin.csv", lambda d: d.replace(b"\n0.0025,", b"\n-1,", 1), "time must not go back"),
]


def _broken(recording: Path, tmp_path: Path, name: str, edit: Edit) -> Path:
    copy = tmp_path / "rec"
    shutil.copytree(recording, copy)
    target = copy / name
    target.write_bytes(edit(target.read_bytes()))
    return copy


@pytest.mark.parametrize(
    ("name", "edit", "needle"),
    CASES,
    ids=[f"{name}-{i}" for i, (name, _, _) in enumerate(CASES)],
)
def test_broken_recording_file_is_one_line_naming_file_and_problem(
    recording: Path,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    name: str,
    edit: Edit,
    needle: str,
) -> None:
    copy = _broken(recording, tmp_path, name, edit)
    assert cli_main(["plot", str(copy)]) == 1
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1, captured.err
    assert captured.err.startswith(f"grasplink: error: {copy / name}")
    assert needle in captured.err
    assert not list(copy.glob("*.png"))  # nothing drawn from a broken recording


def test_file_listed_in_the_summary_but_replaced_by_a_folder_is_named(
    recording: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    copy = tmp_path / "rec"
    shutil.copytree(recording, copy)
    (copy / "skin.csv").unlink()
    assert cli_main(["plot", str(copy)]) == 1
    assert "skin.csv: no such file (summary.json lists it)" in capsys.readouterr().err
    (copy / "skin.csv").mkdir()
    assert cli_main(["plot", str(copy)]) == 1
    assert "skin.csv: is a directory" in capsys.readouterr().err


def test_intact_recording_still_plots_every_picture(recording: Path, tmp_path: Path) -> None:
    copy = tmp_path / "rec"
    shutil.copytree(recording, copy)
    assert cli_main(["plot", str(copy)]) == 0
    assert {p.name for p in copy.glob("*.png")} == {
        "fsr.png",
        "kinematics.png",
        "commands.png",
        "bus.png",
    }


@pytest.mark.slow
def test_the_installed_command_prints_no_traceback_for_a_broken_recording(
    recording: Path, tmp_path: Path
) -> None:
    copy = _broken(recording, tmp_path, "truth.csv", _half)
    result = subprocess.run(
        [sys.executable, "-m", "grasplink.cli", "plot", str(copy)],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert result.returncode == 1
    assert "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1 and "truth.csv" in result.stderr

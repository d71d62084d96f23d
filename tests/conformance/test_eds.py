"""Conformance case 1.0: the EDS checker."""

from __future__ import annotations

import configparser
import subprocess
import sys
from pathlib import Path

from grasplink.profiles import eds_path
from grasplink.profiles import objects as obj

DCFCHK = Path(sys.executable).parent / "dcfchk"


def test_1_0_check_eds_file(kind: str) -> None:
    """1.0 EDS checker: "Check EDS file".

    The shipped EDS passes Lely's ``dcfchk`` (dcf-tools) without errors or
    warnings. dcfchk 2.4.2 needs a node-ID (-n) to resolve $NODEID, so it is
    given the node's default one. On top, the cross-checks the CiA tool's EDS
    checker makes: mandatory objects present, object lists consistent with the
    sections, NrOfRXPDO/NrOfTXPDO matching the PDO parameter objects.
    """
    path = eds_path(kind)
    assert DCFCHK.exists(), "dcfchk missing: install the dev extras (dcf-tools)"
    result = subprocess.run(
        [str(DCFCHK), "-n", str(obj.DEFAULT_NODE_IDS[kind]), str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert not (result.stdout + result.stderr).strip(), result.stdout + result.stderr

    eds = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    eds.optionxform = str
    eds.read(path)
    objects = {int(s, 16) for s in eds.sections() if len(s) == 4 and not s.isalpha()}
    listed = set()
    for section in ("MandatoryObjects", "OptionalObjects", "ManufacturerObjects"):
        count = int(eds[section]["SupportedObjects"], 0)
        indices = [int(eds[section][str(n)], 0) for n in range(1, count + 1)]
        assert len(indices) == count
        listed |= set(indices)
    assert {0x1000, 0x1001, 0x1018} <= objects
    assert listed == objects, (
        f"listed but no section: {listed - objects}, section not listed: {objects - listed}"
    )
    info = eds["DeviceInfo"]
    assert int(info["NrOfRXPDO"]) == sum(1 for i in objects if 0x1400 <= i <= 0x15FF)
    assert int(info["NrOfTXPDO"]) == sum(1 for i in objects if 0x1800 <= i <= 0x19FF)
    for comm, mapping in ((0x1400, 0x1600), (0x1800, 0x1A00)):
        for n in range(512):
            assert (comm + n in objects) == (mapping + n in objects), f"{comm + n:04X}h"

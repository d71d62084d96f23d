"""docs/integration.md's gateway configuration is the one that works: it reads, files and
all, and `gateway --check` says so; its quoted error is the one a user gets."""

from __future__ import annotations

import re
from pathlib import Path

from grasplink.cli import main

REPO = Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "integration.md"


def doc_config(tmp_path: Path, **replace: str) -> Path:
    block = re.search(r"<!-- integration-config -->\n```toml\n(.*?)```", DOC.read_text(), re.S)
    assert block is not None, "docs/integration.md lost its configuration block"
    text = block.group(1).replace('"scenes/devices/', f'"{REPO}/scenes/devices/')
    for old, new in replace.items():
        text = text.replace(old, new)
    path = tmp_path / "gateway.toml"
    path.write_text(text)
    return path


def test_the_documented_configuration_masters_both_vendors_files(tmp_path, capsys):
    assert main(["gateway", "--config", str(doc_config(tmp_path)), "--check"]) == 0
    out = capsys.readouterr().out
    assert "nodes.skin: skin 0x10 from canopendemo_demoDevice.eds (bound: SkinBinding" in out
    assert "nodes.hand: hand 0x40 from cia402_hand.dcf (bound: DriveBinding, mandatory" in out
    assert out.rstrip().endswith("configuration ok: 4 nodes, SYNC every 2.5 ms")


def test_the_documented_error_for_the_eds_instead_of_the_dcf(tmp_path, capsys):
    e35 = REPO / "tests" / "profiles" / "field" / "python-canopen_e35.eds"
    config = doc_config(
        tmp_path,
        **{
            'dcf = "'
            + f"{REPO}/scenes/devices/cia402_hand.dcf"
            + '"': f'eds = "{e35}"\nnode_id = 0x40'
        },
    )
    assert main(["gateway", "--config", str(config), "--check"]) == 1
    err = capsys.readouterr().err
    assert "nodes.hand.drive.target: 0x6071sub0 is in no RPDO of the file" in err
    assert "0x6071sub0 is in no\nRPDO of the file" in DOC.read_text()

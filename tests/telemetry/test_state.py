"""The Sparkplug bdSeq kept across restarts: saved atomically, read back, and a missing,
corrupt or unwritable file never stops telemetry (it starts at 0 and says so)."""

from __future__ import annotations

import os
from pathlib import Path

from grasplink.surfaces.telemetry.state import BdSeqFile


def test_a_saved_bdseq_is_read_back_by_the_next_run_and_no_temporary_file_stays(
    tmp_path: Path,
) -> None:
    lines: list[str] = []
    first = BdSeqFile(tmp_path / "state", "grp", "gw", lines.append)
    assert first.load() is None and "starting at 0" in lines[0]
    first.save(0)
    first.save(1)
    assert BdSeqFile(tmp_path / "state", "grp", "gw", lines.append).load() == 1
    assert [p.name for p in (tmp_path / "state").iterdir()] == ["sparkplug-grp-gw.json"]
    assert BdSeqFile(tmp_path / "state", "grp", "other", lines.append).load() is None


def test_a_corrupt_file_starts_at_0_with_a_log_line(tmp_path: Path) -> None:
    for text in ("{not json", '{"bdSeq": 300}', '{"bdSeq": true}', "[]"):
        (tmp_path / "sparkplug-grp-gw.json").write_text(text)
        lines: list[str] = []
        assert BdSeqFile(tmp_path, "grp", "gw", lines.append).load() is None
        assert len(lines) == 1 and "unreadable" in lines[0] and "starts at 0" in lines[0]


def test_an_unwritable_state_directory_is_logged_once_and_telemetry_goes_on(
    tmp_path: Path,
) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("")
    lines: list[str] = []
    store = BdSeqFile(blocker / "state", "grp", "gw", lines.append)  # below a plain file
    store.save(1)
    store.save(2)
    assert len(lines) == 1 and "cannot save bdSeq" in lines[0]
    assert not os.path.exists(blocker / "state")

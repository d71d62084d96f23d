"""What telemetry keeps across restarts of the gateway: the Sparkplug bdSeq.

A host application tells a new MQTT session of an edge node from a stale Will by
bdSeq, so a restarted gateway must not start again at the number its last run
used: it goes on from the one saved here. One small JSON file per edge node in
the state directory (`[telemetry] state_dir`), written before every CONNECT,
atomically (a temporary file in the same directory, flushed, synced and renamed
over the old one), so a crash leaves the old number or the new one, never half a
file. A missing or unreadable file starts at 0, with one log line.
"""

from __future__ import annotations

import json
import os
import tempfile
from collections.abc import Callable
from pathlib import Path


class BdSeqFile:
    """The last bdSeq an edge node used, in `folder/sparkplug-<group>-<edge>.json`."""

    def __init__(self, folder: Path, group_id: str, edge_node_id: str, log: Callable[[str], None]):
        self.path = Path(folder).expanduser() / f"sparkplug-{group_id}-{edge_node_id}.json"
        self.log = log
        self._saved: int | None = None
        self._failed = False

    def load(self) -> int | None:
        """The bdSeq last saved (0..255), or None (log line: starting at 0)."""
        try:
            body = json.loads(self.path.read_text())
            bdseq = body["bdSeq"] if isinstance(body, dict) else None
            if not isinstance(bdseq, int) or isinstance(bdseq, bool) or not 0 <= bdseq <= 255:
                raise ValueError(f"bdSeq {bdseq!r} is not 0..255")
        except FileNotFoundError:
            self.log(f"telemetry sparkplug: no saved bdSeq in {self.path}; starting at 0")
            return None
        except (OSError, ValueError, KeyError) as exc:
            self.log(f"telemetry sparkplug: {self.path} unreadable ({exc}); bdSeq starts at 0")
            return None
        self._saved = bdseq
        return bdseq

    def save(self, bdseq: int) -> None:
        """Replace the file atomically; a failure is logged once and telemetry goes on."""
        if bdseq == self._saved:
            return
        folder = self.path.parent
        try:
            folder.mkdir(parents=True, exist_ok=True)
            fd, temporary = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=folder)
            try:
                with os.fdopen(fd, "w") as handle:
                    json.dump({"bdSeq": bdseq}, handle)
                    handle.flush()
                    os.fsync(handle.fileno())
                os.replace(temporary, self.path)
            except BaseException:
                Path(temporary).unlink(missing_ok=True)
                raise
            directory = os.open(folder, os.O_RDONLY)
            try:
                os.fsync(directory)  # the rename itself survives a power cut
            finally:
                os.close(directory)
        except OSError as exc:
            if not self._failed:
                self.log(f"telemetry sparkplug: cannot save bdSeq to {self.path} ({exc})")
            self._failed = True
            return
        self._saved = bdseq
        self._failed = False

"""What `grasplink run` writes: ground truth, sensor signals, a CAN log and a summary.

Files in the output folder, all written as the scene runs (bounded memory):

- `truth.csv`  - physics domain: object position/speed/slip state, grip, load, belt...
- `skin.csv`   - the FSR signal at the skin node's sample times (N)
- `emg.csv`    - the surface EMG at the EMG node's sample times (µV)
- `can.asc`    - every frame on the bus (Vector ASC, readable by python-can's LogReader)
- `summary.json` - scene, nodes, effects, frame counts, bus load

Everything is a pure function of the scene and its seed: the same scene and
seed give byte-identical files (the ASC date line is the scene epoch, not
the wall clock; run timing is printed, never recorded).
"""

from __future__ import annotations

import json
from collections import Counter
from datetime import UTC, datetime
from pathlib import Path
from typing import TextIO

import can
import numpy as np

from grasplink.bus.faults import ERROR_FRAME_BITS, ErrorFrame
from grasplink.bus.load import frame_bits_worst_case
from grasplink.core.frames import Frame

SCENE_EPOCH = datetime(2000, 1, 1, tzinfo=UTC)
BITRATE = 1_000_000
DOMAIN_FILES = {"physics": "truth.csv", "skin": "skin.csv", "emg": "emg.csv"}


class SceneAscWriter(can.ASCWriter):
    """python-can's ASC writer with the scene epoch instead of the wall clock in its header.

    Its header times are `FORMAT_DATE` (a public class attribute) given the milliseconds,
    then formatted by strftime: a date with neither braces nor % directives stays as it is.
    """

    FORMAT_DATE = SCENE_EPOCH.strftime("%a %b %d %H:%M:%S.0 %Y")


class CsvStream:
    """Columns t_s + signals, appended chunk by chunk with a fixed number format."""

    def __init__(self, path: Path, columns: list[str]):
        self.columns = columns
        self.file: TextIO = path.open("w", newline="\n")
        self.file.write(",".join(["t_s", *columns]) + "\n")
        self.rows = 0

    def write(self, times_us: np.ndarray, values: dict[str, np.ndarray]) -> None:
        if not len(times_us):
            return
        table = np.column_stack([times_us / 1e6, *(values[c] for c in self.columns)])
        lines = "\n".join(",".join(f"{v:.9g}" for v in row) for row in table)
        self.file.write(lines + "\n")
        self.rows += len(times_us)

    def close(self) -> None:
        self.file.close()


class Recorder:
    def __init__(self, out_dir: Path):
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self._streams: dict[str, CsvStream] = {}
        self._asc = SceneAscWriter(str(self.out_dir / "can.asc"))
        self.frames: Counter[int] = Counter()
        self.error_frames = 0
        self.bits = 0

    def open_domain(self, domain: str, signals: list[str]) -> None:
        if signals:
            self._streams[domain] = CsvStream(self.out_dir / DOMAIN_FILES[domain], signals)

    def write_chunk(self, domain: str, times_us: np.ndarray, values: dict[str, np.ndarray]) -> None:
        stream = self._streams.get(domain)
        if stream is not None:
            stream.write(times_us, values)

    def tap(self, t_us: int, frame: Frame | ErrorFrame, sender: object) -> None:
        """A LockstepNetwork tap: log every frame at its bus time."""
        if isinstance(frame, ErrorFrame):
            self.error_frames += 1
            self.bits += ERROR_FRAME_BITS
            self._asc.on_message_received(can.Message(timestamp=t_us / 1e6, is_error_frame=True))
            return
        self.frames[frame.can_id] += 1
        self.bits += frame_bits_worst_case(frame.length, frame.rtr)
        self._asc.on_message_received(
            can.Message(
                timestamp=t_us / 1e6,
                arbitration_id=frame.can_id,
                is_extended_id=False,
                is_remote_frame=frame.rtr,
                dlc=frame.length,
                data=b"" if frame.rtr else frame.data,
            )
        )

    def close(self, summary: dict) -> None:
        for stream in self._streams.values():
            stream.close()
        self._asc.stop()
        duration_s = summary.get("simulated_s", summary.get("duration_s")) or 1.0
        summary = {
            **summary,
            "files": {d: DOMAIN_FILES[d] for d in self._streams} | {"can": "can.asc"},
            "samples": {d: s.rows for d, s in self._streams.items()},
            "frames": {f"0x{k:03X}": v for k, v in sorted(self.frames.items())},
            "error_frames": self.error_frames,
            "bus_load_percent": round(100.0 * self.bits / duration_s / BITRATE, 4),
        }
        text = json.dumps(summary, indent=2, sort_keys=True)
        (self.out_dir / "summary.json").write_text(text + "\n")

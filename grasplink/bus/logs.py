"""Record a bus to a log file, and replay a log onto a bus or into sans-IO devices.

Logs are the formats CAN tools already read and write, through python-can:
Vector ASC (.asc), Vector BLF (.blf), can-utils `candump -L` (.log) and PEAK
PCAN-View traces (.trc, python-can's TRCReader/TRCWriter; a TRC log written here
holds data frames only: python-can's TRCWriter cannot write error or remote
frames, so a recording leaves them out and counts them).

The timing of a replay is a sans-IO object, `ReplaySchedule`: it turns a log
into (due time, message) pairs honouring the timestamps, a speed factor and
looping, and knows nothing of clocks or buses. Two edges play it:

* `replay_to_bus` - real time: sleeps until each frame is due and sends it on
  any python-can bus (`grasplink replay`);
* `LogPlayer` - virtual time: a sans-IO device that puts the log's frames on a
  `LockstepNetwork` at their log times, so a gateway hears a recorded run
  exactly as it heard it live, in milliseconds and deterministically.

`record_bus` is the IO edge of recording: python-can's writers (`can.Logger`
picks the format by suffix), closed cleanly on a stop request so the file is
complete (an ASC end marker, a BLF header with its object count).
"""

from __future__ import annotations

import copy
import struct
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

import can

from grasplink.bus.url import BusDisconnected, message_to_frame
from grasplink.core.frames import Frame, function_of
from grasplink.core.log_formats import LOG_FORMATS
from grasplink.errors import BusError, ConfigError, RecordingError

#: Formats whose python-can writer holds data frames only (TRCWriter skips error and
#: remote frames with a warning each): a recording leaves those out and counts them.
DATA_FRAMES_ONLY = frozenset({".trc"})
RECV_POLL_S = 0.1  # how often a recording notices a stop request or its deadline
MAX_SLEEP_S = 0.1  # a replay waiting for a distant frame still notices a stop request
NODE_SERVICES = frozenset({"EMCY", "TPDO1", "TPDO2", "TPDO3", "TPDO4", "SDO tx", "heartbeat"})


def _formats() -> str:
    return ", ".join(f"{s} ({name})" for s, name in LOG_FORMATS.items())


def _suffixes() -> str:
    names = list(LOG_FORMATS)
    return ", ".join(names[:-1]) + f" or {names[-1]}"


def log_format(path: Path) -> str:
    """The format name of a log path by its suffix; ConfigError for any other suffix."""
    suffix = Path(path).suffix.lower()
    if suffix not in LOG_FORMATS:
        shown = f"'{suffix}'" if suffix else "no suffix"
        raise ConfigError(f"{path}: unknown log format ({shown}); use {_formats()}")
    return LOG_FORMATS[suffix]


# -- reading ------------------------------------------------------------------------------
@dataclass
class LogSummary:
    """What a log holds: counted before a replay touches the bus."""

    path: Path
    frames: int = 0  # data and remote frames
    error_frames: int = 0
    first_s: float | None = None
    last_s: float | None = None

    @property
    def span_s(self) -> float:
        if self.first_s is None or self.last_s is None:
            return 0.0
        return max(0.0, self.last_s - self.first_s)


def read_log(path: Path) -> Iterator[can.Message]:
    """The messages of a log in file order; RecordingError (one line) if it cannot be read."""
    path = Path(path)
    log_format(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such file")
    if path.is_dir():
        raise RecordingError(f"{path}: is a directory, not a CAN log")
    count = 0
    try:
        with can.LogReader(str(path)) as reader:
            for msg in reader:
                count += 1
                yield msg
    except RecordingError:
        raise
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror or exc}") from None
    except Exception as exc:  # python-can's readers raise ValueError, struct.error, BLFParseError
        where = f"after {count} frames" if count else "at its start"
        what = f"corrupt or truncated ({exc})" if isinstance(exc, struct.error) else repr(exc)
        raise RecordingError(
            f"{path}: not a readable {LOG_FORMATS[path.suffix.lower()]} log ({where}): {what}"
        ) from None


def scan_log(path: Path) -> LogSummary:
    """Read a whole log once: a malformed or empty log fails here, before any frame is sent."""
    summary = LogSummary(Path(path))
    for msg in read_log(path):
        if msg.is_error_frame:
            summary.error_frames += 1
        else:
            summary.frames += 1
        if summary.first_s is None:
            summary.first_s = msg.timestamp
        summary.last_s = msg.timestamp
    if not summary.frames:
        raise RecordingError(
            f"{path}: holds no CAN frames (is it a {LOG_FORMATS[Path(path).suffix.lower()]} log?)"
        )
    return summary


def from_nodes_only(master_id: int) -> Callable[[can.Message], bool]:
    """Keep what the device nodes sent (TPDOs, EMCY, SDO responses, heartbeats, boot-ups).

    Drops what a master sent - NMT, SYNC, SDO requests, RPDOs and the master's own
    heartbeat - so a replay onto a bus with real nodes never commands them, and a
    gateway listening to the replay hears only what it heard live.
    """

    def keep(msg: can.Message) -> bool:
        if msg.is_extended_id or msg.is_error_frame or not 0 <= msg.arbitration_id <= 0x7FF:
            return False
        service, node_id = function_of(msg.arbitration_id)
        return service in NODE_SERVICES and node_id not in (0, master_id)

    return keep


# -- the schedule (sans-IO) ---------------------------------------------------------------
class Scheduled(NamedTuple):
    due_us: int  # after the replay starts
    message: can.Message
    pass_number: int  # 1 for the first pass through the log


@dataclass(frozen=True)
class ReplaySchedule:
    """When each frame of a log is due: log time divided by `speed`, pass after pass.

    Frames keep their file order; each is due (its timestamp - the log's first
    timestamp) / speed after the start, and never before the frame ahead of it (a
    timestamp that steps back is sent at once). Error frames and frames `keep`
    refuses are left out but keep the time line: a filtered replay still starts
    where the log starts. Looping, the next pass begins one mean frame interval
    after the previous pass's last frame, so the average rate carries on.
    """

    speed: float = 1.0
    loop: bool = False
    keep: Callable[[can.Message], bool] | None = None

    def __post_init__(self) -> None:
        if not self.speed > 0 or self.speed == float("inf"):
            raise ConfigError(f"replay speed must be a positive factor, got {self.speed}")

    def timeline(self, read: Callable[[], Iterable[can.Message]]) -> Iterator[Scheduled]:
        """(due_us, message, pass) for every frame; `read()` gives the log from its start."""
        offset_us = 0
        pass_number = 1
        while True:
            t0_us: int | None = None
            last_us = 0
            last_due_us = offset_us
            seen = 0
            for msg in read():
                t_us = round(msg.timestamp * 1e6)
                if t0_us is None:
                    t0_us = t_us
                last_us = t_us
                seen += 1
                if msg.is_error_frame or (self.keep is not None and not self.keep(msg)):
                    continue
                due_us = max(last_due_us, offset_us + round((t_us - t0_us) / self.speed))
                last_due_us = due_us
                yield Scheduled(due_us, msg, pass_number)
            if not self.loop or t0_us is None:
                return
            span_us = max(0, last_us - t0_us)
            interval_us = span_us / (seen - 1) if seen > 1 and span_us else 1e6
            offset_us += round((span_us + interval_us) / self.speed)
            pass_number += 1


# -- real-time edge -----------------------------------------------------------------------
@dataclass
class ReplayStats:
    frames_sent: int = 0
    passes: int = 0
    max_late_s: float = 0.0  # how far behind its due time the latest-sent frame went out
    wall_s: float = 0.0
    stopped: bool = False  # a stop request ended it before the log did


def replay_to_bus(
    bus: can.BusABC,
    timeline: Iterable[Scheduled],
    *,
    should_stop: Callable[[], bool] = lambda: False,
    clock: Callable[[], float] = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
) -> ReplayStats:
    """Send each scheduled frame when it is due (no drift: due times count from the start).

    A frame goes out with the wall-clock time it is sent, as a real controller would
    stamp it; a late frame goes out at once, and the ones after it keep their times.
    """
    stats = ReplayStats()
    start = clock()
    for due_us, msg, pass_number in timeline:
        due = start + due_us / 1e6
        while (wait := due - clock()) > 0:
            if should_stop():
                break
            sleep(min(wait, MAX_SLEEP_S))
        if should_stop():
            stats.stopped = True
            break
        out = copy.copy(msg)
        out.timestamp = time.time()
        out.channel = None
        try:
            bus.send(out)
        except BusDisconnected as exc:
            raise BusError(f"{exc}; {stats.frames_sent} frames were sent") from None
        except can.CanError as exc:
            raise BusError(
                f"sending frame {stats.frames_sent + 1} (0x{msg.arbitration_id:03X}) failed: {exc}"
            ) from None
        stats.frames_sent += 1
        stats.passes = pass_number
        stats.max_late_s = max(stats.max_late_s, clock() - due)
    stats.wall_s = clock() - start
    return stats


# -- virtual-time edge --------------------------------------------------------------------
class LogPlayer:
    """A sans-IO device playing a log's frames at their log times (a `LockstepNetwork` peer).

    `start(t_us)` fixes where the log's first timestamp falls; every frame then
    comes out of `advance` at start + its due time. Frames a `Frame` cannot carry
    (29-bit identifiers, CAN FD) are counted in `skipped`. It hears nothing.
    """

    def __init__(self, timeline: Iterable[Scheduled], node_id: int = 0):
        self.node_id = node_id
        self._timeline = iter(timeline)
        self._next: Scheduled | None = next(self._timeline, None)
        self._origin_us: int | None = None
        self.frames_sent = 0
        self.skipped = 0

    def start(self, t_us: int) -> list[Frame]:
        self._origin_us = t_us
        return self.advance(t_us)

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        return []

    def advance(self, t_us: int) -> list[Frame]:
        frames: list[Frame] = []
        while self._next is not None and self._origin_us is not None:
            if self._origin_us + self._next.due_us > t_us:
                break
            frame = message_to_frame(self._next.message)
            if frame is None:
                self.skipped += 1
            else:
                frames.append(frame)
            self._next = next(self._timeline, None)
        self.frames_sent += len(frames)
        return frames

    def next_deadline_us(self) -> int | None:
        if self._next is None or self._origin_us is None:
            return None
        return self._origin_us + self._next.due_us

    @property
    def finished(self) -> bool:
        return self._next is None


# -- recording ----------------------------------------------------------------------------
def check_record_path(path: Path, *, force: bool = False) -> str:
    """Refuse an unknown suffix, a missing folder or an existing file (unless `force`)."""
    path = Path(path)
    name = log_format(path)
    if path.is_dir():
        raise ConfigError(f"{path}: is a directory; give a file name ending in {_suffixes()}")
    if path.exists() and not force:
        raise ConfigError(f"{path} already exists; use --force to overwrite it")
    if not path.parent.is_dir():
        raise ConfigError(f"{path}: folder {path.parent} does not exist")
    return name


@dataclass
class RecordStats:
    path: Path
    frames: int = 0  # data and remote frames
    error_frames: int = 0
    wall_s: float = 0.0
    by_can_id: dict[int, int] = field(default_factory=dict)
    left_out: int = 0  # error and remote frames a data-frames-only format cannot hold


def record_bus(
    bus: can.BusABC,
    path: Path,
    *,
    duration_s: float | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    force: bool = False,
    bus_name: str = "the bus",
) -> RecordStats:
    """Write every frame `bus` receives to `path` until `duration_s` or a stop request.

    The writer is stopped whatever ends the recording (a stop request, a lost bus,
    an exception), so the file on disk is always a complete log of what came in.
    """
    path = Path(path)
    check_record_path(path, force=force)
    stats = RecordStats(path)
    data_only = path.suffix.lower() in DATA_FRAMES_ONLY
    try:
        writer = can.Logger(str(path))
    except OSError as exc:
        raise ConfigError(f"cannot write {path}: {exc.strerror or exc}") from None
    start = time.monotonic()
    deadline = None if duration_s is None else start + duration_s
    try:
        while not should_stop():
            left = (
                RECV_POLL_S if deadline is None else min(RECV_POLL_S, deadline - time.monotonic())
            )
            if left <= 0:
                break
            try:
                msg = bus.recv(left)
            except BusDisconnected as exc:
                raise BusError(
                    f"lost {bus_name} ({exc}); {path} holds the {stats.frames} frames before"
                ) from None
            except can.CanError as exc:
                raise BusError(
                    f"reading {bus_name} failed ({exc}); {path} holds the {stats.frames} "
                    "frames before"
                ) from None
            if msg is None:
                continue
            if not msg.timestamp:
                msg.timestamp = time.time()
            if data_only and (msg.is_error_frame or msg.is_remote_frame):
                stats.left_out += 1
                continue
            writer.on_message_received(msg)
            if msg.is_error_frame:
                stats.error_frames += 1
            else:
                stats.frames += 1
                stats.by_can_id[msg.arbitration_id] = stats.by_can_id.get(msg.arbitration_id, 0) + 1
    finally:
        writer.stop()
        stats.wall_s = time.monotonic() - start
    return stats

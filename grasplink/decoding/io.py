"""Skin recordings from files: (t_s, force_n) float64 arrays for the decoders.

* CSV with the header ``t_s,force_n`` or ``t_s,skin.force_n`` (the skin.csv
  `grasplink run` writes), spaces around names and values tolerated, one
  sample a line, time strictly increasing.
* NPZ with the arrays ``t_s`` and ``force_n`` (equal length, 1-D, real
  numbers: integer or floating point; complex, boolean, date or text arrays
  are refused rather than silently converted).
* A folder written by `grasplink run`: its skin.csv, with the layout and the
  sample rate from its summary.json (`read_run_folder`).
* CAN logs of the skin node (``.asc``, ``.blf``, ``.log`` candump, ``.trc``
  PCAN-View trace: `core.log_formats.LOG_FORMATS`, read by python-can's LogReader):
  the frames of the TPDO that maps the sample slots (2100h), unpacked by the
  skin EDS's own mapping (`PdoCodec`, as the live gateway unpacks them), with
  samples per PDO (2121h), sample rate (2120h) and the FSR calibration
  defaults (2130h: `skin_frames.SkinCalibration`).

Frames become samples through the live gateway's own front end (`skin_frames.SkinFrames`
over `packets.SampleStream`): sample times from the packet sequence, anchored on the
earliest time stamps of the first `SETTLE_US` and rounded to a sample period, so
time-stamp jitter changes nothing; a frame up to `REORDER_PACKETS` packets late is put
back in place by its sequence number (held frames take the held time stamps in
increasing order); the node's boot-up message starts the sample times anew.

What a CAN log loses is counted in `CanStats` (`CanStats.summary()` is the
line `grasplink decode` prints): frames of the wrong length; frames that
repeat a sequence number already seen (a re-publish); frames arriving more
than `REORDER_PACKETS` packets late; frames whose time stamp is far from
their number's place and that no frame follows (stray); packets missing from
the sequence numbers. A log where fewer than `MIN_USABLE_SHARE` of the skin
frames are usable is refused by `CanStats.check_usable`.

Every problem is a `RecordingError` naming the file and the line, key or
value, so `grasplink decode` can print one line and exit 1.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from grasplink.core.frames import HEARTBEAT_BASE, SDO_RX_BASE
from grasplink.core.log_formats import LOG_FORMATS
from grasplink.decoding.base import MIN_USABLE_SHARE, Decoder, check_sample_rate, skin_limits
from grasplink.decoding.skin_frames import SampleObjects, SkinCalibration, SkinFrames
from grasplink.errors import ConfigError, PdoError, RecordingError
from grasplink.profiles import objects as obj
from grasplink.profiles.pdo_codec import PdoCodec

CSV_HEADER = ("t_s", "force_n")
#: The force column of a CSV: ours, or the skin.csv of `grasplink run`
#: (the recorder's SKIN_FORCE_N signal name; a test ties the two).
FORCE_COLUMNS = ("force_n", "skin.force_n")
CAN_EXTENSIONS = tuple(LOG_FORMATS)  # the formats grasplink record/replay take
RUN_SUMMARY = "summary.json"
DEFAULT_SKIN_NODE_ID = 0x10
#: How late (in packets) a frame may arrive and still be put back in place: 8 packets
#: are 60 ms at 400 Hz, far more than any reordering of a CAN bus or adapter queue.
REORDER_PACKETS = 8
#: Arrivals gathered to anchor the sample times (packets.SampleStream): 250 ms, some 33
#: packets at 400 Hz; the earliest of them sets the anchor, so time-stamp jitter of a
#: USB adapter or a loaded host (a few ms) moves no sample time.
SETTLE_US = 250_000
BOOT_UP_DATA = b"\x00"  # a heartbeat carrying state 0: the node (re)booted
REAL_KINDS = "iuf"  # numpy kinds of a real number: signed, unsigned, floating point


@dataclass
class CanStats:
    """What a CAN log held and what became of the skin's TPDO1 frames.

    frames = packets + malformed + republished + out_of_order + stray.
    """

    frames: int = 0  # skin TPDO1 frames seen
    packets: int = 0  # of them, used: their samples decoded
    malformed: int = 0  # dropped: wrong data length
    republished: int = 0  # dropped: a sequence number already seen (a re-publish)
    out_of_order: int = 0  # dropped: more than REORDER_PACKETS packets late
    stray: int = 0  # dropped: time stamp far from its number's place, no frame following it
    reordered: int = 0  # used, put back in place by their sequence number
    lost_packets: int = 0  # sequence numbers never seen (the frames are not in the log)
    restarts: int = 0  # the node's boot-up messages amid its frames: sample times anew
    resyncs: int = 0  # new anchors where the time stamps contradict the sequence
    frames_read: int = 0  # every frame in the log
    other_frames: int = 0  # frames of other CAN-IDs, remote and error frames
    rate_hz: float = 0.0  # the sample rate the times were built with
    cob_id: int = 0
    other_ids: set[int] = field(default_factory=set)

    @property
    def dropped(self) -> int:
        return self.malformed + self.republished + self.out_of_order + self.stray

    @property
    def usable_share(self) -> float:
        return self.packets / self.frames if self.frames else 0.0

    def reasons(self) -> str:
        parts = [
            (self.malformed, "wrong data length"),
            (self.republished, "repeated sequence number (a re-publish)"),
            (self.out_of_order, f"more than {REORDER_PACKETS} packets late"),
            (self.stray, "time stamp far from its sequence number's place"),
        ]
        return ", ".join(f"{n} {why}" for n, why in parts if n) or "none"

    def summary(self, source: str) -> str:
        """One line: frames read, used, dropped by reason, lost, reordered, anchors, other IDs."""
        ids = sorted(self.other_ids)
        shown = ", ".join(f"0x{i:03X}" for i in ids[:8]) + (", ..." if len(ids) > 8 else "")
        text = (
            f"{source}: {self.frames_read} frames read; skin TPDO1 (0x{self.cob_id:03X}): "
            f"{self.frames} frames, {self.packets} used ({self.usable_share:.0%}), "
            f"{self.dropped} dropped ({self.reasons()})"
        )
        if self.reordered:
            text += f"; {self.reordered} put back in order by sequence number"
        text += f"; {self.lost_packets} packets missing from the sequence numbers"
        if self.restarts:
            text += f"; {self.restarts} node restarts (boot-up), sample times anew"
        if self.resyncs:
            text += (
                f"; {self.resyncs} new time anchors (a silence, or time stamps "
                "contradicting the sequence)"
            )
        if self.other_frames:
            text += f"; {self.other_frames} frames of other CAN-IDs ({shown or 'remote/error'})"
        return text

    def check_usable(self, source: str) -> None:
        """RecordingError when fewer than MIN_USABLE_SHARE of the skin frames were used."""
        if self.usable_share < MIN_USABLE_SHARE:
            raise RecordingError(
                f"{source}: only {self.packets} of {self.frames} skin TPDO1 frames usable "
                f"({self.usable_share:.0%}, below {MIN_USABLE_SHARE:.0%}): {self.reasons()}"
            )


def read_recording(
    path: str | Path, *, node_id: int = DEFAULT_SKIN_NODE_ID, fs_hz: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Read any supported recording by its extension (a folder: `read_run_folder`)."""
    p = Path(path)
    if p.is_dir():
        run = read_run_folder(p)
        return run.t_s, run.force_n
    suffix = p.suffix.lower()
    if suffix == ".npz":
        return read_npz(p)
    if suffix in CAN_EXTENSIONS:
        t, force, _ = read_can_log(p, node_id=node_id, fs_hz=fs_hz)
        return t, force
    return read_csv(p)


def _open_text(path: Path) -> list[str]:
    try:
        return path.read_text(encoding="utf-8-sig").splitlines()
    except FileNotFoundError:
        raise RecordingError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise RecordingError(f"{path}: is a directory, not a recording") from None
    except UnicodeDecodeError as exc:
        raise RecordingError(
            f"{path}: not a text (CSV) file: {exc.reason} at byte {exc.start}"
        ) from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read: {exc.strerror}") from None


def read_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """CSV with header ``t_s,force_n`` (or ``t_s,skin.force_n``); values finite, time increasing."""
    p = Path(path)
    lines = _open_text(p)
    numbered = [(n, line) for n, line in enumerate(lines, start=1) if line.strip()]
    if not numbered:
        raise RecordingError(f"{p}: empty file; expected a header 't_s,force_n' and samples")
    header_line, header = numbered[0]
    names = tuple(name.strip() for name in header.split(","))
    if len(names) != 2 or names[0] != CSV_HEADER[0] or names[1] not in FORCE_COLUMNS:
        raise RecordingError(
            f"{p}:{header_line}: header must be 't_s,force_n' (or 't_s,skin.force_n'), "
            f"found {header.strip()!r}"
        )
    rows = numbered[1:]
    if not rows:
        raise RecordingError(f"{p}: no samples after the header")
    t = np.empty(len(rows))
    force = np.empty(len(rows))
    for k, (n, line) in enumerate(rows):
        fields = line.split(",")
        if len(fields) != 2:
            raise RecordingError(
                f"{p}:{n}: expected 2 values (t_s,force_n), found {len(fields)}: {line.strip()!r}"
            )
        for column, (name, text) in enumerate(zip(CSV_HEADER, fields, strict=True)):
            value = _number(text)
            if value is None:
                raise RecordingError(f"{p}:{n}: {name} {text.strip()!r} is not a finite number")
            (t if column == 0 else force)[k] = value
        if k and t[k] <= t[k - 1]:
            raise RecordingError(
                f"{p}:{n}: time {fields[0].strip()} s is not after the "
                f"previous sample's {t[k - 1]:g} s (time must increase)"
            )
    return t, force


def _number(text: str) -> float | None:
    try:
        value = float(text.strip())
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def read_npz(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """NPZ with 1-D real arrays ``t_s`` and ``force_n`` of equal length, finite, time increasing."""
    p = Path(path)
    try:
        archive = np.load(p, allow_pickle=False)
    except FileNotFoundError:
        raise RecordingError(f"{p}: no such file") from None
    except IsADirectoryError:
        raise RecordingError(f"{p}: is a directory, not a recording") from None
    except EOFError:
        raise RecordingError(f"{p}: empty file, not an .npz archive") from None
    except (OSError, ValueError) as exc:
        raise RecordingError(f"{p}: not a readable .npz archive ({exc})") from None
    if not hasattr(archive, "files"):  # np.load read a lone .npy array
        raise RecordingError(f"{p}: a single array, not an .npz archive with t_s and force_n")
    with archive:
        missing = [key for key in CSV_HEADER if key not in archive.files]
        if missing:
            raise RecordingError(
                f"{p}: missing array(s) {', '.join(missing)}; found "
                f"{', '.join(archive.files) or 'none'}"
            )
        try:
            raw = {key: archive[key] for key in CSV_HEADER}
        except (OSError, ValueError) as exc:
            raise RecordingError(f"{p}: t_s and force_n must be numeric arrays ({exc})") from None
    for name, a in raw.items():
        if a.dtype.kind not in REAL_KINDS:
            raise RecordingError(
                f"{p}: {name} holds {_kind_name(a.dtype)} ({a.dtype}); "
                "a recording must be real numbers (integer or floating point)"
            )
        if a.ndim != 1:
            raise RecordingError(f"{p}: {name} must be 1-D, has shape {a.shape}")
    t = raw["t_s"].astype(np.float64)
    force = raw["force_n"].astype(np.float64)
    if len(t) != len(force):
        raise RecordingError(f"{p}: t_s has {len(t)} values, force_n {len(force)}")
    if not len(t):
        raise RecordingError(f"{p}: no samples")
    for name, a in (("t_s", t), ("force_n", force)):
        bad = np.nonzero(~np.isfinite(a))[0]
        if len(bad):
            raise RecordingError(
                f"{p}: {name}[{bad[0]}] is {a[bad[0]]} (every value must be a finite number)"
            )
    steps = np.nonzero(np.diff(t) <= 0)[0]
    if len(steps):
        k = int(steps[0]) + 1
        raise RecordingError(
            f"{p}: t_s[{k}] = {t[k]:g} s is not after t_s[{k - 1}] = "
            f"{t[k - 1]:g} s (time must increase)"
        )
    return t, force


def _kind_name(dtype: np.dtype) -> str:
    names = {
        "c": "complex numbers",
        "b": "booleans",
        "M": "dates",
        "m": "time differences",
        "U": "text",
        "S": "bytes",
        "O": "Python objects",
        "V": "records",
    }
    return names.get(dtype.kind, "non-numbers")


def infer_rate(t: np.ndarray, source: str) -> float:
    """Sample rate from the median time step; refuses what has no sensible one."""
    if len(t) < 2:
        raise RecordingError(f"{source}: one sample cannot tell the sample rate; give --fs")
    step = float(np.median(np.diff(t)))
    if not step > 0:
        raise RecordingError(
            f"{source}: the median time step is {step:g} s; cannot infer "
            "the sample rate (give --fs)"
        )
    rate = 1.0 / step
    low, high = skin_limits().rate_hz
    if not low <= rate <= high:
        raise RecordingError(
            f"{source}: the median time step {step:g} s means {rate:g} Hz, outside the "
            f"skin node's {low:g}-{high:g} Hz (0x2120); give --fs"
        )
    return rate


# -- a folder written by `grasplink run` ---------------------------------------------------
@dataclass(frozen=True)
class RunRecording:
    """The skin signal of a `grasplink run` folder, with what its summary says about it."""

    t_s: np.ndarray
    force_n: np.ndarray
    layout: str | tuple[float, ...] | None  # a layout name, spacings in mm, or unknown
    rate_hz: float | None
    source: Path  # the CSV read


def read_run_folder(folder: str | Path) -> RunRecording:
    """skin.csv of a run folder, the layout and skin rate from its summary.json."""
    folder = Path(folder)
    summary_path = folder / RUN_SUMMARY
    try:
        summary = json.loads(summary_path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise RecordingError(
            f"{folder}: a folder, but not one written by `grasplink run` (no {RUN_SUMMARY})"
        ) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RecordingError(f"{summary_path}: not a readable run summary ({exc})") from None
    if not isinstance(summary, dict):
        raise RecordingError(f"{summary_path}: not a run summary (a JSON object)")
    files = summary.get("files")
    name = files.get("skin") if isinstance(files, dict) else None
    if not isinstance(name, str) or not name or Path(name).name != name:
        raise RecordingError(f"{summary_path}: files.skin names no skin recording in the folder")
    layout = summary.get("layout")
    if isinstance(layout, list):
        if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in layout):
            raise RecordingError(f"{summary_path}: layout {layout!r} is not spacings in mm")
        layout = tuple(float(v) for v in layout)
    elif layout is not None and not isinstance(layout, str):
        raise RecordingError(f"{summary_path}: layout {layout!r} is not a name or spacings")
    rates = summary.get("rates_hz")
    rate = rates.get("skin") if isinstance(rates, dict) else None
    if rate is not None and (isinstance(rate, bool) or not isinstance(rate, int | float)):
        raise RecordingError(f"{summary_path}: rates_hz.skin {rate!r} is not a number of Hz")
    source = folder / name
    t, force = read_csv(source)
    return RunRecording(t, force, layout, None if rate is None else float(rate), source)


# -- CAN logs ----------------------------------------------------------------------------------
@dataclass(frozen=True)
class SkinTpdo:
    """The skin's sample TPDO as its EDS maps it, and what the samples mean."""

    codec: PdoCodec  # decodes its frames, as the live gateway does
    cob_id: int
    length: int  # data bytes
    samples_per_pdo: int
    rate_hz: float
    calibration: SkinCalibration


def skin_tpdo(node_id: int = DEFAULT_SKIN_NODE_ID) -> SkinTpdo:
    """The TPDO mapping sample slots (2100h), the sample rate (2120h), samples per PDO
    (2121h) and the FSR calibration (2130h) of the shipped skin EDS."""
    from grasplink.profiles import load_profile, od_default

    codec = PdoCodec("skin", node_id)
    for cob_id in sorted(codec.tpdo_can_ids()):
        keys = codec.tpdo_keys(cob_id)
        slots = sum(1 for index, _ in keys if index == obj.SKIN_SAMPLE_SLOTS)
        if slots:
            break
    else:
        raise ConfigError(
            f"skin EDS: no TPDO maps an FSR sample slot (0x{obj.SKIN_SAMPLE_SLOTS:04X})"
        )
    od = load_profile("skin", node_id)
    return SkinTpdo(
        codec,
        cob_id,
        codec.tpdo_length(cob_id),
        min(od_default(od, obj.SKIN_SAMPLES_PER_PDO), slots),
        float(od_default(od, obj.SKIN_SAMPLE_RATE_HZ)),
        SkinCalibration.from_od(od),
    )


def read_can_log(
    path: str | Path, *, node_id: int = DEFAULT_SKIN_NODE_ID, fs_hz: float | None = None
) -> tuple[np.ndarray, np.ndarray, CanStats]:
    """Skin TPDO1 samples from a python-can log: (t_s, force_n, stats).

    Frames go through the live gateway's front end (`skin_frames.SkinFrames`) in log
    order, so the samples are bit for bit those the gateway decodes live: sample
    times from the packet sequence, a reorder window of REORDER_PACKETS packets, the
    anchor settled over SETTLE_US of arrivals; the node's boot-up message starts a
    new anchor.
    """
    import can

    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"{p}: no such file")
    pdo = skin_tpdo(node_id)
    rate = check_sample_rate(pdo.rate_hz if fs_hz is None else fs_hz)
    stats = CanStats(rate_hz=rate, cob_id=pdo.cob_id)
    frames = SkinFrames(
        SampleObjects.of_skin(pdo.calibration, pdo.samples_per_pdo),
        rate,
        reorder_packets=REORDER_PACKETS,
        settle_us=SETTLE_US,
    )
    boot_up = HEARTBEAT_BASE + node_id
    times: list[np.ndarray] = []
    forces: list[np.ndarray] = []

    def keep(released: tuple[np.ndarray, np.ndarray]) -> None:
        if len(released[0]):
            times.append(released[0])
            forces.append(released[1])

    try:
        for msg in can.LogReader(str(p)):
            stats.frames_read += 1
            if msg.is_error_frame or msg.is_remote_frame:
                stats.other_frames += 1
                continue
            if msg.arbitration_id != pdo.cob_id or msg.is_extended_id:
                stats.other_frames += 1
                stats.other_ids.add(msg.arbitration_id)
                if msg.arbitration_id == boot_up and bytes(msg.data) == BOOT_UP_DATA:
                    frames.restart()  # the node rebooted: its numbers start again
                continue
            stats.frames += 1
            try:
                values = pdo.codec.decode(pdo.cob_id, bytes(msg.data))
            except PdoError:  # a length its mapping does not have
                stats.malformed += 1
                continue
            keep(frames.feed(float(msg.timestamp) * 1e6, values))
    except RecordingError:
        raise
    except Exception as exc:  # python-can raises assorted errors on a corrupt log
        raise RecordingError(
            f"{p}: cannot read as a CAN log ({type(exc).__name__}: {exc})"
        ) from None
    keep(frames.flush())
    if not stats.frames:
        seen = ", ".join(f"0x{i:03X}" for i in sorted(stats.other_ids)[:12]) or "none"
        raise RecordingError(
            f"{p}: no skin TPDO1 frames (COB-ID 0x{pdo.cob_id:03X}, node-ID "
            f"0x{node_id:02X}, {pdo.length} data bytes); CAN-IDs seen: {seen}"
        )
    got = frames.stats
    stats.packets = got.released
    stats.republished = got.repeated_packets
    stats.out_of_order = got.late_packets
    stats.stray = got.stray_packets
    stats.reordered = got.reordered
    stats.lost_packets = got.lost_packets
    stats.resyncs = got.resyncs
    stats.restarts = got.restarts
    if not times:
        raise RecordingError(f"{p}: no usable skin samples: {stats.reasons()}")
    t = np.concatenate(times)
    return t, np.concatenate(forces), stats


# -- the hand's grip commands in a CAN log (the efference copy) --------------------------------
DEFAULT_HAND_NODE_ID = 0x40


@dataclass(frozen=True)
class GripCommandLog:
    """The grip commands a CAN log holds: each change of the hand's grip target (0x2400 in
    its RPDO) and when it went on the bus, and the grip rate the gateway wrote (0x2404 by
    SDO; None when the log holds no such write: the hand EDS's default applies)."""

    t_s: np.ndarray
    force_n: np.ndarray
    rate_n_s: float | None
    frames: int  # RPDO frames carrying the grip target

    def feed(self, decoder: Decoder) -> None:
        """Tell `decoder` the commands (all before its samples: only those at or before a
        contact's onset weigh it) and the hand's grip rate when the log holds it."""
        if self.rate_n_s is not None:
            decoder.set_hand_follow(self.rate_n_s)
        for t_s, force_n in zip(self.t_s.tolist(), self.force_n.tolist(), strict=True):
            decoder.note_grip_command(t_s, force_n)

    def summary(self, source: str) -> str:
        """The line `grasplink decode` prints."""
        rate = "the hand EDS's default" if self.rate_n_s is None else f"{self.rate_n_s:g} N/s"
        return (
            f"{source}: hand grip RPDO: {self.frames} frames, {len(self.t_s)} grip commands "
            f"fed to the decoder (grip rate {rate})"
        )


def read_grip_commands(path: str | Path, *, node_id: int = DEFAULT_HAND_NODE_ID) -> GripCommandLog:
    """The hand's grip commands from a python-can log (`GripCommandLog`), unpacked by the
    hand EDS's own RPDO mapping (`PdoCodec`), as the node takes them: only changes are
    kept (the gateway refreshes its command), in log order. A log without a hand gives
    none. RecordingError naming the file for a log python-can cannot read."""
    import can

    from grasplink.profiles.pdo_codec import PdoCodec

    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"{p}: no such file")
    codec = PdoCodec("hand", node_id)
    target = (obj.HAND_TARGET_GRIP_MN, 0)
    number = next(
        (n for n in codec.rpdo_numbers() if any(o.key == target for o in codec.rpdo_objects(n))),
        None,
    )
    if number is None:
        raise ConfigError(f"hand EDS: no RPDO maps the grip target (0x{target[0]:04X})")
    cob_id = codec.rpdo(number).cob_id
    sdo_id = SDO_RX_BASE + node_id
    times: list[float] = []
    forces: list[float] = []
    rate: float | None = None
    frames = 0
    try:
        for msg in can.LogReader(str(p)):
            if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
                continue
            data = bytes(msg.data)
            if msg.arbitration_id == sdo_id:
                written = _expedited_write(data, obj.HAND_GRIP_RATE_MN_S)
                if written is not None:
                    rate = written / 1000.0
                continue
            if msg.arbitration_id != cob_id:
                continue
            try:
                values = codec.decode_rpdo(number, data)
            except PdoError:  # a length its mapping does not have: not a command
                continue
            frames += 1
            force = float(values[target]) / 1000.0
            if not forces or force != forces[-1]:
                times.append(float(msg.timestamp))
                forces.append(force)
    except Exception as exc:  # python-can raises assorted errors on a corrupt log
        raise RecordingError(
            f"{p}: cannot read as a CAN log ({type(exc).__name__}: {exc})"
        ) from None
    return GripCommandLog(np.array(times), np.array(forces), rate, frames)


def _expedited_write(data: bytes, index: int, subindex: int = 0) -> int | None:
    """The value of an expedited SDO download of (index, subindex) in this request, or None."""
    if len(data) != 8 or data[0] & 0xE3 != 0x23:  # initiate download, expedited, size given
        return None
    if int.from_bytes(data[1:3], "little") != index or data[3] != subindex:
        return None
    unused = (data[0] >> 2) & 0x3
    return int.from_bytes(data[4 : 8 - unused], "little")

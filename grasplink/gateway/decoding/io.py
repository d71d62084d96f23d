"""Skin recordings from files: (t_s, force_n) float64 arrays for the decoders.

* CSV with the header ``t_s,force_n`` (spaces around names and values
  tolerated), one sample a line, time strictly increasing.
* NPZ with the arrays ``t_s`` and ``force_n`` (equal length, 1-D).
* CAN logs of the skin node (``.asc``, ``.blf``, ``.log`` candump, read by
  python-can's LogReader): TPDO1 frames decoded through the skin EDS - the
  COB-ID (0x1800:01), the mapping (0x1A00: three U16 sample slots 0x2100 and
  the U8 packet sequence 0x2101), samples per PDO (0x2121), sample rate
  (0x2120) and the FSR calibration defaults (0x2130: resolution, full scale
  in mN, zero offset), force_mN = (counts - zero) x full_scale_mN /
  (2^bits - 1 - zero). A packet's last sample is at its frame's timestamp,
  the samples before it 1/fs apart. Lost packets show as gaps in the
  sequence number (counted; the time stamps skip them anyway); a packet
  repeating the previous sequence number is a re-publish (skipped), as is a
  packet whose samples would overlap the next packet's (the node publishes
  its current, not new, samples on entering OPERATIONAL).

Every problem is a `RecordingError` naming the file and the line, key or
value, so `grasplink decode` can print one line and exit 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from grasplink.errors import ConfigError, RecordingError

CSV_HEADER = ("t_s", "force_n")
CAN_EXTENSIONS = (".asc", ".blf", ".log")
DEFAULT_SKIN_NODE_ID = 0x10
SAMPLE_SLOTS, PACKET_SEQUENCE = 0x2100, 0x2101
SAMPLE_RATE, SAMPLES_PER_PDO, CALIBRATION = 0x2120, 0x2121, 0x2130
TPDO1_COMM, TPDO1_MAP = 0x1800, 0x1A00


@dataclass
class CanStats:
    frames: int = 0  # skin TPDO1 frames seen
    packets: int = 0  # packets decoded
    lost_packets: int = 0  # from sequence-number gaps
    republished: int = 0  # skipped: repeated sequence or overlapping the next packet
    malformed: int = 0  # wrong data length
    rate_hz: float = 0.0  # the sample rate the times were built with
    other_ids: set[int] = field(default_factory=set)


def read_recording(
    path: str | Path, *, node_id: int = DEFAULT_SKIN_NODE_ID, fs_hz: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Read any supported recording by its extension."""
    p = Path(path)
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
    """CSV with header exactly ``t_s,force_n``; every value finite, time increasing."""
    p = Path(path)
    lines = _open_text(p)
    numbered = [(n, line) for n, line in enumerate(lines, start=1) if line.strip()]
    if not numbered:
        raise RecordingError(f"{p}: empty file; expected a header 't_s,force_n' and samples")
    header_line, header = numbered[0]
    names = tuple(name.strip() for name in header.split(","))
    if names != CSV_HEADER:
        raise RecordingError(
            f"{p}:{header_line}: header must be 't_s,force_n', found {header.strip()!r}"
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
    """NPZ with 1-D arrays ``t_s`` and ``force_n`` of equal length, finite, time increasing."""
    p = Path(path)
    try:
        archive = np.load(p, allow_pickle=False)
    except FileNotFoundError:
        raise RecordingError(f"{p}: no such file") from None
    except (OSError, ValueError) as exc:
        raise RecordingError(f"{p}: not a readable .npz archive ({exc})") from None
    with archive:
        if not hasattr(archive, "files"):
            raise RecordingError(f"{p}: a single array, not an .npz archive with t_s and force_n")
        missing = [key for key in CSV_HEADER if key not in archive.files]
        if missing:
            raise RecordingError(
                f"{p}: missing array(s) {', '.join(missing)}; found "
                f"{', '.join(archive.files) or 'none'}"
            )
        try:
            t = np.asarray(archive["t_s"], dtype=np.float64)
            force = np.asarray(archive["force_n"], dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise RecordingError(f"{p}: t_s and force_n must be numeric arrays ({exc})") from None
    for name, a in (("t_s", t), ("force_n", force)):
        if a.ndim != 1:
            raise RecordingError(f"{p}: {name} must be 1-D, has shape {a.shape}")
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
    return 1.0 / step


@dataclass(frozen=True)
class SkinPdo:
    """Where TPDO1 keeps what, from the EDS."""

    cob_id: int
    length: int  # payload bytes
    slots: tuple[tuple[int, int], ...]  # (byte offset, bytes) of each sample slot, in order
    sequence: tuple[int, int] | None  # (byte offset, bytes)
    samples_per_pdo: int
    rate_hz: float
    zero: int
    full_scale_mn: float
    bits: int

    def to_newton(self, counts: np.ndarray) -> np.ndarray:
        levels = (1 << self.bits) - 1 - self.zero
        return (
            (np.asarray(counts, dtype=np.float64) - self.zero)
            * (self.full_scale_mn / levels)
            / 1000.0
        )


def skin_pdo(node_id: int = DEFAULT_SKIN_NODE_ID) -> SkinPdo:
    """Decode TPDO1's layout and the calibration defaults from the shipped skin EDS."""
    from grasplink.profiles import load_profile

    od = load_profile("skin", node_id)

    def default(index: int, sub: int | None = None) -> int:
        entry = od[index] if sub is None else od[index][sub]
        return int(entry.default)

    cob_id = default(TPDO1_COMM, 1) & 0x7FF
    count = default(TPDO1_MAP, 0)
    offset = 0
    slots: list[tuple[int, int, int]] = []
    sequence = None
    for sub in range(1, count + 1):
        mapped = default(TPDO1_MAP, sub)
        index, subindex, bits = mapped >> 16, (mapped >> 8) & 0xFF, mapped & 0xFF
        if bits % 8:
            raise ConfigError(
                f"skin EDS: TPDO1 maps 0x{index:04X}:{subindex} with {bits} bits; "
                "only whole bytes are supported"
            )
        size = bits // 8
        if index == SAMPLE_SLOTS:
            slots.append((subindex, offset, size))
        elif index == PACKET_SEQUENCE:
            sequence = (offset, size)
        offset += size
    if not slots:
        raise ConfigError("skin EDS: TPDO1 maps no FSR sample slot (0x2100)")
    per_pdo = min(default(SAMPLES_PER_PDO), len(slots))
    ordered = tuple((o, s) for _, o, s in sorted(slots))
    bits = default(CALIBRATION, 1)
    zero = default(CALIBRATION, 3)
    if zero >= (1 << bits) - 1:
        raise ConfigError(f"skin EDS: zero offset {zero} is not below full scale at {bits} bits")
    return SkinPdo(
        cob_id,
        offset,
        ordered[:per_pdo],
        sequence,
        per_pdo,
        float(default(SAMPLE_RATE)),
        zero,
        float(default(CALIBRATION, 2)),
        bits,
    )


def read_can_log(
    path: str | Path, *, node_id: int = DEFAULT_SKIN_NODE_ID, fs_hz: float | None = None
) -> tuple[np.ndarray, np.ndarray, CanStats]:
    """Skin TPDO1 samples from a python-can log: (t_s, force_n, stats)."""
    import can

    p = Path(path)
    if not p.is_file():
        raise RecordingError(f"{p}: no such file")
    pdo = skin_pdo(node_id)
    rate = float(fs_hz) if fs_hz is not None else pdo.rate_hz
    if not (math.isfinite(rate) and rate > 0):
        raise ConfigError(f"sample rate must be a positive number of Hz, got {fs_hz}")
    stats = CanStats(rate_hz=rate)
    packets: list[tuple[float, int | None, list[int]]] = []
    try:
        reader = can.LogReader(str(p))
        for msg in reader:
            if msg.is_error_frame or msg.is_remote_frame:
                continue
            if msg.arbitration_id != pdo.cob_id or msg.is_extended_id:
                stats.other_ids.add(msg.arbitration_id)
                continue
            stats.frames += 1
            data = bytes(msg.data)
            if len(data) != pdo.length:
                stats.malformed += 1
                continue
            counts = [int.from_bytes(data[o : o + s], "little") for o, s in pdo.slots]
            seq = None
            if pdo.sequence is not None:
                o, s = pdo.sequence
                seq = int.from_bytes(data[o : o + s], "little")
            packets.append((float(msg.timestamp), seq, counts))
    except RecordingError:
        raise
    except Exception as exc:  # python-can raises assorted errors on a corrupt log
        raise RecordingError(
            f"{p}: cannot read as a CAN log ({type(exc).__name__}: {exc})"
        ) from None
    if not packets:
        seen = ", ".join(f"0x{i:03X}" for i in sorted(stats.other_ids)[:12]) or "none"
        raise RecordingError(
            f"{p}: no skin TPDO1 frames (COB-ID 0x{pdo.cob_id:03X}, node-ID "
            f"0x{node_id:02X}, {pdo.length} data bytes); CAN-IDs seen: {seen}"
        )
    t, counts = _assemble(packets, pdo, rate, stats)
    if not len(t):
        raise RecordingError(f"{p}: no usable skin samples")
    return t, pdo.to_newton(counts), stats


def _assemble(packets, pdo: SkinPdo, rate: float, stats: CanStats) -> tuple[np.ndarray, np.ndarray]:
    per = pdo.samples_per_pdo
    period = 1.0 / rate
    kept: list[tuple[float, int | None, list[int]]] = []
    for stamp, seq, counts in packets:
        if kept and seq is not None and seq == kept[-1][1]:
            stats.republished += 1  # the same packet again (published on a state change)
            continue
        if kept and stamp - kept[-1][0] < (per - 0.5) * period:
            # the previous packet's samples would overlap these: it was a re-publish of
            # stale slot values (as on entering OPERATIONAL), not `per` new samples
            stats.republished += 1
            kept.pop()
        if kept and seq is not None and kept[-1][1] is not None:
            gap = (seq - kept[-1][1]) % 256
            stats.lost_packets += max(0, gap - 1)
        kept.append((stamp, seq, counts))
    stats.packets = len(kept)
    offsets = (np.arange(per) - (per - 1)) * period
    t = (np.array([k[0] for k in kept])[:, None] + offsets[None, :]).ravel()
    counts = np.array([k[2] for k in kept], dtype=np.int64).ravel()
    increasing = np.concatenate([[True], np.diff(t) > 0])
    if not increasing.all():  # time-stamp jitter: drop what would go back in time
        keep = t > np.maximum.accumulate(np.concatenate([[-np.inf], t[:-1]]))
        t, counts = t[keep], counts[keep]
    return t, counts

"""What every skin decoder promises: its input, its output, and how it streams.

A decoder is a sans-IO object fed timestamped FSR samples (`feed`) that
returns estimates on a fixed time grid (`update_period_s`, default 10 ms,
aligned to multiples of the period), so feeding a recording in chunks or in
one piece gives the same estimates. Unknown values are None, never NaN.

The input guard (`Decoder.feed`) keeps out what a decoder cannot use, and
counts it in `decoder.stats`:

* NaN/Inf samples, forces beyond the largest full scale a skin node can be
  calibrated to (`SkinLimits.max_force_n`) and times too large for float64
  to resolve a thousandth of a sample period are rejected (`rejected_*`);
* a sample less than `MIN_STEP_PERIODS` sample periods after the previous
  accepted one (time going backwards, repeated, or 1e-12 s later) is a
  timing error: rejected, counted, never decoded;
* a step longer than `GAP_PERIODS` sample periods is a gap: the decoder is
  reset (`Decoder.reset`, by default to the state it had before its first
  sample) and the update grid restarts at the first sample after it, so no
  update falls inside a gap and work and memory follow the number of
  samples, never the time span.

Layout and sample rate are bounded by what the skin node can hold (its EDS:
spacings 0x2140, rate 0x2120), so an absurd value is a `ConfigError` naming
the bound rather than a numpy error deep inside a decoder.

The second input is the efference copy (`Decoder.note_grip_command`): the grip the
loop commanded the hand, at the time its command went on the bus (the samples' clock),
so a decoder can tell the level bending under a commanded grip change from a ridge
contact (`efference.py`). It has its own guard (NaN/Inf, a force outside the hand's
target range 0x2400, time before the previous command: counted in
`decoder.grip_commands.stats`, named in `input_report`; a value that is no number is a
ValueError). The tracker weighs it; decoders that cannot use it (ratio, mmse, dtw, fft)
take it and ignore it. With no command noted every output is what it was without this
input, bit for bit.
"""

from __future__ import annotations

import bisect
import copy
import math
import types
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any, ClassVar

import numpy as np

from grasplink.decoding.efference import GripCommands, HandFollow
from grasplink.errors import ConfigError, RecordingError

DEFAULT_UPDATE_S = 0.01
UPDATE_PERIOD_RANGE_S = (0.001, 10.0)  # at most one update per sample at 1 kHz

#: A step longer than this many sample periods is a gap (the decoder resets). Two
#: lost CAN packets of three samples (a step of 7 periods) are bridged; at the
#: skin node's 400 Hz a gap is anything over 20 ms.
GAP_PERIODS = 8.0
#: A sample closer than this many periods to the previous accepted one is a timing
#: error (dropped): jitter of +-30 % of a period stays well clear of it.
MIN_STEP_PERIODS = 0.25
#: Times must resolve this fraction of a sample period in float64.
TIME_RESOLUTION_PERIODS = 1e-3
#: `grasplink decode` exits 1 when less than this share of the input could be used
#: (samples the guard accepted; skin frames of a CAN log): the output would describe
#: whatever happened to survive, not the recording.
MIN_USABLE_SHARE = 0.5
#: Chunks up to this many samples (a CAN frame's) are checked and gridded in plain floats.
SMALL_CHUNK = 8


@dataclass(frozen=True, slots=True)
class SlipEstimate:
    """One decoder update (the output contract of `grasplink decode`).

    Speed and direction are separate outputs (issue 22): the belt and the reflex act on
    the speed, which two contacts often determine, while the direction may take more
    contacts or never be told (a uniform skin reads the same both ways).

    * `speed_mm_s`: |speed| (>= 0), None while the contacts do not determine it;
    * `speed_low_mm_s`, `speed_high_mm_s`: the range of speeds the contacts still allow
      while slipping (both None when nothing bounds it yet); with a speed, its range;
    * `direction`: +1 from the first ridge towards the last, -1 back, None when not told;
    * `direction_confidence`: P(the object moves that way), None without a direction;
    * `position_mm`: the leading edge, from the first ridge (needs the direction);
    * `confidence`: 0..1, of the whole estimate.
    """

    t_s: float
    slip: bool
    speed_mm_s: float | None
    position_mm: float | None
    force_n: float | None  # static grip force
    confidence: float
    direction: int | None = None
    direction_confidence: float | None = None
    speed_low_mm_s: float | None = None
    speed_high_mm_s: float | None = None

    def __post_init__(self) -> None:
        if self.speed_mm_s is not None and self.speed_mm_s < 0:
            raise ValueError(
                f"speed_mm_s is a magnitude, got {self.speed_mm_s}: give the sign as "
                "`direction` (SlipEstimate.from_velocity)"
            )
        if self.direction not in (None, 1, -1):
            raise ValueError(f"direction must be +1, -1 or None, got {self.direction!r}")
        if (self.direction is None) != (self.direction_confidence is None):
            raise ValueError("a direction comes with its confidence, and none without")

    @classmethod
    def from_velocity(
        cls,
        t_s: float,
        slip: bool,
        velocity_mm_s: float | None,
        position_mm: float | None,
        force_n: float | None,
        confidence: float,
        direction_confidence: float | None = None,
    ) -> SlipEstimate:
        """An estimate from a signed speed (decoders that estimate the direction with the
        speed): its sign is the direction, told with `direction_confidence` (default: the
        estimate's confidence). A zero or unknown velocity tells no direction."""
        if velocity_mm_s is None or not math.isfinite(velocity_mm_s) or velocity_mm_s == 0:
            speed = None if velocity_mm_s is None else abs(velocity_mm_s)
            return cls(t_s, slip, speed, position_mm, force_n, confidence)
        p_way = confidence if direction_confidence is None else direction_confidence
        return cls(
            t_s, slip, abs(velocity_mm_s), position_mm, force_n, confidence,
            1 if velocity_mm_s > 0 else -1, min(1.0, max(0.0, float(p_way))),
        )  # fmt: skip

    @property
    def velocity_mm_s(self) -> float | None:
        """The signed speed, when both speed and direction are told."""
        if self.speed_mm_s is None or self.direction is None:
            return None
        return self.direction * self.speed_mm_s

    def as_dict(self) -> dict:
        return {
            "t_s": round(self.t_s, 6),
            "slip": self.slip,
            "speed_mm_s": _clean(self.speed_mm_s),
            "speed_low_mm_s": _clean(self.speed_low_mm_s),
            "speed_high_mm_s": _clean(self.speed_high_mm_s),
            "direction": self.direction,
            "direction_confidence": _clean(self.direction_confidence),
            "position_mm": _clean(self.position_mm),
            "force_n": _clean(self.force_n),
            "confidence": round(float(self.confidence), 4),
        }


def _clean(value: float | None) -> float | None:
    if value is None or not math.isfinite(value):
        return None
    return round(float(value), 4)


@dataclass(frozen=True)
class SkinLimits:
    """What the skin node's object dictionary can hold: the decoders' input bounds."""

    spacing_mm: tuple[float, float]  # 0x2140:01.. limits (µm in the EDS)
    max_spacings: int  # 0x2140:00 high limit
    rate_hz: tuple[float, float]  # 0x2120 limits
    max_force_n: float  # 0x2130:02 (full-scale force) high limit


@cache
def skin_limits() -> SkinLimits:
    """Read once from the shipped skin EDS."""
    from grasplink.profiles import object_limits
    from grasplink.profiles.objects import (
        SKIN_FSR_CALIBRATION,
        SKIN_RIDGE_SPACING_UM,
        SKIN_SAMPLE_RATE_HZ,
    )

    low_um, high_um = object_limits("skin", SKIN_RIDGE_SPACING_UM, 1)
    _, count = object_limits("skin", SKIN_RIDGE_SPACING_UM, 0)
    low_hz, high_hz = object_limits("skin", SKIN_SAMPLE_RATE_HZ)
    _, full_scale_mn = object_limits("skin", SKIN_FSR_CALIBRATION, 2)
    return SkinLimits(
        (low_um / 1000.0, high_um / 1000.0),
        count,
        (float(low_hz), float(high_hz)),
        full_scale_mn / 1000.0,
    )


def check_sample_rate(fs_hz: float) -> float:
    """The rate as a float, or ConfigError: the skin node samples at 0x2120's range."""
    low, high = skin_limits().rate_hz
    try:
        fs = float(fs_hz)
    except (TypeError, ValueError):
        raise ConfigError(f"sample rate {fs_hz!r} is not a number of Hz") from None
    if not (math.isfinite(fs) and fs > 0):
        raise ConfigError(f"sample rate must be a positive number of Hz, got {fs_hz}")
    if not low <= fs <= high:
        raise ConfigError(
            f"sample rate {fs:g} Hz is outside {low:g}-{high:g} Hz, the range the skin "
            "node samples at (0x2120) and the decoders are designed for"
        )
    return fs


class SkinGeometry:
    """Ridge positions of a layout: ridge i at x_i = sum of the first i spacings.

    Spacings must fit the skin node's 0x2140 (count and µm limits of its EDS).
    """

    def __init__(self, spacings_mm: Sequence[float]):
        try:
            spacings = np.asarray(spacings_mm, dtype=np.float64)
        except (TypeError, ValueError):
            raise ConfigError(f"ridge spacings must be numbers (mm), got {spacings_mm!r}") from None
        if spacings.ndim != 1 or len(spacings) == 0:
            raise ConfigError("a skin layout needs at least one spacing")
        if not np.all(np.isfinite(spacings)) or np.any(spacings <= 0):
            raise ConfigError(f"ridge spacings must be finite and > 0 mm, got {list(spacings)}")
        limits = skin_limits()
        if len(spacings) > limits.max_spacings:
            raise ConfigError(
                f"a skin layout of {len(spacings)} spacings does not fit the skin node, "
                f"which holds at most {limits.max_spacings} (0x2140)"
            )
        low, high = limits.spacing_mm
        outside = np.nonzero((spacings < low) | (spacings > high))[0]
        if len(outside):
            k = int(outside[0])
            raise ConfigError(
                f"ridge spacing #{k + 1} is {spacings[k]:g} mm; the skin node holds "
                f"spacings of {low:g}-{high:g} mm (0x2140, in µm)"
            )
        self.spacings_mm = spacings
        self.ridges_mm = np.concatenate([[0.0], np.cumsum(spacings)])
        self.length_mm = float(self.ridges_mm[-1])

    @property
    def ridge_count(self) -> int:
        return len(self.ridges_mm)


@dataclass
class InputStats:
    """What the input guard let through and what it kept out, and why."""

    accepted: int = 0
    rejected_nonfinite: int = 0  # NaN or Inf time or force
    rejected_range: int = 0  # force beyond +-max_force_n, or time beyond float64 resolution
    rejected_time: int = 0  # under MIN_STEP_PERIODS after the previous accepted sample
    gaps: int = 0  # steps longer than GAP_PERIODS sample periods (each reset the decoder)
    longest_gap_s: float = 0.0

    @property
    def received(self) -> int:
        return self.accepted + self.rejected

    @property
    def rejected(self) -> int:
        return self.rejected_nonfinite + self.rejected_range + self.rejected_time


_NOT_STATE = (str, bytes, int, float, bool, type(None), type, types.ModuleType)


def _read_only_arrays(root: object) -> list[np.ndarray]:
    """Every read-only numpy array reachable from `root` through containers (dict, list,
    tuple, set, deque) and objects' attributes (`__dict__`, `__slots__`)."""
    found: list[np.ndarray] = []
    seen: set[int] = set()
    stack = [root]
    while stack:
        obj = stack.pop()
        if id(obj) in seen or isinstance(obj, _NOT_STATE):
            continue
        seen.add(id(obj))
        if isinstance(obj, np.ndarray):
            if not obj.flags.writeable:
                found.append(obj)
        elif isinstance(obj, dict):
            stack.extend(obj.values())
        elif isinstance(obj, (list, tuple, set, frozenset, deque)):
            stack.extend(obj)
        else:
            stack.extend(getattr(obj, "__dict__", {}).values())
            for cls in type(obj).__mro__:
                for slot in getattr(cls, "__slots__", ()):
                    if hasattr(obj, slot):
                        stack.append(getattr(obj, slot))
    return found


# attributes of the base class itself, which a reset keeps
# (the grip commands noted too: a gap in the samples does not undo a command)
_BASE_STATE = frozenset({"stats", "_last_t", "_next_update", "_pristine", "grip_commands"})


class Decoder:
    """Base class: input guard, gaps, update grid; subclasses decode slip."""

    name: ClassVar[str] = "base"

    def __init__(
        self, layout_mm: Sequence[float], fs_hz: float, *, update_period_s: float = DEFAULT_UPDATE_S
    ):
        fs = check_sample_rate(fs_hz)
        low, high = UPDATE_PERIOD_RANGE_S
        if not (math.isfinite(update_period_s) and low <= update_period_s <= high):
            raise ConfigError(f"update period must be {low:g}-{high:g} s, got {update_period_s}")
        self.geometry = SkinGeometry(layout_mm)
        self.fs_hz = fs
        self.update_period_s = float(update_period_s)
        self.gap_s = GAP_PERIODS / fs
        self.min_step_s = MIN_STEP_PERIODS / fs
        self.max_time_s = TIME_RESOLUTION_PERIODS / fs / np.finfo(np.float64).eps
        self.max_force_n = skin_limits().max_force_n
        self.stats = InputStats()
        self._last_t: float | None = None
        self._next_update: int | None = None  # index of the next update on the grid
        self._pristine: dict | None = None  # state before the first sample (for reset)
        self.grip_commands = GripCommands()  # the efference copy (`note_grip_command`)

    def warm_up(self) -> None:
        """Load, or on a machine's first run compile, whatever this decoder compiles
        (kernels/), before it goes live: the first call would otherwise stall the loop
        for a second or more. Leaves this decoder's state alone; nothing to do for a
        decoder that compiles nothing."""

    def feed(self, t_s: np.ndarray, force_n: np.ndarray) -> list[SlipEstimate]:
        """Take samples (any chunking) and return the updates that fell due."""
        t = np.asarray(t_s, dtype=np.float64).ravel()
        x = np.asarray(force_n, dtype=np.float64).ravel()
        if t.shape != x.shape:
            raise ValueError(f"{len(t)} times for {len(x)} samples")
        if self._pristine is None:
            self._pristine = self._state_copy(vars(self))
        previous = self._last_t
        t, x = self._guard(t, x)
        if not len(t):
            return []
        first = t[0] if previous is None else previous  # first: no gap
        steps: list[float] | np.ndarray
        if len(t) <= SMALL_CHUNK:  # np.diff's differences, without its temporaries
            times = t.tolist()
            steps = [b - a for a, b in zip([float(first), *times[:-1]], times, strict=True)]
            cuts = [k for k, step in enumerate(steps) if step > self.gap_s]
        else:
            steps = np.diff(t, prepend=first)
            cuts = np.nonzero(steps > self.gap_s)[0].tolist()
        out: list[SlipEstimate] = []
        start = 0
        for cut in cuts:
            if cut > start:
                out += self.process(t[start:cut], x[start:cut])
            self.stats.gaps += 1
            self.stats.longest_gap_s = max(self.stats.longest_gap_s, float(steps[cut]))
            self._next_update = None  # the grid restarts at the first sample after the gap
            self.reset()
            start = cut
        out += self.process(t[start:], x[start:])
        return out

    def note_grip_command(self, t_s: float, force_n: float) -> bool:
        """The loop commanded the hand's grip to `force_n` (N) at `t_s` (when the command
        went on the bus, on the samples' clock): whether the guard kept it. Note commands
        in time order, each no later than the samples after it are fed (live: as they are
        sent; offline: all before the samples will do - only commands at or before a
        contact's onset weigh it). A decoder that cannot use them ignores them."""
        return self.grip_commands.note(t_s, force_n, self.max_time_s)

    def set_hand_follow(self, rate_n_s: float, lag_s: float | None = None) -> None:
        """How the commanded hand follows a command: its grip rate (0x2404, N/s) and its
        actuator's lag (s; default `efference.HAND_LAG_S`). ConfigError when out of range."""
        follow = HandFollow(rate_n_s) if lag_s is None else HandFollow(rate_n_s, lag_s)
        self.grip_commands.follow = follow

    def input_report(self) -> str | None:
        """One line on what the guard kept out and the gaps it saw; None if nothing."""
        s = self.stats
        commands = self.grip_commands.stats.report()
        if not (s.rejected or s.gaps):
            return None if commands is None else f"decoder input: {commands}"
        parts = [f"{s.received} samples, {s.accepted} decoded"]
        reasons = [
            (s.rejected_nonfinite, "NaN/Inf"),
            (
                s.rejected_range,
                f"out of range (|force| over {self.max_force_n:g} N, the largest skin full "
                f"scale, or |time| over {self.max_time_s:.3g} s)",
            ),
            (
                s.rejected_time,
                f"timing errors (under {MIN_STEP_PERIODS:g} sample periods after the "
                "previous sample, or going back)",
            ),
        ]
        if s.rejected:
            parts.append(
                f"rejected {s.rejected}: " + ", ".join(f"{n} {why}" for n, why in reasons if n)
            )
        if s.gaps:
            parts.append(
                f"{s.gaps} gap(s) over {GAP_PERIODS:g} sample periods ({self.gap_s * 1e3:g} ms; "
                f"longest {s.longest_gap_s:.6g} s) reset the decoder, no updates inside"
            )
        if commands is not None:
            parts.append(commands)
        return "decoder input: " + "; ".join(parts)

    def check_usable(self, source: str) -> None:
        """RecordingError when less than MIN_USABLE_SHARE of the samples fed were accepted."""
        s = self.stats
        if s.received and s.accepted < MIN_USABLE_SHARE * s.received:
            raise RecordingError(
                f"{source}: only {s.accepted} of {s.received} samples usable "
                f"({s.accepted / s.received:.0%}, below {MIN_USABLE_SHARE:.0%}); "
                "see the decoder input line above"
            )

    def reset(self) -> None:
        """Forget the signal: called at a gap, before the first sample after it.

        By default every attribute returns to its value before the first sample
        (input statistics and the time of the last sample stay). A subclass may
        override it to keep what a gap does not invalidate; it must forget every
        contact, hypothesis, filter state and buffered sample.
        """
        if self._pristine is None:
            return
        state = self._state_copy(self._pristine)
        for key in [k for k in vars(self) if k not in _BASE_STATE and k not in state]:
            delattr(self, key)
        vars(self).update(state)

    def _state_copy(self, state: dict) -> dict:
        """A deep copy of the subclass's attributes; references to the decoder stay to it,
        and read-only arrays (tables built once) are shared, not copied: a copy would be
        writable, and a compiled kernel's signature tells the two apart - the first contact
        after a gap would compile a kernel in the live loop (seconds)."""
        own = {k: v for k, v in state.items() if k not in _BASE_STATE}
        memo: dict[int, Any] = {id(self): self}
        for array in _read_only_arrays(own):
            memo[id(array)] = array
        return copy.deepcopy(own, memo)

    def _guard(self, t: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        stats = self.stats
        if 0 < len(t) <= SMALL_CHUNK and self._clean(t.tolist(), x.tolist()):
            # a CAN frame's few samples, all usable (the usual case): the checks below in
            # plain floats, the same numbers without a dozen temporary arrays
            self._last_t = float(t[-1])
            stats.accepted += len(t)
            return t.copy(), x.copy()
        finite = np.isfinite(t) & np.isfinite(x)
        stats.rejected_nonfinite += int(np.count_nonzero(~finite))
        t, x = t[finite], x[finite]
        usable = (np.abs(x) <= self.max_force_n) & (np.abs(t) <= self.max_time_s)
        stats.rejected_range += int(np.count_nonzero(~usable))
        t, x = t[usable], x[usable]
        if not len(t):
            return t, x
        keep = self._spaced(t)
        stats.rejected_time += int(np.count_nonzero(~keep))
        t, x = t[keep], x[keep]
        if len(t):
            self._last_t = float(t[-1])
            stats.accepted += len(t)
        return t, x

    def _clean(self, t: list[float], x: list[float]) -> bool:
        """Are all these samples finite, in range and spaced (what `_guard` keeps)?"""
        previous = -math.inf if self._last_t is None else self._last_t
        for tk, xk in zip(t, x, strict=True):
            # NaN fails every comparison; +-inf fails the (finite) bounds
            if not (abs(xk) <= self.max_force_n and abs(tk) <= self.max_time_s):
                return False
            if not tk - previous >= self.min_step_s:
                return False
            previous = tk
        return True

    def _spaced(self, t: np.ndarray) -> np.ndarray:
        """Which samples come at least `min_step_s` after the previous accepted one."""
        previous = -np.inf if self._last_t is None else self._last_t
        if np.all(np.diff(t, prepend=previous) >= self.min_step_s):
            return np.ones(len(t), dtype=bool)  # the usual case, without a loop
        keep = np.zeros(len(t), dtype=bool)
        for k, tk in enumerate(t.tolist()):
            if tk - previous >= self.min_step_s:
                keep[k] = True
                previous = tk
        return keep

    def update_points(self, t: np.ndarray) -> list[tuple[int, float]]:
        """Updates due within this chunk: (samples of the chunk at or before it, update time).

        Updates fall on multiples of the update period, from the first sample on
        (and from the first sample after each gap); an update at time g reflects
        every sample with t <= g. The grid does not depend on how the input is
        chunked, and `feed` never hands a gap to `process`, so the grid spans at
        most GAP_PERIODS sample periods per sample.
        """
        period = self.update_period_s
        if self._next_update is None:
            self._next_update = math.ceil(t[0] / period - 1e-9)
        last = math.floor(t[-1] / period + 1e-9)
        if last < self._next_update:
            return []
        if len(t) <= SMALL_CHUNK and last - self._next_update < SMALL_CHUNK:
            # np.arange * period and np.searchsorted(side="right") in plain floats
            times = t.tolist()
            grid = [float(k) * period for k in range(self._next_update, last + 1)]
            self._next_update = last + 1
            return [(bisect.bisect_right(times, g + 1e-12), g) for g in grid]
        grid_a = np.arange(self._next_update, last + 1) * period
        self._next_update = last + 1
        counts = np.searchsorted(t, grid_a + 1e-12, side="right")
        return list(zip(counts.tolist(), grid_a.tolist(), strict=True))

    def process(self, t: np.ndarray, x: np.ndarray) -> list[SlipEstimate]:
        """Decode accepted samples (finite, in range, spaced, no gap among them)."""
        raise NotImplementedError


class StaticForce:
    """Static grip force: the FSR signal low-passed (2nd-order Butterworth, SOS, carried state).

    The corner (default 2 Hz) sits below the ridge-contact rates of a slip
    (v/D >= ~2 Hz for the thesis speeds), so pulses average out and grip
    steps come through within a few hundred ms. Starts settled on the first
    sample. Runs on `filters.SosFilter`, the decoders' one streaming filter.
    """

    def __init__(self, fs_hz: float, corner_hz: float = 2.0):
        from scipy.signal import butter

        from grasplink.decoding.filters import SosFilter

        corner = min(corner_hz, 0.45 * fs_hz)
        self._filter = SosFilter(butter(2, corner, fs=fs_hz, output="sos"))

    def filter(self, x: np.ndarray) -> np.ndarray:
        return self._filter(x)

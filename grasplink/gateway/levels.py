"""Calibration tables: which belt velocity shows which grip force or slip speed.

The belt shows discrete levels because that is what wearers can read: four
levels of each belt, told apart after five minutes of training (thesis
ch. 8.4). A table lists, per level, the input at which the level starts and
the motor velocity that shows it. A table is checked when it is built
(finite, increasing, inside the belt's limits) and a bad one is a
ConfigError naming the table and the entry, so a wrong calibration is found
when it is loaded, not when a wearer is confused by it.

Level boundaries have hysteresis (`LevelQuantizer`): a level is entered at
`start + hysteresis/2` and left below `start - hysteresis/2`, so an input
dithering across a boundary by less than the band never changes the level.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from enum import StrEnum

from grasplink.errors import ConfigError
from grasplink.profiles import objects as obj

MAX_LEVELS = 8  # the thesis's wearers read four; more is allowed, unbounded is not


class Belt(StrEnum):
    """Which belt the motor turns: the sign of the velocity selects it (ch. 8.2)."""

    NONE = "none"
    FORCE = "force"  # positive velocity: grip force as tap frequency
    SLIP = "slip"  # negative velocity: slip speed as belt surface speed


# Velocity magnitudes each belt can show (devices/belt.py limits the same way).
BELT_RANGE_MRAD_S = {
    Belt.FORCE: (1, obj.FORCE_BELT_MAX_MRAD_S),
    Belt.SLIP: (obj.SLIP_BELT_MIN_MRAD_S, obj.SLIP_BELT_MAX_MRAD_S),
}

# Defaults. Velocities: thesis ch. 8.3.2 (force belt 3.5, 5.0, 6.5, 8.0 rad/s; slip belt
# 55, 100, 145, 190 mm/s at 2.0, 3.7, 5.3, 7.0 rad/s). Input starts: this project's choice,
# explained in docs/feedback.md (force: FSR floor, then quarters of the 40 N crush limit;
# slip: quarters of the 0..45 mm/s a wearer can stop, the top level where the reflex acts).
DEFAULT_FORCE_ENTRIES: tuple[tuple[float, int], ...] = (
    (1.0, 3500),
    (10.0, 5000),
    (20.0, 6500),
    (30.0, 8000),
)
DEFAULT_FORCE_HYSTERESIS_N = 1.0
DEFAULT_SLIP_ENTRIES: tuple[tuple[float, int], ...] = (
    (0.0, 2000),
    (15.0, 3700),
    (30.0, 5300),
    (45.0, 7000),
)
DEFAULT_SLIP_HYSTERESIS_MM_S = 8.0
SLIP_BELT_SURFACE_MM_S = (55, 100, 145, 190)  # what the default slip levels show (ch. 8.3.2)


@dataclass(frozen=True, slots=True)
class LevelTable:
    """Display levels 1..n of one belt: level k is shown from `starts[k-1]` (in `unit`) on,
    at `velocities_mrad_s[k-1]` (a magnitude; the slip belt turns at its negative).

    Build through `force_table` / `slip_table`, which name the unit in their parameters.
    """

    name: str
    belt: Belt
    unit: str
    starts: tuple[float, ...]
    velocities_mrad_s: tuple[int, ...]
    hysteresis: float

    def __post_init__(self) -> None:
        _validate(self)

    @property
    def levels(self) -> int:
        return len(self.starts)

    def velocity_mrad_s(self, level: int) -> int:
        """The signed command of a level (1..n): + force belt, - slip belt."""
        magnitude = self.velocities_mrad_s[level - 1]
        return magnitude if self.belt == Belt.FORCE else -magnitude

    def level_of(self, value: float) -> int:
        """The level (0 = below the first) of a value, without hysteresis."""
        level = 0
        for k, start in enumerate(self.starts, start=1):
            if value >= start:
                level = k
        return level


def force_table(
    entries: Sequence[Sequence[float]] = DEFAULT_FORCE_ENTRIES,
    *,
    hysteresis_n: float = DEFAULT_FORCE_HYSTERESIS_N,
) -> LevelTable:
    """Grip force [N] -> force-belt velocity [mrad/s]; below the first entry the belt stops."""
    return _build("force table", Belt.FORCE, "N", entries, hysteresis_n)


def slip_table(
    entries: Sequence[Sequence[float]] = DEFAULT_SLIP_ENTRIES,
    *,
    hysteresis_mm_s: float = DEFAULT_SLIP_HYSTERESIS_MM_S,
) -> LevelTable:
    """|Slip speed| [mm/s] -> slip-belt velocity magnitude [mrad/s]; the first entry starts
    at 0 mm/s because every slip is shown."""
    return _build("slip table", Belt.SLIP, "mm/s", entries, hysteresis_mm_s)


def _build(name: str, belt: Belt, unit: str, entries: object, hysteresis: float) -> LevelTable:
    """Validated as untrusted (TOML) input: `entries` is checked, not assumed, to be a list."""
    if isinstance(entries, str | bytes) or not isinstance(entries, Sequence):
        raise ConfigError(f"{name}: expected a list of [start {unit}, velocity mrad/s] entries")
    starts: list[float] = []
    velocities: list[int] = []
    for k, entry in enumerate(entries, start=1):
        where = f"{name} entry {k}"
        if isinstance(entry, str | bytes) or not isinstance(entry, Sequence) or len(entry) != 2:
            raise ConfigError(f"{where}: expected [start {unit}, velocity mrad/s], got {entry!r}")
        start, velocity = entry
        starts.append(_number(where, f"start [{unit}]", start))
        speed = _number(where, "velocity [mrad/s]", velocity)
        if not math.isfinite(speed) or speed != int(speed):
            raise ConfigError(
                f"{where}: velocity must be a whole number of mrad/s, got {velocity!r}"
            )
        velocities.append(int(speed))
    hysteresis_value = _number(name, f"hysteresis [{unit}]", hysteresis)
    return LevelTable(name, belt, unit, tuple(starts), tuple(velocities), hysteresis_value)


def _number(where: str, what: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{where}: {what} must be a number, got {value!r}")
    return float(value)


def _validate(table: LevelTable) -> None:
    name, unit = table.name, table.unit
    n = len(table.starts)
    if n == 0:
        raise ConfigError(f"{name}: needs at least one level")
    if n > MAX_LEVELS:
        raise ConfigError(f"{name}: {n} levels, at most {MAX_LEVELS} (wearers read about four)")
    if len(table.velocities_mrad_s) != n:
        raise ConfigError(f"{name}: {n} starts but {len(table.velocities_mrad_s)} velocities")
    low, high = BELT_RANGE_MRAD_S[table.belt]
    for k, (start, velocity) in enumerate(
        zip(table.starts, table.velocities_mrad_s, strict=True), start=1
    ):
        where = f"{name} entry {k}"
        if not math.isfinite(start) or start < 0:
            raise ConfigError(f"{where}: start must be a finite number >= 0 {unit}, got {start}")
        if not math.isfinite(velocity) or not low <= velocity <= high:
            raise ConfigError(
                f"{where}: velocity {velocity} mrad/s is outside the {table.belt.value} belt's "
                f"{low}..{high} mrad/s"
            )
        if k > 1 and start <= table.starts[k - 2]:
            raise ConfigError(
                f"{where}: start {start:g} {unit} must be above entry {k - 1}'s "
                f"{table.starts[k - 2]:g} {unit} (starts increase)"
            )
        if k > 1 and velocity <= table.velocities_mrad_s[k - 2]:
            raise ConfigError(
                f"{where}: velocity {velocity} mrad/s must be above entry {k - 1}'s "
                f"{table.velocities_mrad_s[k - 2]} mrad/s (a larger input shows faster)"
            )
    if table.belt == Belt.SLIP and table.starts[0] != 0:
        raise ConfigError(f"{name} entry 1: must start at 0 {unit} (every slip is shown)")
    h = table.hysteresis
    if not math.isfinite(h) or h < 0:
        raise ConfigError(f"{name}: hysteresis must be a finite number >= 0 {unit}, got {h}")
    gaps = [b - a for a, b in itertools.pairwise(table.starts)]
    if gaps and h >= min(gaps):
        k = gaps.index(min(gaps)) + 2
        raise ConfigError(
            f"{name}: hysteresis {h:g} {unit} must be below the smallest gap between starts "
            f"({min(gaps):g} {unit}, before entry {k}), or a level could be skipped"
        )
    if table.belt == Belt.FORCE and table.starts[0] <= h / 2:
        raise ConfigError(
            f"{name} entry 1: start {table.starts[0]:g} {unit} must exceed half the hysteresis "
            f"({h / 2:g} {unit}), or the belt would never stop when the grip is let go"
        )


class LevelQuantizer:
    """A value -> level (0..n) with hysteresis; None until the first known value.

    Enter level k at `start_k + h/2`, leave it below `start_k - h/2`. The first
    value after a reset is placed at its nominal level (there is no history to
    keep).
    """

    def __init__(self, table: LevelTable):
        self.table = table
        half = table.hysteresis / 2
        self._rise = [start + half for start in table.starts]
        self._fall = [start - half for start in table.starts]
        self.level: int | None = None

    def reset(self) -> None:
        self.level = None

    def update(self, value: float) -> int:
        if self.level is None:
            self.level = self.table.level_of(value)
            return self.level
        level = self.level
        while level < self.table.levels and value >= self._rise[level]:
            level += 1
        while level > 0 and value < self._fall[level - 1]:
            level -= 1
        self.level = level
        return level

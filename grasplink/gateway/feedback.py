"""The feedback controller: what the haptic belt shows, decided from timestamped percepts.

One motor turns either the force belt (positive velocity: grip force as tap
frequency) or the slip belt (negative: slip speed as belt surface speed),
never both (thesis ch. 8.2), so the belt shows one quantity at a time. Modes:

- off: the belt stands still;
- slip occurrence: the slip belt at one fixed speed while slipping;
- slip speed: the slip belt at the level of the slip speed while slipping (while the
  decoder knows only a range of speeds, at the level of its lower end: a bound is shown,
  never overstated, and the first speed known replaces it at once);
- grip force: the force belt at the level of the grip force;
- force and slip: grip force, overridden by slip speed while the object slips;
  force returns once the slip has stopped for `force_return_us`.

Nothing here chatters on a noisy input: slip starts after `slip_on_us` of
slip reports and ends only after `slip_off_us` without one; level boundaries
have hysteresis bands (levels.py); and a shown level changes at most once
per `level_dwell_us`. Sans-IO: `update(percept)` and `advance(t_us)` return
the command for that moment; `next_deadline_us()` says when the command would
change without new input. docs/feedback.md gives every value and its reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import StrEnum

from grasplink.devices.belt import limit_belt_velocity
from grasplink.errors import ConfigError
from grasplink.gateway.encodings import Stimuli, StimulusEncoder
from grasplink.gateway.levels import (
    BELT_RANGE_MRAD_S,
    Belt,
    LevelQuantizer,
    LevelTable,
    force_table,
    slip_table,
)
from grasplink.gateway.percept import Clock, Percept
from grasplink.profiles import objects as obj


class FeedbackMode(StrEnum):
    OFF = "off"
    SLIP_OCCURRENCE = "slip_occurrence"
    SLIP_SPEED = "slip_speed"
    GRIP_FORCE = "grip_force"
    FORCE_AND_SLIP = "force_and_slip"

    @property
    def code(self) -> int:
        """A stable number for register interfaces (Modbus): 0 off … 4 force and slip."""
        return list(FeedbackMode).index(self)

    @classmethod
    def parse(cls, value: FeedbackMode | str | int) -> FeedbackMode:
        """A mode from its name (MQTT) or code (Modbus); ConfigError if unknown."""
        modes = list(cls)
        if isinstance(value, int) and not isinstance(value, bool):
            if 0 <= value < len(modes):
                return modes[value]
        elif isinstance(value, str):
            try:
                return cls(value)
            except ValueError:
                pass
        names = ", ".join(f"{m.code} {m.value}" for m in modes)
        raise ConfigError(f"unknown feedback mode {value!r}; modes: {names}")


class Reason(StrEnum):
    """Why the belt does what it does (published with the command)."""

    MODE_OFF = "feedback off"
    NO_SLIP = "no slip"
    SLIP = "slip"
    SLIP_SPEED = "slip speed"
    SLIP_SPEED_UNKNOWN = "slip, speed unknown"
    GRIP_FORCE = "grip force"
    NO_GRIP = "no grip"
    FORCE_UNKNOWN = "grip force unknown"
    SLIP_ENDED = "slip ended, force returns after the hold"
    SLIP_SPEED_AT_LEAST = "slip, at least this speed"  # a bound's lower end (codes: add last)


@dataclass(frozen=True, slots=True)
class BeltCommand:
    """Target velocity for the belt (60FFh) and what it shows.

    `velocity_mrad_s`: > 0 force belt, < 0 slip belt, 0 stop. `level`: the display
    level 1..n shown (None when stopped or when a slip of unknown speed is shown at
    the occurrence speed; the level of the lower bound, reason `SLIP_SPEED_AT_LEAST`,
    while the decoder knows only a range of speeds). `clamped`: the velocity was limited
    to what the belt can do (an alarm: the tables or the belt's max profile velocity are
    inconsistent).
    """

    t_us: int
    velocity_mrad_s: int
    belt: Belt
    level: int | None
    reason: Reason
    clamped: bool = False


@dataclass(frozen=True, slots=True)
class FeedbackOutput:
    """The belt command and, computed from the same slip state, the external stimuli."""

    belt: BeltCommand
    stimuli: Stimuli
    slipping: bool  # the debounced slip state shown


@dataclass(frozen=True, slots=True)
class FeedbackConfig:
    """Calibration and timing of the feedback controller (defaults: docs/feedback.md)."""

    force_table: LevelTable = field(default_factory=force_table)
    slip_table: LevelTable = field(default_factory=slip_table)
    occurrence_velocity_mrad_s: int = 4500  # "slip": the median of the four slip levels
    slip_on_us: int = 0  # slip reported this long before it is shown
    slip_off_us: int = 250_000  # no slip report this long before the slip is over
    force_return_us: int = 1_000_000  # force-and-slip: belt still this long after a slip
    level_dwell_us: int = 500_000  # a shown level changes at most once per dwell
    stale_us: int = 500_000  # no percept this long: grip force is unknown
    min_speed_confidence: float = 0.25  # slip speeds trusted less are unknown
    encoder: StimulusEncoder = field(default_factory=StimulusEncoder)

    def __post_init__(self) -> None:
        if not isinstance(self.force_table, LevelTable) or self.force_table.belt != Belt.FORCE:
            raise ConfigError("feedback config: force_table must be a force-belt LevelTable")
        if not isinstance(self.slip_table, LevelTable) or self.slip_table.belt != Belt.SLIP:
            raise ConfigError("feedback config: slip_table must be a slip-belt LevelTable")
        low, high = BELT_RANGE_MRAD_S[Belt.SLIP]
        occurrence = self.occurrence_velocity_mrad_s
        if isinstance(occurrence, bool) or not isinstance(occurrence, int):
            raise ConfigError(
                f"feedback config: occurrence_velocity_mrad_s must be whole mrad/s, "
                f"got {occurrence!r}"
            )
        if not low <= occurrence <= high:
            raise ConfigError(
                f"feedback config: occurrence_velocity_mrad_s {occurrence} is outside the slip "
                f"belt's {low}..{high} mrad/s (give the magnitude)"
            )
        for name in ("slip_on_us", "force_return_us", "level_dwell_us"):
            _check_duration(name, getattr(self, name), allow_zero=True)
        for name in ("slip_off_us", "stale_us"):
            _check_duration(name, getattr(self, name), allow_zero=False)
        c = self.min_speed_confidence
        if isinstance(c, bool) or not isinstance(c, int | float) or not 0.0 <= c <= 1.0:
            raise ConfigError(f"feedback config: min_speed_confidence must be 0..1, got {c!r}")


def _check_duration(name: str, value: object, *, allow_zero: bool) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < (0 if allow_zero else 1):
        bound = ">= 0" if allow_zero else "> 0"
        raise ConfigError(
            f"feedback config: {name} must be whole microseconds {bound}, got {value!r}"
        )


class SlipState:
    """Slip on/off with hysteresis in time: on after `on_us` of continuous slip reports,
    off after `off_us` without any. A flag dithering faster than `off_us` stays on."""

    def __init__(self, on_us: int, off_us: int):
        self.on_us, self.off_us = on_us, off_us
        self.active = False
        self.run_start_us: int | None = None  # first report of the current run of slip reports
        self.last_report_us: int | None = None  # last slip report
        self.ended_us: int | None = None  # when the last slip was declared over

    def observe(self, t_us: int, slipping: bool) -> None:
        if slipping:
            if self.run_start_us is None:
                self.run_start_us = t_us
            self.last_report_us = t_us
        else:
            self.run_start_us = None

    def at(self, t_us: int) -> bool:
        """The state at t_us (after the reports observed so far)."""
        quiet = self.last_report_us is None or t_us - self.last_report_us >= self.off_us
        if quiet:
            self.run_start_us = None  # reports stopped coming: the run is over too
            if self.active:
                assert self.last_report_us is not None
                self.active = False
                self.ended_us = self.last_report_us + self.off_us
        elif (
            not self.active
            and self.run_start_us is not None
            and t_us >= self.run_start_us + self.on_us
        ):
            self.active = True
            self.ended_us = None
        return self.active

    def deadline_us(self) -> int | None:
        if self.active and self.last_report_us is not None:
            return self.last_report_us + self.off_us
        if not self.active and self.run_start_us is not None and self.on_us > 0:
            return self.run_start_us + self.on_us
        return None


@dataclass(slots=True)
class _Shown:
    """What the belt shows now: channel ("off", "force", "slip"), level and since when."""

    channel: str = "off"
    level: int | None = None
    since_us: int = 0
    pending: bool = False  # a different level is due but the dwell holds it back
    floor: bool = False  # the slip level shown is a bound's lower end, not a speed


class FeedbackController:
    """Decides the belt command; see the module docstring for the modes and timing."""

    def __init__(
        self,
        config: FeedbackConfig | None = None,
        *,
        mode: FeedbackMode | str | int = FeedbackMode.FORCE_AND_SLIP,
        max_velocity_mrad_s: int = obj.FORCE_BELT_MAX_MRAD_S,
    ):
        self.config = config or FeedbackConfig()
        self.mode = FeedbackMode.parse(mode)
        self.max_velocity_mrad_s = _check_max_velocity(max_velocity_mrad_s)
        self._clock = Clock("feedback controller")
        self._slip = SlipState(self.config.slip_on_us, self.config.slip_off_us)
        self._force_levels = LevelQuantizer(self.config.force_table)
        self._speed_levels = LevelQuantizer(self.config.slip_table)
        self._force_known_us: int | None = None  # last percept with a usable grip force
        self._speed_mm_s: float | None = None  # |speed| (or a bound's low end) last known
        self._speed_bound = False  # _speed_mm_s is the lower end of a range, not a speed
        self._shown = _Shown()

    # --- inputs -----------------------------------------------------------------

    def update(self, percept: Percept) -> FeedbackOutput:
        """A new percept: the command at its time."""
        t_us = self._clock.tick(percept.t_us)
        p = percept.clean()
        if p.grip_force_n is not None:  # unknown: keep the last force until it goes stale
            self._force_known_us = t_us
            self._force_levels.update(p.grip_force_n)
        self._slip.at(t_us)  # a slip that ended before this percept is over first
        self._slip.observe(t_us, p.slipping)
        if p.slipping:  # the speed, or while only a range is known its lower end
            min_confidence = self.config.min_speed_confidence
            floor = p.speed_floor_mm_s(min_confidence)
            if floor is not None:
                self._speed_mm_s = floor
                self._speed_bound = p.speed_magnitude_mm_s(min_confidence) is None
                self._speed_levels.update(floor)
        return self._evaluate(t_us)

    def advance(self, t_us: int) -> FeedbackOutput:
        """Time passes without a percept: holds expire, stale readings are dropped."""
        return self._evaluate(self._clock.tick(t_us))

    def set_mode(self, mode: FeedbackMode | str | int, t_us: int) -> FeedbackOutput:
        """Change mode at run time; the new mode's display starts at once."""
        self.mode = FeedbackMode.parse(mode)
        self._shown = _Shown()
        return self._evaluate(self._clock.tick(t_us))

    def set_max_velocity(self, max_velocity_mrad_s: int, t_us: int) -> FeedbackOutput:
        """The belt's max profile velocity (607Fh) changed: commands above it are clamped."""
        self.max_velocity_mrad_s = _check_max_velocity(max_velocity_mrad_s)
        return self._evaluate(self._clock.tick(t_us))

    def next_deadline_us(self) -> int | None:
        """When the command changes next without a new input (None: not before one)."""
        # asked after every frame the gateway takes: a running minimum, no lists
        cfg, shown, now = self.config, self._shown, self._clock.now_us
        ended = self._slip.ended_us
        best = None
        for due in (
            self._slip.deadline_us(),
            ended + cfg.force_return_us
            if ended is not None and self.mode == FeedbackMode.FORCE_AND_SLIP
            else None,
            shown.since_us + cfg.level_dwell_us if shown.pending else None,
            self._force_known_us + cfg.stale_us
            if self._force_known_us is not None and shown.channel == "force"
            else None,
        ):
            if due is not None and (now is None or due > now) and (best is None or due < best):
                best = due
        return best

    # --- decision ---------------------------------------------------------------

    def _evaluate(self, t_us: int) -> FeedbackOutput:
        slipping = self._slip.at(t_us)
        if not slipping:  # the next slip starts from an unknown speed
            self._speed_mm_s = None
            self._speed_bound = False
            self._speed_levels.reset()
        channel, chosen, reason = self._choose(t_us, slipping)
        level = self._dwell(t_us, channel, chosen)
        if level != chosen:  # the dwell holds the previous level: say so
            reason = Reason.SLIP_SPEED if channel == "slip" else Reason.GRIP_FORCE
            if channel == "slip" and self._shown.floor:
                reason = Reason.SLIP_SPEED_AT_LEAST
            if channel == "force" and not level:
                reason = Reason.NO_GRIP
        if channel == "off" or (channel == "force" and not level):
            target = 0
            shown_level = None
        elif channel == "force":
            assert level is not None
            target = self.config.force_table.velocity_mrad_s(level)
            shown_level = level
        elif level is None:  # slip of unknown speed, or slip occurrence
            target = -self.config.occurrence_velocity_mrad_s
            shown_level = None
        else:
            target = self.config.slip_table.velocity_mrad_s(level)
            shown_level = level
        velocity, clamped = limit_belt_velocity(target, self.max_velocity_mrad_s)
        belt = Belt.FORCE if velocity > 0 else Belt.SLIP if velocity < 0 else Belt.NONE
        command = BeltCommand(t_us, velocity, belt, shown_level, reason, clamped)
        stimuli = self.config.encoder.encode(slipping, self._speed_mm_s)
        return FeedbackOutput(command, stimuli, slipping)

    def _choose(self, t_us: int, slipping: bool) -> tuple[str, int | None, Reason]:
        mode = self.mode
        if mode == FeedbackMode.OFF:
            return "off", None, Reason.MODE_OFF
        if mode == FeedbackMode.SLIP_OCCURRENCE:
            return ("slip", None, Reason.SLIP) if slipping else ("off", None, Reason.NO_SLIP)
        if mode in (FeedbackMode.SLIP_SPEED, FeedbackMode.FORCE_AND_SLIP) and slipping:
            level = self._speed_levels.level
            if level is None:
                return "slip", None, Reason.SLIP_SPEED_UNKNOWN
            reason = Reason.SLIP_SPEED_AT_LEAST if self._speed_bound else Reason.SLIP_SPEED
            return "slip", max(level, 1), reason
        if mode == FeedbackMode.SLIP_SPEED:
            return "off", None, Reason.NO_SLIP
        ended = self._slip.ended_us
        if (
            mode == FeedbackMode.FORCE_AND_SLIP
            and ended is not None
            and t_us < ended + self.config.force_return_us
        ):
            return "off", None, Reason.SLIP_ENDED
        known = self._force_known_us
        if known is None or t_us - known >= self.config.stale_us:
            self._force_levels.reset()
            return "off", None, Reason.FORCE_UNKNOWN
        level = self._force_levels.level or 0
        return "force", level, Reason.GRIP_FORCE if level else Reason.NO_GRIP

    def _dwell(self, t_us: int, channel: str, level: int | None) -> int | None:
        """Hold a shown level for `level_dwell_us` before showing another on the same
        channel; a new channel (mode change, slip start, slip end) is shown at once, and
        so is a slip's first known speed after a start at unknown speed or at a bound
        (which understated it)."""
        shown = self._shown
        floor = channel == "slip" and self._speed_bound
        if channel != shown.channel:
            self._shown = _Shown(channel, level, t_us, floor=floor)
            return level
        if level == shown.level:
            shown.pending = False
            shown.floor = floor
            return level
        first_speed = channel == "slip" and (shown.level is None or (shown.floor and not floor))
        if first_speed or t_us - shown.since_us >= self.config.level_dwell_us:
            self._shown = _Shown(channel, level, t_us, floor=floor)
            return level
        shown.pending = True
        return shown.level


def _check_max_velocity(value: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ConfigError(f"belt max profile velocity must be whole mrad/s >= 0, got {value!r}")
    return value

"""Hybrid control (thesis ch. 2.4.4, 9.3): a local grip reflex for slips too fast for the wearer.

A wearer reacts to slip feedback after 1.51–1.75 s (ch. 2.4.4), so on an
80 mm skin a slip faster than ≈45 mm/s has left the hand before the wearer
can act. Above `threshold_mm_s` the gateway raises the grip itself, by
`gain_n_per_mm_s` per mm/s of slip speed over the grip it had when the slip
began, never beyond the hand's crush limit, and says so (the command carries
the reflex state for the gateway to publish). Below the threshold the
wearer decides through EMG. While the decoder knows only a range of speeds
the reflex acts on its lower end (`Percept.speed_floor_mm_s`): a range
wholly above the threshold fires it, one straddling the threshold does not,
and the slip counts as slowed only once the range's upper end is below
threshold - hysteresis. The direction plays no part.

`GripArbiter` combines both: grip = min(crush limit, max(voluntary, reflex)).
After the fast slip stops the reflex grip is held for `hold_us` (longer than
the wearer's reaction time, so the wearer, told the reflex acted, can take
over), then released at `release_rate_n_s`; the release pauses while the
object slips and ends when the reflex grip meets the wearer's (hand-back).
The release stops above the grip the slip began at (that grip is known not
to hold the load): at `release_floor_share` of the raise. A slip that starts
again because the release went too far is the reflex's own doing: the grip
returns to the one that held and stays there. Either way the reflex keeps
its grip until the wearer grips as hard or opens the hand.
Sans-IO: `update(percept, voluntary)`, `set_voluntary(t, grip)` and
`advance(t)` return the grip command at that moment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum

from grasplink.errors import ConfigError
from grasplink.gateway.percept import Clock, Percept, finite_or_none

DEFAULT_CRUSH_LIMIT_N = 40.0  # hand profile, crush limit 2402h default 40000 mN
HAND_MAX_GRIP_N = 100.0  # hand profile, maximum grip force 2403h
HUMAN_REACTION_S = 1.75  # slowest mean reaction to slip feedback, ch. 2.4.4 (1.51–1.75 s)
MN_PER_N = 1000
US_PER_S = 1_000_000


def human_limit_mm_s(skin_length_mm: float, reaction_time_s: float = HUMAN_REACTION_S) -> float:
    """The fastest slip a wearer can stop before the object leaves the skin (ch. 9.3)."""
    if not (math.isfinite(skin_length_mm) and skin_length_mm > 0):
        raise ConfigError(f"skin length must be > 0 mm, got {skin_length_mm!r}")
    if not (math.isfinite(reaction_time_s) and reaction_time_s > 0):
        raise ConfigError(f"reaction time must be > 0 s, got {reaction_time_s!r}")
    return skin_length_mm / reaction_time_s


class ReflexState(StrEnum):
    IDLE = "idle"  # the wearer decides
    ACTIVE = "active"  # a fast slip: the reflex raises the grip
    HOLD = "hold"  # the fast slip stopped: the raised grip is held
    RELEASE = "release"  # the raised grip is let go at a bounded rate


class GripSource(StrEnum):
    VOLUNTARY = "voluntary"
    REFLEX = "reflex"


@dataclass(frozen=True, slots=True)
class ReflexConfig:
    """The reflex's thresholds, gain and timing (defaults and reasons: docs/feedback.md)."""

    threshold_mm_s: float = 45.0  # human limit on an 80 mm skin (ch. 2.4.4, 9.3)
    hysteresis_mm_s: float = 5.0  # active until |v| (or its upper bound) < threshold - h
    gain_n_per_mm_s: float = 0.1  # grip added per mm/s of slip speed
    crush_limit_n: float = DEFAULT_CRUSH_LIMIT_N
    hold_us: int = 2_000_000  # > the wearer's 1.51-1.75 s reaction time
    release_rate_n_s: float = 2.0
    min_confidence: float = 0.25  # slip speeds trusted less do not trigger the reflex
    stale_us: int = 500_000  # no percept this long: the slip is taken as stopped
    open_below_n: float = 0.5  # a voluntary grip falling to this is the wearer opening the hand
    release_floor_share: float = 0.5  # of the raise kept after the release (0: back to the base)
    enabled: bool = True

    def __post_init__(self) -> None:
        _positive("threshold_mm_s", self.threshold_mm_s)
        h = self.hysteresis_mm_s
        if not _number(h) or not 0 <= h < self.threshold_mm_s:
            raise ConfigError(
                f"reflex config: hysteresis_mm_s must be 0 <= h < threshold "
                f"({self.threshold_mm_s} mm/s), got {h!r}"
            )
        _positive("gain_n_per_mm_s", self.gain_n_per_mm_s)
        check_crush_limit(self.crush_limit_n)
        _positive("release_rate_n_s", self.release_rate_n_s)
        for name, low in (("hold_us", 0), ("stale_us", 1)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < low:
                raise ConfigError(
                    f"reflex config: {name} must be whole microseconds >= {low}, got {value!r}"
                )
        o = self.open_below_n
        if not _number(o) or o < 0:
            raise ConfigError(f"reflex config: open_below_n must be a number >= 0 N, got {o!r}")
        f = self.release_floor_share
        if not _number(f) or not 0 <= f <= 1:
            raise ConfigError(f"reflex config: release_floor_share must be 0..1, got {f!r}")
        c = self.min_confidence
        if not _number(c) or not 0 <= c <= 1:
            raise ConfigError(f"reflex config: min_confidence must be 0..1, got {c!r}")
        if not isinstance(self.enabled, bool):
            raise ConfigError(f"reflex config: enabled must be true or false, got {self.enabled!r}")


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _positive(name: str, value: float) -> None:
    if not _number(value) or value <= 0:
        raise ConfigError(f"reflex config: {name} must be a finite number > 0, got {value!r}")


def check_crush_limit(crush_limit_n: float) -> float:
    """A crush limit the hand accepts (2402h: 0..100 N); ConfigError otherwise."""
    if not _number(crush_limit_n) or not 0 < crush_limit_n <= HAND_MAX_GRIP_N:
        raise ConfigError(
            f"crush limit must be > 0 and <= {HAND_MAX_GRIP_N:g} N (the hand's maximum grip), "
            f"got {crush_limit_n!r}"
        )
    return float(crush_limit_n)


@dataclass(frozen=True, slots=True)
class GripCommand:
    """The grip setpoint for the hand (2400h) and where it came from.

    `grip_n` = min(crush limit, max(voluntary, reflex)). `reflex_grip_n`: the
    reflex's grip (None when idle). `clamped`: a request above the crush limit was
    limited to it. `reflex_active`: the gateway is acting for the wearer (publish it).
    """

    t_us: int
    grip_n: float
    voluntary_grip_n: float
    reflex_grip_n: float | None
    reflex: ReflexState
    source: GripSource
    clamped: bool = False

    @property
    def reflex_active(self) -> bool:
        return self.reflex != ReflexState.IDLE

    @property
    def target_grip_mn(self) -> int:
        """The value for the hand's target grip force (2400h, mN)."""
        return max(0, round(self.grip_n * MN_PER_N))


class GripReflex:
    """The reflex's state machine: idle → active → hold → release → idle."""

    def __init__(self, config: ReflexConfig):
        self.config = config
        self.crush_limit_n = config.crush_limit_n
        self.enabled = config.enabled
        self.state = ReflexState.IDLE
        self.grip_n: float | None = None  # the reflex's grip (None when idle)
        self.base_n = 0.0  # the grip when this reflex episode began
        self.limited = False  # base + gain·v exceeded the crush limit
        self._hold_from_us: int | None = None
        self._released_to_us: int | None = None  # release applied up to this time
        self._last_percept_us: int | None = None
        self._slipping = False  # the last percept's slip flag
        self.held_n: float | None = None  # the grip that stopped the slip (the hold's)
        self.learned = False  # a re-slip during the release: hold held_n until the wearer acts
        self._stopped = False  # the object was seen at rest since the hold began
        self._voluntary_at_start_n = 0.0  # the wearer's grip when the episode began

    def observe(self, percept: Percept, base_grip_n: float, voluntary_n: float) -> None:
        """A percept: time-driven changes up to its time first, then its slip speed."""
        p = percept.clean()
        t = p.t_us
        self.advance(t, voluntary_n)
        self._last_percept_us = t
        self._slipping = p.slipping
        cfg = self.config
        # the speed, or while only a range is known: at least `speed`, at most `ceiling`
        speed = p.speed_floor_mm_s(cfg.min_confidence) if p.slipping else None
        ceiling = p.speed_ceiling_mm_s(cfg.min_confidence) if p.slipping else None
        fast = speed is not None and speed >= cfg.threshold_mm_s
        slowed = not p.slipping or (
            ceiling is not None and ceiling < cfg.threshold_mm_s - cfg.hysteresis_mm_s
        )
        if fast and self.enabled and self.state == ReflexState.IDLE:
            self.base_n = max(0.0, base_grip_n)
            self.grip_n = None
            self._voluntary_at_start_n = max(0.0, voluntary_n)
        if self.state in (ReflexState.HOLD, ReflexState.RELEASE) and not p.slipping:
            self._stopped = True
        if self._reslipped(p.slipping) and not fast:
            self._regrip(t)
        if fast and self.enabled:
            self.state = ReflexState.ACTIVE
            self._hold_from_us = self._released_to_us = None
            self.learned = self._stopped = False
        if self.state == ReflexState.ACTIVE and speed is not None:
            wanted = self.base_n + cfg.gain_n_per_mm_s * speed
            self.limited = self.limited or wanted > self.crush_limit_n
            target = min(self.crush_limit_n, wanted)
            self.grip_n = target if self.grip_n is None else max(self.grip_n, target)
        if self.state == ReflexState.ACTIVE and slowed:
            self._hold(t, stopped=not p.slipping)

    def _hold(self, t_us: int, stopped: bool) -> None:
        self.state = ReflexState.HOLD
        self._hold_from_us = t_us
        self.held_n = self.grip_n
        self._stopped = stopped

    def _reslipped(self, slipping: bool) -> bool:
        """The object slips again while the release lowers the grip that had stopped it."""
        return (
            slipping
            and self.enabled
            and self.state in (ReflexState.HOLD, ReflexState.RELEASE)
            and self._stopped
            and self.held_n is not None
            and self.grip_n is not None
            and self.grip_n < self.held_n
        )

    def _regrip(self, t_us: int) -> None:
        """Back to the grip that held, and no lower for the rest of the episode."""
        self.state = ReflexState.HOLD
        self.grip_n = self.held_n
        self.learned = True
        self._hold_from_us = t_us
        self._stopped = False

    def floor_n(self) -> float:
        """The lowest grip the release goes to: above the base, which did not hold."""
        if not self.enabled or self.held_n is None:
            return 0.0  # switched off: back to the wearer
        return self.base_n + self.config.release_floor_share * max(0.0, self.held_n - self.base_n)

    def advance(self, t_us: int, voluntary_n: float) -> None:
        """Time passes: a stale slip ends, the hold expires, the release progresses."""
        cfg = self.config
        last = self._last_percept_us
        stale = last is None or t_us - last >= cfg.stale_us
        if self.state == ReflexState.ACTIVE and stale:
            self._hold(t_us if last is None else last + cfg.stale_us, stopped=False)
        if self.state == ReflexState.HOLD and not self.learned:
            assert self._hold_from_us is not None
            release_at = self._hold_from_us + cfg.hold_us
            if t_us >= release_at:
                self.state = ReflexState.RELEASE
                self._released_to_us = release_at
        if self.state == ReflexState.RELEASE:
            assert self._released_to_us is not None and self.grip_n is not None
            floor = self.floor_n()
            if not (self._slipping and not stale):  # pause while the object slips
                dt_s = (t_us - self._released_to_us) / US_PER_S
                self.grip_n = max(floor, self.grip_n - cfg.release_rate_n_s * dt_s)
            self._released_to_us = t_us
            if self.grip_n <= floor and floor > voluntary_n:
                self.state = ReflexState.HOLD  # the floor: kept until the wearer acts
                self.learned = True
                self._hold_from_us = t_us
        if self.state in (ReflexState.HOLD, ReflexState.RELEASE):
            assert self.grip_n is not None
            opened = self._voluntary_at_start_n > cfg.open_below_n >= voluntary_n
            if self.grip_n <= voluntary_n or self.grip_n <= 0.0 or opened:
                self._to_idle()  # the wearer grips at least as hard, or opens: hand back

    def stop(self, t_us: int) -> None:
        """Disabled while acting: let go at the release rate from now (never a drop)."""
        if self.state in (ReflexState.ACTIVE, ReflexState.HOLD):
            self.state = ReflexState.RELEASE
            self._released_to_us = t_us

    def deadline_us(self, voluntary_n: float) -> int | None:
        cfg = self.config
        if self.state == ReflexState.ACTIVE and self._last_percept_us is not None:
            return self._last_percept_us + cfg.stale_us
        if self.state == ReflexState.HOLD and self._hold_from_us is not None:
            return None if self.learned else self._hold_from_us + cfg.hold_us
        if self.state == ReflexState.RELEASE and self.grip_n is not None and not self._slipping:
            assert self._released_to_us is not None
            left_n = self.grip_n - max(0.0, voluntary_n, self.floor_n())
            return self._released_to_us + math.ceil(left_n / cfg.release_rate_n_s * US_PER_S)
        return None

    def _to_idle(self) -> None:
        self.state = ReflexState.IDLE
        self.grip_n = None
        self.limited = False
        self._hold_from_us = self._released_to_us = None
        self.held_n = None
        self.learned = self._stopped = False


class GripArbiter:
    """Voluntary (EMG) grip and reflex grip → the hand's grip setpoint.

    The voluntary grip comes from the caller (the EMG decoding); None or a
    non-finite value keeps the last valid one (a bad EMG number must not drop
    the object), a negative one is 0 N.
    """

    def __init__(self, config: ReflexConfig | None = None):
        self.reflex = GripReflex(config or ReflexConfig())
        self._clock = Clock("grip arbiter")
        self.voluntary_n = 0.0
        self.grip_n = 0.0  # the last commanded grip

    @property
    def crush_limit_n(self) -> float:
        return self.reflex.crush_limit_n

    def update(self, percept: Percept, voluntary_grip_n: float | None = None) -> GripCommand:
        """A percept (and optionally a new voluntary grip) at the percept's time."""
        t_us = self._clock.tick(percept.t_us)
        self._take_voluntary(voluntary_grip_n)
        base = max(self.grip_n, self.voluntary_n)
        self.reflex.observe(percept, base, self.voluntary_n)
        return self._evaluate(t_us)

    def set_voluntary(self, t_us: int, voluntary_grip_n: float | None) -> GripCommand:
        """A new voluntary grip from the EMG path."""
        t_us = self._clock.tick(t_us)
        self._take_voluntary(voluntary_grip_n)
        return self._evaluate(t_us)

    def advance(self, t_us: int) -> GripCommand:
        """Time passes: hold and release progress."""
        return self._evaluate(self._clock.tick(t_us))

    def set_crush_limit(self, crush_limit_n: float, t_us: int) -> GripCommand:
        """The hand's crush limit (2402h) changed: nothing commanded goes above it."""
        self.reflex.crush_limit_n = check_crush_limit(crush_limit_n)
        return self._evaluate(self._clock.tick(t_us))

    def set_reflex_enabled(self, enabled: bool, t_us: int) -> GripCommand:
        """Switch the reflex on or off at run time; off while acting releases at the rate."""
        t_us = self._clock.tick(t_us)
        self.reflex.enabled = bool(enabled)
        if not enabled:
            self.reflex.stop(t_us)
        return self._evaluate(t_us)

    def next_deadline_us(self) -> int | None:
        """When the grip changes next without input (the release's end while releasing:
        send commands on the gateway's command period in between)."""
        deadline = self.reflex.deadline_us(self.voluntary_n)
        now = self._clock.now_us
        return deadline if deadline is None or now is None or deadline > now else None

    def _take_voluntary(self, voluntary_grip_n: float | None) -> None:
        value = finite_or_none(voluntary_grip_n)
        if value is not None:
            self.voluntary_n = max(0.0, value)

    def _evaluate(self, t_us: int) -> GripCommand:
        reflex = self.reflex
        reflex.advance(t_us, self.voluntary_n)
        reflex_n = reflex.grip_n if reflex.state != ReflexState.IDLE else None
        wanted = self.voluntary_n if reflex_n is None else max(self.voluntary_n, reflex_n)
        crush = reflex.crush_limit_n
        grip = min(crush, wanted)
        at_limit = reflex.limited and reflex.state in (ReflexState.ACTIVE, ReflexState.HOLD)
        clamped = self.voluntary_n > crush or at_limit
        source = (
            GripSource.REFLEX
            if reflex_n is not None and reflex_n > self.voluntary_n
            else GripSource.VOLUNTARY
        )
        self.grip_n = grip
        return GripCommand(
            t_us, grip, self.voluntary_n, reflex_n, reflex.state, source, clamped=clamped
        )

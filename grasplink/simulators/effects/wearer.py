"""The wearer (physics domain): a scripted contraction level, or a virtual wearer.

`wearer.script` plays contraction levels from the scene. `wearer.virtual`
closes the loop in silico: it feels the haptic belt (`belt.tap_hz`,
`belt.surface_mm_s`), identifies the belt's level and answers with a
contraction level (`wearer.level`, e0..e5, which `emg.surface` turns into
EMG). It is a model of a user, not an optimiser; every stage has thesis
defaults:

- perception (ch. 8): a display that holds for `min_cue_s` is a cue; after
  a reaction time drawn per cue (slip cues 1.51-1.75 s, ch. 2.4.4; force
  cues and the end of a display 0.9-1.0 s, ch. 8.4.1) the wearer names a
  level drawn from the confusion matrix row of the level shown (fig. 8.5; a
  display between two levels blends their rows). Cues are identified one
  at a time, in order, from a bounded queue.
- decision: slip felt -> contract harder (at least the level mapped to the
  perceived slip, and `slip_step` above the current aim), again every
  `slip_repeat_s` while the slip is still felt; force felt -> hold, but
  relax one level every `relax_after_s` while the perceived force is at or
  above `relax_force_level`; nothing felt -> keep the level (or relax every
  `idle_relax_s`).
- execution (ch. 2.4.3): the produced level is the aim off by a scatter
  draw; it lands `motor_delay_s` after the decision, so a cue's reaction
  time runs from the display's onset to the new level.

Draws come from `ctx.rng("wearer.virtual")`, split into one stream per
stage and consumed per event (cue, perception, contraction), never per
sample: chunked stepping equals one-shot stepping and a seed fixes the
wearer.
"""

from __future__ import annotations

import collections
import itertools
import math
from dataclasses import dataclass

import numpy as np

from grasplink.core.params import Params
from grasplink.simulators import signals as sig
from grasplink.simulators.core import PHYSICS, Context, Effect, Io, register
from grasplink.simulators.effects.kinematics import Profile

LEVELS = 5  # e0 (below e_min) .. e5 (above e_max), thesis ch. 2.3.3


@register
class WearerScript(Effect):
    """The wearer's contraction level e0..e5 follows a script.

    `levels` = [[t_s, level], ...], times strictly increasing, each level an
    integer 0..5. Step-wise: a level holds from its time until the next
    point; the first level is held before the first point.
    """

    kind = "wearer.script"
    domain = PHYSICS
    outputs = (sig.WEARER_LEVEL,)
    summary = "scripted contraction level e0..e5 (step-wise [t_s, level] points)"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        pairs = params.pairs("levels", low=0, high=LEVELS, integer=True, what="level")
        self.profile = Profile(params, "levels", "step", pairs)

    def step(self, io: Io) -> None:
        io.put(sig.WEARER_LEVEL, self.profile.value(io.times_us))


# ---------------------------------------------------------------- wearer.virtual

US_PER_S = 1_000_000
NOTHING, FORCE, SLIP = 0, 1, 2  # which belt the wearer feels
BELT_NAMES = {FORCE: "force", SLIP: "slip"}
MAX_DISPLAY_LEVELS = 8  # level tables hold 2..8 levels (the thesis' wearers read four)

# Ch. 8.3.3: the four display levels of each belt.
FORCE_LEVELS_RAD_S = (3.5, 5.0, 6.5, 8.0)
SLIP_LEVELS_MM_S = (55.0, 100.0, 145.0, 190.0)
# Ch. 8.4.1, fig. 8.5: identification rates (rows: level shown, columns: level answered). The
# text export keeps every entry of at least ~10 %; the smaller ones are the row's remainder
# to 100 %, split where two are missing by the standard deviations the figure reports.
FORCE_CONFUSION = (
    (0.796, 0.196, 0.008, 0.000),
    (0.084, 0.672, 0.240, 0.004),
    (0.012, 0.208, 0.664, 0.116),
    (0.000, 0.048, 0.272, 0.680),
)
SLIP_CONFUSION = (
    (0.668, 0.296, 0.032, 0.004),
    (0.128, 0.576, 0.268, 0.028),
    (0.020, 0.156, 0.552, 0.272),
    (0.000, 0.040, 0.268, 0.692),
)
SLIP_REACTION_S = (1.51, 1.75)  # ch. 2.4.4, fig. 2.6: slip onset -> EMG rise, 1.51-1.75 s
FORCE_REACTION_S = (0.9, 1.0)  # ch. 8.4.1: a force level identified after 0.92 s (slip 0.99 s)
# Ch. 2.4.3, fig. 2.5D (slip speed feedback): contractions mostly on the expected level, the
# drifts mostly one level and more often low than high. The figure's values are not in the
# text; these probabilities of landing -2, -1, 0, +1, +2 levels off keep that shape.
SCATTER = (0.05, 0.15, 0.70, 0.08, 0.02)
ROW_SUM_TOLERANCE = 1e-3  # rounded percentages are accepted, then normalised


def _draw(probabilities: np.ndarray, u: float) -> int:
    """Index of the category a uniform draw u in [0, 1) falls in; never a zero-probability one."""
    cumulative = np.cumsum(probabilities)
    index = int(np.searchsorted(cumulative, u * cumulative[-1], side="right"))
    return min(index, int(np.flatnonzero(probabilities > 0)[-1]))


def _probabilities(params: Params, name: str, values: object, size: int | None) -> np.ndarray:
    """A probability row: `size` (or any odd count when None) numbers >= 0 that sum to 1."""
    if not isinstance(values, list) or not values:
        raise params.error(name, f"expected a list of probabilities, got {values!r}")
    if size is not None and len(values) != size:
        raise params.error(name, f"expected {size} probabilities, got {len(values)}")
    if size is None and len(values) % 2 == 0:
        raise params.error(name, f"expected an odd count (centre = on target), got {len(values)}")
    for i, value in enumerate(values):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if not ok or not math.isfinite(value) or value < 0:
            raise params.error(f"{name}[{i}]", f"expected a probability >= 0, got {value!r}")
    row = np.array(values, dtype=np.float64)
    if abs(row.sum() - 1.0) > ROW_SUM_TOLERANCE:
        raise params.error(name, f"expected probabilities summing to 1, got {row.sum():.6g}")
    return row / row.sum()


def _confusion(params: Params, name: str, default: tuple, size: int) -> np.ndarray:
    """A size x size confusion matrix: row = level shown, column = level identified."""
    value = params.raw(name, [list(row) for row in default])
    if not isinstance(value, list) or len(value) != size:
        count = len(value) if isinstance(value, list) else value
        raise params.error(name, f"expected {size} rows (one per display level), got {count!r}")
    return np.stack(
        [_probabilities(params, f"{name}[{i}]", row, size) for i, row in enumerate(value)]
    )


def _level_table(params: Params, name: str, default: tuple[float, ...]) -> np.ndarray:
    values = params.numbers(name, list(default), low=0.0, low_open=True, min_len=2)
    if len(values) > MAX_DISPLAY_LEVELS:
        raise params.error(name, f"expected at most {MAX_DISPLAY_LEVELS} levels, got {len(values)}")
    if any(b <= a for a, b in itertools.pairwise(values)):
        raise params.error(name, f"expected strictly increasing levels, got {list(values)}")
    return np.array(values, dtype=np.float64)


def _bounds_s(params: Params, name: str, default: tuple[float, float]) -> tuple[float, float]:
    values = params.numbers(name, list(default), low=0.0, high=60.0, min_len=2)
    if len(values) != 2 or values[0] > values[1]:
        raise params.error(name, f"expected [low_s, high_s] with low <= high, got {list(values)}")
    return values[0], values[1]


def _period_us(params: Params, name: str, default: float) -> int:
    """A re-evaluation period: 0 = off, else at least 0.1 s (one decision per period)."""
    value = params.number(name, default, low=0.0, high=600.0)
    if 0 < value < 0.1:
        raise params.error(name, f"expected 0 (off) or at least 0.1 s, got {value:g}")
    return round(value * US_PER_S)


@dataclass(slots=True)
class Cue:
    """A display change the wearer will identify: shown from `onset_us`, decided at `decide_us`."""

    onset_us: int
    belt: int  # NOTHING, FORCE or SLIP
    position: float  # fractional index into the belt's level table (nan for NOTHING)
    decide_us: int
    held_level: int = 0  # the level the wearer aimed at when the display came up


@register
class WearerVirtual(Effect):
    """A virtual wearer: feels the belt, identifies its level, contracts (thesis ch. 2, 8).

    Perception: the display is classified per sample (slip belt when surface
    speed >= `slip_detect_mm_s`, else force belt when the tap frequency >=
    `force_detect_hz`, else nothing). A display that holds for `min_cue_s`
    is a cue; after a reaction time drawn per cue (slip cues `slip_reaction_s`,
    ch. 2; force cues and the end of a display `force_reaction_s`, ch. 8) the
    wearer identifies a level drawn from the confusion matrix row of the shown
    level. Decision: slip -> contract harder; force -> hold, relax after a
    while at a high force; nothing -> keep the level. Execution: the level
    lands off by a scatter draw, `motor_delay_s` after the decision. The
    module docstring and docs/scenes.md give the rules.
    """

    kind = "wearer.virtual"
    domain = PHYSICS
    inputs = (sig.BELT_TAP_HZ, sig.BELT_SURFACE_MM_S)
    outputs = (sig.WEARER_LEVEL, sig.WEARER_PERCEIVED)
    summary = (
        "virtual wearer: identifies belt levels, contracts against slip, relaxes at high force"
    )

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        # Perception.
        self.nubs = params.integer("nubs", 6, low=1, high=64)
        self.force_levels_rad_s = _level_table(params, "force_levels_rad_s", FORCE_LEVELS_RAD_S)
        self.slip_levels_mm_s = _level_table(params, "slip_levels_mm_s", SLIP_LEVELS_MM_S)
        lowest_tap_hz = self.nubs * self.force_levels_rad_s[0] / (2 * math.pi)
        self.force_detect_hz = params.number("force_detect_hz", 1.5, low=0.0, low_open=True)
        if self.force_detect_hz >= lowest_tap_hz:
            raise params.error(
                "force_detect_hz",
                f"expected a threshold below the lowest force level's {lowest_tap_hz:.3g} Hz, "
                f"got {self.force_detect_hz:g}",
            )
        self.slip_detect_mm_s = params.number("slip_detect_mm_s", 25.0, low=0.0, low_open=True)
        if self.slip_detect_mm_s >= self.slip_levels_mm_s[0]:
            raise params.error(
                "slip_detect_mm_s",
                f"expected a threshold below the lowest slip level's "
                f"{self.slip_levels_mm_s[0]:g} mm/s, got {self.slip_detect_mm_s:g}",
            )
        self.confusion = {
            FORCE: _confusion(
                params, "force_confusion", FORCE_CONFUSION, len(self.force_levels_rad_s)
            ),
            SLIP: _confusion(params, "slip_confusion", SLIP_CONFUSION, len(self.slip_levels_mm_s)),
        }
        self.min_cue_us = round(params.number("min_cue_s", 0.1, low=0.0, high=5.0) * US_PER_S)
        self.motor_delay_us = round(
            params.number("motor_delay_s", 0.1, low=0.0, high=5.0) * US_PER_S
        )
        self.reaction_s = {
            SLIP: _bounds_s(params, "slip_reaction_s", SLIP_REACTION_S),
            FORCE: _bounds_s(params, "force_reaction_s", FORCE_REACTION_S),
        }
        floor_s = (self.min_cue_us + self.motor_delay_us) / US_PER_S
        for belt, (low_s, _) in self.reaction_s.items():
            if low_s < floor_s:
                raise params.error(
                    f"{BELT_NAMES[belt]}_reaction_s",
                    f"expected a shortest reaction >= min_cue_s + motor_delay_s "
                    f"({floor_s:g} s), got {low_s:g}",
                )
        self.max_pending = params.integer("max_pending_cues", 8, low=1, high=64)
        # Decision.
        self.rest_level = params.integer("rest_level", 0, low=0, high=LEVELS)
        self.max_level = params.integer("max_level", 4, low=max(1, self.rest_level), high=LEVELS)
        responses = params.numbers(
            "slip_response_levels",
            list(range(1, len(self.slip_levels_mm_s) + 1)),
            low=0,
            high=self.max_level,
        )
        if len(responses) != len(self.slip_levels_mm_s) or any(
            not float(r).is_integer() for r in responses
        ):
            raise params.error(
                "slip_response_levels",
                f"expected {len(self.slip_levels_mm_s)} integer levels 0..{self.max_level} "
                f"(one per slip level), got {list(responses)}",
            )
        if any(b < a for a, b in itertools.pairwise(responses)):
            raise params.error(
                "slip_response_levels",
                f"expected levels that never fall for a faster slip, got {list(responses)}",
            )
        self.slip_response = tuple(int(r) for r in responses)
        self.slip_adds = params.boolean("slip_response_adds", False)
        self.slip_step = params.integer("slip_step", 1, low=0, high=LEVELS)
        self.slip_repeat_us = _period_us(params, "slip_repeat_s", 2.0)
        self.relax_force_level = params.integer(
            "relax_force_level", 3, low=1, high=len(self.force_levels_rad_s)
        )
        self.relax_after_us = _period_us(params, "relax_after_s", 3.0)
        self.idle_relax_us = _period_us(params, "idle_relax_s", 0.0)
        # Execution.
        self.scatter = _probabilities(params, "scatter", params.raw("scatter", list(SCATTER)), None)
        self.scatter_offsets = np.arange(len(self.scatter)) - len(self.scatter) // 2

        # Every draw comes from the effect's generator, one stream per purpose: each stream is
        # consumed in event order (cues, perceptions, contractions), never per sample.
        streams = ctx.rng(self.kind).spawn(3)
        self._rng_reaction, self._rng_perception, self._rng_execution = streams

        # Display debouncing: the candidate display key and when it began.
        self._candidate_key = 0
        self._candidate_onset_us = 0
        self._candidate_done = True  # promoted to a cue, or the display the last cue showed
        self._last_cue_key = 0
        self._queue: collections.deque[Cue] = collections.deque()
        self._last_decide_us = -1  # decision time of the last cue taken off the queue
        # The wearer.
        self.perceived_belt = NOTHING
        self.perceived_level = 0
        self.intended = self.rest_level
        self.level = float(self.rest_level)  # what the muscle produces now
        self._landing: tuple[int, int] | None = None  # (time_us, level) of the pending contraction
        self._last_eval_us = 0
        self._timer_us: int | None = None
        self.counts = dict.fromkeys(
            (
                "invalid_samples",  # a NaN/inf/negative tap_hz or surface_mm_s: felt as nothing
                "brief_displays",  # displays shorter than min_cue_s: never identified
                "cues",
                "dropped_cues",  # the queue was full: the newest pending cue was replaced
                "perceptions",
                "contractions",  # decisions that changed the intended level
            ),
            0,
        )

    # -- perception ------------------------------------------------------------------
    def _classify(self, tap_hz: np.ndarray, surface_mm_s: np.ndarray) -> tuple[np.ndarray, ...]:
        """Per sample: display key (0 nothing, 1.. force levels, then slip levels) and position."""
        valid_tap = np.isfinite(tap_hz) & (tap_hz >= 0)
        valid_surface = np.isfinite(surface_mm_s) & (surface_mm_s >= 0)
        self.counts["invalid_samples"] += int(np.count_nonzero(~(valid_tap & valid_surface)))
        tap = np.where(valid_tap, tap_hz, 0.0)
        surface = np.where(valid_surface, surface_mm_s, 0.0)
        slip = surface >= self.slip_detect_mm_s
        force = (tap >= self.force_detect_hz) & ~slip
        rad_s = tap * (2 * math.pi / self.nubs)
        force_position = np.interp(
            rad_s, self.force_levels_rad_s, np.arange(len(self.force_levels_rad_s))
        )
        slip_position = np.interp(
            surface, self.slip_levels_mm_s, np.arange(len(self.slip_levels_mm_s))
        )
        position = np.where(slip, slip_position, force_position)
        nothing = ~(slip | force)
        # the nearest level, 0 where nothing shows (the key ignores it there): what
        # nan_to_num gave with NaN there, without its Python wrapper (levels are finite)
        nearest = np.floor(np.where(nothing, 0.0, position) + 0.5).astype(np.int64)
        position[nothing] = np.nan  # no level shown
        key = np.where(
            slip, 1 + len(self.force_levels_rad_s) + nearest, np.where(force, 1 + nearest, 0)
        )
        return key, position

    def _belt_of(self, key: int) -> int:
        if key == 0:
            return NOTHING
        return FORCE if key <= len(self.force_levels_rad_s) else SLIP

    def _cues(
        self, times_us: np.ndarray, key: np.ndarray, position: np.ndarray
    ) -> list[tuple[int, int, int, int, float]]:
        """Displays that held min_cue_s: (promoted_us, onset_us, key, reaction belt, position)."""
        found = []
        starts = [0, *(np.flatnonzero(np.diff(key)) + 1).tolist()]
        ends = [*starts[1:], len(key)]
        for start, end in zip(starts, ends, strict=True):
            k = int(key[start])
            if not (start == 0 and k == self._candidate_key):
                if not self._candidate_done:
                    self.counts["brief_displays"] += 1
                self._candidate_key, self._candidate_onset_us = k, int(times_us[start])
                self._candidate_done = k == self._last_cue_key
            if self._candidate_done:
                continue
            at = int(np.searchsorted(times_us, self._candidate_onset_us + self.min_cue_us))
            at = max(at, start)
            if at < end:
                # The end of a display is timed like the belt that stopped.
                belt = self._belt_of(k) or self._belt_of(self._last_cue_key)
                found.append((int(times_us[at]), self._candidate_onset_us, k, belt, position[at]))
                self._last_cue_key = k
                self._candidate_done = True
        return found

    def _queue_cue(
        self, now_us: int, onset_us: int, key: int, reaction_belt: int, position: float
    ) -> None:
        low_s, high_s = self.reaction_s[reaction_belt]
        reaction_us = round((low_s + (high_s - low_s) * self._rng_reaction.random()) * US_PER_S)
        self.counts["cues"] += 1
        if len(self._queue) == self.max_pending:
            self._queue.pop()  # coalesce: the newest pending cue is overtaken by this one
            self.counts["dropped_cues"] += 1
        previous_us = self._queue[-1].decide_us if self._queue else self._last_decide_us
        decide_us = max(onset_us + reaction_us - self.motor_delay_us, now_us, previous_us)
        self._queue.append(
            Cue(onset_us, self._belt_of(key), float(position), decide_us, self.intended)
        )

    def _identify(self, cue: Cue) -> int:
        """The level the wearer names for the cue's display: a draw from the confusion row."""
        if cue.belt == NOTHING:
            return 0
        matrix = self.confusion[cue.belt]
        lower = min(math.floor(cue.position), len(matrix) - 1)
        fraction = cue.position - lower
        row = (
            matrix[lower]
            if fraction == 0
            else (1 - fraction) * matrix[lower] + fraction * matrix[lower + 1]
        )
        return 1 + _draw(row, self._rng_perception.random())

    # -- decision and execution ----------------------------------------------------------
    def _perceive(self, now_us: int, cue: Cue) -> None:
        self.counts["perceptions"] += 1
        self._last_decide_us = cue.decide_us
        self.perceived_belt, self.perceived_level = cue.belt, self._identify(cue)
        self._last_eval_us = now_us
        if cue.belt == SLIP:
            self._contract(now_us, self._slip_target(cue.held_level))
        self._arm_timer()

    def _slip_target(self, held_level: int | None = None) -> int:
        """Slip felt: at least the level mapped to the perceived slip, and `slip_step` harder.

        With `slip_response_adds` the mapped level is added to the level held when the
        display came up (the speed measured the grip missing then), never lowering the aim;
        a slip still felt `slip_repeat_s` later (`held_level` None) adds `slip_step`."""
        response = self.slip_response[self.perceived_level - 1]
        if not self.slip_adds:
            wanted = max(response, self.intended + self.slip_step)
        elif held_level is None:
            wanted = self.intended + self.slip_step
        else:
            wanted = max(self.intended, held_level + response)
        return min(self.max_level, wanted)

    def _on_timer(self, now_us: int) -> None:
        self._last_eval_us = now_us
        if self.perceived_belt == SLIP:
            self._contract(now_us, self._slip_target())
        else:  # high force felt for a while, or nothing felt for a while: relax one level
            self._contract(now_us, max(self.intended - 1, min(self.rest_level, self.intended)))
        self._arm_timer()

    def _arm_timer(self) -> None:
        period_us = 0
        if self.perceived_belt == SLIP:
            period_us = self.slip_repeat_us
        elif self.intended > self.rest_level:
            high_force = (
                self.perceived_belt == FORCE and self.perceived_level >= self.relax_force_level
            )
            if high_force:
                period_us = self.relax_after_us
            elif self.perceived_belt == NOTHING:
                period_us = self.idle_relax_us
        self._timer_us = self._last_eval_us + period_us if period_us else None

    def _contract(self, now_us: int, target: int) -> None:
        """Aim at `target`; the muscle produces it off by a scatter draw, motor_delay_s later."""
        if target == self.intended:
            return
        self.counts["contractions"] += 1
        self.intended = target
        produced = target
        if target > 0:
            offset = self.scatter_offsets[_draw(self.scatter, self._rng_execution.random())]
            produced = int(np.clip(target + offset, 0, LEVELS))
        # A newer aim replaces a contraction that has not landed yet.
        self._landing = (now_us + self.motor_delay_us, produced)

    # -- stepping ----------------------------------------------------------------------
    def step(self, io: Io) -> None:
        times_us = io.times_us.astype(np.int64)
        n = len(times_us)
        level = np.full(n, self.level)
        perceived = np.full(n, self._perceived_value())
        if n == 0:
            io.put(sig.WEARER_LEVEL, level)
            io.put(sig.WEARER_PERCEIVED, perceived)
            return
        key, position = self._classify(io.get(sig.BELT_TAP_HZ), io.get(sig.BELT_SURFACE_MM_S))
        cues = self._cues(times_us, key, position)
        end_us = int(times_us[-1])
        next_cue = 0
        while True:
            # (time, order): at equal times a contraction lands, then cues queue, then
            # perceptions, then timers; every event at or before the chunk's last sample runs.
            events = []
            if self._landing is not None:
                events.append((self._landing[0], 0))
            if next_cue < len(cues):
                events.append((cues[next_cue][0], 1))
            if self._queue:
                events.append((self._queue[0].decide_us, 2))
            if self._timer_us is not None:
                events.append((self._timer_us, 3))
            if not events:
                break
            now_us, which = min(events)
            if now_us > end_us:
                break
            if which == 0:
                assert self._landing is not None  # event 0 is queued only while a landing is set
                self.level = float(self._landing[1])
                self._landing = None
                level[np.searchsorted(times_us, now_us) :] = self.level
            elif which == 1:
                self._queue_cue(*cues[next_cue])
                next_cue += 1
            elif which == 2:
                self._perceive(now_us, self._queue.popleft())
                perceived[np.searchsorted(times_us, now_us) :] = self._perceived_value()
            else:
                self._on_timer(now_us)
        io.put(sig.WEARER_LEVEL, level)
        io.put(sig.WEARER_PERCEIVED, perceived)

    def _perceived_value(self) -> float:
        return float(-self.perceived_level if self.perceived_belt == SLIP else self.perceived_level)

"""How the grasped object moves along the slip axis (physics domain).

Every effect here writes the three object signals:

- `object.position_mm`: the object's LEADING edge along the slip axis, from
  the skin's first ridge (x = 0) towards the last;
- `object.speed_mm_s`: signed, positive from the first ridge towards the last;
- `object.slipping`: 1.0 while the speed is non-zero, else 0.0.

`object.scripted` plays a speed profile, `object.coulomb` integrates Coulomb
friction between the grip and a tangential load, `object.slip_task` replays
the thesis' slip-stopping task (ch. 2.3.3) and `object.ridge_dips` modifies
any of them with the real speed dips at each ridge (ch. 5.4.2, 5.5.1).

Times are taken from the integer microsecond clock (`io.times_us`) so that
positions are analytic functions of the clock wherever the physics allows,
and state carried between chunks makes chunked stepping bit-identical to
one-shot stepping.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from grasplink.core.params import Params
from grasplink.simulators import signals as sig
from grasplink.simulators.core import PHYSICS, Context, Effect, Io, register
from grasplink.simulators.effects.skin import JUMP_SLACK, JUMP_TOLERANCE_MM

US_PER_S = 1_000_000
POSITION, SPEED, SLIPPING = sig.OBJECT_POSITION_MM, sig.OBJECT_SPEED_MM_S, sig.OBJECT_SLIPPING
OBJECT_OUTPUTS = (POSITION, SPEED, SLIPPING)
MU_SKIN = 0.7813  # SPEC ch. 4.3: friction coefficient object/silicone skin
INTERPOLATIONS = ("linear", "step")


class Profile:
    """A [t_s, value] profile on the microsecond clock, with its exact integral.

    `linear` interpolates between points, `step` holds each point's value
    until the next point. Before the first point the first value is held,
    after the last point the last value. Point times are rounded to the
    microsecond clock (the scene clock cannot resolve finer).
    """

    def __init__(
        self,
        params: Params,
        name: str,
        interpolation: str,
        pairs: tuple[tuple[float, float], ...] | None = None,
    ):
        pairs = params.pairs(name) if pairs is None else pairs
        knots_us = np.array([round(t * US_PER_S) for t, _ in pairs], dtype=np.int64)
        if np.any(np.diff(knots_us) <= 0):
            raise params.error(name, "times must be at least 1 µs apart")
        values = np.array([v for _, v in pairs], dtype=np.float64)
        self.linear = interpolation == "linear"
        if knots_us[0] > 0:  # integrate from t = 0: hold the first value before the first point
            knots_us = np.concatenate(([0], knots_us))
            values = np.concatenate((values[:1], values))
        self.knots_us = knots_us
        self.values = values
        widths_s = np.diff(knots_us) / US_PER_S
        if self.linear:
            self.slopes = np.concatenate((np.diff(values) / widths_s, [0.0]))
            areas = 0.5 * (values[:-1] + values[1:]) * widths_s
        else:
            self.slopes = np.zeros(len(values))
            areas = values[:-1] * widths_s
        self.cumulative = np.concatenate(([0.0], np.cumsum(areas)))

    def _segment(self, times_us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        index = np.searchsorted(self.knots_us, times_us, side="right") - 1
        index = np.clip(index, 0, len(self.knots_us) - 1)
        elapsed_s = (times_us - self.knots_us[index]) / US_PER_S
        return index, elapsed_s

    def value(self, times_us: np.ndarray) -> np.ndarray:
        index, elapsed_s = self._segment(times_us)
        elapsed_s = np.maximum(elapsed_s, 0.0)  # before t = 0: hold the first value
        return self.values[index] + self.slopes[index] * elapsed_s

    def integral(self, times_us: np.ndarray) -> np.ndarray:
        """∫_0^t value dt in value·s, closed form per segment (no accumulation over samples)."""
        index, elapsed_s = self._segment(times_us)
        slope = np.where(elapsed_s > 0, self.slopes[index], 0.0)
        return (
            self.cumulative[index]
            + self.values[index] * elapsed_s
            + 0.5 * slope * elapsed_s * elapsed_s
        )


def put_object(io: Io, position_mm: np.ndarray, speed_mm_s: np.ndarray) -> None:
    io.put(POSITION, position_mm)
    io.put(SPEED, speed_mm_s)
    io.put(SLIPPING, (speed_mm_s != 0).astype(np.float64))


def sample_steps_s(times_us: np.ndarray, last_us: int | None) -> np.ndarray:
    """Seconds from each sample's predecessor: the first from the previous chunk's last
    sample (0 at the very first), so chunked stepping integrates as one-shot does."""
    previous = times_us[0] if last_us is None else last_us
    return np.diff(times_us, prepend=previous) / US_PER_S


def integrate_mm(start_mm: float, speed_mm_s: np.ndarray, dt_s: np.ndarray) -> np.ndarray:
    """Positions x_k = x_{k-1} + v_k·dt_k from `start_mm`, summed sequentially."""
    return np.cumsum(np.concatenate(([start_mm], speed_mm_s * dt_s)))[1:]


def _direction_sign(params: Params) -> tuple[float, bool]:
    """(+1 or -1, whether `direction` was given)."""
    if not params.has("direction"):
        params.string("direction", "forward")  # mark as known
        return 1.0, False
    direction = params.string("direction", choices=("forward", "reverse"))
    return (1.0 if direction == "forward" else -1.0), True


@register
class ScriptedObject(Effect):
    """The object slides with a scripted speed profile.

    Parameters:
    - `speed_mm_s`: [[t_s, speed_mm_s], ...], times strictly increasing.
      Without `direction` the speeds are signed (+ towards the last ridge).
      With `direction` they are magnitudes (>= 0, refused otherwise) and
      `direction` gives the sign.
    - `interpolation`: "linear" (default) or "step".
    - `direction`: "forward" (+) or "reverse" (-); optional.
    - `start_mm`: leading-edge position at t = 0 (default 0).
    - `object_length_mm`: optional (> 0). Without it one edge is integrated
      continuously, whatever the sign of the motion. With it the reported
      position is the edge the object leads with: at a reversal (the sign of
      the last non-zero speed changes) it jumps by the length to the other
      edge, so `skin.fsr`'s coverage stays continuous and the contacts after
      a reversal come from the edge that now leads. Before the first motion
      the object leads in the direction of the profile's first non-zero
      speed, and `start_mm` is that edge.

    The position is the closed-form integral of the profile evaluated at each
    sample time: no per-sample accumulation, hence no drift and no dependence
    on chunking (the leading side is the one state carried between chunks).
    """

    kind = "object.scripted"
    domain = PHYSICS
    outputs = OBJECT_OUTPUTS
    summary = "object slides with a scripted (piecewise linear or step) speed profile"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        interpolation = params.string("interpolation", "linear", choices=INTERPOLATIONS)
        self.sign, magnitudes = _direction_sign(params)
        pairs = params.pairs("speed_mm_s")
        if magnitudes:
            for i, (_, speed) in enumerate(pairs):
                if speed < 0:
                    raise params.error(
                        f"speed_mm_s[{i}][1]",
                        f"expected a speed magnitude >= 0 when direction is "
                        f"given (the direction sets the sign), got {speed:g}",
                    )
        self.profile = Profile(params, "speed_mm_s", interpolation, pairs)
        self.start_mm = params.number("start_mm", 0.0)
        self.length_mm = params.number("object_length_mm", None, low=0.0, low_open=True)
        moving = self.sign * self.profile.values[self.profile.values != 0]
        self.forward = not (len(moving) and moving[0] < 0)  # the side the object leads with
        # start_mm is the edge leading at first; leading the other way, the other edge leads:
        # the rear edge is `length_mm` behind the front one
        self.other_edge_mm = -(self.length_mm or 0.0) if self.forward else self.length_mm or 0.0
        self.forward_at_start = self.forward

    def step(self, io: Io) -> None:
        speed = self.sign * self.profile.value(io.times_us)
        travel = self.sign * self.profile.integral(io.times_us)
        if self.length_mm is None:
            put_object(io, self.start_mm + travel, speed)
            return
        forward = leading_forward(speed, self.forward)
        if len(forward):
            self.forward = bool(forward[-1])
        shift = np.where(forward == self.forward_at_start, 0.0, self.other_edge_mm)
        position = self.start_mm + travel + shift
        put_object(io, position, speed)


def leading_forward(speed_mm_s: np.ndarray, last_forward: bool) -> np.ndarray:
    """Per sample: does the object lead forward (its last non-zero speed > 0)?

    The rule `skin.fsr` uses for the edge it reads, so an effect reporting
    the leading edge agrees with the sensor about which edge that is.
    """
    index = np.where(speed_mm_s != 0, np.arange(len(speed_mm_s)), -1)
    last = np.maximum.accumulate(index) if len(index) else index
    return np.where(last >= 0, speed_mm_s[np.maximum(last, 0)] > 0, last_forward)


@register
class CoulombObject(Effect):
    """The object held by the grip against a tangential load, with Coulomb friction.

    Parameters: `mass_kg` (> 0, required), `mu_static` (default 0.7813, the
    skin's µ from SPEC ch. 4.3), `mu_kinetic` (default = mu_static, must not
    exceed it), `contact_surfaces` (default 2: two fingers each press with
    the grip, so the friction capacity is 2·µ·grip), `start_mm` (default 0).

    Friction capacity F_s = surfaces·µ_s·max(grip, 0), kinetic F_k likewise.
    At rest the object stays while |load| <= F_s (the limit itself holds).
    Sliding: m·a = load − sign(v)·F_k; a kinetic step that would reach or
    cross zero speed stops exactly at zero, after which the static test
    applies again — no chattering around zero. Semi-implicit Euler on the
    sample clock: v_k = v_{k−1} + a_k·dt_k, x_k = x_{k−1} + v_k·dt_k, with
    the forces of sample k. The recursion is vectorised in stretches of
    constant sliding direction (a sequential cumulative sum, so chunked and
    one-shot stepping agree bit for bit).
    """

    kind = "object.coulomb"
    domain = PHYSICS
    inputs = (sig.HAND_GRIP_N, sig.LOAD_FORCE_N)
    outputs = OBJECT_OUTPUTS
    summary = "object held by Coulomb friction (static/kinetic) between grip and load"

    WINDOW = 64  # first look-ahead when sliding; doubles while no stop is found

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.mass_kg = params.number("mass_kg", low=0.0, low_open=True)
        self.mu_static = params.number("mu_static", MU_SKIN, low=0.0)
        self.mu_kinetic = params.number("mu_kinetic", self.mu_static, low=0.0)
        if self.mu_kinetic > self.mu_static:
            raise params.error(
                "mu_kinetic",
                f"expected a number <= mu_static ({self.mu_static:g}), got {self.mu_kinetic:g}",
            )
        self.surfaces = params.integer("contact_surfaces", 2, low=1)
        self.position_mm = params.number("start_mm", 0.0)
        self.speed_mm_s = 0.0
        self.last_us: int | None = None

    def step(self, io: Io) -> None:
        times = io.times_us
        n = len(times)
        if n == 0:
            put_object(io, np.zeros(0), np.zeros(0))
            return
        grip = np.maximum(io.get(sig.HAND_GRIP_N), 0.0)
        load = io.get(sig.LOAD_FORCE_N)
        dt_s = sample_steps_s(times, self.last_us)
        static_n = self.surfaces * self.mu_static * grip
        kinetic_n = self.surfaces * self.mu_kinetic * grip
        breaks = np.flatnonzero(np.abs(load) > static_n)  # samples where a resting object moves
        position = np.empty(n)
        speed = np.empty(n)
        x, v, i = self.position_mm, self.speed_mm_s, 0
        while i < n:
            if v == 0.0:
                following = int(np.searchsorted(breaks, i))
                if following == breaks.size:
                    position[i:], speed[i:] = x, 0.0
                    break
                j = int(breaks[following])
                position[i:j], speed[i:j] = x, 0.0
                i = j
                direction = math.copysign(1.0, load[i])
            else:
                direction = math.copysign(1.0, v)
            window = self.WINDOW
            while True:
                end = min(i + window, n)
                # a in m/s² = N / kg; ×1000 for mm/s²
                increments = (
                    (load[i:end] - direction * kinetic_n[i:end])
                    * (1000.0 / self.mass_kg)
                    * dt_s[i:end]
                )
                speeds = np.cumsum(np.concatenate(([v], increments)))[1:]
                stops = np.flatnonzero(direction * speeds <= 0.0)
                count = int(stops[0]) + 1 if stops.size else end - i
                speeds = speeds[:count]
                if stops.size:
                    speeds[-1] = 0.0
                positions = np.cumsum(np.concatenate(([x], speeds * dt_s[i : i + count])))[1:]
                speed[i : i + count], position[i : i + count] = speeds, positions
                v, x = float(speeds[-1]), float(positions[-1])
                i += count
                if stops.size or i >= n:
                    break
                window *= 2
        self.position_mm, self.speed_mm_s, self.last_us = x, v, int(times[-1])
        put_object(io, position, speed)


@register
class PulledObject(Effect):
    """An object pulled out of the grip at a set speed, held once the grip's friction wins.

    The slips of the thesis's experiments (ch. 5.4) were made by pulling an
    object at a set speed; the pull can exert at most `pull_n`. From
    `start_s` on the object slides at `speed_mm_s` (magnitude; `direction`
    gives the sign) whenever the pull exceeds the grip's friction capacity
    `contact_surfaces`·µ·grip, and sticks (speed 0) while the grip holds it;
    a grip that weakens again lets it slip again. So a slip is stopped by
    raising the grip above pull_n / (surfaces·µ) — what the wearer (through
    EMG) or the gateway's reflex has to achieve — and the slip speed is the
    scene's to choose. Parameters: `speed_mm_s` (> 0, required), `pull_n`
    (> 0, required), `start_s` (default 0), `mu` (default 0.7813, SPEC ch.
    4.3), `contact_surfaces` (default 2), `start_mm` (default 0), `direction`.

    Semi-implicit on the sample clock like `object.coulomb`: the sliding test
    uses sample k's grip, x_k = x_{k-1} + v_k·dt_k summed sequentially from the
    carried position, so chunked and one-shot stepping agree bit for bit.
    """

    kind = "object.pulled"
    domain = PHYSICS
    inputs = (sig.HAND_GRIP_N,)
    outputs = OBJECT_OUTPUTS
    summary = "object pulled at a set speed with a bounded force; held once grip friction wins"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        speed = params.number("speed_mm_s", low=0.0, low_open=True, high=10_000.0)
        sign, _ = _direction_sign(params)
        self.velocity_mm_s = sign * speed
        self.pull_n = params.number("pull_n", low=0.0, low_open=True, high=10_000.0)
        self.start_us = round(params.number("start_s", 0.0, low=0.0) * US_PER_S)
        self.mu = params.number("mu", MU_SKIN, low=0.0, low_open=True, high=10.0)
        self.surfaces = params.integer("contact_surfaces", 2, low=1, high=10)
        self.position_mm = params.number("start_mm", 0.0)
        self.last_us: int | None = None

    def step(self, io: Io) -> None:
        times = io.times_us
        if not len(times):
            put_object(io, np.zeros(0), np.zeros(0))
            return
        grip = np.maximum(io.get(sig.HAND_GRIP_N), 0.0)
        sliding = (times >= self.start_us) & (self.pull_n > self.surfaces * self.mu * grip)
        speed = np.where(sliding, self.velocity_mm_s, 0.0)
        position = integrate_mm(self.position_mm, speed, sample_steps_s(times, self.last_us))
        self.position_mm, self.last_us = float(position[-1]), int(times[-1])
        put_object(io, position, speed)


@register
class RidgeDips(Effect):
    """The real slip speed dips each time the leading edge crosses a ridge (ch. 5.4.2, 5.5.1).

    Modifies `object.position_mm` and `object.speed_mm_s` (and rewrites
    `object.slipping`). Parameters: `depth_mm_s` = [low, high] (default
    [4, 15], the thesis' 4–15 mm/s fluctuations): each crossing draws a dip
    depth d uniformly from the interval (from `ctx.rng("object.ridge_dips")`),
    capped at the speed magnitude at the crossing; `recovery_s` (default
    0.05): the dip decays as d·exp(−(t − t_c)/recovery_s) and ends (exactly
    0) after 30 recovery times, where it is below 1e-13 of its depth — a
    finite tail keeps the work per sample bounded and chunk-independent.

    Speed: v = sign(v0)·max(|v0| − D(t), 0) with D the sum of active dips,
    so a dip slows the object but never reverses it.
    Position: p = p0 − offset, where over each sample interval the offset
    grows by the closed-form integral of the dips,
    Σ d·τ·(e^(−a_{k−1}/τ) − e^(−a_k/τ)) with a_k = clip(t_k − t_c, 0, 30τ),
    against the direction of
    the original displacement and never by more than that displacement (so
    the object never moves backwards because of a dip).
    Crossings are detected on the modified position, in either direction:
    ridge r (at x_r = cumsum([0, *layout])[r]) is crossed when the number of
    ridges at or behind the edge changes; each crossing counts once and
    starts its dip at the sample where it is detected (≤ one sample late).
    A jump of the input edge (`object.scripted` with `object_length_mm`
    switching edges at a reversal: a step longer than 4·max|v|·dt + 1e-6 mm,
    the test `skin.ridge_contacts` uses) passes ridges without touching them,
    so it starts no dips.
    Needs the skin layout.
    """

    kind = "object.ridge_dips"
    domain = PHYSICS
    inputs = OBJECT_OUTPUTS  # modifies position, speed and slip state
    outputs = OBJECT_OUTPUTS
    summary = "real speed dips and recovers at each ridge crossing (4-15 mm/s)"

    TAIL = 30.0  # a dip ends after this many recovery times (exp(-30) ≈ 9e-14)
    WINDOW = 64  # first look-ahead for the next crossing; doubles while none is found

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        layout = ctx.require_layout(params, self.kind)
        self.ridges_mm = np.cumsum([0.0, *layout])
        depth = params.numbers("depth_mm_s", [4.0, 15.0], low=0.0, min_len=2)
        if len(depth) != 2 or depth[0] > depth[1]:
            raise params.error(
                "depth_mm_s", f"expected [low, high] with low <= high, got {list(depth)}"
            )
        self.depth_low, self.depth_high = depth
        self.recovery_s = params.number("recovery_s", 0.05, low=0.0, low_open=True)
        self.tail_us = self.TAIL * self.recovery_s * US_PER_S
        self.rng = ctx.rng(self.kind)
        self.dip_start_us: list[int] = []
        self.dip_depth: list[float] = []
        self.offset_mm = 0.0
        self.last_us: int | None = None
        self.last_p0_mm = 0.0
        self.last_v0_mm_s = 0.0
        self.behind = 0  # ridges at or behind the (modified) leading edge

    def _dips(self, times_us: np.ndarray, previous_us: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(total dip at each t_k in mm/s, its integral over (t_{k-1}, t_k] in mm)."""
        total = np.zeros(len(times_us))
        area = np.zeros(len(times_us))
        tau_us = self.recovery_s * US_PER_S
        for start_us, depth in zip(self.dip_start_us, self.dip_depth, strict=True):
            age_us = times_us - start_us
            upper = np.exp(-np.clip(age_us, 0, self.tail_us) / tau_us)
            lower = np.exp(-np.clip(previous_us - start_us, 0, self.tail_us) / tau_us)
            total += np.where((age_us >= 0) & (age_us <= self.tail_us), depth * upper, 0.0)
            area += (depth * self.recovery_s) * (lower - upper)
        return total, area

    def _forget(self, now_us: int) -> None:
        """Drop dips that have ended by `now_us` (they add exactly 0.0 from then on)."""
        keep = [j for j, s in enumerate(self.dip_start_us) if now_us - s <= self.tail_us]
        if len(keep) < len(self.dip_start_us):
            self.dip_start_us = [self.dip_start_us[j] for j in keep]
            self.dip_depth = [self.dip_depth[j] for j in keep]

    def _crosses_nothing(self, p0: np.ndarray) -> bool:
        """Whether the edge, `p0` less the offset (no dip adds to it), stays within the
        ridges around it: finite positions, and the count at or behind it the same."""
        low, high = float(p0.min()), float(p0.max())
        if not (math.isfinite(low) and math.isfinite(high)):
            return False
        edges = self.ridges_mm
        behind = self.behind
        return (behind == 0 or edges[behind - 1] <= low - self.offset_mm) and (
            behind == len(edges) or high - self.offset_mm < edges[behind]
        )

    def step(self, io: Io) -> None:
        times = io.times_us
        n = len(times)
        p0 = io.get(POSITION)
        v0 = io.get(SPEED)
        if n == 0:
            put_object(io, p0, v0)
            return
        if self.last_us is None:
            self.last_us, self.last_p0_mm = int(times[0]), float(p0[0])
            self.last_v0_mm_s = float(v0[0])
            self.behind = int(np.searchsorted(self.ridges_mm, p0[0], side="right"))
        self._forget(self.last_us)
        if not self.dip_start_us and self._crosses_nothing(p0):
            # No dip in force and no ridge in reach (an object at rest or between ridges,
            # its dips decayed): what the loop below would give, without its windows.
            position = p0 - self.offset_mm
            speed = np.sign(v0) * np.maximum(np.abs(v0) - np.zeros(n), 0.0)
            self.last_us, self.last_p0_mm = int(times[-1]), float(p0[-1])
            self.last_v0_mm_s = float(v0[-1])
            put_object(io, position, speed)
            return
        previous_us = np.concatenate(([self.last_us], times[:-1]))
        moved = np.diff(p0, prepend=self.last_p0_mm)
        moved_abs, moved_sign = np.abs(moved), np.sign(moved)
        fastest = np.maximum(np.abs(v0), np.abs(np.concatenate(([self.last_v0_mm_s], v0[:-1]))))
        jumps = (
            moved_abs > JUMP_SLACK * fastest * (times - previous_us) / US_PER_S + JUMP_TOLERANCE_MM
        )
        position = np.empty(n)
        dip = np.empty(n)
        i, window = 0, self.WINDOW
        while i < n:  # look ahead in growing windows until the next crossing
            end = min(i + window, n)
            self._forget(int(previous_us[i]))
            total, area = self._dips(times[i:end], previous_us[i:end])
            lost = moved_sign[i:end] * np.minimum(area, moved_abs[i:end])
            offsets = np.cumsum(np.concatenate(([self.offset_mm], lost)))[1:]
            modified = p0[i:end] - offsets
            behind = np.searchsorted(self.ridges_mm, modified, side="right")
            changes = np.flatnonzero(behind != self.behind)
            count = int(changes[0]) + 1 if changes.size else end - i
            position[i : i + count] = modified[:count]
            dip[i : i + count] = total[:count]
            self.offset_mm = float(offsets[count - 1])
            i += count
            if not changes.size:
                window *= 2
                continue
            k, now = i - 1, int(behind[count - 1])
            crossed = (
                range(self.behind, now)
                if now > self.behind
                else range(self.behind - 1, now - 1, -1)
            )
            if jumps[k]:  # the reported edge jumped to the other edge: no ridge was touched
                crossed = range(0)
            for _ in crossed:  # a new dip starts at full depth at the detecting sample
                depth = float(self.rng.uniform(self.depth_low, self.depth_high))
                depth = min(depth, abs(float(v0[k])))
                self.dip_start_us.append(int(times[k]))
                self.dip_depth.append(depth)
                dip[k] += depth
            self.behind = now
            window = self.WINDOW
        speed = np.sign(v0) * np.maximum(np.abs(v0) - dip, 0.0)
        self.last_us, self.last_p0_mm = int(times[-1]), float(p0[-1])
        self.last_v0_mm_s = float(v0[-1])
        self._forget(self.last_us)
        put_object(io, position, speed)


@register
class SlipTask(Effect):
    """The thesis' slip-stopping task (ch. 2.3.3): the wearer's contraction level slows the object.

    Parameters: `initial_speed_mm_s` (default 6.0, must be one of the level
    speeds), `level_speeds_mm_s` (V = [v1, v2, v3, v4], default
    [1.8, 3.2, 4.6, 6.0], strictly increasing, > 0), `update_period_s`
    (default 1.0: one phase), `direction` ("forward" default / "reverse"),
    `start_mm` (default 0).

    Derivation. The thesis states f(e_j) = v_j for j = 1..4, f(e0) = 0,
    f(e5) = ∞ and v_{t+1} = v_t − f(e_t) if f(e_t) <= v_t, else 0 (crushed),
    with v_{t+1}: V → V ∪ {0}. Read literally (f(e3) = v3 = 4.6) the worked
    example v_t = v4 = 6.0 at e3 would give 1.4 mm/s, which is not in V; the
    thesis instead computes "v4 − v3 = 6.0 − 3·1.4 = 1.8 mm/s = v1": level
    e_j removes j steps of 1.4 mm/s, using v_j = v_i − 1.4·(i − j). In speed
    indices this is the only reading that keeps v_{t+1} in V ∪ {0} and
    matches the example and the procedure text (level equal to the speed's
    level stops the object, higher crushes it, lower slows it):

        at speed v_i with level e_j:  j = 0 → v_i (unchanged);
                                      0 < j < i → v_{i−j};
                                      j = i → 0, stopped (success);
                                      j > i (including e5 = ∞) → 0, crushed.

    So 6.0 (v4) at e3 → v1 = 1.8 mm/s; at e1 → v3 = 4.6; at e4 → stopped.
    With non-uniform `level_speeds_mm_s` the same index rule applies.

    Timing: the speed updates at t = k·update_period_s (k = 1, 2, ...),
    using `wearer.level` at the first sample at or after that instant
    (rounded to the nearest integer, clamped to 0..5). Once the object is
    stopped or crushed the session is over: later levels are ignored (the
    thesis ends the session there). The position integrates the piecewise
    constant speed in closed form between updates.
    """

    kind = "object.slip_task"
    domain = PHYSICS
    inputs = (sig.WEARER_LEVEL,)
    outputs = (*OBJECT_OUTPUTS, sig.HAND_CRUSHED)
    summary = "thesis ch. 2.3.3 slip-stopping task: contraction levels slow/stop/crush the object"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        speeds = params.numbers(
            "level_speeds_mm_s", [1.8, 3.2, 4.6, 6.0], low=0.0, low_open=True, min_len=4
        )
        if len(speeds) != 4 or any(b <= a for a, b in itertools.pairwise(speeds)):
            raise params.error(
                "level_speeds_mm_s",
                f"expected 4 strictly increasing speeds (levels e1..e4), got {list(speeds)}",
            )
        self.level_speeds = speeds
        initial = params.number("initial_speed_mm_s", 6.0)
        matches = [i for i, v in enumerate(speeds) if math.isclose(v, initial, abs_tol=1e-9)]
        if not matches:
            raise params.error(
                "initial_speed_mm_s",
                f"expected one of the level speeds {list(speeds)}, got {initial:g}",
            )
        self.speed_index = matches[0] + 1  # 1..4, 0 once over
        period_s = params.number("update_period_s", 1.0, low=0.0, low_open=True)
        self.period_us = round(period_s * US_PER_S)
        if self.period_us < 1:
            raise params.error("update_period_s", f"expected at least 1 µs, got {period_s:g}")
        self.sign, _ = _direction_sign(params)
        self.anchor_mm = params.number("start_mm", 0.0)  # position at anchor_us
        self.anchor_us = 0
        self.phase = 0  # updates applied so far
        self.crushed = False

    def _speed(self) -> float:
        return self.sign * self.level_speeds[self.speed_index - 1] if self.speed_index else 0.0

    def _update(self, level: int) -> None:
        i = self.speed_index
        if i == 0 or level == 0:
            return
        if level < i:
            self.speed_index = i - level
        else:
            self.speed_index = 0
            self.crushed = level > i

    def step(self, io: Io) -> None:
        times = io.times_us
        n = len(times)
        phases = times // self.period_us
        levels = np.clip(np.rint(io.get(sig.WEARER_LEVEL)), 0, 5).astype(np.int64)
        position = np.empty(n)
        speed = np.empty(n)
        crushed = np.empty(n)
        start = 0
        # the clock only increases, so a new phase begins where the phase index steps up
        for k in np.flatnonzero(phases > np.concatenate(([self.phase], phases[:-1]))):
            self._fill(times, position, speed, crushed, start, int(k))
            for phase in range(self.phase + 1, int(phases[k]) + 1):
                boundary_us = phase * self.period_us
                self.anchor_mm += self._speed() * (boundary_us - self.anchor_us) / US_PER_S
                self.anchor_us = boundary_us
                self._update(int(levels[k]))
            self.phase = max(self.phase, int(phases[k]))
            start = int(k)
        self._fill(times, position, speed, crushed, start, n)
        put_object(io, position, speed)
        io.put(sig.HAND_CRUSHED, crushed)

    def _fill(self, times, position, speed, crushed, start: int, stop: int) -> None:
        v = self._speed()
        position[start:stop] = self.anchor_mm + v * (times[start:stop] - self.anchor_us) / US_PER_S
        speed[start:stop] = v
        crushed[start:stop] = float(self.crushed)

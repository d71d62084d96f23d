"""Actuators and scripted forces (physics domain): the hand's grip, the load, the belt motor.

- `hand.actuator`: the hand follows its commanded grip with a first-order lag;
- `grip.scripted` / `load.scripted`: force profiles for scenes without a hand;
- `belt.motor`: the haptic belt's single DC motor (thesis ch. 8): positive
  speed drives the force belt (taps), negative speed the slip belt (brushing).

First-order lags use the exact discretisation of dy/dt = (u − y)/τ for an
input held over each sample interval: y_k = α·y_{k−1} + (1 − α)·u_k with
α = exp(−dt_k/τ), dt_k the (integer microsecond) sample interval.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
from scipy.signal import lfilter

from grasplink.core.params import Params
from grasplink.simulators import signals as sig
from grasplink.simulators.core import (
    PHYSICS,
    SHORT_CHUNK_SAMPLES,
    Context,
    Effect,
    Io,
    register,
)
from grasplink.simulators.effects.kinematics import INTERPOLATIONS, US_PER_S, Profile

G_M_S2 = 9.81


class FirstOrderLag:
    """y_k = α_k·y_{k−1} + (1 − α_k)·u_k, α_k = exp(−dt_k/τ), state carried across chunks.

    Runs of equal sample intervals are filtered in one `lfilter` call each, a
    short chunk sample by sample in floats (lfilter's call costs more than a
    few samples); every sample is computed by the same two products and one
    sum either way, so chunked and one-shot outputs agree bit for bit.
    """

    def __init__(self, time_constant_s: float, initial: float = 0.0):
        self.time_constant_s = time_constant_s
        self.value = initial
        self.last_us: int | None = None
        self._alphas: dict[int, float] = {}  # sample interval (µs) -> α

    def _alpha(self, dt_us: int) -> float:
        alpha = self._alphas.get(dt_us)
        if alpha is None:
            alpha = self._alphas[dt_us] = math.exp(-(dt_us / US_PER_S) / self.time_constant_s)
        return alpha

    def step(self, times_us: np.ndarray, target: np.ndarray) -> np.ndarray:
        n = len(times_us)
        if n <= SHORT_CHUNK_SAMPLES:
            return self._step_floats(times_us.tolist(), target.tolist())
        out = np.empty(n)
        previous = times_us[0] if self.last_us is None else self.last_us
        dt_us = np.diff(times_us, prepend=previous)
        edges = [0, *(np.flatnonzero(np.diff(dt_us)) + 1).tolist(), n]
        y = self.value
        for a, b in itertools.pairwise(edges):
            alpha = math.exp(-(dt_us[a] / US_PER_S) / self.time_constant_s)
            out[a:b], _ = lfilter([1.0 - alpha], [1.0, -alpha], target[a:b], zi=[alpha * y])
            y = float(out[b - 1])
        self.value, self.last_us = y, int(times_us[-1])
        return out

    def _step_floats(self, times_us: list[int], target: list[float]) -> np.ndarray:
        if not times_us:
            return np.empty(0)
        previous = times_us[0] if self.last_us is None else self.last_us
        y = self.value
        out = []
        for t_us, u in zip(times_us, target, strict=True):
            alpha = self._alpha(t_us - previous)
            y = alpha * y + (1.0 - alpha) * u  # lfilter's y = z + b0·x with z = α·y
            out.append(y)
            previous = t_us
        self.value, self.last_us = y, previous
        return np.array(out)


class CrushLatch:
    """1.0 from the first sample whose grip exceeds the limit on (None: never)."""

    def __init__(self, limit_n: float | None):
        self.limit_n = limit_n
        self.crushed = False

    def step(self, grip_n: np.ndarray) -> np.ndarray:
        if self.limit_n is None or self.crushed:
            return np.full(len(grip_n), float(self.crushed))
        over = grip_n > self.limit_n  # NaN: not over
        latched = np.zeros(len(grip_n))
        if over.any():
            latched[int(over.argmax()) :] = 1.0
            self.crushed = True
        return latched


@register
class HandActuator(Effect):
    """The hand closes towards its commanded grip with a first-order lag.

    Parameters: `time_constant_s` (default 0.1), `max_force_n` (default 100:
    the commanded grip is clamped to [0, max_force_n]), `initial_n` (grip at
    the first sample, default 0), `crush_limit_n` (the object's crush limit;
    default none = uncrushable). `hand.crushed` latches to 1.0 at the first
    sample whose grip exceeds the limit; the grip itself keeps following the
    command (the crushed object no longer resists).
    """

    kind = "hand.actuator"
    domain = PHYSICS
    inputs = (sig.HAND_TARGET_N,)
    outputs = (sig.HAND_GRIP_N, sig.HAND_CRUSHED)
    summary = "hand grip follows its command with a first-order lag; latches a crush"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        tau = params.number("time_constant_s", 0.1, low=0.0, low_open=True)
        self.max_force_n = params.number("max_force_n", 100.0, low=0.0, low_open=True)
        initial = params.number("initial_n", 0.0, low=0.0, high=self.max_force_n)
        self.initial_n = initial  # the hand node starts out holding this grip
        self.lag = FirstOrderLag(tau, initial)
        self.latch = CrushLatch(params.number("crush_limit_n", None, low=0.0, low_open=True))

    def step(self, io: Io) -> None:
        target = np.clip(io.get(sig.HAND_TARGET_N), 0.0, self.max_force_n)
        grip = self.lag.step(io.times_us, target)
        io.put(sig.HAND_GRIP_N, grip)
        io.put(sig.HAND_CRUSHED, self.latch.step(grip))


@register
class ScriptedGrip(Effect):
    """The grip force follows a profile: `grip_n` = [[t_s, N], ...] (N >= 0).

    `interpolation`: "linear" (default) or "step"; the first value is held
    before the first point, the last after the last.
    """

    kind = "grip.scripted"
    domain = PHYSICS
    outputs = (sig.HAND_GRIP_N,)
    summary = "grip force from a scripted [t_s, N] profile"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        interpolation = params.string("interpolation", "linear", choices=INTERPOLATIONS)
        pairs = params.pairs("grip_n", low=0.0, what="grip [N]")
        self.profile = Profile(params, "grip_n", interpolation, pairs)

    def step(self, io: Io) -> None:
        io.put(sig.HAND_GRIP_N, self.profile.value(io.times_us))


@register
class ScriptedLoad(Effect):
    """The tangential load on the object: a profile or an object's weight.

    Give exactly one of `force_n` = [[t_s, N], ...] (signed: + pulls towards
    the last ridge; `interpolation` "linear" default or "step") or
    `mass_kg` (> 0): a constant load of mass_kg·9.81 N.
    """

    kind = "load.scripted"
    domain = PHYSICS
    outputs = (sig.LOAD_FORCE_N,)
    summary = "tangential load from a [t_s, N] profile or a constant weight mass_kg*g"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        interpolation = params.string("interpolation", "linear", choices=INTERPOLATIONS)
        has_force, has_mass = params.has("force_n"), params.has("mass_kg")
        if has_force == has_mass:
            raise params.error(
                "force_n",
                "give exactly one of force_n (a [t_s, N] profile) or mass_kg (a constant weight)",
            )
        self.profile: Profile | None = None
        self.weight_n = 0.0
        if has_force:
            self.profile = Profile(params, "force_n", interpolation)
        else:
            self.weight_n = params.number("mass_kg", low=0.0, low_open=True) * G_M_S2

    def step(self, io: Io) -> None:
        if self.profile is None:
            io.put(sig.LOAD_FORCE_N, np.full(len(io), self.weight_n))
        else:
            io.put(sig.LOAD_FORCE_N, self.profile.value(io.times_us))


@register
class BeltMotor(Effect):
    """The haptic belt's DC motor (thesis ch. 8): one motor, the direction picks the belt.

    `belt.command_mrad_s` is the signed speed demand; the motor follows it
    with a first-order lag (`time_constant_s`, default 0.05), so a change of
    direction passes through zero as the ratchet requires.
    - w > 0 drives the force belt: `belt.tap_hz` = nubs·w/(2π) (`nubs`,
      default 6 square nubs on the force belt), else 0;
    - w < 0 drives the slip belt: `belt.surface_mm_s` = |w|·r
      (`effective_radius_mm`, default 27: 2.0/3.7/5.3/7.0 rad/s ↔
      ≈55/100/145/190 mm/s), else 0.
    """

    kind = "belt.motor"
    domain = PHYSICS
    inputs = (sig.BELT_COMMAND_MRAD_S,)
    outputs = (sig.BELT_VELOCITY_MRAD_S, sig.BELT_TAP_HZ, sig.BELT_SURFACE_MM_S)
    summary = "belt DC motor: first-order speed; + taps the force belt, - runs the slip belt"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        tau = params.number("time_constant_s", 0.05, low=0.0, low_open=True)
        self.nubs = params.integer("nubs", 6, low=1)
        self.radius_mm = params.number("effective_radius_mm", 27.0, low=0.0, low_open=True)
        self.lag = FirstOrderLag(tau)

    def step(self, io: Io) -> None:
        velocity = self.lag.step(io.times_us, io.get(sig.BELT_COMMAND_MRAD_S))
        rad_s = velocity / 1000.0
        io.put(sig.BELT_VELOCITY_MRAD_S, velocity)
        io.put(sig.BELT_TAP_HZ, np.where(rad_s > 0, self.nubs * rad_s / (2 * math.pi), 0.0))
        io.put(sig.BELT_SURFACE_MM_S, np.where(rad_s < 0, -rad_s * self.radius_mm, 0.0))

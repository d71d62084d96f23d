"""An object pulled out of the grip against a damper: its slip speed says how far the grip
falls short (physics domain).

`object.pulled` slides at the scene's speed whatever the grip, so any grip that holds
stops it and the slip speed tells the wearer nothing about what to do. The thesis's
task (ch. 2.3.3) was built the other way round: each contraction level slowed the
object by a set amount, so the level had to match the speed, a lower one failed and a
higher one crushed. `object.damped` is the physical version of that rule: a load pulls
the object through a viscous contact (a damped pull, or a wet glove), so while it slides

    speed = (load − surfaces·µ_k·grip) / damping

and the speed is a measure of the missing grip, (damping·speed) / (surfaces·µ_k). A
wearer who reads the speed can answer with the grip that stops it and no more; one who
only knows *that* it slips has to guess or step up.
"""

from __future__ import annotations

import numpy as np

from grasplink.core.params import Params
from grasplink.simulators import signals as sig
from grasplink.simulators.core import PHYSICS, Context, Effect, Io, register
from grasplink.simulators.effects.kinematics import (
    MU_SKIN,
    OBJECT_OUTPUTS,
    Profile,
    integrate_mm,
    put_object,
    sample_steps_s,
)


@register
class DampedObject(Effect):
    """An object pulled by a load through a damper, held by the grip's Coulomb friction.

    Parameters: `damping_n_s_per_mm` (> 0, required), `mu_static` (default 0.7813,
    SPEC ch. 4.3), `mu_kinetic` (default = mu_static, not above it), `friction_scale`
    ([[t_s, factor], ...], piecewise linear, default 1: friction that changes, a wet or
    oily object), `contact_surfaces` (default 2), `max_speed_mm_s` (default 300: what the
    pull can reach), `start_mm`. The load is `load.force_n` (`load.scripted`: a weight
    or a pull profile); its sign is the slip's direction.

    At rest the object stays while |load| ≤ surfaces·µ_s·grip (the limit itself holds).
    Once moving it slides at min(max, (|load| − surfaces·µ_k·grip) / damping) and stops at
    the first sample where that is ≤ 0: with µ_k < µ_s a slip needs more grip to stop
    than to prevent. Overdamped (no mass): the speed follows the grip sample by sample,
    which is what a pull through a damper does at these speeds. The position sums
    v_k·dt_k from the carried position, so chunked and one-shot stepping agree bit for
    bit.
    """

    kind = "object.damped"
    domain = PHYSICS
    inputs = (sig.HAND_GRIP_N, sig.LOAD_FORCE_N)
    outputs = OBJECT_OUTPUTS
    summary = "object pulled through a damper: slip speed grows with the grip it lacks"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.damping = params.number("damping_n_s_per_mm", low=0.0, low_open=True, high=1_000.0)
        self.mu_static = params.number("mu_static", MU_SKIN, low=0.0, low_open=True, high=10.0)
        self.mu_kinetic = params.number(
            "mu_kinetic", self.mu_static, low=0.0, low_open=True, high=10.0
        )
        if self.mu_kinetic > self.mu_static:
            raise params.error(
                "mu_kinetic",
                f"expected a number <= mu_static ({self.mu_static:g}), got {self.mu_kinetic:g}",
            )
        self.friction_scale = (
            Profile(params, "friction_scale", "linear", params.pairs("friction_scale", low=0.0))
            if params.has("friction_scale")
            else None
        )
        self.surfaces = params.integer("contact_surfaces", 2, low=1, high=10)
        self.max_speed_mm_s = params.number(
            "max_speed_mm_s", 300.0, low=0.0, low_open=True, high=10_000.0
        )
        self.position_mm = params.number("start_mm", 0.0)
        self.sliding = False
        self.last_us: int | None = None

    def step(self, io: Io) -> None:
        times = io.times_us
        n = len(times)
        if n == 0:
            put_object(io, np.zeros(0), np.zeros(0))
            return
        grip_n = np.maximum(np.nan_to_num(io.get(sig.HAND_GRIP_N), nan=0.0), 0.0)  # NaN: none
        scale = 1.0 if self.friction_scale is None else self.friction_scale.value(times)
        capacity_n = self.surfaces * grip_n * scale
        load_n = np.nan_to_num(io.get(sig.LOAD_FORCE_N), nan=0.0)
        pull_n = np.abs(load_n)
        breaks = pull_n > self.mu_static * capacity_n
        shortfall_n = pull_n - self.mu_kinetic * capacity_n
        sliding = self._sliding(breaks, shortfall_n > 0.0)
        speed_mm_s = np.where(
            sliding, np.minimum(shortfall_n / self.damping, self.max_speed_mm_s), 0.0
        )
        speed_mm_s *= np.sign(load_n)
        dt_s = sample_steps_s(times, self.last_us)
        position = integrate_mm(self.position_mm, speed_mm_s, dt_s)
        self.position_mm, self.last_us = float(position[-1]), int(times[-1])
        put_object(io, position, speed_mm_s)

    def _sliding(self, breaks: np.ndarray, keeps: np.ndarray) -> np.ndarray:
        """Static/kinetic hysteresis: a resting object starts where the static limit
        breaks; a sliding one goes on while the kinetic friction is short of the load."""
        n = len(breaks)
        sliding = np.zeros(n, dtype=bool)
        starts = np.flatnonzero(breaks)
        stops = np.flatnonzero(~keeps)
        i, moving = 0, self.sliding
        while i < n:
            if moving:
                following = int(np.searchsorted(stops, i))
                end = int(stops[following]) if following < stops.size else n
                sliding[i:end] = True
                i, moving = end, end >= n
            else:
                following = int(np.searchsorted(starts, i))
                if following == starts.size:
                    break
                i, moving = int(starts[following]), True
        self.sliding = bool(sliding[-1])  # step() never asks about an empty chunk
        return sliding

"""The wearer (physics domain): a scripted contraction level for scenes without a human model."""

from __future__ import annotations

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

"""The least-force task (thesis ch. 2.3.3, made physical): the slip speed says how much grip.

In `grasplink bench loop`'s headline physics any grip above 5.76 N stops the slip, so what
the belt says about the slip changes how hard the wearer squeezes, not whether the slip
stops, and slip-speed and slip-occurrence feedback tie. The thesis's task was built so
the contraction had to match the speed: a lower level only slowed the object, a higher one
crushed it. Here the object (`object.damped`) is pulled out through a damper, so while it
slides its speed is the grip it lacks; it is fragile, so one level too many breaks it; and
the wearer is told to hold with the least force (`slip_response_adds`: a slip at display
level k asks for k levels more than the wearer held when the display came up).

One contraction level is GRIP_STEP_N more grip, which the damper turns into LEVEL_SPAN_MM_S
of slip speed; the gateway's slip table starts a display level every LEVEL_SPAN_MM_S. A
trial's slip speed (at the resting grip, e1) thus fixes the object: its load, the level
that stops it and the grip that breaks it (`TaskObject`). Slip occurrence runs the slip
belt at its first level: to a wearer trained on the task it means "one level more".
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass

from grasplink.simulators.effects.kinematics import MU_SKIN

GRIP_LEVELS_N = (0.0, 5.0, 8.0, 11.0, 14.0, 20.0)  # e0..e5 (loop_headline.toml)
REST_LEVEL = 1
GRIP_STEP_N = 3.0  # e1..e4 are 3 N apart
SURFACES = 2
LEVEL_SPAN_MM_S = 8.0  # one slip display level = one contraction level missing
DAMPING_N_S_PER_MM = SURFACES * MU_SKIN * GRIP_STEP_N / LEVEL_SPAN_MM_S  # 0.586
SLIP_TABLE = [[k * LEVEL_SPAN_MM_S, v] for k, v in enumerate((2000, 3700, 5300, 7000))]
SLIP_HYSTERESIS_MM_S = 2.0  # below the table's 8 mm/s gaps (the default 8 is not)
OCCURRENCE_MRAD_S = 2000  # the first slip level: "one level more"
# The thesis's phase (ch. 2: "a four-second phase time" per attempt): a wearer holding with
# the least force waits that long for a slip to stop before adding a level. At 4 mm/s over
# the 12 mm spacing a stop cannot show for 3 s: the next contact is due then.
REPEAT_S = 4.0
FRAGILITY_MARGIN_N = 2.0  # the object breaks this far above the grip of the level that stops it
#: Slips in the middle of each display level: one, two, three and four levels of grip missing.
SPEEDS_MM_S = (4.0, 12.0, 20.0, 28.0)
#: Friction that changes: the object gets wet one phase after a wearer adding a level per
#: phase would hold it, and its friction falls (over WETTING_S) until the held grip lets it
#: slide again at RESLIP_MM_S, the middle of the first display level: one level short again.
RESLIP_MM_S = 4.0
WETTING_S = 0.5
#: After the wetting: two of the wearer's phases to answer the new slip.
AFTER_WETTING_S = 2 * REPEAT_S
#: 28 mm/s already needs e5, the strongest level: wet, nothing would hold it.
WET_SPEEDS_MM_S = (4.0, 12.0, 20.0)
#: The loop trials' names of the task, dry and wet (`loop.Trial.task`).
DRY_TASK, WET_TASK = "least_force", "least_force_wet"


@dataclass(frozen=True)
class TaskObject:
    """The object a slip speed at the resting grip implies; `wet`: its friction falls
    mid-task (`friction_after`), and it breaks above the level that holds it then."""

    speed_mm_s: float
    wet: bool = False

    @property
    def load_n(self) -> float:
        rest_n = SURFACES * MU_SKIN * GRIP_LEVELS_N[REST_LEVEL]
        return rest_n + DAMPING_N_S_PER_MM * self.speed_mm_s

    @property
    def holding_grip_n(self) -> float:
        """The grip whose kinetic friction equals the load: the least that stops it (dry)."""
        return self.load_n / (SURFACES * MU_SKIN)

    @property
    def stopping_level(self) -> int:
        """The lowest contraction level whose grip stops it dry (e5 if none below does)."""
        return _level_holding(self.holding_grip_n)

    @property
    def friction_after(self) -> float:
        """The friction factor once wet: the dry stopping level's grip slides at RESLIP_MM_S."""
        if not self.wet:
            return 1.0
        held_n = GRIP_LEVELS_N[self.stopping_level]
        return (self.load_n - DAMPING_N_S_PER_MM * RESLIP_MM_S) / (SURFACES * MU_SKIN * held_n)

    @property
    def final_level(self) -> int:
        """The level that holds it at the end: the dry one, or the one that holds it wet."""
        return _level_holding(self.holding_grip_n / self.friction_after)

    @property
    def crush_limit_n(self) -> float:
        return GRIP_LEVELS_N[self.final_level] + FRAGILITY_MARGIN_N

    @property
    def levels_missing(self) -> int:
        """Levels short at the resting grip, dry: what the first slip's speed says."""
        return self.stopping_level - REST_LEVEL

    def wetting_s(self, start_s: float) -> float:
        """When the friction starts to fall: one phase after a wearer adding one level per
        phase from `start_s` would hold the dry object."""
        return start_s + REPEAT_S * (self.levels_missing + 1)


def _level_holding(grip_n: float) -> int:
    for level, level_n in enumerate(GRIP_LEVELS_N):
        if level_n >= grip_n - 1e-9:
            return level
    return len(GRIP_LEVELS_N) - 1


def adapt(
    data: dict, speed_mm_s: float, start_s: float, start_mm: float, *, wet: bool = False
) -> dict:
    """A headline loop scene (`loop.scene_data`) turned into the task at `speed_mm_s`: the
    damped object, its load and fragility (and, `wet`, its falling friction), the task's
    slip table and the trained wearer."""
    if not (math.isfinite(speed_mm_s) and speed_mm_s > 0):
        raise ValueError(f"the task's slip speed must be > 0 mm/s, got {speed_mm_s!r}")
    task = TaskObject(speed_mm_s, wet)
    if wet and task.final_level == task.stopping_level:
        raise ValueError(
            f"a wet object at {speed_mm_s:g} mm/s needs more than e{task.stopping_level}, the "
            f"strongest level: the wet task's speeds are {WET_SPEEDS_MM_S}"
        )
    out = copy.deepcopy(data)
    out["scene"]["name"] = out["scene"]["name"].replace("loop-", "least-force-", 1)
    out["scene"]["description"] = "grasplink bench loop trial: the least-force task"
    out["controller"]["feedback"] |= {
        "slip_table": SLIP_TABLE,
        "slip_hysteresis_mm_s": SLIP_HYSTERESIS_MM_S,
        "occurrence_velocity_mrad_s": OCCURRENCE_MRAD_S,
    }
    effects = []
    for effect in out["effects"]:
        kind = effect["type"]
        if kind == "hand.actuator":
            effect = effect | {"crush_limit_n": task.crush_limit_n}
        elif kind == "load.scripted":
            effect = {
                "type": "load.scripted",
                "force_n": [[0.0, 0.0], [start_s, task.load_n]],
                "interpolation": "step",
            }
        elif kind == "object.pulled":
            effect = {
                "type": "object.damped",
                "damping_n_s_per_mm": DAMPING_N_S_PER_MM,
                "start_mm": start_mm,
            }
            if wet:
                at_s = task.wetting_s(start_s)
                effect["friction_scale"] = [
                    [0.0, 1.0],
                    [at_s, 1.0],
                    [at_s + WETTING_S, task.friction_after],
                ]
        elif kind == "wearer.virtual":
            effect = effect | {
                "max_level": 5,
                "slip_response_adds": True,
                "slip_repeat_s": REPEAT_S,
            }
        effects.append(effect)
    out["effects"] = effects
    return out

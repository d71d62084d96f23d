"""The slip flag held over a step shaped like a ridge's until its next ridge is due (issue 22).

Physics: a slip that stops makes the level step (static friction takes the load: thesis
ch. 4.3), and a stop's step is fast and monotone; a ridge pulse whose fall the FSR's
hysteresis holds up, a reversal's turn through rest (the 25 mm object wholly on the
skin), a grip rising under a sliding object all rise slowly (`step_shape.classify`:
89 % of the stops' plain steps fast, 94 % of the ridges' slow). The posterior still takes
such a step for the stop whenever "stopped there" explains the contacts as well as the
slip going on - until the next ridge's contact tells them apart, the stop is likelier
only by its prior (`benchmarks/dropped_causes.py --kinds reversal,loop,saturation
--seeds 3`: 38 % of the updates the flag drops while the object slides are a track
stopped at a step shaped like a ridge's, nearly all after the flag had been up).

The rule: once the flag was up past the step, while the chosen hypothesis is a track
stopped at a step told RIDGE_LIKE, the flag is held - no speed, no direction: the speed
before the step may be gone - until the next ridge due after the step at the speed before
it would have been decided (`kernels.posterior.stop_seen`: its time plus the detector's
latency, times `wait`; the ridge after when the step lies on the next one), and no
longer than `max_s` after the step: the chosen track's speed may be an alias's far below
the slip's (the loop kind's 30 mm/s slip on alpha0.3, seed 161200: a track at 8 mm/s
stopped at the last ridge's step, its next ridge 48 mm on, 6 s away). Its silence then
tells the stop; a held object's flag never went up. A step shaped like a stop's (or
not yet shaped) is told at once, as before: the stops figure is what a ridge-shaped stop
step costs.

Two limits (s31) keep that cost off the stops. The wait runs to the next ridge only, never
the one after (`stop_seen` skips to it when the step lies within 3 sigma of the next: the
step may be that ridge's contact; a stop just short of the next ridge then waited a whole
spacing more: stop 95100 cleared 0.61 s late). And a contact told after the step ends the
hold once it is `STEP_HOLD_AFTER_S` old with the stop still chosen (`unlinked`): had the
object slid on or turned, a moving track would have taken it up by then (loop 161210: a
ridge-shaped step at 3.40 s while sliding, then the stop's own step at 3.60 s, untold;
without the limit the flag stayed up to the stop's end, 2.6 s). Not the other way round
(hold only while contacts keep coming after the step): 93 % of what the hold buys on the
reversals are updates with no contact after the step at all - the 25 mm object sliding
across a long spacing - so that costs the gain (reversal dropped 15.6 -> 22.4 %).
Only contacts not told RIDGE_LIKE count (s32, `STEP_HOLD_AFTER_UNRIDGED`): a held pulse
after the step is the slip's own (reversal 102110: the 25 mm object's trailing edge leaving
a ridge), while the stop's own step in 161210 is untold.
"""

from __future__ import annotations

import math

import numpy as np

from grasplink.decoding.detector import step_shape
from grasplink.decoding.kernels import posterior as posterior_kernels


def hold_constants(K: np.ndarray, wait: float) -> np.ndarray:
    """The posterior kernels' constants `K` with the step's wait set to `wait` (x the time
    to the next ridge plus the latency: `kernels.posterior.stop_seen`)."""
    if not wait > 0:
        raise ValueError(f"step hold: wait must be > 0, got {wait!r}")
    out = K.copy()
    out[posterior_kernels.STEP_STOP_WAIT] = wait
    return out


def holds(
    shape: int, up_s: float, step_s: float, now_s: float, seen_s: float, max_s: float
) -> bool:
    """Whether the flag is held at `now_s` over a stop at a step at `step_s` of shape
    `shape` (`step_shape`): the flag last up at `up_s` (at or after the step), the step
    shaped like a ridge's, its next ridge (`seen_s`, `stop_seen`) not yet decided and the
    step no more than `max_s` ago."""
    if not (math.isfinite(step_s) and up_s >= step_s):
        return False  # not a step's stop, or the flag was not up past it
    return shape == step_shape.RIDGE_LIKE and now_s < min(seen_s, step_s + max_s)


def unlinked(after_s: list[float], now_s: float, within_s: float) -> bool:
    """Whether a contact told after the step (`after_s`: their onsets) is more than
    `within_s` old at `now_s` while the stop is still the chosen hypothesis: had the object
    slid on (or turned), the next ridge's contact would have joined a moving track by then;
    left to the stop, it was no ridge of the slip's."""
    return bool(after_s) and now_s - min(after_s) > within_s

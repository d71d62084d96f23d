"""The slip flag held while the skin's level ramps (issue 22, "slip dropped").

Physics: the one FSR under the skin reads the load through the skin the object covers
(`arrival`), so while an edge slides onto the skin (or off it) the covered length - and
with it the static level - changes at a rate set by the speed: the loop scenes' 90 mm
object sliding onto an 84 mm skin raises the level about 0.47 N/s at 10 mm/s and 1.4 N/s
at 30 mm/s, the stop kind's object 0.6 N/s at 12 mm/s. At rest the level is flat but for
drift (the stop kind's: up to 0.14 N/s). The contacts alone leave long stretches with
nothing to go by - ridges absorbed by the FSR's hysteresis after the arrival, a 48 mm
spacing crossed at 30 mm/s (1.6 s without a contact) - and there the posterior's flag
drops to "no slip" or to one-contact tracks, though the level still climbs
(`benchmarks/dropped_causes.py --kinds loop,reversal --seeds 3`: the loop kind's flag
down 37.6 % of its sliding updates, 68 % of them with no hypothesis chosen, nearly all
after the flag had been up).

The rule: once the flag was up (the posterior, its keep, the rail, the arrival: a held
object's never was), it is held - no speed, no direction: a ramp tells neither, the
covered length grows whichever end the object enters - while the level ramps one way:
the medians of the last `steps` + 1 windows of `window_s` each step the same way by at
least `slope_n_s` x `window_s` and `z` standard deviations of a step of medians under the
white noise (so heavy noise asks a steeper ramp). Medians, so that a ridge's pulse on a
flat level makes no ramp (on a shallow ramp it can still break one: the hold then waits
for the windows to pass it). A commanded grip change under way (the efference copy) moves the
level with no slip: no ramp counts then. The window's lag (about one window past a stop)
is what it costs the stop figures.

With the flag up at the previous update the test asks only half the least step (the
tracker's `RAMP_KEEP_SHARE`, a hysteresis): near that step the medians passed and failed
from one update to the next, and a slow slip's flag flickered every few updates.

Tried, off by default (the tracker's `RAMP_ONE_WAY`): one way only. While the object
slides one way the covered length changes one way, so a ramp is held only the way the
last one held went (`ramp_way`; forgotten once the
posterior flags with a speed: a track, the object may have turned). In a stick the
coverage stops changing and what moves the level is the stick's own transient - the
step as it sticks, then the last ridge pulse's fall: stick-slip 14 mm/s on alpha0.1,
reversed, seed 80121, ramped up 0.7 N/s sliding, stepped 1.1 N up at the stick (3.115
s) and fell 2 N/s through it, and the hold raised the flag again 0.04 s before the
object moved on, the stop never cleared (`benchmarks/stop_causes.py --kinds stick-slip
--seeds 3`, with and without `--try RAMP_HOLD=0`: that stop the only one it made late).
One way clears it, but a ramp's way turns while sliding too (a pulse's fall, the object's
restart): `benchmarks/tune_tracker_kinds.py --full --seeds 3 --try RAMP_ONE_WAY=2`, stops
95.7 -> 96.0 %, slip dropped 10.7 -> 10.9 % (loop 26.3 -> 27.3, accelerating 4.9 -> 5.6).
"""

from __future__ import annotations

import math

import numpy as np

from grasplink.decoding.kernels.common import medians_way

#: the median of m samples of white noise sigma s spreads about sqrt(pi / 2) s / sqrt(m)
_MEDIAN_SPREAD = math.sqrt(math.pi / 2)


def step_min_n(window_s: float, fs_hz: float, slope_n_s: float, z: float, white_n: float) -> float:
    """The least step (N) between two windows' medians that counts as a ramp: `slope_n_s`
    over a window, and `z` sigmas of the difference of two medians of a window's samples
    under white noise `white_n` (N per sample)."""
    if not (window_s > 0 and fs_hz > 0):
        raise ValueError(f"level_ramp: window {window_s!r} s and rate {fs_hz!r} Hz must be > 0")
    if slope_n_s < 0 or z < 0 or not white_n >= 0:
        raise ValueError(
            f"level_ramp: slope {slope_n_s!r} N/s, z {z!r} and white noise {white_n!r} N "
            "must be >= 0"
        )
    m = max(1, round(window_s * fs_hz))
    spread = math.sqrt(2.0) * _MEDIAN_SPREAD * white_n / math.sqrt(m)
    return max(slope_n_s * window_s, z * spread)


def ramp_way(x: np.ndarray | None, steps: int, step_n: float) -> int:
    """The way the samples `x` (the last `steps` + 1 windows, oldest first, a whole number
    of samples each) show the level ramping: +1 up, -1 down when every step between
    consecutive windows' medians is at least `step_n` that way, else 0 (and 0 for None:
    the samples not held). With `RAMP_ONE_WAY` the tracker holds only a ramp the way its
    last held one went (the module doc)."""
    if steps < 1:
        raise ValueError(f"level_ramp: steps must be >= 1, got {steps!r}")
    if x is None or len(x) < steps + 1 or len(x) % (steps + 1):
        return 0
    # compiled: numpy's sort, medians and diff cost ~13 us an update, the kernel ~3.5
    return int(medians_way(np.ascontiguousarray(x, dtype=np.float64), steps + 1, float(step_n)))

"""Heavy noise told by the white noise itself, not by the told pulses' height alone.

The tracker's heavy-noise rules (the measured detection chance under a missed or due
ridge, `detect_chance`) open while the told ridge pulses stand under a few white-noise
units at their median (`rise_evidence.RiseEvidence.blind`). That test is relative: a
slip whose pulses are weak - the stick-slip kind's, the loop's FSR hysteresis - opens
it too, at thesis-like noise (0.02 N), where a due ridge's silence is real evidence of a
stop. Session 28 measured the silence floor so gated: snr10 speed missing 51.7 -> 49.4 %,
but stops cleared over the moving kinds 96.0 -> 95.3 % (stick-slip 95.7 -> 94.3, loop
100 -> 98.0).

What tells 10 dB SNR apart is the noise: a ridge pulse of the thesis skin
(`PULSE_PRIOR_N`, 0.8 N; the simulator's pulses are 0.3-1 N by layout) over white noise
of 0.1-0.3 N there, against 0.02 N elsewhere. So a rule meant for heavy noise may also
ask that the white noise the detector measures (`NoiseFloor.white_at_sample`, N per
sample) reach a level set between the two.
"""

from __future__ import annotations

import math


def heavy(white_n: float | None, least_n: float) -> bool:
    """Is the white noise `white_n` (N per sample; None: not measured yet) at least
    `least_n`? `least_n` 0 or less: always (the gate is off). ValueError for a level that
    is not a number."""
    if math.isnan(least_n):
        raise ValueError("noise gate: the least white noise is not a number")
    if least_n <= 0.0:
        return True
    return white_n is not None and white_n >= least_n

"""Heavy noise told by the white noise itself, not by the told pulses' height alone.

The tracker's heavy-noise tests read the told ridge pulses' height in white-noise units
(`rise_evidence.RiseEvidence.blind`). That test is relative: a slip whose pulses are
weak - the stick-slip kind's, the loop's FSR hysteresis - passes it at thesis-like noise
(0.02 N), where a due ridge's silence is real evidence of a stop; and early in a 10 dB
slip, before any pulse is told, it does not pass at all.

What tells 10 dB SNR apart is the noise: a ridge pulse of the thesis skin
(`PULSE_PRIOR_N`, 0.8 N; the simulator's pulses are 0.3-1 N by layout) over white noise
of 0.1-0.3 N there, against 0.02 N elsewhere. So a rule meant for heavy noise (the
report's overdue rules rest there: `TrackerDecoder.OVERDUE_NOISY_WHITE`) may ask that the
white noise the detector measures (`NoiseFloor.white_at_sample`, N per sample) reach a
level set between the two. (Session 28/29's measured detection chance used it too:
measured, off, removed in session 30; docs/decoding.md has its figures.)
"""

from __future__ import annotations

import math


def heavy(white_n: float | None, least_n: float) -> bool:
    """Is the white noise `white_n` (N per sample; None: not measured yet) at least
    `least_n`? `least_n` 0 or less: never (the gate is off: no noise counts as heavy).
    ValueError for a level that is not a number."""
    if math.isnan(least_n):
        raise ValueError("noise gate: the least white noise is not a number")
    if least_n <= 0.0:
        return False
    return white_n is not None and white_n >= least_n

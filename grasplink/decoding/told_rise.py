"""A told contact's own rise, read at the speed of each track taking it for its ridge.

Physics (thesis ch. 5.3.1, `ridge_pulses`): the leading edge reaching a ridge starts a
pulse that rises to its height within `RISE_MM` of the edge's travel - at the track's
speed, within a rise time the track predicts. The kink bank (`detector.hinges`) also
tells kinks that are no pulse: as an object slides onto the skin the level follows the
coverage ramp (the object's share over the sensor grows with its travel), and after each
ridge pulse the FSR's play holds the level flat while the pulse's tail falls against the
ramp, until the ramp takes over. That bend is a slope jump of about the ramp's own slope
(issue 22's headline loop: 1.496 s, 1.58 N/s against 1.68 N/s, found on the 80 ms scale),
and splitting the interval of two true ridges, it read as a third ridge on alpha0.1
(19 : 12 for 0.615 : 0.385) at 65 mm/s where the object slid at 33-40.

The pulse probe's rise statistic z (`rise_evidence.RiseEvidence.z_each`: mean after less
mean before on a window, the same 2 windows either side taken out - a ramp is no rise -,
in white-noise units) read at the contact's onset on the window of the track's rise time
tells them apart: a ridge pulse there stands as high as a told pulse (tens of units in a
clean signal), a bend onto a ramp reads about 0 (the headline's 1.496 s: -1.1 on 16
samples, -2.1 on 8). A track taking a contact for its ridge whose z there lies under
`Z_MAX` loses `LOG_LOSS` nats against the same contact read as clutter.

Only samples before the contact's decision are read (as `rise_evidence` does: a replay
weighs it alike), so a contact told at once (a sharp ridge pulse: decided 1-8 samples
after its onset) is never read - the window is not yet held - and only contacts the bank
decided late (a slow, coarse-scale rise: the suspects) are. Windows touching the upper
rail read flat and are not read either.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from grasplink.decoding.detector.events import ContactEvent
from grasplink.decoding.kernels.layout import F_SCORE, F_STOP, F_V, I_LAST, I_RUN
from grasplink.decoding.rise_evidence import OFFSET, RiseEvidence

Z_MAX = 2.0  # under this many white-noise units no pulse rose at the onset
LOG_LOSS = -4.0  # what a ridge child of such a contact loses (nats)


def rise_z(
    floats: np.ndarray,
    ints: np.ndarray,
    ev: ContactEvent,
    evidence: RiseEvidence,
    blind_s: Iterable[tuple[float, float]] = (),
    tail_z: float | None = None,
    tail_fall_z: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rows of ev's children that take it for a ridge with a speed (the run's second
    contact or later, not stopped), the probe window of each speed's rise time and the z
    each reads there at ev's onset. z is NaN where the window is not held before ev's
    decision, or touches a rail interval of `blind_s` (times, s), or - with `tail_z` - on
    a level falling more than `tail_z` units before the onset (and, with `tail_fall_z`,
    falling on through the window: z under -`tail_fall_z`)."""
    rows = np.flatnonzero(
        (ints[:, I_LAST] == ev.id) & (ints[:, I_RUN] >= 2) & np.isnan(floats[:, F_STOP])
    )
    if not len(rows):
        return rows, np.zeros(0, np.int64), np.zeros(0)
    width = evidence.width_for(np.abs(floats[rows, F_V]))
    onsets = np.full(len(rows), float(ev.index))
    if tail_z is None:
        z = evidence.z_each(onsets, width, ev.emit_index)
    else:  # on a falling tail: a ridge pulse held under the fall, unread
        z, trend = evidence.z_and_trend_each(onsets, width, ev.emit_index)
        tail = trend < -tail_z
        if tail_fall_z is not None:  # ... and the level fell on through the rise's window
            tail &= z < -tail_fall_z
        z[tail] = np.nan
    fs = evidence.fs_hz
    for r0, r1 in blind_s:  # a flat rail is no evidence
        centre_s = ev.t_s + OFFSET * width / fs
        touch = (centre_s - 3.0 * width / fs < r1) & (centre_s + 3.0 * width / fs > r0)
        z[touch] = np.nan
    return rows, width, z


def ridge_loss(
    floats: np.ndarray,
    ints: np.ndarray,
    ev: ContactEvent,
    evidence: RiseEvidence,
    blind_s: Iterable[tuple[float, float]] = (),
    z_max: float = Z_MAX,
    log_loss: float = LOG_LOSS,
    read: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    tail_z: float | None = None,
    tail_fall_z: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """`rise_z`'s rows and z (or `read`, when already taken); adds `log_loss` to the score
    of those whose z is finite and under `z_max`."""
    if not (np.isfinite(z_max) and np.isfinite(log_loss) and log_loss <= 0.0):
        raise ValueError(f"told rise: z_max {z_max!r} must be finite, log_loss {log_loss!r} <= 0")
    if read is None:
        read = rise_z(floats, ints, ev, evidence, blind_s, tail_z, tail_fall_z)
    rows, _, z = read
    if not len(rows):
        return rows, np.zeros(0)
    low = np.isfinite(z) & (z < z_max)
    floats[rows[low], F_SCORE] += log_loss
    return rows, z

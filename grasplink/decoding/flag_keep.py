"""Keeping the slip flag up while the contacts still say the object moves (issue 22).

The flag (`kernels.posterior.posterior`) is up when slipping tracks that are *evidently*
a slip hold half the posterior mass: two contacts, one told a pulse (or
`TrackerDecoder.EVIDENT_CONTACTS` with no step and no noise pulse). That rule starts a
slip safely - a held object's noise contacts never make one - but it also drops a slip
already told whenever the mass moves onto tracks that have no such evidence *yet*: a
reversal's first contact (the other edge leads: new tracks of one contact), a slip whose
last contacts are not yet told (or told unclear under the FSR's hysteresis). Slip
*occurrence* is not slip *speed*: while contacts keep coming where moving tracks put
them, the object moves, whichever track's speed is right.

So once the flag is up it is kept while the moving tracks hold half the mass under a
wider evidence rule (`widened`): by `level`,

1. a track whose one contact was told a pulse (a reversal's or restart's first ridge);
2. also a track of two or more contacts none of which was told a step or a noise pulse
   (their verdicts not yet told, or unclear);
3. also a track of one contact not (yet) told a step or a noise pulse.

A restart held by its contact's verdict (`RESTART_CONFIRM`: a contact at rest restarting a
stopped track) stays no slip at every level (`unheld`: while the flag is up, only a
verdict of step or noise pulse holds it - `TrackerDecoder.KEEP_FLAG_UNHOLD`), and tracks
stopped (silence, a step, braked) count against the flag as before: the stop figures are
what a looser flag costs. The flag is only *kept*, never raised, by this rule: a held
object's flag never went up (false slip on held objects stays the evident rule's). A
kept flag carries no speed (the speed stays the evident tracks'; `TrackerDecoder._report`).
"""

from __future__ import annotations

import numpy as np

# the levels (`TrackerDecoder.KEEP_FLAG`); 0: off
OFF, PULSE_ONE, UNTOLD_MANY, UNTOLD_ONE = 0, 1, 2, 3


def unheld(hold: np.ndarray, verdicts: tuple[int, ...]) -> np.ndarray:
    """The restart hold (`TrackerDecoder._evidence_tables`: per verdict, does a restart
    on a contact with it wait) lifted for `verdicts`: while the flag is up the slip was
    never reported stopped, so a restart on a contact not yet told (or unclear) is the slip
    going on, not a contact at rest; a step or a noise pulse still holds it."""
    out = hold.copy()
    out[..., list(verdicts)] = False
    return out


def widened(
    evident: np.ndarray, pulses: np.ndarray, steps: np.ndarray, noise: np.ndarray, level: int
) -> np.ndarray:
    """The evidence table (rows: min(n, 4) contacts, then the same held by a restart's
    verdict; columns: the packed verdict counts) widened to `level` (module doc).

    `evident` is `TrackerDecoder._evidence_tables`' table; `pulses`, `steps`, `noise` the
    counts each column packs. Rows 5-9 (a held restart) are left as they are."""
    if level not in (OFF, PULSE_ONE, UNTOLD_MANY, UNTOLD_ONE):
        raise ValueError(f"KEEP_FLAG must be 0, 1, 2 or 3, got {level!r}")
    out = evident.copy()
    if level == OFF:
        return out
    clean = (steps + noise) == 0
    out[1] |= pulses > 0
    if level >= UNTOLD_MANY:
        out[2:5] |= clean[None, :]
    if level >= UNTOLD_ONE:
        out[1] |= clean
    return out

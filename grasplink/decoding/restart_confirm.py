"""Which pulse verdicts hold a restart as no slip yet: on its first contact, and on its
first two (the table `kernels.posterior._evidence` reads).

Why (issue 22, *speed after a stop's report was due*): a stopped object makes no ridge
contacts, but its level still kinks now and then (noise, the grip settling). One such
kink restarts a stopped track with its speed unknown, and `RESTART_CONFIRM` holds that
restart until its contact is told a pulse. A second kink a little later then gives the
restarted track a speed from the two (stop 96200: the object at rest from 0.84 s, kinks
at 1.603 and 1.847 s, z 5.0 and 5.4, neither ever told a pulse, restart the track at 16.4
mm/s - 4 mm in 0.244 s - where it slid at 79 before the stop, and the report flags that
speed at 1.87 and 1.88 s). The pulse evidence that makes the track a slip is then the
contacts' before the stop. So a restart's first speed, from its restart contact and the
one after, is held too while neither of the two is told a pulse (`second`): a slip
that really restarted tells one of them a pulse within a verdict's wait, or makes a third
contact. Only while the flag is down: while it is up the keep lifts the hold of untold
contacts (`flag_keep.unheld`), so a slip's own restarts are not held up by it.

But a slip going on after a stick resumes about the speed it stopped at, and two kinks at
rest give any speed (96200: 16.4 mm/s where it slid at 79). So a restart's first speed
within `TrackerDecoder.RESTART_AGREE_REL` of the speed the track had before it stopped
(the bank's `before` column, kept by `kernels.branch._restart`) is not held
(`kernels.posterior.agrees`, in the kernel that reads this table): the slip's own restarts
report at once, the disagreeing ones wait for the pulse verdict or the third contact.
"""

from __future__ import annotations

import numpy as np


def hold_table(
    verdicts: int, step: int, noise: int, unclear: int, unknown: int, confirm: float, second: bool
) -> np.ndarray:
    """(2, `verdicts`): per verdict, does it hold a restart on its first contact (row 0,
    `confirm` as `TrackerDecoder.RESTART_CONFIRM`: 1 a step or a noise pulse, 2 unclear
    too, 3 not yet told too), and (row 1, only if `second`) on its first two, both held."""
    hold = np.zeros((2, verdicts), np.bool_)
    hold[0, step] = hold[0, noise] = confirm >= 1
    hold[0, unclear] = confirm >= 2
    hold[0, unknown] = confirm >= 3
    if second:
        hold[1] = hold[0]
    return hold

"""The slip flag raised again by a ridge pulse soon after it dropped (issue 22, "slip dropped").

Physics: a contact told a pulse (`PulseCheck`: the force rose and fell back like a ridge
pulse, above `TrackerDecoder.WEAK_PULSE_SNR`) is an edge crossing a ridge - the object
moves at that moment. The posterior flags a slip only once a track has two contacts, one
told a pulse, so after a slip it had flagged was read as stopped (a step, silence) or
turned (a reversal's rear edge leads back: new tracks of one contact), the flag stays
down until the next ridge, however the contacts in between read
(`benchmarks/dropped_causes.py`, full plan, 2 seeds: the reversal kind's flag down 30 % of
its sliding updates, a step no ridge made - the 25 mm object wholly on the skin, its
level stops rising - taken for the stop 35 % of them, one-contact and not-evident tracks
after the turn most of the rest).

The rule: a contact told a pulse that came after the flag was last up, and no more than
`within_s` after it (the object was sliding then; a held object's flag never went up, so
no pulse of its noise raises it), flags the slip again - no speed, no direction: one
contact tells neither - for as long as the slip's next ridge may still be unseen,
P(no ridge contact told yet | a slip from that contact, the tracker's speed prior and
detection model, averaged over every ridge either way) at least `hold_p`, as the arrival
flag (`arrival_flag`) holds for a first contact.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Protocol


class _Contact(Protocol):
    @property
    def id(self) -> int: ...
    @property
    def t_s(self) -> float: ...


class Reflag:
    """Which pulse contact the flag is raised again for, and whether its wait has ended.

    `candidate` picks the contact; `expire` ends its flag (its next ridge overdue): the
    waiting probability only falls as the silence lasts."""

    __slots__ = ("_done", "_id")

    def __init__(self) -> None:
        self._id = -1
        self._done = False

    def candidate(
        self,
        contacts: Sequence[_Contact],
        verdict: Callable[[int], bool],
        up_t: float,
        within_s: float,
    ) -> tuple[int, float] | None:
        """The latest contact (id, time) of `contacts` (time order) after the flag was last
        up at `up_t` and within `within_s` of it, if `verdict(id)` tells it a pulse and its
        flag has not expired; None otherwise."""
        if within_s < 0:
            raise ValueError(f"reflag: within_s must be >= 0 s, got {within_s!r}")
        for c in reversed(contacts):
            cid, t_s = c.id, c.t_s
            if t_s <= up_t:
                return None
            if t_s - up_t > within_s or not verdict(cid):
                continue
            if cid != self._id:
                self._id, self._done = cid, False
            return None if self._done else (cid, t_s)
        return None

    def expire(self) -> None:
        """The current contact's silence has ended its flag."""
        self._done = True

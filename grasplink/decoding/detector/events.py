"""What the contact detector tells, and the contacts told so far that more than one of its
parts reads."""

from __future__ import annotations

from collections import deque
from typing import NamedTuple


class ContactEvent(NamedTuple):
    """A detected ridge contact (pulse onset)."""

    id: int
    t_s: float  # onset time, sub-sample
    index: int  # type: ignore[assignment]  # (shadows tuple.index) the sample nearest the onset
    emit_index: int  # global index of the sample that decided it
    z: float  # strength: slope jump in noise units
    jump_n_s: float  # slope jump, N/s
    scale_s: float  # the scale that found it
    sigma_s: float  # timing uncertainty (one sigma)


class PulseCheck(NamedTuple):
    """Later verdict on a contact: did the force fall back like a pulse?"""

    id: int
    emit_index: int
    pulse: bool | None  # True: rose and fell back; False: rose and stayed (a step); None: unclear
    # a step: the level's rising trend (the object covering more of the sensor) went on
    # after it (True: the object still moves), stopped (False), or no trend to tell (None)
    trend_on: bool | None = None
    # a pulse the kink bank found: its height above its base in white-noise units (noise
    # that crosses the threshold falls back like a pulse too, but stands a few units high)
    height_snr: float | None = None
    # a step told at the sure hold (`WatchSettings.sure_hold_s`): sharp, tall and flat
    # (`watch.sharp_flat_step`), which ridge pulses seldom are
    sure: bool = False
    # a step told with an earlier pulse's course out (`detector.pulse_under`): the level on
    # its own rises and falls back with that pulse, the step itself is flat - a stop's shape
    under: bool = False


class Ledger:
    """The contacts told so far, as the parts that find them share them: the kink bank and
    the pulse probe number theirs in one series and both record their onsets (a step
    probe's candidate or a pulse watch reads them: another contact near it, or after it);
    the heights of those told pulses open or shut the pulse probe."""

    __slots__ = ("heights", "next_id", "onsets")

    def __init__(self) -> None:
        self.next_id = 0
        self.onsets: deque[tuple[int, int]] = deque(maxlen=32)  # contacts emitted: (index, emit)
        # heights of the contacts told pulses (N above their base): (emit, height)
        self.heights: deque[tuple[int, float]] = deque(maxlen=32)

    def take_id(self) -> int:
        """The next contact id of the series."""
        cid = self.next_id
        self.next_id += 1
        return cid

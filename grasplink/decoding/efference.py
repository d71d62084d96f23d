"""The efference copy: the grip the loop commanded, as the decoder is told it (issue 22).

In the closed loop the gateway commands the hand's grip (the reflex, the wearer's EMG).
A commanded change moves the skin's level while the hand follows it, and the contact
detector reads that bend in the level as a ridge contact: in the headline loop the
reflex's grip rise made a contact 14 noise units high at 1.826 s, and a braking track
through it reported 24 -> 8 mm/s for 17 updates while the object had been at rest since
1.768 s. The gateway knows when it changed the grip; `Decoder.note_grip_command` tells
the decoder, and this module says how likely a contact is the grip's.

How fast the grip follows a command (`HandFollow`): the hand node slews its setpoint at
its grip rate (0x2404, the hand EDS's default 50 N/s, written by the gateway from
`[controller.nodes.hand] grip_rate_n_s`), and the actuator follows the setpoint with a
first-order lag (the `hand.actuator` effect's `time_constant_s`, default 0.1 s: a test
ties `HAND_LAG_S` to it). A change of dF commanded at t moves the grip from t until
t + |dF| / rate + `SETTLE_LAGS` lags (95 % settled): its *window*. Commands whose windows
overlap are one change (a slew-limited ramp is a command every 10 ms).

The odds (`GripCommands.contact_rate_per_s`): a grip *rise* bends the level up where the
grip starts to move - one onset of a rise per change, whatever its size or ramp, within
one lag of its first command (plus the detector's timing); a *fall* turns the level
down and makes none (`benchmarks/grip_ramp_contacts.py`: a held object, the hand's slew
and lag, the loop scenes' skin chain: `KINKS_PER_RISE`, `ONSET_TIMING_S`). So a rise
makes contacts at KINKS_PER_RISE / (lag + ONSET_TIMING_S) per second over that onset.
A long run of rising commands (10-28 N, the wearer's contraction) now and then bends the
level again just past its onset, up to a lag plus `LATE_ONSET_S` after its first command
(`KINKS_LATE_IN_RISE` per run; `benchmarks/grip_long_rise_contacts.py`); none later in the
rise, however long the grip still moves. A rise cannot make a bend
steeper than the level's share of the grip (the level over the grip held before the
change: at rest the sensor reads the grip times the object's share over it) times the
rate the grip moves at; a contact's slope jump beyond that is charged as a Gaussian in
log ratio (`FIT_LOG_SIGMA`). Ridge pulses bend the level far more steeply than a grip
ramp does, so real ridge contacts during a grip change keep most of their weight.

Only commands at or before a contact's onset count: a contact is decided after its
onset (the detector's delay), by which time every command before it has been noted -
live and offline alike, whichever way the input is chunked.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from functools import cache

import numpy as np

from grasplink.errors import ConfigError

#: the hand actuator's first-order lag (simulators' `hand.actuator` time_constant_s default)
HAND_LAG_S = 0.1
#: lags after the hand's slew before the grip has settled (3: 95 %)
SETTLE_LAGS = 3.0
#: contacts the detector tells per commanded grip rise, where the grip starts to move
#: (`benchmarks/grip_ramp_contacts.py --seeds 8 [--ramp 6.33]`: a held object over all or
#: half of alpha0.1, hand slew 50 N/s and lag 0.1 s, gateway ramps of 50 and 6.33 N/s,
#: rises of 0.5-6.5 N: 150 contacts in 160 rises, 0.4-1.4 by size; falls of 0.5-3.8 N:
#: none in 128)
KINKS_PER_RISE = 0.94
#: those contacts' onsets come within a lag of the rise's first command plus this (the
#: detector times a slow bend late: 149 of the 150 onsets 0-0.127 s after it, the lag
#: being 0.1 s; the other at 0.98 s, as often as clutter)
ONSET_TIMING_S = 0.05
#: contacts a run of rising commands makes just past its onset window (up to a lag plus
#: LATE_ONSET_S after its first command), spread over that span; none later in the rise
#: (`benchmarks/grip_long_rise_contacts.py --seeds 16 --layouts alpha0.1`, a held object
#: over all or half of the skin; every layout tells the same contacts: `--seeds 4`): the
#: wearer's 2.5 N / 50 ms and the gateway's 0.5 N / 10 ms steps up to 10-28 N, slower
#: stairs, the crush trial's two runs - 1076 contacts in onset windows, 49 past them: 46
#: at 0.15-0.22 s after their run's first command, 3 at 0.29-0.30 s, none later; 47 of
#: them in the 384 runs of 10 N or more (0.12 each), 2 in the 192 stair steps of 2.5 N.
#: The crush trial's bends (loop benchmark, 20 mm/s seed 8) came 0.201 and 0.157 s into
#: their runs. Until s25 a rising change's whole window was charged 2 contacts (unmeasured).
KINKS_LATE_IN_RISE = 0.12
#: the late contacts come within a lag plus this of their run's first command (46 of 49)
LATE_ONSET_S = 0.13
#: a contact's slope jump beyond what the grip can make: charged as a Gaussian in log ratio
#: of this sigma - the jump is measured to about 1/z (under 25 % at the detector's z >= 4),
#: the level's share of the grip read within about a third: a factor of ~1.4 together
FIT_LOG_SIGMA = math.log(2.0) / 2
#: the level a contact rose from: the mean of the samples this long before its onset
LEVEL_BEFORE_S = 0.02
#: commands older than this before the newest are forgotten (a contact is decided within
#: a fraction of a second; replays go back a few contacts)
KEEP_S = 30.0


@cache
def hand_limits() -> tuple[tuple[float, float], tuple[float, float], float]:
    """((lowest, highest) grip target N (0x2400), (lowest, highest) grip rate N/s (0x2404),
    the default grip rate N/s), read once from the shipped hand EDS."""
    from grasplink.profiles import load_profile, object_limits, od_default
    from grasplink.profiles.objects import HAND_GRIP_RATE_MN_S, HAND_TARGET_GRIP_MN

    low, high = object_limits("hand", HAND_TARGET_GRIP_MN)
    rate_low, rate_high = object_limits("hand", HAND_GRIP_RATE_MN_S)
    default = od_default(load_profile("hand", 0x40), HAND_GRIP_RATE_MN_S)
    return (low / 1000, high / 1000), (rate_low / 1000, rate_high / 1000), default / 1000


@dataclass(frozen=True)
class HandFollow:
    """How the hand's grip follows a command: its slew rate (N/s) and actuator lag (s)."""

    rate_n_s: float
    lag_s: float = HAND_LAG_S

    @classmethod
    def default(cls) -> HandFollow:
        return cls(hand_limits()[2])

    def __post_init__(self) -> None:
        low, high = hand_limits()[1]
        if not (math.isfinite(self.rate_n_s) and low <= self.rate_n_s <= high):
            raise ConfigError(
                f"hand grip rate {self.rate_n_s!r} N/s is outside {low:g}-{high:g} N/s, "
                "what the hand node's 0x2404 holds"
            )
        if not (math.isfinite(self.lag_s) and 0.0 <= self.lag_s <= 10.0):
            raise ConfigError(f"hand actuator lag {self.lag_s!r} s must be 0-10 s")

    def window_s(self, change_n: float) -> float:
        """How long the grip moves after a command changing it by change_n."""
        return abs(change_n) / self.rate_n_s + SETTLE_LAGS * self.lag_s


@dataclass
class CommandStats:
    """Grip commands noted and those the guard kept out, and why."""

    accepted: int = 0
    rejected_nonfinite: int = 0  # NaN or Inf time or force
    rejected_range: int = 0  # force outside the hand's target range, or time out of range
    rejected_time: int = 0  # before the previous accepted command

    @property
    def rejected(self) -> int:
        return self.rejected_nonfinite + self.rejected_range + self.rejected_time

    def report(self) -> str | None:
        """One line on what was kept out; None if nothing."""
        if not self.rejected:
            return None
        low, high = hand_limits()[0]
        reasons = [
            (self.rejected_nonfinite, "NaN/Inf"),
            (self.rejected_range, f"out of range (force outside {low:g}-{high:g} N, 0x2400)"),
            (self.rejected_time, "earlier than the previous command"),
        ]
        why = ", ".join(f"{n} {text}" for n, text in reasons if n)
        return f"grip commands: {self.accepted + self.rejected} noted, rejected {why}"


@dataclass(frozen=True)
class Change:
    """A commanded grip change under way: when it started, how long the grip moves, by how
    much (N), from which grip (N), and the rate it moves at (N/s)."""

    start_s: float
    window_s: float
    change_n: float
    from_n: float
    rate_n_s: float


class GripCommands:
    """The grip commands noted so far (time order) and the odds they give a contact."""

    def __init__(self, follow: HandFollow | None = None):
        self.follow = follow or HandFollow.default()
        self.stats = CommandStats()
        self._t: list[float] = []
        self._f: list[float] = []

    def __len__(self) -> int:
        return len(self._t)

    def note(self, t_s: object, force_n: object, max_time_s: float) -> bool:
        """Keep a command if usable (counted in `stats` either way); whether it was kept.
        A value that is no number at all is a ValueError naming it."""
        t, f = _number(t_s, "time"), _number(force_n, "force")
        low, high = hand_limits()[0]
        if not (math.isfinite(t) and math.isfinite(f)):
            self.stats.rejected_nonfinite += 1
            return False
        if not (low <= f <= high and abs(t) <= max_time_s):
            self.stats.rejected_range += 1
            return False
        if self._t and t < self._t[-1]:
            self.stats.rejected_time += 1
            return False
        self.stats.accepted += 1
        if self._f and f == self._f[-1]:
            return True  # the same grip again (a refresh): nothing changes
        self._t.append(t)
        self._f.append(f)
        if t - self._t[0] > 2 * KEEP_S:
            cut = bisect.bisect_left(self._t, t - KEEP_S) - 1  # keep the grip held before
            if cut > 0:
                del self._t[:cut], self._f[:cut]
        return True

    def change_at(self, t_s: float) -> Change | None:
        """The commanded change whose window holds t_s, from the commands at or before it
        (None: the grip is still). The first command only tells the grip held."""
        k = bisect.bisect_right(self._t, t_s) - 1
        if k < 1:
            return None
        follow = self.follow
        end = -math.inf
        start = k + 1
        for j in range(k, 0, -1):  # back through the commands whose windows run into t_s
            until = self._t[j] + follow.window_s(self._f[j] - self._f[j - 1])
            if until < t_s and (start > k or until < self._t[start]):
                break  # neither under way at t_s nor overlapping the change after it
            start = j
            end = max(end, until)
        if start > k:
            return None
        change = self._f[k] - self._f[start - 1]
        span = self._t[k] - self._t[start]
        rate = follow.rate_n_s if span <= 0 else min(follow.rate_n_s, abs(change) / span)
        return Change(self._t[start], end - self._t[start], change, self._f[start - 1], rate)

    def grip_at(self, t_s: np.ndarray) -> np.ndarray:
        """The grip (N) the commands hold the hand at, at times t_s: the command in force a
        lag before (the actuator follows a command about a lag late; the slew is ignored:
        a gateway's ramp is a command every 10 ms). NaN before the first command."""
        times = np.asarray(self._t)
        k = np.searchsorted(times, np.asarray(t_s) - self.follow.lag_s, side="right") - 1
        grip = np.asarray(self._f)[np.maximum(k, 0)]
        return np.where(k >= 0, grip, np.nan)

    def rise_at(self, t_s: float, within_s: float | None = None) -> Change | None:
        """The commanded rise whose onset holds t_s (None: none): a run of commands each
        raising the grip within a lag of the one before, started no more than
        `onset_s` (or `within_s`) before t_s; its window is that span, its change the run's
        rise."""
        k = bisect.bisect_right(self._t, t_s) - 1
        if k < 1:
            return None
        follow = self.follow
        onset = self.onset_s if within_s is None else within_s
        first = max(1, bisect.bisect_left(self._t, t_s - onset))
        for j in range(k, first - 1, -1):  # the newest rise's start first
            if not (self._f[j] > self._f[j - 1] and self._starts_rise(j)):
                continue
            end = j
            while end < k and self._rising(end + 1):
                end += 1
            change = self._f[end] - self._f[j - 1]
            span = self._t[end] - self._t[j]
            rate = follow.rate_n_s if span <= 0 else min(follow.rate_n_s, change / span)
            return Change(self._t[j], onset, change, self._f[j - 1], rate)
        return None

    @property
    def onset_s(self) -> float:
        """How long after a rise's first command its contacts come."""
        return self.follow.lag_s + ONSET_TIMING_S

    @property
    def late_s(self) -> float:
        """How long after a run's first command its late bends still come."""
        return self.follow.lag_s + LATE_ONSET_S

    def _rising(self, j: int) -> bool:
        """Command j raises the grip on from a rise under way (within a lag of the last)."""
        return self._f[j] > self._f[j - 1] and self._t[j] - self._t[j - 1] <= self.follow.lag_s

    def _starts_rise(self, j: int) -> bool:
        """Command j (raising the grip) starts a rise: the one before held or lowered it,
        or came more than a lag earlier (the grip all but still by then)."""
        return j < 2 or not (self._f[j - 1] > self._f[j - 2] and self._rising(j))

    def contact_rate_per_s(self, t_s: float, jump_n_s: float, level_n: float | None) -> float:
        """Contacts per s the commanded grip makes like this one (onset t_s, slope jump
        jump_n_s, the level it rose from level_n): a rise's onset rate; past the onset, up
        to `late_s` after a run's first command, its late bends' (`KINKS_LATE_IN_RISE`);
        0 after both."""
        rise = self.rise_at(t_s)
        if rise is not None and rise.change_n > 0 and rise.window_s > 0:
            return KINKS_PER_RISE / rise.window_s * _fit(rise, jump_n_s, level_n)
        late = self.rise_at(t_s, self.late_s)
        span = self.late_s - self.onset_s
        if late is None or late.change_n <= 0 or span <= 0:
            return 0.0
        return KINKS_LATE_IN_RISE / span * _fit(late, jump_n_s, level_n)


def _fit(change: Change, jump_n_s: float, level_n: float | None) -> float:
    """How well a contact's slope jump fits a bend the change can make: 1 up to the level's
    share of the grip (the level over the grip held before; at most all) times the rate the
    grip moves at, a Gaussian in log ratio (`FIT_LOG_SIGMA`) beyond; 0 if it cannot bend."""
    share = 1.0
    if level_n is not None and change.from_n > 0:
        share = min(1.0, max(0.0, level_n / change.from_n))
    bend_n_s = share * change.rate_n_s  # the steepest bend the grip can make
    if bend_n_s <= 0:
        return 0.0
    excess = max(0.0, math.log(abs(jump_n_s) / bend_n_s)) if jump_n_s else 0.0
    return math.exp(-0.5 * (excess / FIT_LOG_SIGMA) ** 2)


def _number(value: object, what: str) -> float:
    if isinstance(value, bool):
        raise ValueError(f"grip command {what} must be a number, got {value!r}")
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"grip command {what} must be a number, got {value!r}") from None


def charge_grip(
    children: np.ndarray, scores: np.ndarray, null: float, log_base: float, log_grip: float
) -> float:
    """Weigh a contact the commanded grip may have made, in the scores of the tracker's
    children of it (`children`: a view; `kernels.branch` puts first, in order, the
    len(scores) children taking it for no ridge, at their clutter or grip-step rate;
    `scores`: those tracks' scores before it): each such
    child, and "no slip" (`null`, before the contact; `log_base` its rate then), explains
    it at its own rate plus the grip's (`log_grip`, per s). In place; the new null."""
    n = len(scores)
    children[:n] = np.logaddexp(children[:n], scores + log_grip)
    return null + float(np.logaddexp(log_base, log_grip))

"""TrackerDecoder ("tracker"): slip, speed and position by tracking ridge contacts.

Physics: the leading edge of a slipping object makes one pulse each time it
reaches a ridge; ridge i sits at x_i = cumsum([0, *spacings])[i]. The contact
*times* are all that matter (amplitudes and shapes vary), and the contact
sequence is a position measurement: contact k happened when the edge was at
a ridge. Which ridge, and in which direction the object moves, is unknown
and must be inferred from the timing pattern (thesis ch. 5.2: with constant
speed, successive intervals are in the ratio of the spacings). Real slips
speed up, slow down, stop, restart and reverse; the end of a slip shows in
the static force too (thesis ch. 4.3: the FSR reads M = (1 - k mu) W + k P
while slipping, W at rest, so the level steps when the object sticks).

Design (a multiple-hypothesis tracker, its hypotheses held as arrays):

* `contacts.ContactDetector` turns the signal into contact onsets (sub-sample
  times) and, later, tells whether each one fell back like a pulse or rose
  and stayed (a *step*: sharp ones are told within 0.1 s).
* A hypothesis (track) is a direction, the ridge of the last contact it
  assigned and a Kalman filter on the distance travelled, the speed, the
  acceleration and the distance each ridge's speed dip costs (ridge
  positions are measurements at contact times). Its motion model is chosen
  when its speed is first measured: *steady* (the acceleration held at 0,
  the speed a slow random walk: ratios of intervals stay those of the
  spacings, which tells the alignment) or *changing* (a constant
  acceleration of unknown size with a slowly varying jerk: speeding up and
  braking are followed). Each new contact branches every hypothesis: assign
  it to the next ridge or a later one (missed contacts), call it spurious,
  or - the object stopped unseen and went on - restart at the next ridge
  with its speed unknown. A contact may also start a new track at any
  ridge, either way (a slip starting, or reversing: after a reversal the
  other edge leads, at a place no contact tells).
* A contact whose onset falls in a commanded grip change's window (the efference copy,
  `Decoder.note_grip_command`: `efference.py`) may be the grip's: every child taking it
  for no ridge, and "no slip", explain it at their rate plus the grip's.
* A contact judged a step branches a slipping track into "stopped there"
  (position held, speed 0) and "a grip change, slipping on"; the next
  contact (or its absence) decides. A contact told a pulse whose jump was as
  fast as a stop's (on the falling tail of the last ridge's pulse) is branched
  so too, each track weighed by its speed (`stop_jumps`: a ridge's rise spans
  about a millimetre of travel). A stopped track restarts with a contact
  at its next ridge, speed unknown until the one after.
* Silence is evidence too: a track that expected a ridge well before now
  and saw none either missed it or has stopped, whichever is likelier.
  Samples on a rail (saturation) show no contacts: expected ones there are
  not missed.
* Output: posterior over hypotheses (plus "no slip": every contact is
  clutter). Slip is flagged when slipping tracks with two or more contacts
  (one of which fell back like a pulse, or `EVIDENT_CONTACTS` with no step and no
  pulse as low as noise among them) hold half the mass - or, before that, from a first
  contact onto an unloaded sensor (the object has just slid onto the skin:
  `arrival_flag`, no speed, until silence, a flat level or the posterior ends it). Once
  up, the flag is held (no speed) while the level ramps with no grip command moving it:
  an edge sliding onto or off the skin changes the length it covers (`level_ramp`). The
  speed needs no
  direction (the belt and the reflex act on it): it is given when the slipping
  tracks agree on it whichever way they go, else the range of speeds they allow
  (`_report`: SPEED_* constants).
  The direction (and the position, which needs it) is told when the best
  track has three contacts and every track moving its way explains them
  better than those moving the other way by at least `LOG_REPORT_ODDS`, and
  kept down to `LOG_KEEP_ODDS`; the confidence grows with that margin (and
  with how much of the posterior agrees), so an early answer is a
  low-confidence one. On a symmetric skin both ways explain the contacts
  equally: a speed, never a direction. Between contacts the speed is extrapolated with
  the track's acceleration only as far as silence allows: a track whose next ridge is
  not told by now has not reached it, so its mean speed since its contact is bounded
  (`SILENCE_REACH`). Past the last ridge no contact can come: a
  braking there goes on only as far as the contacts made it certain (`LAST_BRAKE_Z`),
  else the speed last measured is held until a step tells the stop or the coast ends.

Contacts are decided with a delay (longest detector scale), sometimes out of
time order, and a step is told ~0.1 s after its onset; the tracker keeps
snapshots of its last few steps and replays them, so results do not depend
on how the input is chunked. Figures: docs/benchmarks/decoding.md, slip_reporting.md.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from functools import cached_property
from typing import Any

import numpy as np

from grasplink.decoding import (
    arrival,
    arrival_flag,
    coast_bound,
    flag_keep,
    flat_step_speed,
    level_ramp,
    noise_gate,
    overdue_speed,
    rail_hold,
    reflag,
    restart_confirm,
    rise_evidence,
    step_hold,
    stop_jumps,
    told_height,
    told_rise,
)
from grasplink.decoding.base import DEFAULT_UPDATE_S, Decoder, SlipEstimate, StaticForce
from grasplink.decoding.contacts import (
    STEP_IDS,
    ContactDetector,
    ContactEvent,
    PulseCheck,
)
from grasplink.decoding.detector import step_shape
from grasplink.decoding.detector.noise_floor import NOISE_FLOOR_N
from grasplink.decoding.efference import LEVEL_BEFORE_S, charge_grip
from grasplink.decoding.kernels import posterior as posterior_kernels
from grasplink.decoding.kernels.branch import Model, branch, pack_constants
from grasplink.decoding.kernels.common import ring_slot
from grasplink.decoding.kernels.layout import (
    F_COLS,
    F_D,
    F_S,
    F_SCORE,
    F_STOP,
    F_WIDTH,
    I_COLS,
    I_DIRN,
    I_FIRST,
    I_IDS,
    I_LAST,
    I_N,
    I_RIDGE,
    I_WIDTH,
    IDS,
)
from grasplink.decoding.kernels.prune import prune_choice
from grasplink.errors import ConfigError

V_MIN_MM_S = 2.0
V_MAX_MM_S = 400.0
# pulse verdicts in the ring of recent contacts (RING slots per id series: `ring_slot`)
# NOISE: told a pulse, but standing no higher than noise does (`WEAK_PULSE_SNR`)
UNKNOWN, PULSE, STEP, UNCLEAR, NOISE = 0, 1, 2, 3, 4
RING = 256


# the columns of a bank's two matrices (`kernels.layout`: the kernels read them as plain
# ints): floats (P flattened row-major, X = (s, v, a, d), m, score, sig, stop, t) and
# integers (dirn, first, ids, model, n, ridge, run); a field is a view
_F_COLS: dict[str, int | slice] = {
    "X": slice(F_S, F_D + 1),
    **{key: F_COLS[key] for key in ("P", "m", "score", "sig", "stop", "t", "before")},
}
_I_COLS: dict[str, int | slice] = dict(I_COLS)
_F_WIDTH, _I_WIDTH = F_WIDTH, I_WIDTH
_EMPTY: list[_Bank] = []  # _Bank.empty()'s one instance
_WARM = False  # this process's kernels are loaded
_NO_BLIND = np.zeros(0)  # the posterior kernel's blind times when none


def _fill(floats: np.ndarray, ints: np.ndarray, fields: dict) -> None:
    """Write `fields` (arrays or scalars, per track) into the bank matrices."""
    for key, value in fields.items():
        col = _F_COLS.get(key)
        if col is not None:
            if key == "P":
                value = value.reshape(len(value), 16)
            floats[:, col] = value
        else:
            ints[:, _I_COLS[key]] = value


def _put_bounded(table: dict, key: Any, value: Any, keep: int) -> None:
    """table[key] = value, then its oldest entries (insertion order) dropped past `keep`."""
    table[key] = value
    while len(table) > keep:
        del table[next(iter(table))]


def _tracks(B: _Bank) -> tuple:
    """A bank's fields as the posterior's kernels take them (a plain tuple)."""
    return tuple(
        posterior_kernels.Tracks(
            score=B.score, X=B.X, P=B.P, m=B.m, t=B.t, stop=B.stop, dirn=B.dirn,
            ridge=B.ridge, run=B.run, n=B.n, ids=B.ids, before=B.before,
        )
    )  # fmt: skip


def warm_up_signal(ridges_mm: np.ndarray, fs_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """(t_s, force_n) of an edge slipping at 40 mm/s across ridges at `ridges_mm`: a held
    level with a small noise and one pulse a ridge - what `TrackerDecoder.warm_up` feeds
    (the gateway imports no simulator: a plain stand-in for one)."""
    speed_mm_s, lead_s, pulse_n, width_s = 40.0, 0.3, 0.4, 0.008
    t = np.arange(round((lead_s * 2 + ridges_mm[-1] / speed_mm_s) * fs_hz)) / fs_hz
    x = 2.0 + 0.002 * np.random.default_rng(0).standard_normal(len(t))
    for at_s in lead_s + ridges_mm / speed_mm_s:
        x += pulse_n * np.exp(-0.5 * ((t - at_s) / width_s) ** 2)
    return t, x


class _Bank:
    """The hypotheses as arrays (immutable once built: snapshots share them).

    Per track: direction (+1/-1), the ridge (travel order) of its last contact,
    ridge contacts assigned `n`, contacts since it last (re)started `run`
    (1: speed unknown), motion model, time `t` of its last contact, Kalman state
    X = (s, v, a, d) at t - s the edge's travel from the first ridge met, v the
    speed without dips, a the acceleration, d the distance each ridge's dip
    costs - and covariance P, dip memory m (the not yet recovered share of the
    dips, in units of d), timing sigma of its last contact, score (log), the
    ids of its last contacts, the id it started at, and `stop`: NaN while
    slipping, else the time it stopped (X[:, 0] then holds where), and `before`:
    the speed it had before it last restarted (0: never; `restart_confirm`).

    Stored as one float and one int matrix (a row per track): taking tracks is two
    numpy calls, not one per field, and the compiled branching (`kernels.branch`)
    takes and gives the two matrices. The fields are views of their columns, made on
    first reading.
    """

    FIELDS: tuple[str, ...] = (
        "P", "X", "dirn", "first", "ids", "m", "model", "n", "ridge", "run", "score", "sig",
        "stop", "t", "before",
    )  # fmt: skip
    __slots__ = (*FIELDS, "_f", "_i", "_sched")
    P: np.ndarray
    X: np.ndarray
    dirn: np.ndarray
    first: np.ndarray
    ids: np.ndarray
    m: np.ndarray
    model: np.ndarray
    n: np.ndarray
    ridge: np.ndarray
    run: np.ndarray
    score: np.ndarray
    sig: np.ndarray
    stop: np.ndarray
    t: np.ndarray
    before: np.ndarray
    _f: np.ndarray
    _i: np.ndarray
    _sched: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None  # (a `Schedule`)

    def __init__(self, floats: np.ndarray, ints: np.ndarray):
        self._f, self._i = floats, ints
        self._sched = None

    def __getattr__(self, key: str) -> np.ndarray:
        """A field's view, made when first read (a bank's readers use a few fields)."""
        col = _F_COLS.get(key)
        if col is not None:
            view = self._f[:, col]
            if key == "P":
                view = view.reshape(len(view), 4, 4)
        elif key in _I_COLS:
            view = self._i[:, _I_COLS[key]]
        else:
            raise AttributeError(key)
        setattr(self, key, view)
        return view

    def __len__(self) -> int:
        return len(self._f)

    @classmethod
    def of(cls, **fields) -> _Bank:
        """A bank of the given fields (every one of FIELDS, per track)."""
        N = len(fields["score"])
        floats = np.empty((N, _F_WIDTH))
        ints = np.empty((N, _I_WIDTH), np.int64)
        _fill(floats, ints, fields)
        return cls(floats, ints)

    @classmethod
    def empty(cls) -> _Bank:
        """The empty bank (one shared instance: banks are never changed in place)."""
        if _EMPTY:
            return _EMPTY[0]
        bank = cls(np.zeros((0, _F_WIDTH)), np.zeros((0, _I_WIDTH), np.int64))
        bank._f.flags.writeable = False
        bank._i.flags.writeable = False
        _EMPTY.append(bank)
        return bank

    def take(self, idx: np.ndarray) -> _Bank:
        """The tracks at integer indices idx (`ndarray.take`: half the cost of `a[idx]`;
        two calls, one per matrix, whatever fields the caller reads)."""
        return _Bank(self._f.take(idx, 0), self._i.take(idx, 0))


class _One:
    """One track's numbers as plain floats (the chosen track, read at every update)."""

    __slots__ = (
        "a", "d", "dirn", "index", "m", "n", "numbers", "p00", "p01", "p02", "p11", "p12", "p22",
        "ridge", "run", "s", "stop", "t", "v",
    )  # fmt: skip

    def __init__(self, B: _Bank, i: int):
        self.index = i  # its row in the bank it was read from
        self.dirn, self.ridge = int(B.dirn[i]), int(B.ridge[i])
        self.n, self.run = int(B.n[i]), int(B.run[i])
        self.t, self.stop, self.m = float(B.t[i]), float(B.stop[i]), float(B.m[i])
        self.s, self.v, self.a, self.d = (float(x) for x in B.X[i])
        P = B.P[i]
        self.p00, self.p01, self.p02 = float(P[0, 0]), float(P[0, 1]), float(P[0, 2])
        self.p11, self.p12, self.p22 = float(P[1, 1]), float(P[1, 2]), float(P[2, 2])
        # as `kernels.posterior.where` takes them (a `posterior.One` as a plain tuple)
        self.numbers = (
            self.s, self.v, self.a, self.d, self.m, self.t, self.stop,
            self.p00, self.p01, self.p11, self.p02, self.p12, self.p22, self.dirn, self.ridge,
        )  # fmt: skip


def _flag_only(out: SlipEstimate, p: float) -> SlipEstimate:
    """`out` as a slip flagged with no speed, position or direction, confidence `p` (at
    most 1): what the keep, rail, arrival and reflag rules report."""
    return SlipEstimate(out.t_s, True, None, None, out.force_n, min(1.0, p))


class TrackerDecoder(Decoder):
    """Contact tracker: hypotheses over (direction, ridge, motion); Kalman speed, acceleration."""

    name = "tracker"

    # model constants (see module doc); all times in s, distances in mm
    # chance a ridge contact is detected, by the spacing crossed before it (its pulse is
    # 1 - exp(-spacing / 10 mm) high and starts on the previous one's decay): measured by
    # benchmarks/detector_contacts.py --spacings (with the tail kinks, `detector.tail_kinks`:
    # 3 mm 46 %, 4 mm 92 %, 5 mm 99 %, 6-34 mm 100 % of 3964 contacts, 8-120 mm/s; 22, 91,
    # 99 % without them); interpolated between, flat beyond
    DETECT_SPACINGS_MM = (3.0, 4.0, 5.0)
    DETECT_P = (0.46, 0.92, 0.99)
    LOG_CLUTTER_IDLE = math.log(0.01)  # spurious contacts per s without slip
    LOG_NEW_TRACK = math.log(0.01)  # slips starting per s
    LOG_REVERSE = math.log(0.2)  # a contact while slipping is the first after a reversal
    # ... or the first after the slip stopped unseen and went on its way from a ridge its
    # tracks do not place (a clutter contact took the restart's ridge): without it a
    # reversal starts anywhere while going on must restart at the next ridge, and a
    # stick-slip's restart reads as a reversal (rates-drops 130101). -inf: off
    LOG_REBIRTH = -math.inf
    CLUTTER_PER_S = 0.05  # spurious contacts per s (detector false alarms, grip changes)
    P_TIP = 0.3  # extra contacts per ridge contact while slipping (tipping front edge) ...
    TIP_MM = 10.0  # ... within this travel after it, into a spacing of at least TIP_GAP_MM
    TIP_GAP_MM = 10.0  # (the edge tips over a long gap, never right before the next ridge)
    TIP_S = 0.3  # ... or, speed unknown, within this time
    LOG_STOP = math.log(0.2)  # a slip stops before the next ridge (silence)
    # silence is *reported* as a stop once P(all due ridges missed) falls below this (None:
    # LOG_STOP); the hypotheses' scores keep LOG_STOP, so a later contact resumes the slip
    LOG_STOP_REPORT: float | None = None
    LOG_RESTART = math.log(0.05)  # a slip stopped unseen and restarted before this contact
    RESTART_PER_S = 1.0  # a stopped slip restarts (per s)
    # a slip that stopped unseen and went on reaches the next ridge later than one that
    # did not, never sooner: its restart child is weighed by P(speed >= distance / time
    # since the last contact) under the speed prior, to this power (`kernels.branch.
    # _log_reach`; 0: off). Full plan, 3 seeds: moving speed missing 26.8 -> 26.2 %,
    # stops cleared in time 92.9 -> 93.1 % (docs/decoding.md, tracker section)
    RESTART_REACH = 1.0
    # ... and a stopped track's restart, from where and when it stopped (0: off). It
    # clears a stick-slip stop whose own friction step read as the restart
    # (test_restart_confirm's case); a noise contact 0.18 s after a stop at 15 mm/s is no
    # longer the restart two ridges (33 mm) on, which kept the slip reported stopped 0.6 s
    # longer (test_restart_reach); nor a step 0.1 s after one the restart at the last
    # ridge 36 mm on, which no silence refutes: it held a 33 mm gap reported stopped
    # (test_restart_reach, test_quantised_input). Full plan, 3 seeds, against off: moving
    # missing 26.2 -> 25.9 %, stops cleared 93.1 -> 93.3 % (docs/decoding.md)
    STOPPED_REACH = 1.0
    # a restarted track (speed unknown until its next contact) is no slip yet while its
    # restart contact is told a step (1), or also unclear (2), or also not yet told (3);
    # 0: a slip at once. After a stop the level steps (static friction), and that step
    # read as the restart at the next ridge held the flag up with no speed through the
    # stop (issue 22 item 4; figures: docs/decoding.md, tracker section). 3 (s25): a
    # stopped object makes no ridge contacts, and a contact at rest (the friction step's
    # tail, a held object's kinks) restarting the track before it is told held the flag
    # up through the stop (rates-drops 136501, loop 161000/161211): full plan, 2 seeds,
    # against 1: stops cleared 94.9 -> 96.0 %, slip dropped 17.6 -> 18.3 %
    RESTART_CONFIRM = 3.0
    # ... and a restarted track's first speed (its restart contact and the next) while
    # neither is told a pulse, the flag down (`restart_confirm`): two kinks at rest are no
    # restart (stop 96200: 2 updates with a speed after due -> 0); 0: held on the first
    # contact only. Alone it cost the slips' own restarts after a stick (s30: stick-slip
    # slip dropped 6.9 -> 7.9 %, rates-drops 8.1 -> 9.0), so it ships with the agreement
    # below (s31; docs/decoding.md)
    RESTART_CONFIRM_TWO = 1.0
    # ... but not a first speed within this share of the speed the track had before it
    # stopped (`restart_confirm`, `kernels.posterior.agrees`): a slip going on after a
    # stick resumes about its speed, two kinks at rest give any (96200: 16.4 against 79
    # mm/s, 79 % off). 0: every such first speed held. Full plan, 3 seeds, one run,
    # against both off: stick-slip and rates-drops slip dropped 6.9 / 8.1 % both, stops
    # cleared 95.7 -> 96.0 %, constant missing 4.8 -> 4.9 %, held 0.0 % both
    RESTART_AGREE_REL = 0.6
    # a step (sharp rise that stays) while slipping: the slip stopped, or the grip changed
    STOP_STEP_PER_S = 1.0
    # ... a stop there is told once the next ridge due after the step, had the slip gone
    # on, would have been decided (its time at the speed before the step plus the
    # detector's latency, times this; 0: at once; none past the last ridge): a ridge told
    # a step (hysteresis holds a pulse's fall) is confirmed by the contact due, a stop by
    # the silence where it was due
    STEP_STOP_WAIT = 0.0
    GRIP_STEP_PER_S = 0.3
    # a contact told a step at the detector's sure hold (sharp, tall, flat: `PulseCheck.sure`,
    # which ridge pulses seldom are) taken as a ridge the slip went on from: else a stop right
    # where the next ridge was due is that ridge by its timing (issue 22 item 4); 0: any step
    LOG_SURE_STEP_RIDGE = math.log(0.01)
    LOG_STOP_AT_RIDGE = math.log(0.05)  # a slip stops just as it reaches a ridge
    # a step not sure by its shape (`step_shape.classify`, from its samples up to the
    # verdict): a fast monotone rise is a stop's - taken as a ridge the slip went on from
    # with this prior -, a slow one (or none above its base) a ridge pulse the FSR's
    # hysteresis held up, or the grip rising under a sliding object - taken as a stop
    # (there or at the ridge) with this one; a fast rise to a peak, or off a falling tail,
    # is either (AMBIGUOUS: neither prior, unless SHAPE_AMBIGUOUS_RIDGE). Measured
    # (stop_causes.py --shapes, full plan): 89 % of the stops' plain steps fast, 94 % of the
    # ridges' slow (the loop's 96 %). Full plan, 2 seeds, one run (tune_tracker_kinds.py):
    # the stop side alone clears stops in time 87.0 -> 89.9 % at no cost. The ridge side
    # (dropped_causes.py: a slow step read as a stop holds 14 % of the updates the slip flag
    # drops while sliding) at log 0.1, against it off: slip dropped 18.1 -> 16.0 %
    # (saturation 28.5 -> 15.5, reversal 36.0 -> 31.0, stick-slip 8.9 -> 6.4, loop 41.8 ->
    # 38.8), moving missing 29.8 -> 27.5 %; cost: stops cleared in time 89.9 -> 88.8 %
    # (87.7 with AMBIGUOUS ridge-like, 86.6 before the falling-tail jump), speed after a
    # stop's report due 1.0 -> 1.1 %, wrong direction 3.0 -> 3.2 %, snr10 flagged at rest
    # 40.9 -> 46.3 %; held objects 0.0 %. It also failed three decoding tests (a stop past
    # the last ridge at 10 dB cleared in 0.42 s, > 0.3; a stop on a ridge placed 0.067 mm
    # past the bound; the rail before the object arrives): off until s34, gated by noise
    # (LOG_SHAPE_RIDGE_STOP below)
    LOG_SHAPE_STOP_RIDGE = math.log(0.1)
    # a verdict told before its contact (the watcher judges before the kink bank decides)
    # is read when the contact comes (`_read_early`): 1 a step's shape, 2 also a pulse's
    # jump; 0: never read. Rare: over the full plan's ten seed windows (every kind, one run
    # each, tune_tracker_kinds.py) two cases move - constant 51140 (seed window 3-5:
    # constant missing 6.0 -> 5.3 %) and, its cost, rates-drops 134010 (0-2: rates-drops
    # missing 25.5 -> 26.1 %); window 9 the same to the digit, 6-8 too but loop missing
    # 50.0 -> 49.9 % (run at 2: jumps as well) (s35)
    EARLY_CHECKS = 1
    # a contact onto an unloaded sensor (its level under this, N: `arrival`) is the edge
    # sliding onto the skin: tracks born there at a later ridge of their way had every
    # ridge before it missed (0: off, the start prior alone). Full plan, one run
    # (tune_tracker_kinds.py): see docs/decoding.md, "Arrival"
    ARRIVAL_EMPTY_N = arrival.EMPTY_N
    # ... and it is a slip from then: flagged (no speed, no direction) while the posterior
    # flags none, until P(its next ridge not yet told) falls below this (`arrival_flag`;
    # 0: off). Figures: docs/decoding.md, "Arrival"
    ARRIVAL_FLAG_P = arrival_flag.HOLD_P
    # ... over a stop the posterior reports before it ever flagged the slip (1; 0: the
    # stop reported): such a stop rests on a track pairing the arrival with a contact no
    # ridge made (the loop's 40 mm/s seed 1: stopped at 1.42 s, its ridge 1 at 1.68 s)
    ARRIVAL_FLAG_OVER_STOP = 1.0
    # ... and ended by the level lying flat since (`arrival_flag.STALL_N`, N; 0: off)
    ARRIVAL_STALL_N = arrival_flag.STALL_N
    # ... not ended by its contact told a step (1; 0: ended, as until s27): an edge sliding
    # onto the skin leaves the object lying there, so its level rises and stays - a step
    # (the reversal kind's 25 mm object: 7 of 9 arrivals of seed 1 told steps 0.1 s on,
    # the flag down to the 2nd ridge); a placed object is told by the stall and silence.
    # Full plan, 2 seeds, one run (tune_tracker_kinds.py --try ARRIVAL_STEP_KEEP=1):
    # slip dropped 13.6 -> 12.8 % (reversal 30.0 -> 23.1, loop 39.2 -> 37.3, rates-drops
    # 8.7 -> 8.0), every other column of every kind unchanged (held 0.0 %)
    ARRIVAL_STEP_KEEP = 1.0
    # a contact taken for a ridge whose onset shows no pulse's rise on the track's rise
    # time (`told_rise`: the probe's z under TOLD_RISE_Z, read only where its window is
    # held by the contact's decision) loses this (0: off) - a bend of the level (hysteresis
    # letting go onto the coverage ramp: the headline loop's 1.496 s), not its ridge.
    # With GRIP_FLAT_STEP, full plan, 2 seeds, one run against both off
    # (tune_tracker_kinds.py): moving missing 21.0 -> 20.4 %, loop 51.7 -> 49.8 % (p90
    # 67.2 -> 50.1), slip dropped 14.7 -> 14.4 %, stops cleared 95.7 % both; cost: constant
    # missing 4.0 -> 4.4 %, stop kind 7.1 -> 9.3 % (docs/decoding.md, Gaps: the headline)
    TOLD_RISE_LOG = told_rise.LOG_LOSS
    TOLD_RISE_Z = told_rise.Z_MAX
    # ... but not where the level fell just before the onset by more than this (white-noise
    # units of `RiseEvidence.z_and_trend_each`; 0: read everywhere) and fell on through the
    # rise's window (z under -TOLD_RISE_TAIL_FALL_Z; 0: whatever z): a ridge after a short
    # spacing starts on the previous pulse's fall with a small pulse (its height grows with
    # the spacing before it), the level falls on through its rise and the probe reads no
    # rise (constant 50151: its true 10 mm/s track lost 4 nats at the 3 mm ridge, z -22
    # and -9, and was pruned). Where a fall ends, the level flattens after the bend and z
    # reads near 0 (loop_least_force's 2.55 s: z -4.7, trend -6.2; the tail rule alone
    # let an alias take it and show 0.17 s of speed at rest, `test_efference.py`). Full
    # plan, one run per window (tune_tracker_kinds.py --try TOLD_RISE_TAIL_Z=3,
    # TOLD_RISE_TAIL_FALL_Z=6 against both 0), seeds 0-2 / 3-5: constant missing 4.5 ->
    # 3.7 / 5.3 -> 4.6 %, stop 7.9 -> 6.5 / 7.6 both, stick-slip wrong direction 3.2 both
    # / 4.5 -> 2.2, moving 20.2 -> 19.8 / 22.0 -> 21.7, slip dropped 8.5 -> 8.3 / 8.8 ->
    # 8.7; no kind worse by 0.1 but rates-drops 25.7 -> 25.8 / 25.3 -> 25.4. The tail rule
    # alone (FALL_Z 0) gained more (constant 3.3 / 4.5, accelerating 33.9 -> 26.2 on 3-5)
    # and cost reversal, rates-drops and saturation up to 0.6 (docs/decoding.md, s36-s37)
    TOLD_RISE_TAIL_Z = 3.0
    TOLD_RISE_TAIL_FALL_Z = 6.0
    # weight of a told contact's height against the spacing before the ridge a child gives
    # it (`told_height`: the probe's z at its onset on the track's rise time, over the told
    # median, against 1 - exp(-spacing / 10 mm)); 0: off. Full plan, 1 seed, one run
    # against 0 (tune_tracker_kinds.py, docs/decoding.md): snr10 missing 47.9 -> 47.8 %,
    # wrong direction 1.3 -> 0.6 %, flagged / speed at rest 34.3 / 12.3 -> 32.9 / 11.3 %;
    # constant and held-noise the same to the digit. 3 seeds, one run: snr10 missing 51.9
    # -> 52.0 %, wrong direction 2.6 -> 1.0 %, speed at rest 13.8 -> 13.6 %; loop p90
    # 52.7 -> 53.5 %; stick-slip the same; held-noise 0 false slips: on (for the direction)
    TOLD_HEIGHT = 1.0
    TOLD_HEIGHT_SIGMA = told_height.SIGMA  # ... the spread of log z about the line (nats)
    TOLD_HEIGHT_SLOPE = told_height.SLOPE  # ... log z per log f
    # ... only while the told pulses stand under RISE_EVIDENCE_GATE at their median (1;
    # 0: always)
    TOLD_HEIGHT_NOISY = 1.0
    # a step after which the level lay flat (its trend ended) is not charged to a commanded
    # grip rise (1; 0: it is): the grip's bend starts the level rising with it. Alone it
    # moves no full-plan figure; with TOLD_RISE_LOG it lets the headline's stop step
    # (1.768 s, in the reflex's grip rise) end the two-contact slip: no speed at rest
    GRIP_FLAT_STEP = 1.0
    # weight of the soft evidence of skipped and due ridges (`rise_evidence`: the signal's
    # rise where a track puts a ridge no contact told, scored in place of log(1 - DETECT_P),
    # never below it); 0: off (the fixed penalty alone). Alone it nearly doubled the snr10
    # speed at rest (slips tracked to the end held their speed through the rest); with the
    # coast bounded (COAST_INTERVALS 1), full plan, 2 seeds, one run against off/off
    # (tune_tracker_kinds.py, docs/decoding.md): snr10 speed missing 59.0 -> 52.2 %, wrong
    # direction 11.8 -> 6.4 %, flagged / speed at rest 37.1 / 13.0 -> 32.8 / 13.3 %; no met
    # target moved: on
    RISE_EVIDENCE = 1.0
    # ... while the pulses told stand under this many white-noise units at their median
    # (`PulseCheck.height_snr`: heavy noise). 6, not the pulse probe's 10: at 10 the loop's
    # weak pulses (hysteresis) open it and stops cleared falls 94.1 -> 92.2 % there
    RISE_EVIDENCE_GATE = 6.0
    RISE_H_LOW = rise_evidence.H_LOW  # ... the pulse size's prior from this x the told median
    RISE_SILENCE_AHEAD = 3  # ... and the silence of this many ridges due so read (0: none)
    # the white noise (N per sample, `noise_gate`) from which the report's overdue rules
    # rest (OVERDUE_NOISY_WHITE): 10 dB SNR puts 0.1-0.3 N under the simulator's 0.3-1 N
    # pulses, thesis-like noise is 0.02 N - the stick-slip and loop kinds' weak pulses
    # pass the told-height test (RISE_EVIDENCE_GATE) at that. 0: off (no such test)
    NOISY_WHITE_N = 0.05
    # the ridge side of the step's shape (above, off since s23): a stop at a step told
    # RIDGE_LIKE takes this prior, except where the white noise reads heavy
    # (SHAPE_RIDGE_STOP_NOISY 0, NOISY_WHITE_N: at 10 dB a shape is read off noise, and
    # the prior kept snr10 tracks moving past their slip's end, speed at rest 13.6 ->
    # 16.9 % at log 0.1). Constant 52270: a 15 mm/s slip's ridge pulse held up before a
    # 67 mm spacing was taken for the stop, its speed gone for 4.5 s. Full plan, every
    # kind, one run per seed window (s34, tune_tracker_kinds.py, docs/decoding.md), off
    # against log 0.2 gated, seeds 0-2 / 3-5 (held out): moving missing 21.9 -> 20.1 /
    # 23.9 -> 22.3 %, slip dropped 8.9 -> 8.5 / 9.3 -> 9.0 % (loop 21.1 -> 19.1 / 21.3 ->
    # 18.8), constant missing 4.9 -> 4.5 / 6.4 -> 6.0 %; stops cleared 95.7 -> 95.5 /
    # 95.9 -> 95.7 % (one stop each), speed after due 0.0 / 0.2 % unchanged, snr10 and
    # held objects unchanged. Log 0.1 gains a little more but shows stop 95100 (stopped
    # just short of a ridge) at 35 mm/s for 0.3 s of its rest
    LOG_SHAPE_RIDGE_STOP = math.log(0.2)
    SHAPE_RIDGE_STOP_NOISY = 0.0  # ... also where the white noise reads heavy (1)
    SHAPE_AMBIGUOUS_RIDGE = 0.0
    # 1: below 227 Hz a fast rise that goes on past its one-sample step is no stop's
    # (`step_shape.THEN_SHARE`)
    SHAPE_READ_THEN = 1
    # a contact told a pulse that jumped as fast as a stop's step (`stop_jumps`): branched
    # like a step, its ridge children whose speed makes that jump under this travel get
    # LOG_FAST_JUMP_RIDGE, its stop children whose speed makes it more LOG_FAST_JUMP_STOP
    # (0: off, the contact a pulse only)
    FAST_JUMP_TRAVEL_MM = 0.8
    LOG_FAST_JUMP_RIDGE = math.log(0.1)
    LOG_FAST_JUMP_STOP = math.log(0.05)
    # ... its jump, read on unsmoothed samples (100 Hz), bounded by the samples it crossed
    # between (`stop_jumps.resolved_s`): 2, a ridge child weighed on the longest it can
    # have lasted, a stop child on the shortest; 0: its time to 90 % and a sample more for
    # both (1: the longest for both, 3 / 4: a sample more for the ridge, the longest /
    # shortest for the stop). 2 on: full plan, 3 seeds, rates-drops stops cleared 88.9 ->
    # 90.7 %, speed after due 4.7 -> 2.8 %, but missing 23.3 -> 25.6 % (docs/decoding.md)
    RESOLVED_JUMP = 2.0
    # a track whose last contact came from a probe waits this share of the probes' latency
    # for its next (`_latency_floor`; 0: the kink bank's latency for every track)
    PROBE_WAIT = 1.0
    # ... also when that contact came from the step probe (`STEP_IDS`: a small step, found
    # at its hold); 0: only the kink bank's late contacts and the pulse probe's wait. Off
    # (1): full plan, 3 seeds, stops cleared 95.7 -> 96.0 % and after due 92 -> 76 updates,
    # but the loop's held ridges the step probe finds lose their wait (loop missing 51.2 ->
    # 51.7 %, slip dropped 18.2 -> 18.3 %): docs/decoding.md, *Gaps*
    STEP_PROBE_WAIT = 1.0
    # ... and with it (1) a step probe's contact waits only when one of the this many
    # contacts before it came late too (`_step_probe_regime`; 0: always). Off: at 3, full
    # plan, 3 seeds, stops cleared 95.7 -> 96.0 %, loop missing 51.2 -> 51.3 %, but the
    # first held ridge of a run loses its wait (tests/decoding/test_tracker_probe_wait.py:
    # the flag drops 2.57-2.65 s; docs/decoding.md, *Gaps*)
    STEP_PROBE_REGIME = 0.0
    PROBE_STOP = 0.4  # a small step (step probe) is a stop less often than a clear one
    LOG_PROBE_RIDGE = math.log(0.3)  # ... and a ridge contact (merged pulses) sometimes
    PROBE_SIGMA_S = 0.02  # its timing (mid-rise of an unresolved pulse train)
    ROBUST_FLOOR = 0.05  # weight of the broad part of the contact-time likelihood
    # ridge-contact position noise (ridge compliance, speed dips). 0.25 (was 0.3): a braking
    # slip's intervals fit the steady model's position noise less easily (see JERK_PER_S2)
    SIGMA_POS_MM = 0.25
    SPEED_WALK = 0.01  # relative speed change (1 sigma) per sqrt(SPEED_WALK_MM) of travel
    SPEED_WALK_MM = 10.0
    # prior of the changing-speed model at each (re)start (0.53, was 0.5: see JERK_PER_S2)
    LOG_CHANGING = math.log(0.53)
    ACC_PER_S = 2.0  # changing: acceleration sigma at a (re)start, x speed (v doubles in 0.5 s)
    # changing: the acceleration drifts this much (sigma) in 1 s, x speed. 0.5 (was 1): the
    # acceleration the contacts measured is trusted on between far-apart contacts, where a
    # steady track reported lags a braking slip (decelerating updates in intervals > 0.5 s:
    # median error 42 % from a steady track, 3.6 % from a changing one). With SIGMA_POS_MM
    # 0.25 and LOG_CHANGING 0.53, full plan, 3 seeds, one run (tune_tracker_kinds.py):
    # decelerating median 11.2 -> 7.1 %, stick-slip wrong direction 10.8 -> 6.7 %, constant
    # missing 12.3 -> 12.1 %; cost: stick-slip stops cleared in time 78.7 -> 76.9 %
    JERK_PER_S2 = 0.5
    ACC_FLOOR = 0.4  # predicted braking keeps at least sqrt(1 - 2 x this) of the speed
    DIP_RECOVERY_S = 0.05  # the speed recovers from a ridge's dip within about this time
    DIP_PRIOR_MM = 0.1  # prior sigma of the distance lost at each ridge (mean 0): thesis
    # dips of 4-15 mm/s recovering over ~50 ms cost 0.2-0.75 mm, but a wider prior takes a
    # slowing slip for dips (decelerating and stick-slip figures), more than dips gain
    DIP_PRIOR_CHANGING_MM = 0.1  # the changing model's (its own, to tune apart)
    DIP_MAX_MM = 0.8  # a 15 mm/s dip recovering over 50 ms costs 0.75 mm (thesis ch. 5.5.1)
    SPEED_INIT_REL = 0.1  # relative speed uncertainty from two contacts (besides timing)
    LATE_REL = 0.15  # a contact may come this share of its interval late (speed changes)
    # the next contact's timing sigma counts at most this share of its interval (so its 3
    # sigma, 1.5 intervals): a braking hypothesis with an unsure acceleration otherwise
    # waits seconds for it. 1/6 (3 sigma at half an interval), measured in docs/decoding.md
    # at s27: stops cleared 96.0 -> 96.4 %, after due 0.13 -> 0.09 %, slip dropped 14.9 ->
    # 15.2 %; not shipped
    SPAN_MAX_REL = 0.5
    # the speed shown (not the flag) is withheld once its own track's ridge ahead is overdue
    # by the report's schedule (`overdue_speed`): the timing sigma capped at
    # OVERDUE_SPAN_REL of the interval (3 sigma: half of it), OVERDUE_LATE_REL of it late,
    # the contact's latency (OVERDUE_PROBE_WAIT of the probes' floor), at the first ridge
    # by which all would be missed with P <= OVERDUE_MISS_P (a 4 mm ridge, told 92 %, leaves
    # it to the one after). 0: off. Full plan, one run (tune_tracker_kinds.py,
    # after_due_cases.py, docs/decoding.md): speed after due 58 -> 37 of 46021 updates, the
    # flag, stops cleared and slip dropped unchanged; at P 1 (every next ridge) constant
    # missing 4.6 -> 9.9 %, at 0.05 4.6 %
    OVERDUE_SPEED = 1.0
    OVERDUE_SPAN_REL = 1.0 / 6.0
    OVERDUE_LATE_REL = 0.0
    OVERDUE_PROBE_WAIT = 1.0
    OVERDUE_MISS_P = 0.05
    # ... but never a ridge past the one whose silence the posterior itself reports as a
    # stop (P(all missed) below LOG_STOP_REPORT, else LOG_STOP: `overdue_speed.
    # report_log_p`; 0: OVERDUE_MISS_P alone). A 4 mm ridge (told 92 %) stops the track
    # at its own silence; the report waited for the ridge after it, which the posterior
    # never schedules (due: inf), so the speed went on until the posterior's later due
    # time (stick-slip 86111, rates-drops 130101/130111: docs/decoding.md)
    OVERDUE_STOP_RIDGE = 1.0
    # ... and the report's latency floor reads the step probe's contacts as
    # STEP_PROBE_REGIME would at this count (0: as the posterior, STEP_PROBE_REGIME): a
    # late step after contacts told in time is a stop's, so the speed of the track it
    # revived is not held the probes' latency; the flag still is (rates-drops 136321)
    OVERDUE_PROBE_REGIME = 3.0
    # ... and once withheld, withheld for every track whose last contact is that one's,
    # until a contact comes (0: each track by its own schedule): silence since that
    # contact already refuted the speed shown; a twin of it braking or a slower alias
    # chosen next has no contact more behind it (rates-drops 130101). Off: it costs
    # decelerating slips 4.6 points of missing speed (their braking twins' next ridge
    # comes later than the report's capped schedule; full plan, 2 seeds, 17.0 -> 21.6 %)
    OVERDUE_LATCH = 1.0
    # ... for this long after that contact's speed first went overdue (inf: until a contact
    # comes). 0.05 s (s30): the twin chosen next at 130101 showed 1.32-1.33 s, its own due
    # time 1.338 s; a braking slip's twin whose ridge does come later keeps its speed after
    # it (full plan, 3 seeds, one run: decelerating missing 17.3 -> 17.4 %, constant 4.9
    # both, rates-drops after due 0.1 -> 0.0 %; docs/decoding.md)
    OVERDUE_LATCH_S = 0.05
    # 1: no speed either from a track whose last contact was told a step the level lay
    # flat after (`flat_step_speed`: a stop's friction step). Only the speed: the flag and
    # the range stay the posterior's. Clears stick-slip 81200 (7 updates after due), but
    # ridge contacts read so too: the 40 mm/s rail start over ADC counts
    # (test_quantised_input, seed 1) gives 106 speeds while slipping instead of 170, the
    # last 0.64 s of its slip without one. 2 (s30): only where the track's recent contacts
    # told fewer than two pulses (`flat_step_speed.lone_pulse`: an alias on a contact no
    # ridge made; the rail start's ridge train told five): 81200 7 -> 0, the rail start's
    # 170 speeds kept (docs/decoding.md); 0: off
    FLAT_STEP_SPEED = 2.0
    # ... also under heavy noise (1; 0: not where the rise evidence reads the silence,
    # RISE_EVIDENCE_GATE): at 10 dB a silent ridge says little (snr10 missing +5 points)
    OVERDUE_NOISY = 0.0
    # ... nor (0) where the white noise measured reads heavy (`noise_gate`, NOISY_WHITE_N):
    # the rise evidence reads the silence soft only once pulses are told, so early in a
    # 10 dB slip the report withheld speeds no stop had refuted (1: the old test alone)
    OVERDUE_NOISY_WHITE = 0.0
    # a braking track whose own motion, braking this many sigma gentler than its estimate,
    # has brought it below V_MIN_MM_S (or REST_SHARE) is reported stopped (a contact
    # revives it). 0: as estimated - the headline's speed at rest after the reflex stopped
    # the object ends at 2.13 s, not 2.79 (1 sigma: 2.32, 2: 2.79); the full set unchanged
    BRAKE_Z = 0.0
    # ... below this share of its speed at the last contact, if above V_MIN_MM_S: `_where`
    # shows no less than a quarter of it, so past that point the speed shown was a floor,
    # not the track's motion (the headline's last speed at rest 2.15 -> 2.08 s with
    # JERK_PER_S2 0.5, observable + 0.15 s = 2.14; the full plan unchanged but rates-drops
    # stops cleared 71.1 -> 73.7 %; 0: V_MIN_MM_S alone)
    REST_SHARE = 0.25
    # past the last ridge no contact can come, so no later contact can confirm a braking
    # and no silence can refute it: a braking track carries on there only with the braking
    # its contacts made certain, this many sigma gentler than estimated (none left: its
    # speed at the last contact held, until a step tells the stop or the coast ends).
    # 0: braked on as estimated, to a "stop" nothing observed while the object may slide
    # off. Cost: an alias that wrongly puts itself there lingers at its low speed
    # (accelerating speed missing +1.4 %: benchmarks/tune_tracker_kinds.py)
    LAST_BRAKE_Z = 2.0
    # silence bounds the speed shown (`_where`): its next ridge not told by now, a track
    # travelled less than this x the distance to it (misses weighted in); 0: no bound
    SILENCE_REACH = 1.0
    # ... below the speed at the contact too: 0 no (it undoes a speeding up), 1 to the mean
    # it allows, 2 braking; 0 as noise misses more ridges than DETECT_P says
    SILENCE_BRAKE = 0.0
    LOG_PULSE = math.log(8.0)  # a contact that fell back like a pulse: likelier a slip
    # ... unless it stands under this many white-noise units above its base: noise that
    # crosses the kink threshold falls back like a pulse too (a held object's two noise
    # contacts a second apart, 1.9-2.4 units high, were a slip; 1.6 % of the ridge pulses
    # told stand under 3, mostly merged ones mid-train); 0: every pulse verdict counts
    WEAK_PULSE_SNR = 3.0
    LOG_STEP = math.log(3.0)  # a contact that rose and stayed (a grip step): likelier not
    # a track is evidently a slip with two contacts one of which fell back like a pulse, or
    # with this many, none told a step or a noise pulse (`WEAK_PULSE_SNR`): under the FSR's
    # hysteresis a ridge often reads unclear; 3 flagged an hour held (unclear noise
    # contacts), steps allowed made periodic grip ramps a slip (docs/decoding.md)
    EVIDENT_CONTACTS = 4
    # a flag up is kept while moving tracks hold KEEP_FLAG_SHARE of the mass under a wider
    # evidence rule (`flag_keep`: 1 a pulse-told first contact, 2 also untold contacts, 3
    # also an untold first contact; 0: off, the evident rule alone). Quick plan, one run
    # (tune_tracker_kinds.py): slip dropped 12.9 -> 12.8 % at every level, the cost: the
    # stop kind's flagged at rest 0.0 -> 8.7 % (the flag held into the stop): off
    KEEP_FLAG = 0
    KEEP_FLAG_SHARE = 0.5
    KEEP_FLAG_WITHIN_S = 0.0  # ... also re-raised this long after it went down (0: kept only)
    # 1: while the flag is up a restart is not held by its contact's verdict not yet told
    # (or unclear): RESTART_CONFIRM 3 is for a contact at rest restarting a slip already
    # reported stopped, with the flag down; a restart told a step or a noise pulse is still
    # held (the stop's own friction step: test_restart_confirm). Figures: docs/decoding.md,
    # "slip dropped" (issue 22)
    KEEP_FLAG_UNHOLD = 1.0
    # a flag up within RAIL_HOLD_BEFORE_S of the rail the sensor sits on now is held (no
    # speed) until RAIL_HOLD_AFTER_S past the rail's end (`rail_hold`: a saturated sensor
    # shows no contact, the object does not stop for it); 0: off. Full plan, 2 seeds, one
    # run (tune_tracker_kinds.py): saturation slip dropped 29.3 -> 12.7 % (0.3 s before:
    # 20.0 - at 22 mm/s the squeeze's step is read as the stop up to 0.6 s before the
    # rail), moving 14.7 -> 13.6 %, every other figure of every kind unchanged. 0.3 s
    # after the rail: saturation flagged at rest 0.0 -> 10.5 % (the object stops soon
    # after the squeeze ends at 118 mm/s): 0
    RAIL_HOLD = 1.0
    RAIL_HOLD_BEFORE_S = 0.6
    RAIL_HOLD_AFTER_S = 0.0
    # a contact told a pulse within REFLAG_WITHIN_S after the flag was last up raises it
    # again (no speed) while P(its next ridge not yet told) is at least REFLAG_P
    # (`reflag`: a ridge pulse is motion); 0: off
    REFLAG_P = 0.0
    REFLAG_WITHIN_S = 1.0
    # a flag up within RAMP_HOLD_WITHIN_S is held (no speed) while the level ramps: the
    # medians of RAMP_STEPS + 1 windows of RAMP_WINDOW_S each step one way by at least
    # RAMP_SLOPE_N_S x the window and RAMP_Z sigmas of the white noise's (`level_ramp`: an
    # edge sliding onto or off the skin changes the covered length); 1: where the
    # posterior reports no stop, 2: over its stop too; 0: off
    RAMP_HOLD = 1.0
    RAMP_HOLD_WITHIN_S = 3.0
    # 1: with RAMP_HOLD 1, also over the posterior's stop once the ramp's windows all lie
    # RAMP_OVER_STOP_S after the stop was first reported (the stop's own step and the
    # ramp before it are then out of them: a covered length ramping on is the object
    # still sliding) and the ramp is at least RAMP_OVER_STOP_SLOPE_N_S steep (the
    # drift of a sensor at rest wanders about 0.2 N/s); 2: the same, up only (a pulse's
    # tail decays after a stop); 0: off. Full plan, 3 seeds, every kind (s32,
    # docs/decoding.md, "ramp hold over a stop"): 2 at 0.6 N/s, slip dropped 9.7 -> 9.1
    # % (the page; loop 24.5 -> 22.5, accelerating 4.3 -> 2.6), stops and at rest
    # unchanged; the loop kind's decoder ~13 % dearer (the ramp test at stop reports)
    RAMP_OVER_STOP = 2.0
    RAMP_OVER_STOP_S = 0.0
    RAMP_OVER_STOP_SLOPE_N_S = 0.6
    # a flag up past a step told RIDGE_LIKE is held (no speed) while the chosen track is
    # stopped there, until its next ridge at the speed before would be decided, times this
    # (`step_hold`: a slow step is a held ridge pulse or a turn, seldom a stop); 0: off.
    # Alone (s29) it cost three stops (a contact after the step the stop kept, an alias's
    # wait, the ridge after): with the two limits below, full plan, 3 seeds, one run
    # (tune_tracker_kinds.py, docs/decoding.md "slip dropped"): moving slip dropped 10.7
    # -> 9.9 % (reversal 23.4 -> 16.4), stops cleared 95.7 % both, flagged at rest 2.5 ->
    # 2.7 % (snr10 31.7 -> 33.5), held 0.0 %
    STEP_HOLD = 1.0
    STEP_HOLD_MAX_S = 3.0  # ... and no longer than this after the step (an alias's speed)
    # ... and no longer than this after the first contact told after the step with the
    # stop still chosen (`step_hold.unlinked`: no moving track took it up, so no ridge of
    # the slip's: loop 161210 held its stop 2.6 s); 0: off
    STEP_HOLD_AFTER_S = 0.3
    # 1: ... counting only contacts not told RIDGE_LIKE (reversal 102110: the 25 mm
    # object's trailing edge leaving a ridge is a held pulse, not the stop's; full plan,
    # 3 seeds, every kind, one run each: reversal dropped 16.4 -> 15.9 %, saturation 8.6
    # -> 8.5 %, every other figure unchanged); 0: every contact
    STEP_HOLD_AFTER_UNRIDGED = 1.0
    # 1: the wait runs to the ridge after the next when the step lies within 3 sigma of the
    # next (`stop_seen`: it may be that ridge's contact); 0: to the next ridge only (a stop
    # just short of it: stop 95100 cleared 0.61 s late with 1, 0.02 s with 0)
    STEP_HOLD_SKIP = 0.0
    RAMP_WINDOW_S = 0.05
    RAMP_STEPS = 4
    RAMP_SLOPE_N_S = 0.2
    RAMP_Z = 1.5
    # ... and none within this after a commanded grip change's window (the FSR's level
    # creeps back after a grip rise: the loop kind at 10 mm/s on uniform4 fell 0.25 N/s
    # for 0.6 s at rest after its grip rose 5 -> 8.8 N)
    RAMP_GRIP_SETTLE_S = 1.0
    # 1: ... unless the level still ramps up with the commanded grip's share taken out
    # (the level over the grip a lag before: a held object's level follows its grip, a
    # sliding object's covered length ramps it on; the loop raises the grip mid-slide).
    # Loop kind, 3 seeds: slip dropped 25.9 -> 24.5 %, every other figure and kind as it
    # was, held false slip 0 (docs/decoding.md). 0: off
    RAMP_GRIP_SHARE = 1.0
    # ... and only the way the last ramp held went (`level_ramp`: a ridge pulse's tail
    # falls in a stick while the covered length rose before it), 2: that way forgotten
    # once the posterior flags with a speed (a track: the object may have turned), 1:
    # never; 0 (shipped): any way. 2, full plan 3 seeds: stops 95.7 -> 96.0 %
    # (stick-slip 95.4 -> 96.3), dropped 10.7 -> 10.9 % (loop 26.3 -> 27.3,
    # accelerating 4.9 -> 5.6): off, the stops target met without it (docs/decoding.md)
    RAMP_ONE_WAY = 0.0
    # ... and with the flag up at the previous update, held on while the ramp's steps reach
    # this share of the least step (hysteresis; 1: none). A ramp near its least step
    # passes and fails the medians' test from one update to the next: a slow slip's flag
    # chattered (constant 8 mm/s on alpha0.9, seed 54001: 158 runs of the flag under
    # 50 ms, 58 at 0.5). Full plan, every kind, seeds 0-2 / 3-5 (one run each): flag
    # chatter 50.4 -> 18.7 / 57.5 -> 20.9 runs a minute, slip dropped 9.1 -> 8.9 / 9.5 ->
    # 9.3 %, stops cleared 96.0 -> 95.7 / 95.9 both, every other figure the same
    RAMP_KEEP_SHARE = 0.5
    SPEED_PRIOR_MM_S = 35.0  # slips are mostly 10-120 mm/s: log-normal prior on the speed
    SPEED_PRIOR_LOG_SIGMA = 1.0
    MAX_SKIP = 2  # missed contacts allowed between two detected ones
    STRONG_Z = 60.0  # ridge contacts: strengths spread log-uniformly up to about this
    STRENGTH_MIN, STRENGTH_MAX = math.log(0.1), math.log(3.0)
    REFRESH_S = 0.5  # how often silence (and the agreement) is re-scored between contacts
    NEGLIGIBLE = 25.0  # hypotheses this far (log) below the best are left out
    MAX_SPEED_JUMP = 2.0  # largest speed change between two contacts (far-off contact)
    START_CONTACTS = 2  # a slip may start at any of the last this many contacts
    MAX_HYPOTHESES = 24  # tracks of two or more contacts kept by score (`_prune`)
    PER_START = 4  # tracks kept per start contact, beyond the best max_hypotheses
    DETECT_MM = 1.2  # travel after a contact before the detector has decided it
    # the detector runs on whole blocks of this length (by default): 10 ms decides a contact
    # 10 ms sooner on average than 30 ms (slip shown ~45 -> ~29 ms past the second contact)
    # at about the CPU 30 ms blocks cost before the tracker's CPU work (issue 7)
    DETECT_BLOCK_S = 0.01
    AGREE_MM = 3.0
    AGREE_SPEED = 0.15
    CONF_POS_MM = 3.0  # the position's own sigma halves the confidence at this value
    CONF_CONTACTS = 2.0  # confidence grows as 1 - exp(-(contacts - 1) / this)
    # the direction: a signed speed once the best track has an interval ratio (three
    # contacts) and every track moving its way explains them this much better than those
    # moving the other way; the confidence carries P(this way), the logistic of those odds
    DIRECTION_CONTACTS = 3
    LOG_REPORT_ODDS = math.log(9.0)
    LOG_KEEP_ODDS = math.log(3.0)  # a direction told is kept down to these odds (flicker)
    # the speed whichever way: given when this share of the slipping posterior agrees on
    # it within AGREE_SPEED, or SPEED_NARROW_SHARE does and every track holding BOUND_SHARE
    # of it lies within SPEED_RANGE_MAX, or the likeliest track has three contacts and
    # SPEED_RATIO_SHARE agrees; else the range of the speeds of those tracks. A share of
    # 0.3 alone halves the missing speed at constant speed (8.9 -> 4.0 %) but gives guesses
    # from ranges like 7-94 mm/s (54 mm/s for 20: tests/decoding/test_can_path_slip.py)
    SPEED_AGREE_SHARE = 0.8
    # ... in heavy noise (the rise evidence's gate open: `RiseEvidence.blind`), where half
    # the ridges go untold and a true track's skips leave aliases a share of the mass;
    # None: SPEED_AGREE_SHARE. 0.7: full plan, 2 seeds, one run (tune_tracker_kinds.py):
    # snr10 speed missing 51.7 -> 49.4 %, its speed at rest 13.3 -> 14.9 %, p90 75.9 ->
    # 78.2 %; every other kind's figures unchanged (docs/decoding.md, snr10 section).
    # Off: it buys speeds with speeds at rest and wider errors, not with information
    SPEED_AGREE_SHARE_NOISY: float | None = None
    SPEED_NARROW_SHARE = 0.3
    SPEED_RATIO_SHARE = 0.5  # ... and with three contacts, at least this share
    # 5 gave a speed on two noise contacts of a held object; 2 (inclusive) one of a missed
    # ridge's alias (23-47 mm/s: 47 at rest fired a 45 mm/s reflex, loop_slow_wearer)
    SPEED_RANGE_MAX = 1.5
    BOUND_SHARE = 0.01
    SCHEDULE = 3  # ridges ahead whose silence is scored
    COAST_S = 0.5  # a slip past the last ridge: stopped by silence no sooner (see _coast_end)
    # ... and stopped (no speed shown) this many intervals (the spacing into the last ridge
    # at the speed there) after the last ridge's contact: past it no contact can come, so
    # the speed is unobserved (`coast_bound`); 0: shown until a step or the coast end.
    # snr10 at-rest updates with a speed 1944 -> 1052 (rest_speed_causes.py, evidence on).
    # A speed is owed until then, not after (test_tracker, test_can_path_slip score so;
    # benchmarks/coast_scored_window.py: inside that window the bound moves no figure)
    COAST_INTERVALS = 1.0
    COAST_GAP = 0.0  # ... the interval's spacing: 0 the one into the last ridge, 1 the largest
    TURN_PER_S = 0.3  # a slip stops or reverses unseen between contacts (rate, per s)
    MEMO = 8  # contacts whose branches are kept for a replay on the same inputs (`_step`)
    VERDICTS_KEPT = 64  # contacts whose step / fast-jump / grip verdicts are remembered
    # a track silent this long has stopped or left the skin (None: the slowest slip's time
    # to cross the skin and the coast past it, (length + coast) / V_MIN_MM_S)
    STALE_S: float | None = None

    def __init__(
        self,
        layout_mm: Sequence[float],
        fs_hz: float,
        *,
        update_period_s: float = DEFAULT_UPDATE_S,
        max_hypotheses: int | None = None,
        history: int = 8,
        detect_block_s: float | None = None,
        detector: ContactDetector | None = None,
        tuning: Mapping[str, float | tuple[float, ...]] | None = None,
    ):
        super().__init__(layout_mm, fs_hz, update_period_s=update_period_s)
        for key, value in (tuning or {}).items():  # the trade-off curves' settings
            setattr(self, key, self._tuning_value(key, value))
        geometry = self.geometry
        x = geometry.ridges_mm
        self.length = geometry.length_mm
        self.count = len(x)
        spacings = geometry.spacings_mm
        R = self.count
        # travel-order ridge positions (index 0 = +1, 1 = -1) and the coast past the end
        self._coast = float(np.max(spacings))  # how far past the last ridge a slip goes on
        pos = np.stack([x, self.length - x[::-1]])
        self._pos = np.concatenate([pos, pos[:, -1:] + self._coast], axis=1)  # + coast end
        lead = self.length  # a slip may start anywhere up to a skin length before
        before = np.stack(
            [np.concatenate([[lead], spacings]), np.concatenate([[lead], spacings[::-1]])]
        )
        total = 2.0 * float(before[0].sum())
        self._log_prior = np.log(before / total)  # (2, R): where a new track starts
        # the spacing after each ridge, travel order (0 after the last)
        self._gap = np.concatenate([before[:, 1:], np.zeros((2, 1))], axis=1)
        pd = np.vectorize(self._detect_probability)(before)
        self._pd = np.concatenate([pd, np.zeros((2, 1))], axis=1)  # the coast end: never seen
        with np.errstate(divide="ignore"):
            self._log_pd = np.log(self._pd)
            self._log_miss = np.log1p(-self._pd)
        self._log_miss[:, -1] = -np.inf  # past the coast: stopped
        # `_assign`'s log prior per (direction, ridge, skip): the next `skip` ridges all
        # missed (sequential sums from 0, as one skip after another), the one after seen
        ahead = np.minimum(np.arange(R)[:, None] + 1 + np.arange(self.MAX_SKIP + 1), R - 1)
        self._skip_prior = np.empty((2, R, self.MAX_SKIP + 1))
        for way in range(2):
            skipped = np.zeros(ahead.shape)
            skipped[:, 1:] = np.cumsum(self._log_miss[way, ahead[:, :-1]], axis=1)
            self._skip_prior[way] = skipped + self._log_pd[way, ahead]
        # the slowest slip a track takes crosses the whole skin and the coast past it in this
        # time: a track silent for longer has stopped or left the skin, so a later contact is
        # no part of its slip (a new one starts there); such tracks retire (`_retire`)
        self._stale_s = (
            (self.length + self._coast) / V_MIN_MM_S if self.STALE_S is None else self.STALE_S
        )
        # per (direction, start ridge): log distance to each ridge ahead, and P(all missed
        # from the next one up to it); rows padded with +inf / 1
        # and the coast end after them: past it the slip has stopped (missed = 0 there)
        self._ahead_log = np.full((2, R, R + 1), np.inf)
        self._ahead_missed = np.ones((2, R, R + 1))
        for di in range(2):
            for r in range(R):
                missed = 1.0
                for j, k in enumerate(range(r + 1, R)):
                    missed *= 1.0 - pd[di, k]
                    self._ahead_log[di, r, j] = math.log(float(pos[di, k] - pos[di, r]))
                    self._ahead_missed[di, r, j] = missed
                coast = float(self._pos[di, R] - pos[di, r])
                self._ahead_log[di, r, R - 1 - r] = math.log(coast)
                self._ahead_missed[di, r, R - 1 - r] = 0.0
        # what the waiting tracks' score derives from them, per (direction, start ridge):
        # P(all missed before each ridge ahead) and which ridges exist
        self._ahead_before = np.concatenate(
            [np.ones((2, R, 1)), self._ahead_missed[:, :, :-1]], axis=2
        )
        self._ahead_finite = np.isfinite(self._ahead_log)
        self._erf_scale = 1.0 / (self.SPEED_PRIOR_LOG_SIGMA * math.sqrt(2.0))
        self.max_hypotheses = self.MAX_HYPOTHESES if max_hypotheses is None else int(max_hypotheses)
        if self.max_hypotheses < 1:
            raise ConfigError(f"tracker: max_hypotheses must be >= 1, got {self.max_hypotheses}")
        self.detector = detector or ContactDetector(fs_hz)
        block_s = self.DETECT_BLOCK_S if detect_block_s is None else float(detect_block_s)
        self._block = max(1, round(block_s * self.fs_hz))  # latency against CPU
        # a contact is known this late: the detector's own delay, then the block's end
        self._max_latency = (self.detector.lag + self._block) / self.fs_hz
        # a contact found by the probes comes later (`ContactDetector.probe_lag`)
        self._probe_latency = (self.detector.probe_lag + self._block) / self.fs_hz
        self._min_latency = (2.0 * self.detector.channels[0].width + self._block / 2) / self.fs_hz
        self._static = StaticForce(fs_hz)
        self._n_in = 0  # samples taken by the detector
        self._n_seen = 0  # samples accepted
        self._pending_t = np.zeros(0)
        self._pending_x = np.zeros(0)
        self._items: list[tuple[int, int, int, object]] = []  # (emit, kind, id, item) queue
        # tracker state
        self._null = 0.0
        self._tracks = _Bank.empty()
        self._contacts: list[ContactEvent] = []  # processed, in time order (last `history`)
        self._snapshots: list[tuple[float, _Bank]] = []  # state before each of them
        self._history = int(history)
        # pulse verdicts of recent contacts: the kink bank's, then the probes' (`ring_slot`)
        self._ring_id = np.full(2 * RING, -1, np.int64)
        self._ring = np.zeros(2 * RING, np.int64)
        # contacts told to be steps (replayed as such): id -> did the trend go on after it
        self._steps: dict[int, bool | None] = {}
        self._sure: set[int] = set()  # ... of which told at the sure hold (`PulseCheck.sure`)
        self._shapes: dict[int, int] = {}  # ... their shapes' verdicts (`step_shape.classify`)
        self._fast: dict[int, stop_jumps.Jump] = {}  # told pulses that jumped like a stop's
        self._early: dict[int, PulseCheck] = {}  # verdicts told before their contact was
        self._recent = step_shape.Recent(fs_hz)  # the samples their shapes are read from
        # the banks' open schedules and the due ridges read (`_soft_schedule`)
        self._soft_banks: dict[int, tuple[_Bank, tuple, dict, dict]] = {}
        noise = self.detector.noise  # skipped ridges' rises read from them (`rise_evidence`)
        self._rise = rise_evidence.RiseEvidence(
            fs_hz, self._recent, noise.white, noise.block, NOISE_FLOOR_N
        )
        self._rise.h_low = self.RISE_H_LOW
        # the last contacts' branches by their inputs, and their pruning (`_step`, `_prune`)
        self._memo: dict[tuple, tuple[_Bank, float, _Bank]] = {}
        self._pruned: dict[int, tuple[_Bank, np.ndarray, _Bank]] = {}
        self._force: float | None = None
        self._cache: tuple | None = None
        self._told_way = 0  # the direction the last update told (0: none)
        self._flagged = False  # the last update's slip flag (`flag_keep`)
        self._flag_t = -math.inf  # ... the last update that had it up
        self._kept: tuple | None = None  # (the posterior it was read with, P(moving))
        self._due: tuple[_Bank, np.ndarray] | None = None  # (bank, `_overdue`'s times due)
        self._withheld = -1  # the last contact whose track's speed went overdue (OVERDUE_LATCH)
        self._withheld_s = -math.inf  # ... when it first did (OVERDUE_LATCH_S)
        self._grip_rates: dict[int, float] = {}  # contact id -> `_grip_rate`
        self._unloaded: dict[int, bool] = {}  # contact id -> `_onto_empty_skin`
        # the last contact held that came onto an unloaded sensor, (id, t_s, index) or None
        # (`_arrival_contact`), looked up again only once stale: the contacts held changed
        # (`_add_contact`; a replay re-adds the same ones) or a load verdict came or went
        self._arrival_at: tuple[int, float, int] | None = None
        self._arrival_stale = True
        self._arrival_flag = arrival_flag.ArrivalFlag()  # whether the posterior took over
        self._reflag = reflag.Reflag()  # the pulse contact the flag is raised again for
        self._up_t = -math.inf  # the last update flagged but by `reflag`
        self._ramp_way = 0  # the way the level ramped when the ramp hold last held
        self._stopped_at = math.inf  # when the posterior's current stop report began
        log_f = told_height.log_factor(before)  # (`told_height`: mu per direction, ridge)
        c = told_height.centre(log_f, pd)
        self._height_mu = self.TOLD_HEIGHT_SLOPE * (log_f - c)
        self._entry = arrival.entry_adjustment(self._log_prior, self._log_miss[:, :R])
        # what every contact's one-contact tracks share: a bank that `_births` copies and
        # fills in (the contact's id, time, sigma and the score)
        dirn = np.repeat(np.array([1, -1]), R)
        ridge = np.tile(np.arange(R), 2)
        X = np.zeros((2 * R, 4))
        X[:, 0] = self._pos[(1 - dirn) // 2, ridge]
        ones = np.ones(2 * R, np.int64)
        zeros = np.zeros(2 * R)
        self._birth = _Bank.of(
            P=np.zeros((2 * R, 4, 4)),
            X=X,
            dirn=dirn,
            first=-ones,
            ids=np.full((2 * R, IDS), -1, np.int64),
            m=np.ones(2 * R),
            model=np.zeros(2 * R, np.int64),
            n=ones,
            ridge=ridge,
            run=ones,
            score=zeros,
            sig=zeros,
            stop=np.full(2 * R, np.nan),
            t=zeros,
            before=zeros,
        )
        self._birth._f.flags.writeable = False
        self._birth._i.flags.writeable = False
        # what `kernels.branch` reads besides the tracks: built once (a plain tuple)
        self._branch_model = tuple(
            Model(
                c=pack_constants(self._branch_constant_values()),
                pos=self._pos,
                gap=self._gap,
                log_prior=self._log_prior,
                skip_prior=self._skip_prior,
                birth_f=self._birth._f,
                birth_i=self._birth._i,
            )
        )

    @classmethod
    def _tuning_value(cls, key: str, value: Any) -> float | int | tuple[float, ...]:
        """A model constant's tuned value, checked: a number for a number, a table of
        numbers for a table (DETECT_P); ConfigError naming the key otherwise."""
        default = getattr(cls, key, None) if key.isupper() else None
        optional = ("STALE_S", "LOG_STOP_REPORT", "SPEED_AGREE_SHARE_NOISY")  # None by default
        if not (isinstance(default, float | int | tuple) or key in optional):
            raise ConfigError(f"tracker tuning: no model constant {key!r}")
        try:
            numbers = [float(x) for x in value] if isinstance(default, tuple) else [float(value)]
        except (TypeError, ValueError):
            raise ConfigError(f"tracker tuning {key} = {value!r} is not a number") from None
        if not all(math.isfinite(x) for x in numbers):
            raise ConfigError(f"tracker tuning {key} = {value!r} is not finite")
        if isinstance(default, tuple):
            return tuple(numbers)
        if isinstance(default, int) and numbers[0].is_integer():
            return int(numbers[0])  # a count (MAX_SKIP sizes arrays)
        return numbers[0]

    def warm_up(self) -> None:
        """Load (or compile) the kernels: a throwaway decoder on this one's layout and rate
        decodes a slip's ridge pulses (`warm_up_signal`: every kernel and argument type a
        live stream meets), once per process."""
        global _WARM
        if _WARM:
            return
        t, x = warm_up_signal(self.geometry.ridges_mm, self.fs_hz)
        throwaway: TrackerDecoder = TrackerDecoder(self.geometry.spacings_mm.tolist(), self.fs_hz)
        for i in range(0, len(t), 3):  # as a skin TPDO brings them
            throwaway.feed(t[i : i + 3], x[i : i + 3])
        # a held level has no arrival: its flag's waiting kernel is called from here
        rows = (0, throwaway.count)
        arrival_flag.waiting_p(1.0, rows, throwaway._waiting, throwaway._K, 0.1)
        # nor a level ramping after a flag: the ramp hold's medians kernel
        level_ramp.ramp_way(x[: int(self.RAMP_STEPS) + 1], int(self.RAMP_STEPS), 0.0)
        _WARM = True

    def _detect_probability(self, spacing_before: float) -> float:
        return float(np.interp(spacing_before, self.DETECT_SPACINGS_MM, self.DETECT_P))

    # ------------------------------------------------------------------ streaming
    def process(self, t: np.ndarray, x: np.ndarray) -> list[SlipEstimate]:
        force = self._static.filter(x)
        points = self.update_points(t)
        base = self._n_seen
        self._n_seen += len(t)
        self._pending_t = np.concatenate([self._pending_t, t])
        self._pending_x = np.concatenate([self._pending_x, x])
        out: list[SlipEstimate] = []
        for count, g in points:
            if count > 0:
                self._force = float(force[count - 1])
            self._run_detector(base + count)
            out.append(self._report(g))
        self._force = float(force[-1])
        return out

    def _run_detector(self, received: int) -> None:
        """Detect in whole blocks of `self._block` samples (fixed by sample index, so
        chunking cannot matter), then apply what the detector decided, in order."""
        upto = received - received % self._block
        count = upto - self._n_in
        if count > 0:
            t, x = self._pending_t[:count], self._pending_x[:count]
            self._pending_t, self._pending_x = self._pending_t[count:], self._pending_x[count:]
            self._n_in = upto
            events, checks = self.detector.feed(t, x)
            self._recent.append(x)  # (a step's shape is read from them: `_step_shape`)
            for ev in events:
                bisect.insort(self._items, (ev.emit_index, 0, ev.id, ev))
            for ck in checks:
                bisect.insort(self._items, (ck.emit_index, 1, ck.id, ck))
        while self._items and self._items[0][0] < self._n_in:
            _, kind, _, item = self._items.pop(0)
            if kind == 0:
                self._add_contact(item)  # type: ignore[arg-type]
            else:
                self._add_check(item)  # type: ignore[arg-type]

    def _add_check(self, check: PulseCheck) -> None:
        slot = ring_slot(check.id, len(self._ring))
        self._ring_id[slot] = check.id
        verdict = {True: PULSE, False: STEP, None: UNCLEAR}[check.pulse]
        snr = check.height_snr
        weak = self.WEAK_PULSE_SNR > 0 and snr is not None and snr < self.WEAK_PULSE_SNR
        if verdict == PULSE and weak:
            verdict = NOISE  # noise falls back like this too
        self._ring[slot] = verdict
        self._rise.note_height(check.id, snr)
        self._cache = None
        if check.pulse is True and check.id in self._steps:  # a step revised: a slow pulse
            del self._steps[check.id]
            self._sure.discard(check.id)
            self._shapes.pop(check.id, None)
            for at, c in enumerate(self._contacts):
                if c.id == check.id:
                    self._replay(at, [])
                    break
        if verdict == PULSE and self.LOG_FAST_JUMP_RIDGE and check.id not in self._fast:
            self._fast_jump(check)
        onset = self._onset(check.id)
        if self.EARLY_CHECKS and onset is None:
            _put_bounded(self._early, check.id, check, self.VERDICTS_KEPT)  # (`_read_early`)
        if check.pulse is False:
            self._steps[check.id] = check.trend_on
            if check.sure:
                self._sure.add(check.id)
            self._shapes[check.id] = (
                step_shape.UNTOLD if onset is None else self._step_shape(check, onset)
            )
            while len(self._steps) > self.VERDICTS_KEPT:
                oldest = next(iter(self._steps))
                del self._steps[oldest]
                self._sure.discard(oldest)
                self._shapes.pop(oldest, None)
            # replay from that contact, now a step (stop or grip change)
            for at, c in enumerate(self._contacts):
                if c.id == check.id:
                    self._replay(at, [])
                    break

    def _fast_jump(self, check: PulseCheck) -> None:
        """A contact told a pulse that jumped like a stop's step (`stop_jumps`): noted, and
        replayed from (branched as a step, weighed by each track's speed)."""
        at = next((k for k, c in enumerate(self._contacts) if c.id == check.id), None)
        if at is not None and self._note_jump(check, self._contacts[at].index):
            self._replay(at, [])

    def _note_jump(self, check: PulseCheck, onset: int) -> bool:
        """Note how fast the pulse told by `check` (its onset at sample `onset`) jumped, if
        like a stop's step (`stop_jumps.fast_jump_s`); whether it did."""
        resolved = int(self.RESOLVED_JUMP)
        jump = stop_jumps.fast_jump_s(self._recent, onset, check.emit_index, resolved)
        if jump is None:
            return False
        _put_bounded(self._fast, check.id, jump, self.VERDICTS_KEPT)
        return True

    def _onset(self, contact_id: int) -> int | None:
        """The sample index of a held contact's onset; None when not (or no longer) held."""
        return next((c.index for c in self._contacts if c.id == contact_id), None)

    def _read_early(self, ev: ContactEvent) -> None:
        """What a verdict told before ev itself was (`EARLY_CHECKS`) says of ev, read now
        that its onset is known and before ev is branched: a step's shape, a pulse's jump.
        The watcher can judge a contact before the kink bank decides it (at 400 Hz the
        80 ms scale decides 0.16 s after the onset; constant 51140's ridge 3, told a
        step 0.1 s after its onset, went unshaped: the slide read as a stop for 4.8 s)."""
        check = self._early.pop(ev.id, None)
        if check is None:
            return
        if check.pulse is False and ev.id in self._steps:
            self._shapes[ev.id] = self._step_shape(check, ev.index)
        elif (
            check.pulse is True
            and self.EARLY_CHECKS >= 2
            and self.LOG_FAST_JUMP_RIDGE
            and ev.id not in self._fast
        ):
            self._note_jump(check, ev.index)  # (read before ev is branched: no replay)

    def _step_shape(self, check: PulseCheck, onset: int) -> int:
        """The shape verdict of a contact told a step (`step_shape.classify`), its onset at
        sample `onset`, read from the samples up to the verdict (the same however the input
        is chunked); UNTOLD when its samples are no longer held."""
        if check.sure:
            return step_shape.UNTOLD
        if check.under:  # flat with the earlier pulse's course out (`detector.pulse_under`)
            return step_shape.STOP_LIKE
        return self._recent.verdict(onset, check.emit_index, bool(self.SHAPE_READ_THEN))

    # ------------------------------------------------------------------ hypotheses
    def _add_contact(self, ev: ContactEvent) -> None:
        self._cache = None
        if self._early:
            self._read_early(ev)
        times = [c.t_s for c in self._contacts]
        at = bisect.bisect_right(times, ev.t_s)
        if at == len(self._contacts):
            self._snapshots.append((self._null, self._tracks))
            self._contacts.append(ev)
            self._step(ev)
        else:  # an earlier contact decided late: replay from before it
            if at == 0 and len(self._contacts) >= self._history:
                return  # older than anything we can replay: drop it
            self._replay(at, [ev])
        while len(self._contacts) > self._history:
            self._contacts.pop(0)
            self._snapshots.pop(0)
        self._arrival_stale = True

    def _replay(self, at: int, extra: list[ContactEvent]) -> None:
        self._null, self._tracks = self._snapshots[at]
        replay = [*extra, *self._contacts[at:]]
        del self._snapshots[at:]
        del self._contacts[at:]
        for c in replay:
            self._snapshots.append((self._null, self._tracks))
            self._contacts.append(c)
            self._step(c)
        self._cache = None

    def _step(self, ev: ContactEvent) -> None:
        """Take contact ev: branch every track (`_branch`), then prune.

        The branches are those of an earlier pass when it ran on the same inputs (the
        same bank object - banks are immutable -, null score, contact and step verdict):
        a step told and then revised to a pulse replays the very contacts first taken,
        and only the pruning can differ (a replay holds one contact fewer)."""
        key = (
            ev, self._null, ev.id in self._steps, self._steps.get(ev.id), ev.id in self._sure,
            self._shapes.get(ev.id), self._fast.get(ev.id),
        )  # fmt: skip
        known = self._memo.get(key)
        if known is not None and known[0] is self._tracks:
            self._null, pool = known[1], known[2]
        else:
            before = self._tracks
            pool = self._branch(ev)
            _put_bounded(self._memo, key, (before, self._null, pool), self.MEMO)
        recent_ids = np.array([c.id for c in self._contacts[-self.START_CONTACTS :]], np.int64)
        held_ids = np.array([c.id for c in self._contacts], np.int64)
        self._tracks = self._prune(pool, recent_ids, held_ids)

    def _branch(self, ev: ContactEvent) -> _Bank:
        """Every track's children for contact ev (updates the null score), unpruned: one
        compiled kernel (`kernels.branch`); what needs Python objects (the step verdicts)
        is decided here and passed as numbers."""
        step = ev.id in self._steps
        # a stop ends the rising trend of the level (the object no longer covers more of
        # the sensor): a step after which it went on is seldom one
        stop_rate = self.STOP_STEP_PER_S * (0.1 if self._steps.get(ev.id) else 1.0)
        probe = ev.id >= STEP_IDS
        sigma_s = ev.sigma_s
        if probe:  # a small step the kink bank missed: often a weak ridge pulse
            stop_rate *= self.PROBE_STOP
            # pulses after short spacings start on the one before (thesis ch. 5.3.1) and
            # pile up like a step - so perhaps a ridge it could not time (mid-rise, loosely)
            sigma_s = max(ev.sigma_s, self.PROBE_SIGMA_S)
        log_strength = 0.0 if probe else self._log_strength(ev.z)  # (a probe starts none)
        # the tracks and the contact: a `kernels.branch.Bank` and `Contact`, as plain tuples
        tracks = (self._tracks._f, self._tracks._i)
        log_stop = math.log(stop_rate)
        # a pulse that jumped like a stop's step: branched as a step (`stop_jumps`)
        fast = None if step else self._fast.get(ev.id)
        as_step = step or fast is not None
        contact = (ev.t_s, ev.id, ev.sigma_s, sigma_s, log_strength, log_stop, as_step, probe)
        null = self._null
        floats, ints, self._null = branch(tracks, contact, null, self._branch_model)
        if fast is not None:
            self._weigh_fast(floats, ints, ev, fast)
        if self.ARRIVAL_EMPTY_N > 0 and len(floats) and self._onto_empty_skin(ev):
            born = ints[:, I_FIRST] == ev.id  # the slip enters at an end (`arrival`)
            way = (1 - ints[born, I_DIRN]) // 2
            floats[born, F_SCORE] += self._entry[way, ints[born, I_RIDGE]]
        grip_per_s = self._grip_rate(ev)
        if step and self.GRIP_FLAT_STEP and self._steps.get(ev.id) is False:
            grip_per_s = 0.0  # the level lay flat after it: no grip rise's bend
        if grip_per_s > 0:  # the commanded grip may have made it (`efference.py`)
            # (a fast pulse's no-ridge children are back at clutter's odds: `_weigh_fast`)
            base = math.log(self.GRIP_STEP_PER_S) if step else self.LOG_CLUTTER_IDLE
            kept = ~(ev.t_s - self._tracks.t > self._stale_s)  # the kernel's `_kept`
            self._null = charge_grip(
                floats[:, F_SCORE], self._tracks.score[kept], null, base, math.log(grip_per_s)
            )
        shape = self._shapes.get(ev.id, step_shape.UNTOLD) if step else step_shape.UNTOLD
        if ev.id in self._sure or shape == step_shape.STOP_LIKE:
            # a step beyond doubt (or shaped as a stop's): seldom a ridge the slip went on from
            ridge = (ints[:, I_LAST] == ev.id) & (ints[:, I_N] >= 2) & np.isnan(floats[:, F_STOP])
            sure = ev.id in self._sure
            floats[ridge, F_SCORE] += (
                self.LOG_SURE_STEP_RIDGE if sure else self.LOG_SHAPE_STOP_RIDGE
            )
        elif (
            shape == step_shape.RIDGE_LIKE
            or (shape == step_shape.AMBIGUOUS and self.SHAPE_AMBIGUOUS_RIDGE)
        ) and (self.SHAPE_RIDGE_STOP_NOISY or not self._noisy()):
            # a ridge pulse held up: seldom a stop (here)
            floats[floats[:, F_STOP] == ev.t_s, F_SCORE] += self.LOG_SHAPE_RIDGE_STOP
        # both read the probe's z at the onset on each ridge child's rise time (`rise_z`)
        rise_check = bool(self.TOLD_RISE_LOG) and not probe and bool(len(floats))
        heights = (
            bool(self.TOLD_HEIGHT)
            and bool(len(floats))
            and (not self.TOLD_HEIGHT_NOISY or self._rise.blind(self.RISE_EVIDENCE_GATE))
        )
        if rise_check or heights:
            tail_z = self.TOLD_RISE_TAIL_Z if self.TOLD_RISE_TAIL_Z > 0 else None
            fall_z = self.TOLD_RISE_TAIL_FALL_Z if self.TOLD_RISE_TAIL_FALL_Z > 0 else None
            read = told_rise.rise_z(
                floats, ints, ev, self._rise, self.detector.blind, tail_z, fall_z
            )
        if rise_check:
            # no pulse rose at the onset on the track's rise time: a bend, not its ridge
            told_rise.ridge_loss(
                floats, ints, ev, self._rise, self.detector.blind,
                self.TOLD_RISE_Z, self.TOLD_RISE_LOG, read,
            )  # fmt: skip
        if heights:  # its height against the spacing before its ridge
            told_height.weigh(
                floats, ints, read, self._rise, self._height_mu, self.TOLD_HEIGHT,
                self.TOLD_HEIGHT_SIGMA,
            )  # fmt: skip
        if self.RISE_EVIDENCE and len(floats):
            self._weigh_skips(floats, ints, ev)
        return _Bank(floats, ints) if len(floats) else _Bank.empty()

    def _weigh_skips(self, floats: np.ndarray, ints: np.ndarray, ev: ContactEvent) -> None:
        """Children that skipped ridges: each skipped ridge scored by the signal's rise where
        the child puts it (`rise_evidence.skip_adjustment`), read from samples before ev's
        decision (the same on a replay)."""
        earlier = {c.id: (c.t_s, c.index) for c in self._contacts}
        rows, gain = rise_evidence.skip_adjustment(
            floats, ints, (ev.id, ev.t_s, ev.index, ev.emit_index), earlier, self._pos,
            self._log_miss, self.MAX_SKIP, self._rise, self.RISE_EVIDENCE_GATE,
        )  # fmt: skip
        floats[rows, F_SCORE] += self.RISE_EVIDENCE * gain

    def _onto_empty_skin(self, ev: ContactEvent) -> bool:
        """Whether the sensor read unloaded just before ev's onset (`arrival.unloaded`):
        decided once per contact, so a replay weighs it alike."""
        known = self._unloaded.get(ev.id)
        if known is None:
            known = self._reads_unloaded(ev.index)
            _put_bounded(self._unloaded, ev.id, known, self.VERDICTS_KEPT)
            self._arrival_stale = True
        return known

    def _reads_unloaded(self, index: int) -> bool:
        """Whether the sensor read unloaded over `arrival.LEVEL_S` before sample `index`."""
        return arrival.unloaded_before(
            index,
            self.fs_hz,
            self._recent.mean,
            self.detector.noise.white_at_sample,
            self.ARRIVAL_EMPTY_N,
        )

    def _grip_rate(self, ev: ContactEvent) -> float:
        """Contacts per s like ev the commanded grip makes at its onset (0: none noted, or
        none under way); decided once per contact, so a replay weighs it alike."""
        commands = self.grip_commands
        if not len(commands):
            return 0.0
        known = self._grip_rates.get(ev.id)
        if known is None:
            n = max(1, round(LEVEL_BEFORE_S * self.fs_hz))
            level = self._recent.mean(ev.index - n, ev.index)
            known = commands.contact_rate_per_s(ev.t_s, ev.jump_n_s, level)
            _put_bounded(self._grip_rates, ev.id, known, self.VERDICTS_KEPT)
        return known

    def _weigh_fast(
        self, floats: np.ndarray, ints: np.ndarray, ev: ContactEvent, jump: stop_jumps.Jump
    ) -> None:
        """The children of a pulse branched as a step: "no slip" and the tracks that take
        it for none of theirs keep clutter's odds (it fell back: no grip change), and each
        track's ridge or stop child is weighed by its speed (`stop_jumps.weigh`)."""
        log_grip = math.log(self.GRIP_STEP_PER_S)
        self._null += self.LOG_CLUTTER_IDLE - log_grip
        ignored = (ints[:, I_LAST] != ev.id) & (floats[:, F_STOP] != ev.t_s)
        floats[ignored, F_SCORE] += math.log(self.CLUTTER_PER_S) - log_grip
        stop_jumps.weigh(
            floats, ints, ev.id, ev.t_s, jump.longest_s, self.FAST_JUMP_TRAVEL_MM,
            self.LOG_FAST_JUMP_RIDGE, self.LOG_FAST_JUMP_STOP, jump.shortest_s,
        )  # fmt: skip

    def _branch_constant_values(self) -> dict[str, float]:
        """The constants `kernels.branch` reads, by its names (`branch.CONSTANTS`)."""
        return {
            "stale_s": self._stale_s,
            "clutter_per_s": self.CLUTTER_PER_S,
            "p_tip": self.P_TIP,
            "tip_mm": self.TIP_MM,
            "tip_gap_mm": self.TIP_GAP_MM,
            "tip_s": self.TIP_S,
            "tip_slow_per_s": self.P_TIP / self.TIP_S,
            "log_grip": math.log(self.GRIP_STEP_PER_S),
            "log_probe_ridge": self.LOG_PROBE_RIDGE,
            "log_stop_at_ridge": self.LOG_STOP_AT_RIDGE,
            "log_clutter_idle": self.LOG_CLUTTER_IDLE,
            "log_new_track": self.LOG_NEW_TRACK,
            "log_reverse": self.LOG_REVERSE,
            "log_2": math.log(2.0),
            "log_rebirth": self.LOG_REBIRTH,
            "dip_recovery_s": self.DIP_RECOVERY_S,
            "log_restart": self.LOG_RESTART,
            "log_restart_rate": math.log(self.RESTART_PER_S),
            "v_min_mm_s": V_MIN_MM_S,
            "v_max_mm_s": V_MAX_MM_S,
            "max_speed_jump": self.MAX_SPEED_JUMP,
            "pos_var_mm2": self.SIGMA_POS_MM**2,
            "speed_init_rel": self.SPEED_INIT_REL,
            "dip_var_mm2": self.DIP_PRIOR_MM**2,
            "dip_var_changing_mm2": self.DIP_PRIOR_CHANGING_MM**2,
            "acc_per_s": self.ACC_PER_S,
            "log_changing": self.LOG_CHANGING,
            "log_steady": math.log(1.0 - math.exp(self.LOG_CHANGING)),
            "speed_prior_mm_s": self.SPEED_PRIOR_MM_S,
            "speed_prior_log_sigma": self.SPEED_PRIOR_LOG_SIGMA,
            "log_speed_norm": math.log(self.SPEED_PRIOR_LOG_SIGMA * math.sqrt(2.0 * math.pi)),
            "speed_walk2": self.SPEED_WALK**2,
            "speed_walk_mm": self.SPEED_WALK_MM,
            "jerk_per_s2": self.JERK_PER_S2,
            "robust_floor": self.ROBUST_FLOOR,
            "dip_max_mm": self.DIP_MAX_MM,
            "restart_reach": self.RESTART_REACH,
            "stopped_reach": self.STOPPED_REACH,
            "erf_scale": self._erf_scale,
        }

    def _log_strength(self, z: float) -> float:
        """Log likelihood ratio ridge contact / false alarm of a contact of strength z.

        False alarms crowd just above the detector's threshold (a Gaussian tail);
        ridge contacts spread over a wide range of strengths.
        """
        thr = self.detector.threshold
        log_false_alarm = math.log(thr) - thr * (z - thr)
        log_ridge = -math.log(z * math.log(self.STRONG_Z / thr))
        return min(self.STRENGTH_MAX, max(self.STRENGTH_MIN, log_ridge - log_false_alarm))

    def _prune(self, B: _Bank, recent: np.ndarray, held: np.ndarray) -> _Bank:
        """Best first, one per (direction, ridge, model, state, last three contacts); bounded.

        Tracks with two or more contacts: the best max_hypotheses, plus the best
        PER_START of every contact a track starts at while that contact is in the
        bounded history (`held`), so that a slip whose true start came after a
        spurious contact is not crowded out by the tracks that took the spurious
        one for its start (an older start competes on score alone: memory stays
        bounded however long the stream). One-contact tracks (a slip starting at
        one of the `recent` contacts) are all kept.
        """
        if not len(B):
            return B
        chosen = prune_choice(
            B.score,
            B.stop,
            B._i,
            recent,
            held,
            self.NEGLIGIBLE,
            self.max_hypotheses,
            self.PER_START,
        )
        # the same pool pruned to the same tracks: the same bank object again, so that the
        # next contact of a replay finds its branches in the memo (`_step`)
        known = self._pruned.get(id(B))
        if known is not None and known[0] is B and np.array_equal(known[1], chosen):
            return known[2]
        out = B.take(chosen)
        _put_bounded(self._pruned, id(B), (B, chosen, out), self.MEMO)
        return out

    # ------------------------------------------------------------------ motion
    @cached_property
    def _silence_tables(self) -> dict[str, np.ndarray]:
        """The silence tables (`_tables_for` the ridges' misses)."""
        return self._tables_for(self._log_miss)

    @cached_property
    def _silence_open(self) -> tuple:
        """The silence tables with no ridge's miss counted (only the coast end stops a
        track), as the schedule kernel takes them: every ridge ahead gets its time due, and
        `rise_evidence.silence` scores them."""
        open_miss = np.where(np.isfinite(self._log_miss), 0.0, self._log_miss)
        return tuple(posterior_kernels.Silence(**self._tables_for(open_miss)))

    def _tables_for(self, log_miss: np.ndarray) -> dict[str, np.ndarray]:
        """What a track's schedule (`_schedule`) takes from its direction and ridge alone,
        per row di * (count + 1) + ridge (a ridge past the last one schedules as the
        coast end does), for idle tracks (stopped, or no speed yet: rows from 0) and
        active ones (rows from 2 (count + 1)): the ridges ahead (the coast end is index
        count), their positions, P(all missed) so far, and the (due, adj, stopped, limit)
        rows but for the times due. The same numbers as from each track's own arrays:
        the cumulative misses summed one ridge after the other as there."""
        R, S = self.count, self.SCHEDULE
        di = np.repeat(np.arange(2), R + 1)
        ridge = np.tile(np.arange(R + 1), 2)
        k = ridge[:, None] + 1 + np.arange(S)
        kk = np.minimum(k, R)
        miss = np.cumsum(log_miss[di[:, None], kk], axis=1)
        go_on = miss >= self.LOG_STOP
        # reported as still slipping (`LOG_STOP_REPORT`): the score keeps LOG_STOP
        told = miss >= (self.LOG_STOP if self.LOG_STOP_REPORT is None else self.LOG_STOP_REPORT)
        ended = np.logical_or.accumulate(~go_on | (k >= R), axis=1)
        done = np.zeros(ended.shape, bool)  # active tracks: done before each ridge ahead
        done[:, 1:] = ended[:, :-1]
        rows, J = 2 * (R + 1), S + 1
        due = np.full((2 * rows, J), np.inf)
        due[:, 0] = -np.inf
        adj = np.zeros((2 * rows, J))
        adj[rows:, 1:] = np.where(done, 0.0, np.where(go_on, miss, self.LOG_STOP))
        stopped = np.zeros((2 * rows, J), bool)
        stopped[rows:, 1:] = ~((go_on & told) | done)
        limit = np.zeros((2 * rows, J), np.int64)
        limit[:, 0] = np.tile(np.minimum(ridge + 1, R), 2)
        limit[rows:, 1:] = np.where(done, 0, kk + (go_on & told))
        return {
            "due": due,
            "adj": adj,
            "stopped": stopped,
            "limit": limit,
            "done": done,
            "coast": kk >= R,
            "target": self._pos[di[:, None], kk],
        }

    def _schedule(self, B: _Bank):
        """Silence of slipping tracks with a speed: per track and ridge ahead (time due,
        score adjustment from then, stopped from then, next ridge not reached from then).
        All but the times due come from tables (`_silence_tables`); the times are
        computed for the active tracks only (kernels.posterior.schedule). Cached on the
        bank (banks are immutable)."""
        if B._sched is None:
            B._sched = self._coast_bound(
                B,
                posterior_kernels.schedule(
                    _tracks(B), self._silence, self._skin, self._latency_floor(B)
                ),
            )
        return B._sched

    def _coast_bound(self, B: _Bank, sched: tuple) -> tuple:
        """`sched` (fresh arrays) with the coasts past the last ridge bounded
        (`coast_bound`, COAST_INTERVALS; 0: as it is)."""
        if not self.COAST_INTERVALS or not len(B):
            return sched
        fields = {"s": B.X[:, 0], "t": B.t, "v": B.X[:, 1], "stop": B.stop, "run": B.run}
        fields |= {"dirn": B.dirn, "ridge": B.ridge}
        return coast_bound.bound(
            sched, fields, self._pos, self._last_gaps, self.count, self.COAST_INTERVALS
        )

    @cached_property
    def _last_gaps(self) -> np.ndarray:
        """Per direction, the spacing into the last ridge (`coast_bound.last_gaps`)."""
        if self.COAST_GAP:  # the layout's largest spacing (`_coast`) either way
            return np.full(2, self._coast)
        return coast_bound.last_gaps(self._pos, self.count)

    def _soft_schedule(self, B: _Bank, g: float):
        """The schedule with each due ridge scored by the signal's rise where the track puts
        it (`rise_evidence.silence`; heavy noise, `RISE_EVIDENCE`): the open schedule and
        the ridges read so far cached on the bank."""
        known = self._soft_banks.get(id(B))
        if known is None or known[0] is not B:
            open_sched = posterior_kernels.schedule(
                _tracks(B), self._silence_open, self._skin, self._latency_floor(B)
            )
            known = (B, open_sched, {}, {})
            _put_bounded(self._soft_banks, id(B), known, 2)
        _, open_sched, scored, memo = known
        index = {c.id: c.index for c in self._contacts}
        last = np.fromiter((index.get(int(k), -1) for k in B._i[:, I_LAST]), np.int64, len(B))
        fields = {key: getattr(B, key) for key in ("X", "t", "stop", "run", "dirn", "ridge")}
        return self._coast_bound(B, rise_evidence.silence(
            open_sched, self._silence_tables, fields, last, self._n_in, g, self._log_miss,
            self.LOG_STOP, self.RISE_EVIDENCE, scored, self._rise, int(self.RISE_SILENCE_AHEAD),
            memo,
        ))  # fmt: skip

    def _noisy(self) -> bool:
        """The white noise measured at the samples taken reaches NOISY_WHITE_N (`noise_gate`;
        never with it 0)."""
        if self.NOISY_WHITE_N <= 0:
            return False  # (the gate off: no white-noise lookup)
        white = self.detector.noise.white_at_sample(self._n_in - 1)
        return noise_gate.heavy(white, self.NOISY_WHITE_N)

    def _latency_floor(self, B: _Bank, regime: float | None = None) -> np.ndarray:
        """How late each track's next contact may still be told, at least: the probes'
        latency where its last contact came from a probe (told later than the kink bank
        tells any), else 0. Where the FSR's hysteresis holds the ridge pulses' fall (the
        loop scenes) the kink bank misses many ridges and the probes find them ~0.2 s
        late; a track waits for them as long before its silence is taken for a stop.
        `regime`: `STEP_PROBE_REGIME`'s count for this reading (None: that constant's)."""
        regime = self.STEP_PROBE_REGIME if regime is None else regime
        late = {c.id for c in self._contacts if c.emit_index - c.index > self.detector.lag}
        if not self.STEP_PROBE_WAIT:  # a step probe's contact taken for a stop's step
            late = {k for k in late if k < STEP_IDS}
        elif regime > 0:  # ... unless contacts just before it came late too
            late = self._step_probe_regime(late, int(regime))
        if not late or not len(B):
            return np.zeros(len(B))
        slow = np.fromiter((int(k) in late for k in B._i[:, I_LAST]), bool, len(B))
        return np.where(slow, self.PROBE_WAIT * self._probe_latency, 0.0)

    def _step_probe_regime(self, late: set[int], n: int) -> set[int]:
        """`late` without the step probe's contacts that follow `n` contacts all told in
        time (`STEP_PROBE_REGIME`, `OVERDUE_PROBE_REGIME`): the FSR's hysteresis holds ridge
        pulses run after run (the loop's probes find 21 % of its ridges), so a held ridge
        found late follows other late ones; a late step after contacts told in time is a
        stop's (issue 22, 136321)."""
        if all(k < STEP_IDS for k in late):
            return late
        keep = set(late)
        for at, c in enumerate(self._contacts):  # (in time order: `_add_contact`)
            if c.id in late and c.id >= STEP_IDS:
                before = self._contacts[max(0, at - n) : at]
                if not any(b.id in late for b in before):
                    keep.discard(c.id)
        return keep

    # ------------------------------------------------------------------ reporting
    def _report(self, g: float) -> SlipEstimate:
        out = self._report_kept(g)
        if out.slip or out.speed_mm_s is None:
            self._stopped_at = math.inf
        elif self._stopped_at == math.inf:
            self._stopped_at = g
        if self.ARRIVAL_FLAG_P > 0 and self.ARRIVAL_EMPTY_N > 0:
            out = self._report_arrival(g, out)
        if not out.slip and self.STEP_HOLD > 0:
            out = self._report_step(g, out)
        if not out.slip and self.RAMP_HOLD:
            out = self._report_ramp(g, out)
        if out.slip:
            self._up_t = g  # up by the posterior, its keep, the rail, the arrival or the ramp
            if self.RAMP_ONE_WAY >= 2 and out.speed_mm_s is not None:
                self._ramp_way = 0
        elif self.REFLAG_P > 0:
            out = self._report_reflag(g, out)
        return out

    def _report_reflag(self, g: float, out: SlipEstimate) -> SlipEstimate:
        """`out`, or the slip flagged again by a pulse contact soon after the flag was last
        up (`reflag`: no speed, no direction)."""
        if not math.isfinite(self._up_t):
            return out  # never flagged (a held object): nothing to raise again
        picked = self._reflag.candidate(
            self._contacts,
            lambda cid: arrival_flag.verdict(cid, self._ring, self._ring_id) == PULSE,
            self._up_t,
            self.REFLAG_WITHIN_S,
        )
        if picked is None:
            return out
        p = self._waiting_p(g, picked[1], range(2 * self.count))  # its ridge unknown
        if p < self.REFLAG_P:
            self._reflag.expire()
            return out
        return _flag_only(out, p)

    def _report_step(self, g: float, out: SlipEstimate) -> SlipEstimate:
        """`out`, or the slip held over the chosen track's stop at a step shaped like a
        ridge's until its next ridge would be decided (`step_hold`: no speed, no direction)."""
        if self._cache is None or not len(self._tracks):
            return out
        chosen = self._cache[1]
        if chosen is None or not chosen[1]:
            return out
        h = chosen[0]
        if not (math.isfinite(h.stop) and h.v > 0 and self._up_t >= h.stop):
            return out  # not a step's stop (silence, braked), or the flag not up past it
        shape = step_shape.UNTOLD
        for c in reversed(self._contacts):
            if c.t_s == h.stop:
                shape = self._shapes.get(c.id, step_shape.UNTOLD)
                break
        if shape != step_shape.RIDGE_LIKE:
            return out
        sigma = 0.0  # the next ridge's time, never the one after (STEP_HOLD_SKIP 0)
        if self.STEP_HOLD_SKIP:
            tau = h.stop - h.t
            sigma = math.sqrt(max(h.p00 + 2.0 * tau * h.p01 + tau * tau * h.p11, 0.0))
        seen = posterior_kernels.stop_seen(
            h.s, h.v, h.stop, sigma, h.dirn, h.ridge, self._pos, self._step_hold_K
        )
        if not step_hold.holds(shape, self._up_t, h.stop, g, float(seen), self.STEP_HOLD_MAX_S):
            return out
        if self.STEP_HOLD_AFTER_S > 0:
            after = [
                c.t_s
                for c in self._contacts
                if c.t_s > h.stop
                and not (
                    self.STEP_HOLD_AFTER_UNRIDGED
                    and self._shapes.get(c.id) == step_shape.RIDGE_LIKE
                )
            ]
            if step_hold.unlinked(after, g, self.STEP_HOLD_AFTER_S):
                return out  # a contact after the step no moving track took up: the stop
        return _flag_only(out, 0.5)  # the step tells neither a stop nor a speed

    @cached_property
    def _step_hold_K(self) -> np.ndarray:
        """The posterior's constants with the step's wait STEP_HOLD (`step_hold`)."""
        return step_hold.hold_constants(self._K, self.STEP_HOLD)

    def _report_ramp(self, g: float, out: SlipEstimate) -> SlipEstimate:
        """`out`, or the slip held while the level ramps, the flag up within
        RAMP_HOLD_WITHIN_S (`level_ramp`: no speed, no direction)."""
        if g - self._up_t > self.RAMP_HOLD_WITHIN_S:
            return out  # never up (a held object), or too long ago
        m = max(1, round(self.RAMP_WINDOW_S * self.fs_hz))
        span = (int(self.RAMP_STEPS) + 1) * m
        over_stop = out.speed_mm_s is not None and self.RAMP_HOLD < 2
        if over_stop:
            since = g - span / self.fs_hz - self._stopped_at
            if not (self.RAMP_OVER_STOP and since >= self.RAMP_OVER_STOP_S):
                return out  # the posterior's stop (or its windows reach back to it)
        white = self.detector.noise.white_at_sample(self._n_in - 1)
        if white is None:
            return out
        slope = self.RAMP_OVER_STOP_SLOPE_N_S if over_stop else self.RAMP_SLOPE_N_S
        step = level_ramp.step_min_n(self.RAMP_WINDOW_S, self.fs_hz, slope, self.RAMP_Z, white)
        if g - self._up_t <= 1.5 * self.update_period_s:  # the flag up at the last update
            step *= self.RAMP_KEEP_SHARE
        x = self._recent.held(self._n_in - span, self._n_in)
        way = level_ramp.ramp_way(x, int(self.RAMP_STEPS), step)
        if not way or (way < 0 and over_stop and self.RAMP_OVER_STOP >= 2):
            return out  # (2: over a stop only up: a pulse's tail decays after a stop)
        if self.RAMP_ONE_WAY and self._ramp_way and way != self._ramp_way:
            return out  # the level turned: no coverage ramp (a pulse's tail in a stick)
        # read last: the commands' windows are looked up every hand lag
        if self._grip_moves(g - span / self.fs_hz - self.RAMP_GRIP_SETTLE_S, g) and not (
            self.RAMP_GRIP_SHARE and self._ramps_past_grip(x, g, step)
        ):
            return out  # the commanded grip moves the level (or it settles), no more
        self._ramp_way = way
        return _flag_only(out, 0.5)  # a ramp tells motion, not how fast

    def _ramps_past_grip(self, x: np.ndarray | None, g: float, step_n: float) -> bool:
        """Whether the samples `x` (the ramp's, ending at g) still ramp up with the
        commanded grip's share taken out (each sample over the grip then, times the grip
        now): a held object's level follows its grip, a sliding object's covered length
        ramps it on past that (the loop raises the grip mid-slide)."""
        if x is None:
            return False
        t = g - (np.arange(len(x))[::-1] + 1) / self.fs_hz
        grip = self.grip_commands.grip_at(t)
        if not np.all(grip > 0):
            return False
        steps = int(self.RAMP_STEPS)
        return level_ramp.ramp_way(x / grip * grip[-1], steps, step_n) == 1

    def _grip_moves(self, start_s: float, end_s: float) -> bool:
        """Whether a commanded grip change's window (`efference`: at least three hand lags
        long, a slew's |dF| / rate more) overlaps [start_s, end_s]: read every lag (10 ms
        at least)."""
        commands = self.grip_commands
        if not len(commands):
            return False
        every = max(commands.follow.lag_s, 0.01)
        at = end_s
        while at > start_s - every:
            if commands.change_at(max(at, start_s)) is not None:
                return True
            at -= every
        return False

    def _report_arrival(self, g: float, out: SlipEstimate) -> SlipEstimate:
        """`out`, or the slip flagged from its arrival onto an unloaded sensor while the
        posterior flags none (`arrival_flag`: no speed, no direction)."""
        arrival = self._arrival_contact()
        arrival_id = -1 if arrival is None else arrival[0]
        if not self._arrival_flag.note(arrival_id, out.slip) or out.slip:
            return out
        assert arrival is not None  # `note` is False without an arrival
        _, arrived_s, onset = arrival
        if out.speed_mm_s is not None and not self.ARRIVAL_FLAG_OVER_STOP:
            return out  # the posterior's stop
        ends = (NOISE,) if self.ARRIVAL_STEP_KEEP else (STEP, NOISE)
        if arrival_flag.verdict(arrival_id, self._ring, self._ring_id) in ends:
            return out  # the contact a grip's press or noise's pulse
        if self._reads_unloaded(self._n_in):
            return out  # nothing lies on the skin now: the contact was no edge sliding on
        if arrival_flag.stalled(
            self._recent.mean, self._n_in, onset, self.fs_hz, self.ARRIVAL_STALL_N
        ):
            self._arrival_flag.expire()  # no more skin covered: it stopped
            return out
        p = self._waiting_p(g, arrived_s, (0, self.count))  # its first ridge, either way
        if p < self.ARRIVAL_FLAG_P:
            self._arrival_flag.expire()
            return out
        return _flag_only(out, p)

    def _waiting_p(self, g: float, contact_s: float, rows: Sequence[int]) -> float:
        """P(the next ridge after a contact at `contact_s` on one of `rows` is not yet due
        at g), the time on the rail since it not counted (`arrival_flag.waiting_p`)."""
        elapsed = g - contact_s - self._rail_s(contact_s, g)
        return arrival_flag.waiting_p(elapsed, rows, self._waiting, self._K, self._max_latency)

    def _arrival_contact(self) -> tuple[int, float, int] | None:
        """The last contact held that came onto an unloaded sensor (`_onto_empty_skin`):
        (id, t_s, onset index), or None. Looked up again only after the contacts held or
        their verdicts changed (`_arrival_stale`), not at every update."""
        if self._arrival_stale:
            self._arrival_stale = False
            self._arrival_at = None
            for c in reversed(self._contacts):
                if self._unloaded.get(c.id):
                    self._arrival_at = (c.id, c.t_s, c.index)
                    break
        return self._arrival_at

    def _report_kept(self, g: float) -> SlipEstimate:
        """The posterior's report, its flag kept while moving tracks hold half the mass
        under the wider evidence rule (`flag_keep`), once it was up."""
        out = self._report_evident(g)
        keep = self.KEEP_FLAG or self.KEEP_FLAG_UNHOLD
        recent = self._flagged or g - self._flag_t <= self.KEEP_FLAG_WITHIN_S
        if not out.slip and keep and recent and len(self._tracks):
            p_moving = self._keep_share(g)
            if p_moving >= self.KEEP_FLAG_SHARE:  # kept: the flag, no speed (`flag_keep`)
                out = _flag_only(out, p_moving)
        if not out.slip and self.RAIL_HOLD and self._rail_holds(g):
            # the rail tells neither a stop nor a slip: the confidence of a coin's toss
            out = _flag_only(out, 0.5)
        self._flagged = out.slip
        if out.slip:
            self._flag_t = g
        return out

    def _rail_holds(self, g: float) -> bool:
        """Is the flag held at g for the rail the sensor sits on (`rail_hold`)? The rail is
        told per noise block, after the detector's block: that long late."""
        noise = self.detector.noise
        lag_s = (noise.block + self._block + 1) / self.fs_hz
        return rail_hold.holds(
            noise.blind, g, self._flag_t, lag_s, (noise.block + 1) / self.fs_hz,
            self.RAIL_HOLD_BEFORE_S, self.RAIL_HOLD_AFTER_S,
        )  # fmt: skip

    def _keep_share(self, g: float) -> float:
        """P(moving) at g under the widened evidence rule (`flag_keep.widened`): read once
        per posterior cached (`_report`: valid as long as it is)."""
        if self._kept is None or self._kept[0] is not self._cache:
            out = self._posterior_kernel(g, self._keep_tables)
            self._kept = (self._cache, float(out[4]))
        return self._kept[1]

    @cached_property
    def _keep_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """`_evidence_tables` with the evidence widened to KEEP_FLAG (`flag_keep`)."""
        weight, bonus, evident, hold = self._evidence_tables
        packed = np.arange(evident.shape[1])
        pulses, steps, noise = packed & 7, (packed >> 3) & 7, packed >> 6
        wide = flag_keep.widened(evident, pulses, steps, noise, int(self.KEEP_FLAG))
        if self.KEEP_FLAG_UNHOLD:  # a told step or noise pulse still holds (`flag_keep`)
            hold = flag_keep.unheld(hold, (UNKNOWN, UNCLEAR))
        return weight, bonus, wide, hold

    def _report_evident(self, g: float) -> SlipEstimate:
        force = self._force
        if not len(self._tracks):
            self._told_way = 0
            return SlipEstimate(g, False, None, None, force, 1.0)
        # the posterior changes only when a contact or verdict arrives or silence lasts;
        # the agreement (confidence) is refreshed every REFRESH_S
        if self._cache is None or g >= self._cache[0]:
            self._cache = self._posterior(g)
        _, chosen, p_slip, agree, odds, magnitude = self._cache
        if chosen is None:
            self._told_way = 0
            return SlipEstimate(g, False, None, None, force, min(1.0, max(0.0, 1.0 - p_slip)))
        h, stopped, limit = chosen
        n, run = h.n, h.run
        if stopped:
            self._told_way = 0
            s, _, sigma = self._where(h, g, True, limit)
            conf = agree * self._maturity(n) / (1.0 + (sigma / self.CONF_POS_MM) ** 2)
            x = self._on_skin(self._x1(h, s))
            return SlipEstimate(g, False, 0.0, x, force, min(1.0, max(0.0, conf)))
        # the direction is told once the chosen track has an interval ratio (three
        # contacts) and the tracks moving its way outweigh the others by LOG_REPORT_ODDS
        # once told, the direction is kept while the odds stay above LOG_KEEP_ODDS: silence
        # between contacts moves the odds, not the evidence for a way
        bar = self.LOG_KEEP_ODDS if h.dirn == self._told_way else self.LOG_REPORT_ODDS
        told = run > 1 and n >= self.DIRECTION_CONTACTS and odds >= bar
        self._told_way = h.dirn if told else 0
        if told and self._withhold(h, g):  # its next ridge overdue: flagged, no speed
            bound = self._speed_range(magnitude)
            return SlipEstimate(g, True, None, None, force, min(1.0, max(0.0, p_slip)), None,
                                None, *bound)  # fmt: skip
        if told:
            s, speed, sigma = self._where(h, g, False, limit)
            p_way = 1.0 / (1.0 + math.exp(-odds))  # P(this way)
            conf = agree * self._maturity(n) * p_way / (1.0 + (sigma / self.CONF_POS_MM) ** 2)
            # told at the last contact: since then the slip may have turned
            conf *= math.exp(-max(0.0, g - h.t) * self.TURN_PER_S)
            x = self._x1(h, s)  # slipping past an end: extrapolated with the speed (coast)
            bound = self._speed_range(magnitude, speed)
            return SlipEstimate(
                g, True, max(0.0, speed), x, force, min(1.0, max(0.0, conf)), h.dirn,
                p_way, *bound,
            )  # fmt: skip
        # no direction yet (or never, on a symmetric skin): the speed whichever way, when
        # the slipping tracks agree on it, else the range they allow
        fast, share, low, high = magnitude
        known = run == 1 and n > self.DIRECTION_CONTACTS and odds >= self.LOG_REPORT_ODDS
        held = self._on_skin(self._x1(h, h.s)) if known else None  # restarted: where, not speed
        conf = min(1.0, max(0.0, p_slip))
        # the speed is given when the hypotheses agree on it (or enough of them do, and
        # none of the others is far off), or when the likeliest has an interval ratio to go
        # by (three contacts): then with the agreement as confidence
        narrow = share >= self.SPEED_NARROW_SHARE and high < self.SPEED_RANGE_MAX * low
        agreed = share >= self._agree_share() or narrow
        ratio = fast is not None and fast.n >= self.DIRECTION_CONTACTS
        given = fast is not None and (agreed or (ratio and share >= self.SPEED_RATIO_SHARE))
        if not given or self._withhold(fast, g):
            bound = self._speed_range(magnitude)
            return SlipEstimate(g, True, None, held, force, conf, None, None, *bound)
        assert fast is not None
        _, speed, _ = self._where(fast, g, False, self.count)
        conf = share * self._maturity(fast.n) * math.exp(-max(0.0, g - fast.t) * self.TURN_PER_S)
        bound = self._speed_range(magnitude, speed)
        return SlipEstimate(
            g, True, max(0.0, speed), held, force, min(1.0, max(0.0, conf)), None, None, *bound
        )

    def _agree_share(self) -> float:
        """The share of the slipping posterior that must agree on a speed: lower in heavy
        noise (SPEED_AGREE_SHARE_NOISY, while the rise evidence's gate is open)."""
        noisy = self.SPEED_AGREE_SHARE_NOISY
        if noisy is None or not self._rise.blind(self.RISE_EVIDENCE_GATE):
            return self.SPEED_AGREE_SHARE
        return noisy

    def _withhold(self, h: _One, g: float) -> bool:
        """Is the speed of track `h` (read from the bank now) withheld at g: its last
        contact a step the level lay flat after (`flat_step_speed`, FLAT_STEP_SPEED), or
        its next ridge overdue (`_overdue`)?"""
        last = int(self._tracks._i[h.index, I_LAST])
        if self.FLAT_STEP_SPEED and flat_step_speed.withheld(last, self._steps):
            ids = self._tracks._i[h.index, I_IDS : I_LAST + 1]
            if self.FLAT_STEP_SPEED < 2 or flat_step_speed.lone_pulse(self._told_pulses(ids)):
                return True
        return self._overdue(h, g)

    def _told_pulses(self, ids: np.ndarray) -> int:
        """How many of the contacts `ids` are told a pulse (their verdicts still in the ring)."""
        return sum(arrival_flag.verdict(int(k), self._ring, self._ring_id) == PULSE for k in ids)

    def _overdue(self, h: _One, g: float) -> bool:
        """Is the speed of track `h` (read from the bank now) withheld at g: its next ridge
        overdue by the report's schedule (`overdue_speed`, OVERDUE_SPEED; the time its
        contact spent on the rail not counted)? The times due are read once per bank."""
        if not self.OVERDUE_SPEED:
            return False
        if self.OVERDUE_NOISY == 0 and self._silence_read_soft():
            return False  # heavy noise: ridges are missed far more often than DETECT_P says
        if self.OVERDUE_NOISY_WHITE == 0 and self._noisy():
            return False  # ... or the white noise reads heavy before any pulse is told
        B = self._tracks
        last = int(B._i[h.index, I_LAST])
        if self.OVERDUE_LATCH and overdue_speed.latched(
            last, self._withheld, self._withheld_s, g, self.OVERDUE_LATCH_S
        ):
            return True  # no contact since a speed from it went overdue (`overdue_speed`)
        if self._due is None or self._due[0] is not B:
            due = overdue_speed.next_due_s(
                _tracks(B),
                self._silence,
                self._report_skin,
                self.OVERDUE_PROBE_WAIT * self._latency_floor(B, self._overdue_regime),
                self._overdue_columns,
            )
            self._due = (B, due)
        late = overdue_speed.overdue(float(self._due[1][h.index]), g, self._rail_s(h.t, g))
        if late and last != self._withheld:
            self._withheld, self._withheld_s = last, g
        return late

    @property
    def _overdue_regime(self) -> float | None:
        """The step-probe regime the report's latency floor reads (`OVERDUE_PROBE_REGIME`;
        None: the posterior's, `STEP_PROBE_REGIME`)."""
        return self.OVERDUE_PROBE_REGIME if self.OVERDUE_PROBE_REGIME > 0 else None

    @cached_property
    def _overdue_columns(self) -> np.ndarray:
        """Per silence-table row, the ridge ahead whose silence withholds a speed."""
        log_stop = self.LOG_STOP if self.LOG_STOP_REPORT is None else self.LOG_STOP_REPORT
        log_p = overdue_speed.report_log_p(
            self.OVERDUE_MISS_P, log_stop if self.OVERDUE_STOP_RIDGE else None
        )
        return overdue_speed.report_columns(self._log_miss, self.SCHEDULE, log_p)

    @cached_property
    def _report_skin(self) -> tuple:
        """The skin with the report's constants (`overdue_speed.report_constants`)."""
        K = overdue_speed.report_constants(self._K, self.OVERDUE_SPAN_REL, self.OVERDUE_LATE_REL)
        return tuple(posterior_kernels.Skin(pos=self._pos, K=K))

    def _maturity(self, n: int) -> float:
        """How far n contacts make an estimate (the confidence grows as 1 - exp(...))."""
        return 1.0 - math.exp(-(n - 1) / self.CONF_CONTACTS)

    @staticmethod
    def _speed_range(
        magnitude: tuple, speed: float | None = None
    ) -> tuple[float | None, float | None]:
        """The range of speeds the slipping tracks allow (None, None without one), widened
        to hold a reported speed (extrapolated from the last contact, it may lie outside
        the tracks' own)."""
        _, _, low, high = magnitude
        if not (math.isfinite(low) and math.isfinite(high)):
            return None, None
        if speed is None:
            return low, high
        return min(low, max(0.0, speed)), max(high, max(0.0, speed))

    def _x1(self, h: _One, s: float) -> float:
        return s if h.dirn > 0 else self.length - s

    def _on_skin(self, x: float) -> float:
        """A position held (stopped) is held on the skin: past its ends the edge meets no
        ridge, so where it stopped there is not observed."""
        return min(self.length, max(0.0, x))

    def _where(self, h: _One, g: float, stopped: bool, limit: int) -> tuple[float, float, float]:
        """(travel of the edge from the first ridge met, speed, sigma) of one track at g:
        extrapolated with its speed and acceleration, less the dip still recovering; held
        where it stopped (kernels.posterior.where). Its acceleration is capped so that it
        has not yet reached where its next contact would have been told by now
        (`SILENCE_REACH`, `_reach_mm`): the contact's latency and time on the rail
        (`_blind`) show nothing."""
        reach, silent = math.inf, 0.0
        if self.SILENCE_REACH > 0 and not stopped and math.isnan(h.stop):
            reach = self.SILENCE_REACH * float(self._reach_mm[(1 - h.dirn) // 2, h.ridge])
            silent = g - h.t - self._silence_latency - self._rail_s(h.t, g)
        return posterior_kernels.where(h.numbers, g, stopped, limit, (reach, silent), self._skin)

    @cached_property
    def _silence_latency(self) -> float:
        """The longest a ridge contact takes to be told (the kink bank's or the probes')."""
        return max(self._max_latency, self._probe_latency)

    @cached_property
    def _reach_mm(self) -> np.ndarray:
        """Per (direction, ridge of the last contact): how far a track may travel unseen
        from there - the distance to the next ridge, plus each further one's spacing times
        P(all ridges before it missed), the coast past the last (never seen) so weighted
        too; inf from the last ridge (no contact can come)."""
        R = self.count
        out = np.full((2, R), np.inf)
        for di in range(2):
            for r in range(R - 1):
                reach, unseen = 0.0, 1.0
                for k in range(r + 1, R + 1):
                    reach += unseen * float(self._pos[di, k] - self._pos[di, k - 1])
                    unseen *= 1.0 - float(self._pd[di, k])
                out[di, r] = reach
        return out

    def _posterior(self, g: float):
        """(valid until, chosen (index, stopped, limit) or None, P(slip), agreement,
        direction log odds, magnitude) at g; magnitude: (the best slipping track with a
        speed or None, the share agreeing on its speed either way, the speed range).

        Agreement: the share of the posterior that puts the edge within AGREE_MM of
        the chosen track's position (and, slipping, its speed within AGREE_SPEED).
        Direction log odds: the posterior mass of the slipping tracks, and the tracks just
        started (a slip starting or reversing), moving the chosen track's way over that
        moving the other way.
        """
        B = self._tracks
        (until, i, is_stopped, lim, p_slip, agree, odds, fast, share, low, high) = (
            self._posterior_kernel(g, self._evidence_tables)
        )
        magnitude = (_One(B, fast) if fast >= 0 else None, share, low, high)
        if i < 0:
            return (until, None, p_slip, 0.0, -math.inf, magnitude)
        return (until, (_One(B, i), is_stopped, lim), p_slip, agree, odds, magnitude)

    def _posterior_kernel(self, g: float, tables: tuple) -> tuple:
        """`kernels.posterior.posterior` at g on the bank now, with the evidence tables
        `tables` (`_evidence_tables`, or `_keep_tables`)."""
        B = self._tracks
        sched = self._soft_schedule(B, g) if self._silence_read_soft() else self._schedule(B)
        blind = self._blind(B.t, g)  # time on the rail since each track's contact: unseen
        verdicts = tuple(posterior_kernels.Verdicts(self._ring, self._ring_id, *tables))
        return posterior_kernels.posterior(
            g, self._null, _tracks(B), sched, _NO_BLIND if blind is None else blind,
            blind is not None, verdicts, self._waiting, self._skin,
        )  # fmt: skip

    def _silence_read_soft(self) -> bool:
        """Whether the due ridges' silence is scored by the rise read there (`rise_evidence`:
        heavy noise, the told pulses under RISE_EVIDENCE_GATE) rather than by DETECT_P."""
        return bool(self.RISE_EVIDENCE) and self._rise.blind(self.RISE_EVIDENCE_GATE)

    def _rail_s(self, t_s: float, g: float) -> float:
        """Seconds of [t_s, g] the sensor sat on its rail (`_blind` for one time; 0: none)."""
        if not self.detector.blind:
            return 0.0
        blind = self._blind(np.array([t_s]), g)
        return 0.0 if blind is None else float(blind[0])

    def _blind(self, t: np.ndarray, g: float) -> np.ndarray | None:
        """Seconds of [t, g] the sensor sat on its upper rail (no contact can show there);
        None when it sat there for none of them."""
        out = None
        for r0, r1 in self.detector.blind:
            if r1 <= float(t.min(initial=g)) or r0 >= g:
                continue
            if out is None:
                out = np.zeros(len(t))
            out += np.clip(np.minimum(g, r1) - np.maximum(t, r0), 0.0, None)
        return out

    @cached_property
    def _evidence_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """What the pulse verdicts on a track's recent contacts say (is it a slip, a score
        bonus; kernels.posterior), read off their counts packed as pulses + 8 steps + 64 noise: the
        weight of each verdict in such a count, the bonus per count, and whether it is
        evident per count and min(n, 4) contacts (rows 5-9: none, a restart held by its
        contact's verdict), and which verdicts of a restart contact hold it
        (RESTART_CONFIRM). (A ring slot never written holds id -1 and no verdict: an
        unused id, -1, reads no verdict there.)"""
        weight = np.zeros(max(UNKNOWN, PULSE, STEP, UNCLEAR, NOISE) + 1, np.int64)
        weight[PULSE], weight[STEP], weight[NOISE] = 1, 8, 64  # counts <= IDS < 8 each
        packed = np.arange(64 * IDS + 8 * IDS + IDS + 1)
        pulses, steps, noise = packed & 7, (packed >> 3) & 7, packed >> 6
        bonus = np.minimum(pulses, 2) * self.LOG_PULSE - steps * self.LOG_STEP
        n = np.arange(5)[:, None]
        # enough contacts that fit a track are a slip when none is a step or noise's pulse
        evident = (n >= 2) & ((pulses > 0) | ((n >= self.EVIDENT_CONTACTS) & (steps + noise == 0)))
        hold = restart_confirm.hold_table(
            len(weight), STEP, NOISE, UNCLEAR, UNKNOWN, self.RESTART_CONFIRM,
            bool(self.RESTART_CONFIRM_TWO),
        )  # fmt: skip
        return weight, bonus, np.concatenate([evident, np.zeros_like(evident)]), hold

    @cached_property
    def _K(self) -> np.ndarray:
        """The posterior kernels' constants (kernels.posterior.NAMES)."""
        return posterior_kernels.constants(
            negligible=self.NEGLIGIBLE,
            refresh_s=self.REFRESH_S,
            v_min_mm_s=V_MIN_MM_S,
            acc_floor=self.ACC_FLOOR,
            dip_recovery_s=self.DIP_RECOVERY_S,
            detect_mm=self.DETECT_MM,
            late_rel=self.LATE_REL,
            min_latency_s=self._min_latency,
            max_latency_s=self._max_latency,
            coast_mm=self._coast,
            coast_s=self.COAST_S,
            length_mm=self.length,
            agree_mm=self.AGREE_MM,
            agree_speed=self.AGREE_SPEED,
            direction_contacts=self.DIRECTION_CONTACTS,
            log_report_odds=self.LOG_REPORT_ODDS,
            speed_prior_mm_s=self.SPEED_PRIOR_MM_S,
            erf_scale=self._erf_scale,
            bound_share=self.BOUND_SHARE,
            span_max_rel=self.SPAN_MAX_REL,
            brake_z=self.BRAKE_Z,
            step_stop_wait=self.STEP_STOP_WAIT,
            last_brake_z=self.LAST_BRAKE_Z,
            rest_share=self.REST_SHARE,
            silence_brake=self.SILENCE_BRAKE,
            restart_agree_rel=self.RESTART_AGREE_REL,
        )

    @cached_property
    def _silence(self) -> tuple:
        """The silence tables as `kernels.posterior.schedule` takes them (a `Silence`)."""
        return tuple(posterior_kernels.Silence(**self._silence_tables))

    @cached_property
    def _waiting(self) -> tuple:
        """The waiting tables as `kernels.posterior.posterior` takes them (a `Waiting`)."""
        return tuple(posterior_kernels.Waiting(*self._waiting_tables))

    @cached_property
    def _skin(self) -> tuple:
        """The ridge positions and the constants, as the posterior's kernels take them."""
        return tuple(posterior_kernels.Skin(pos=self._pos, K=self._K))

    @cached_property
    def _waiting_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The waiting tracks' tables (P(no contact yet), kernels.posterior) by row
        di * count + ridge."""
        rows = 2 * self.count
        return (
            self._ahead_log.reshape(rows, -1),
            self._ahead_finite.reshape(rows, -1),
            self._ahead_before.reshape(rows, -1),
        )

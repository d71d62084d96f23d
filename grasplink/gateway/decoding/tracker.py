"""TrackerDecoder ("tracker"): slip, speed and position by tracking ridge contacts.

Physics: the leading edge of a slipping object makes one pulse each time it
reaches a ridge; ridge i sits at x_i = cumsum([0, *spacings])[i]. The contact
*times* are all that matter (amplitudes and shapes vary), and the contact
sequence is a position measurement: contact k happened when the edge was at
a ridge. Which ridge, and in which direction the object moves, is unknown
and must be inferred from the timing pattern (thesis ch. 5.2: with constant
speed, successive intervals are in the ratio of the spacings).

Design (a small multiple-hypothesis tracker):

* `contacts.ContactDetector` turns the signal into contact onsets (sub-sample
  times) and, later, tells whether each one fell back like a pulse.
* A hypothesis is a direction, the ridge of the last contact it assigned,
  and a Kalman filter on the distance travelled, the speed and the distance
  each ridge's speed dip costs (ridge positions are measurements at contact
  times). Each assignment is tried with a steady speed (little process
  noise: the dip loss stays identifiable) and with a changing one (much
  more): the likelier survives, so accelerating or braking slips are
  followed. Each new contact branches every hypothesis:
  assign it to the next ridge, to a later one (missed contacts: weak pulses
  after short spacings), or call it spurious (tip pulses, noise, grip
  changes). A contact may also start a new track at any ridge, either way,
  with a prior proportional to the distance from which a slip reaches that
  ridge first (the spacing before it; an approach length for the end ridge).
* Scores are log-likelihoods of the contact *times*: with two contacts the
  speed is D/T, scored by a broad log-normal speed prior (density
  p(ln v)/T); from the third on, the Kalman innovation (robust: a Gaussian
  plus a broad floor). Hypotheses with the same recent
  history are merged, the best `max_hypotheses` kept; memory is bounded.
* Silence is evidence too: a hypothesis that expected a ridge well before
  now and saw none either missed it (log(1 - P_D) for that ridge) or the
  slip has stopped (a fixed cost) - whichever is likelier. A stopped track
  reports slip False, speed 0 and its last position, held below the ridge
  it never reached.
* Output: posterior over hypotheses (plus "no slip": every contact is
  clutter). Slip is flagged when tracks with two or more contacts (one of
  which fell back like a pulse, or four or more contacts) hold half the
  mass; speed and position come from the best such track, position
  extrapolated at its speed from its last ridge (and no further than the
  next ridge it has not reached yet). Confidence is the mass of hypotheses
  that agree with that position (within 3 mm) and speed (within 15 %),
  discounted by the position's own uncertainty - ambiguous layouts split
  the mass and so give low confidence rather than a confident wrong answer.
* The direction must be told by the contacts, not by the priors: speed
  and position are given only when the best track has three contacts (an
  interval ratio; two contacts fit some alignment either way) and explains
  the contacts at least 9 times better than the best track moving the
  other way. Until then a slip is reported with speed and position None
  (confidence P(slip)); on a symmetric skin that is always the case.

Contacts are decided with a delay (longest detector scale), sometimes out of
time order; the tracker keeps snapshots of its last few steps and replays
them when an earlier contact arrives, so results do not depend on how the
input is chunked.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from grasplink.gateway.decoding.base import DEFAULT_UPDATE_S, Decoder, SlipEstimate, StaticForce
from grasplink.gateway.decoding.onsets import ContactDetector, ContactEvent, PulseCheck

V_MIN_MM_S = 2.0
V_MAX_MM_S = 400.0


class _Track:
    """One hypothesis: direction, last ridge reached, Kalman state at its last contact.

    State: s (edge position along the travel, mm), v (speed without dips,
    mm/s), d (distance lost to the speed dip at each ridge, mm); covariance
    p00 .. p22. `m` is the dip memory: the not yet recovered share of the
    dips so far, in units of d (1 right after a contact).
    """

    __slots__ = (
        "crossings",
        "d",
        "direction",
        "evidence",
        "first",
        "ids",
        "m",
        "n",
        "p00",
        "p01",
        "p02",
        "p11",
        "p12",
        "p22",
        "ridge",
        "s",
        "schedule",
        "score",
        "sig",
        "t",
        "v",
    )

    def __init__(
        self,
        direction: int,
        ridge: int,
        t: float,
        s: float,
        score: float,
        ids: tuple[int, ...],
        sig: float,
    ):
        self.direction = direction
        self.sig = sig  # timing sigma of the last contact
        self.ridge = ridge  # index along the travel order
        self.t = t
        self.s = s
        self.v = self.d = 0.0
        self.m = 1.0
        self.p00 = self.p01 = self.p02 = self.p11 = self.p12 = self.p22 = 0.0
        self.n = 1
        self.score = score
        self.ids = ids  # ids of the last assigned contacts, newest last
        self.first = ids[0]  # id of the contact the track started at
        self.schedule: list[tuple[float, float, bool, int]] | None = None
        self.crossings: list[tuple[float, float, float]] | None = None
        self.evidence: tuple | None = None  # (verdict count, _evidence result) cache

    def copy(self) -> _Track:
        c = _Track.__new__(_Track)
        c.crossings, c.d, c.direction, c.evidence = (
            self.crossings,
            self.d,
            self.direction,
            self.evidence,
        )
        c.first, c.ids, c.m, c.n, c.p00 = self.first, self.ids, self.m, self.n, self.p00
        c.p01, c.p02, c.p11, c.p12, c.p22 = self.p01, self.p02, self.p11, self.p12, self.p22
        c.ridge, c.s, c.schedule, c.score = self.ridge, self.s, self.schedule, self.score
        c.sig, c.t, c.v = self.sig, self.t, self.v
        return c


class TrackerDecoder(Decoder):
    """Contact tracker: multiple hypotheses over (direction, ridge), Kalman speed."""

    name = "tracker"

    # model constants (see module doc); all times in s, distances in mm
    P_DETECT_MAX = 0.9  # chance a ridge contact is detected, after a long spacing
    P_DETECT_MIN = 0.5  # ... after a very short one (its pulse is small and merges)
    LOG_CLUTTER_IDLE = math.log(0.01)  # spurious contacts per s without slip
    LOG_NEW_TRACK = math.log(0.01)  # slips starting per s
    CLUTTER_PER_S = 0.05  # spurious contacts per s (detector false alarms, grip changes)
    P_TIP = 0.3  # extra contacts per ridge contact while slipping (tipping front edge)
    RATE_WINDOW_S = 1.0  # contacts seen in this window set the rate of tip contacts
    LOG_STOP = math.log(0.2)  # a slip stops before the next ridge
    ROBUST_FLOOR = 0.05  # weight of the broad part of the contact-time likelihood
    SIGMA_POS_MM = 0.3  # ridge-contact position noise (ridge compliance, speed dips)
    SPEED_WALK = 0.03  # relative speed change (1 sigma) per sqrt(SPEED_WALK_MM) of travel
    SPEED_WALK_MM = 10.0
    SPEED_WALK_CHANGING = 0.3  # ... while the slip speeds up or slows down
    LOG_SPEED_CHANGE = 0.0  # prior log odds changing : steady at each contact (the data decide)
    DIP_RECOVERY_S = 0.05  # the speed recovers from a ridge's dip within about this time
    DIP_PRIOR_MM = 1.0  # prior sigma of the distance lost at each ridge (mean 0)
    DIP_MAX_MM = 1.5
    SPEED_INIT_REL = 0.1  # relative speed uncertainty from two contacts (besides timing)
    LATE_REL = 0.15  # a contact may come this share of its interval late (speed changes)
    LOG_PULSE = math.log(8.0)  # a contact that fell back like a pulse: likelier a slip
    LOG_STEP = math.log(3.0)  # a contact that rose and stayed (a grip step): likelier not
    SPEED_PRIOR_MM_S = 35.0  # slips are mostly 10-120 mm/s: log-normal prior on the speed
    SPEED_PRIOR_LOG_SIGMA = 1.0
    MAX_SKIP = 2  # missed contacts allowed between two detected ones
    STRONG_Z = 60.0  # ridge contacts: strengths spread log-uniformly up to about this
    STRENGTH_MIN, STRENGTH_MAX = math.log(0.1), math.log(3.0)
    REFRESH_S = 0.2  # how often silence (and the agreement) is re-scored between contacts
    NEGLIGIBLE = 25.0  # hypotheses this far (log) below the best are left out of the posterior
    MAX_SPEED_JUMP = 2.0  # largest speed change between two contacts
    START_CONTACTS = 2  # a slip may start at any of the last this many contacts
    PER_START = 4  # tracks kept per start contact, beyond the best max_hypotheses
    DETECT_MM = 1.2  # travel after a contact before the detector has decided it
    DETECT_BLOCK_S = 0.03  # the detector runs on whole blocks of this length (by default)
    AGREE_MM = 3.0
    AGREE_SPEED = 0.15
    CONF_POS_MM = 3.0  # the position's own sigma halves the confidence at this value
    CONF_CONTACTS = 2.0  # confidence grows as 1 - exp(-(contacts - 1) / this)
    # a signed speed only when the best track has an interval ratio (three contacts) and
    # explains the contacts at least 9 times better than the best one moving the other
    # way (between the two, P(direction) >= 0.9)
    DIRECTION_CONTACTS = 3
    LOG_DIRECTION_ODDS = math.log(9.0)

    def __init__(
        self,
        layout_mm: Sequence[float],
        fs_hz: float,
        *,
        update_period_s: float = DEFAULT_UPDATE_S,
        max_hypotheses: int = 24,
        history: int = 8,
        detect_block_s: float | None = None,
        detector: ContactDetector | None = None,
    ):
        super().__init__(layout_mm, fs_hz, update_period_s=update_period_s)
        geometry = self.geometry
        x = geometry.ridges_mm
        self.length = geometry.length_mm
        self.count = len(x)
        spacings = geometry.spacings_mm
        # travel-order ridge positions and the spacing crossed before each ridge
        self._pos = {1: x.copy(), -1: (self.length - x[::-1]).copy()}
        # where a slip starts is unknown: any edge position up to a skin length before
        # the first ridge met is as likely as any within the skin
        lead = self.length
        self._coast = float(np.max(spacings))  # how far past the last ridge a slip goes on
        before = {
            1: np.concatenate([[lead], spacings]),
            -1: np.concatenate([[lead], spacings[::-1]]),
        }
        total = 2.0 * float(sum(before[1]))
        self._log_prior = {d: [math.log(b / total) for b in before[d]] for d in (1, -1)}
        self._p_detect = {d: [self._detect_probability(b) for b in before[d]] for d in (1, -1)}
        # per start ridge: (log distance, P(all missed up to it)) of every ridge ahead
        self._ahead: dict[int, list[list[tuple[float, float]]]] = {}
        for d in (1, -1):
            pos, pd = self._pos[d], self._p_detect[d]
            rows = []
            for r in range(self.count):
                row, missed = [], 1.0
                for k in range(r + 1, self.count):
                    missed *= 1.0 - pd[k]
                    row.append((math.log(float(pos[k] - pos[r])), missed))
                rows.append(row)
            self._ahead[d] = rows
        self._erf_scale = 1.0 / (self.SPEED_PRIOR_LOG_SIGMA * math.sqrt(2.0))
        self.max_hypotheses = int(max_hypotheses)
        self.detector = detector or ContactDetector(fs_hz)
        block_s = self.DETECT_BLOCK_S if detect_block_s is None else float(detect_block_s)
        self._block = max(1, round(block_s * self.fs_hz))  # latency against CPU
        # a contact is known this late: the detector's own delay, then the block's end
        self._max_latency = (self.detector.lag + self._block) / self.fs_hz
        self._min_latency = (2.0 * self.detector.channels[0].width + self._block / 2) / self.fs_hz
        self._static = StaticForce(fs_hz)
        self._n_in = 0  # samples taken by the detector
        self._n_seen = 0  # samples accepted
        self._pending_t = np.zeros(0)
        self._pending_x = np.zeros(0)
        self._items: list[tuple[int, int, int, object]] = []  # (emit, kind, id, item) queue
        # tracker state
        self._null = 0.0
        self._tracks: list[_Track] = []
        self._contacts: list[ContactEvent] = []  # processed, in time order (last `history`)
        self._snapshots: list[tuple[float, list[_Track]]] = []  # state before each of them
        self._history = int(history)
        self._pulse: dict[int, bool | None] = {}
        self._pulse_order: deque[int] = deque()
        self._verdicts = 0  # how many verdicts so far (invalidates cached evidence)
        self._force: float | None = None
        self._cache: tuple | None = None

    def _detect_probability(self, spacing_before: float) -> float:
        share = min(1.0, max(0.0, (spacing_before - 3.0) / 5.0))
        return self.P_DETECT_MIN + (self.P_DETECT_MAX - self.P_DETECT_MIN) * share

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
        self._pulse[check.id] = check.pulse
        self._verdicts += 1
        self._pulse_order.append(check.id)
        while len(self._pulse_order) > 64:
            self._pulse.pop(self._pulse_order.popleft(), None)
        self._cache = None

    # ------------------------------------------------------------------ hypotheses
    def _add_contact(self, ev: ContactEvent) -> None:
        self._cache = None
        times = [c.t_s for c in self._contacts]
        at = bisect.bisect_right(times, ev.t_s)
        if at == len(self._contacts):
            self._snapshots.append((self._null, self._tracks))
            self._contacts.append(ev)
            self._step(ev)
        else:  # an earlier contact decided late: replay from before it
            if at == 0 and len(self._contacts) >= self._history:
                return  # older than anything we can replay: drop it
            self._null, self._tracks = self._snapshots[at]
            replay = [ev, *self._contacts[at:]]
            del self._snapshots[at:]
            del self._contacts[at:]
            for c in replay:
                self._snapshots.append((self._null, self._tracks))
                self._contacts.append(c)
                self._step(c)
        while len(self._contacts) > self._history:
            self._contacts.pop(0)
            self._snapshots.pop(0)

    def _step(self, ev: ContactEvent) -> None:
        tc = ev.t_s
        best_before = max([self._null, *(h.score for h in self._tracks)])
        children: list[_Track] = []
        # spurious contacts: detector false alarms, plus tip contacts in proportion to
        # the contact rate actually seen
        recent = sum(1 for c in self._contacts[:-1] if tc - c.t_s <= self.RATE_WINDOW_S)
        rate = self.CLUTTER_PER_S + self.P_TIP * recent / self.RATE_WINDOW_S
        for h in self._tracks:
            children.extend(self._branch(h, ev, rate))
        # a new track starting at this contact (the earlier story ends here)
        base = best_before + self.LOG_NEW_TRACK + self._log_strength(ev.z)
        for d in (1, -1):
            pos = self._pos[d]
            for r in range(self.count):
                children.append(
                    _Track(
                        d, r, tc, float(pos[r]), base + self._log_prior[d][r], (ev.id,), ev.sigma_s
                    )
                )
        self._null += self.LOG_CLUTTER_IDLE
        recent_ids = {c.id for c in self._contacts[-self.START_CONTACTS :]}
        held_ids = {c.id for c in self._contacts}
        self._tracks = self._prune(children, recent_ids, held_ids)

    def _branch(self, h: _Track, ev: ContactEvent, rate: float) -> list[_Track]:
        """Children of h for contact ev: assigned to one of the next ridges, or spurious.

        `rate` is the density of spurious contacts (per s), the same for every
        hypothesis - else the fastest one would explain everything as clutter.
        """
        tc = ev.t_s
        dt = tc - h.t
        if dt <= 0:
            return [self._clutter(h, rate)]
        out: list[_Track] = []
        pd = self._p_detect[h.direction]
        last = self.count - 1
        ids = (*h.ids[-5:], ev.id)
        miss = 0.0
        for k in range(h.ridge + 1, min(last, h.ridge + 1 + self.MAX_SKIP) + 1):
            skipped = k - h.ridge - 1
            if h.n == 1:  # speed from two contacts; every alignment is equally likely
                c = self._start_speed(h, k, tc, dt, skipped, ev.sigma_s)
                if c is not None:
                    c.score += miss + math.log(pd[k]) + self._log_speed_prior(c.v) - math.log(dt)
            else:  # steady, or changing speed (the likelier of the two survives pruning)
                c = self._kalman(
                    h, k, tc, dt, skipped, ev.sigma_s, miss + math.log(pd[k]), self.SPEED_WALK
                )
                c2 = self._kalman(
                    h,
                    k,
                    tc,
                    dt,
                    skipped,
                    ev.sigma_s,
                    miss + math.log(pd[k]) + self.LOG_SPEED_CHANGE,
                    self.SPEED_WALK_CHANGING,
                )
                if c2 is not None:
                    c2.ids = ids
                    out.append(c2)
            if c is not None:
                c.ids = ids
                out.append(c)
            miss += math.log(1.0 - pd[k])
        out.append(self._clutter(h, rate))
        return out

    def _log_waiting(self, h: _Track, g: float) -> float:
        """Log P(no contact detected yet) for a one-contact track, g - h.t after it.

        Under the speed prior: every ridge ahead not yet reached, or reached and
        missed. Silence makes a fast slip unlikely, then any slip.
        """
        elapsed = g - h.t - self._max_latency
        if elapsed <= 0:
            return 0.0
        shift = math.log(elapsed * self.SPEED_PRIOR_MM_S)
        total, reached_before = 0.0, 0.0
        missed = 1.0
        for log_dist, missed_after in self._ahead[h.direction][h.ridge]:
            # P(v < dist / elapsed): not there yet
            not_reached = 0.5 * (1.0 + math.erf((log_dist - shift) * self._erf_scale))
            total += missed * (not_reached - reached_before)
            reached_before = not_reached
            missed = missed_after
        total += missed * (1.0 - reached_before)  # past the last ridge, all missed
        return math.log(max(total, 1e-12))

    def _log_strength(self, z: float) -> float:
        """Log likelihood ratio ridge contact / false alarm of a contact of strength z.

        False alarms crowd just above the detector's threshold (a Gaussian tail);
        ridge contacts spread over a wide range of strengths.
        """
        thr = self.detector.threshold
        log_false_alarm = math.log(thr) - thr * (z - thr)
        log_ridge = -math.log(z * math.log(self.STRONG_Z / thr))
        return min(self.STRENGTH_MAX, max(self.STRENGTH_MIN, log_ridge - log_false_alarm))

    def _log_speed_prior(self, v: float) -> float:
        """Log density of ln(v): log-normal around the usual slip speeds."""
        z = math.log(v / self.SPEED_PRIOR_MM_S) / self.SPEED_PRIOR_LOG_SIGMA
        return -0.5 * z * z - math.log(self.SPEED_PRIOR_LOG_SIGMA * math.sqrt(2.0 * math.pi))

    def _start_speed(
        self,
        h: _Track,
        k: int,
        tc: float,
        dt: float,
        skipped: int,
        sigma_t: float,
        d: float = 0.0,
        var_d: float | None = None,
    ) -> _Track | None:
        """A track at ridge k whose speed comes from its last contact and this one."""
        pos = self._pos[h.direction]
        lag = h.m * (1.0 - math.exp(-dt / self.DIP_RECOVERY_S)) + skipped
        v = (pos[k] - h.s + lag * d) / dt
        if not V_MIN_MM_S <= v <= V_MAX_MM_S:
            return None
        c = h.copy()
        var_d = self.DIP_PRIOR_MM**2 if var_d is None else var_d
        r = self._meas_var(v, sigma_t)
        r_before = self._meas_var(v, h.sig)
        c.ridge, c.t, c.s, c.v, c.d, c.n = k, tc, float(pos[k]), v, d, max(h.n + 1, 2)
        c.sig = sigma_t
        c.p00, c.p01, c.p02 = r, r / dt, 0.0
        c.p11 = (r + r_before + lag * lag * var_d) / (dt * dt) + (self.SPEED_INIT_REL * v) ** 2
        c.p12 = lag * var_d / dt
        c.p22 = var_d
        c.m = 1.0 + h.m * math.exp(-dt / self.DIP_RECOVERY_S)
        c.schedule = c.crossings = c.evidence = None
        return c

    def _kalman(
        self,
        h: _Track,
        k: int,
        tc: float,
        dt: float,
        skipped: int,
        sigma_t: float,
        log_prior: float,
        walk: float,
    ) -> _Track | None:
        """Predict h to tc and update it with ridge k; None if the speed leaves the range."""
        pos = self._pos[h.direction]
        v, d = h.v, h.d
        decay = math.exp(-dt / self.DIP_RECOVERY_S)
        a = h.m * (1.0 - decay) + skipped  # lag to come, in units of d
        q = walk**2 * v**3 / self.SPEED_WALK_MM
        p00 = (
            h.p00
            + 2 * dt * h.p01
            - 2 * a * h.p02
            + dt * dt * h.p11
            - 2 * a * dt * h.p12
            + a * a * h.p22
            + q * dt**3 / 3.0
        )
        p01 = h.p01 + dt * h.p11 - a * h.p12 + q * dt * dt / 2.0
        p02 = h.p02 + dt * h.p12 - a * h.p22
        p11 = h.p11 + q * dt
        p12, p22 = h.p12, h.p22
        s_pred = h.s + v * dt - a * d
        var = p00 + self._meas_var(v, sigma_t) + skipped * self.SIGMA_POS_MM**2
        resid = pos[k] - s_pred
        inlier = (
            (1.0 - self.ROBUST_FLOOR)
            * v
            * math.exp(-0.5 * resid * resid / var)
            / math.sqrt(2 * math.pi * var)
        )
        outlier = self.ROBUST_FLOOR * v / (4.0 * max(pos[k] - h.s, 1.0))  # within a few intervals
        if inlier >= outlier:
            c = h.copy()
            k0, k1, k2 = p00 / var, p01 / var, p02 / var
            c.s = s_pred + k0 * resid
            c.v = v + k1 * resid
            c.d = min(self.DIP_MAX_MM, max(0.0, d + k2 * resid))
            c.p00, c.p01, c.p02 = p00 - k0 * p00, p01 - k0 * p01, p02 - k0 * p02
            c.p11, c.p12, c.p22 = p11 - k1 * p01, p12 - k1 * p02, p22 - k2 * p02
            c.m = 1.0 + h.m * decay
            c.ridge, c.t, c.n, c.sig = k, tc, h.n + 1, sigma_t
            c.schedule = c.crossings = c.evidence = None
            if not V_MIN_MM_S <= c.v <= V_MAX_MM_S:
                return None
        else:  # far off: the speed changed; start again from the last two contacts
            restart = self._start_speed(
                h, k, tc, dt, skipped, sigma_t, d, max(h.p22, self.DIP_PRIOR_MM**2)
            )
            if (
                restart is None
                or not 1.0 / self.MAX_SPEED_JUMP <= restart.v / v <= self.MAX_SPEED_JUMP
            ):
                return None
            c = restart
        c.score += log_prior + math.log(inlier + outlier)
        return c

    def _clutter(self, h: _Track, rate: float) -> _Track:
        """h with the contact called spurious (noise, a tipping edge, a grip change)."""
        c = h.copy()
        c.score += math.log(rate)
        return c

    def _meas_var(self, v: float, sigma_t: float) -> float:
        """Variance of a ridge contact as a position measurement at speed v."""
        return self.SIGMA_POS_MM**2 + (v * sigma_t) ** 2

    def _prune(self, children: list[_Track], recent: set[int], held: set[int]) -> list[_Track]:
        """Best first, one per (direction, ridge, last three contacts); bounded.

        Tracks with two or more contacts: the best max_hypotheses, plus the best
        PER_START of every contact a track starts at while that contact is still in
        the bounded history (`held`), so that a slip whose true start came after a
        spurious contact is not crowded out by the tracks that took the spurious one
        for its start. A start older than the history competes on score alone:
        otherwise every contact ever seen would keep tracks alive and a gateway
        running for hours would grow without bound. One-contact tracks (a slip
        starting at one of the `recent` contacts) are all kept.
        """
        children.sort(key=lambda c: -c.score)
        seen: set[tuple] = set()
        kept: list[_Track] = []
        count = 0
        per_start: dict[int, int] = {}
        for c in children:
            key = (c.direction, c.ridge, c.n >= 2, c.ids[-3:] if c.n >= 2 else c.ids[-1:])
            if key in seen:
                continue
            if c.n >= 2:
                starts = per_start.get(c.first, 0)
                if count >= self.max_hypotheses and (
                    starts >= self.PER_START or c.first not in held
                ):
                    continue
                count += 1
                per_start[c.first] = starts + 1
            elif c.ids[-1] not in recent:
                continue
            seen.add(key)
            kept.append(c)
        return kept

    # ------------------------------------------------------------------ motion
    def _crossings(self, h: _Track) -> list[tuple[float, float, float]]:
        """Predicted crossings of the ridges ahead: [(time, position, dip memory after)].

        Constant speed h.v, minus the distance each ridge's dip costs (h.d, recovering
        over DIP_RECOVERY_S); the last entry is the end of the coasting past the skin.
        """
        if h.crossings is not None:
            return h.crossings
        pos = self._pos[h.direction]
        tau = self.DIP_RECOVERY_S
        v, d = h.v, h.d
        t0, s0, m = h.t, h.s, h.m
        out = []
        for k in range(h.ridge + 1, self.count + 1):
            target = float(pos[k]) if k < self.count else float(pos[-1]) + self._coast
            dist = max(target - s0, 0.0)
            dt = (dist + d * m) / v
            for _ in range(3):  # fixed point: the part of the dip recovered by then
                dt = (dist + d * m * (1.0 - math.exp(-dt / tau))) / v
            t0 += dt
            m = 1.0 + m * math.exp(-dt / tau)
            s0 = target
            out.append((t0, s0, m))
        h.crossings = out
        return out

    def _motion(self, h: _Track, g: float) -> tuple[float, float, float]:
        """(edge position along the travel, speed, position sigma) predicted at g."""
        t0, s0, m = h.t, h.s, h.m
        for tk, sk, mk in self._crossings(h)[:-1]:
            if tk > g:
                break
            t0, s0, m = tk, sk, mk
        dt = max(0.0, g - t0)
        decay = math.exp(-dt / self.DIP_RECOVERY_S)
        s = s0 + h.v * dt - h.d * m * (1.0 - decay)
        speed = max(0.0, h.v - h.d * m * decay / self.DIP_RECOVERY_S)
        span = max(0.0, g - h.t)
        var = h.p00 + 2 * span * h.p01 + span * span * h.p11
        return s, speed, math.sqrt(max(var, 0.0))

    def _schedule(self, h: _Track) -> list[tuple[float, float, bool, int]]:
        """Silence: [(from time, score adjustment, stopped, next ridge not reached)], in order."""
        if h.schedule is not None:
            return h.schedule
        sched: list[tuple[float, float, bool, int]] = [(-math.inf, 0.0, False, h.ridge + 1)]
        if h.n >= 2:
            pd = self._p_detect[h.direction]
            miss = 0.0
            latency = self._latency(h.v)
            for k, (tk, _, _) in enumerate(self._crossings(h), start=h.ridge + 1):
                dt = tk - h.t
                span = math.sqrt(max(h.p00 + 2 * dt * h.p01 + dt * dt * h.p11, 0.0)) / h.v
                due = tk + 3.0 * span + self.LATE_REL * dt + latency
                p_miss = 1.0 - pd[k] if k < self.count else 0.0
                miss = miss + math.log(p_miss) if p_miss > 0 else -math.inf
                if miss >= self.LOG_STOP:
                    sched.append((due, miss, False, k + 1))
                    continue
                sched.append((due, self.LOG_STOP, True, k))
                break
        h.schedule = sched
        return sched

    @staticmethod
    def _state_at(sched: list[tuple[float, float, bool, int]], g: float) -> tuple[float, bool, int]:
        state = sched[0]
        for entry in sched:
            if g >= entry[0]:
                state = entry
            else:
                break
        return state[1], state[2], state[3]

    # ------------------------------------------------------------------ reporting
    def _report(self, g: float) -> SlipEstimate:
        force = self._force
        if not self._tracks:
            return SlipEstimate(g, False, None, None, force, 1.0)
        # the posterior changes only when a contact or verdict arrives or silence lasts;
        # the agreement (confidence) is refreshed every REFRESH_S
        if self._cache is None or g >= self._cache[0]:
            self._cache = self._posterior(g)
        _, chosen, p_slip, agree, direction_odds = self._cache
        if chosen is None:
            return SlipEstimate(g, False, None, None, force, min(1.0, max(0.0, 1.0 - p_slip)))
        _, h, stopped, _, limit, _ = chosen
        if not stopped and (
            h.n < self.DIRECTION_CONTACTS or direction_odds < self.LOG_DIRECTION_ODDS
        ):
            # a slip, but its direction is not told yet (two contacts fit any alignment
            # either way; a third may fit both): say so rather than guess a sign
            return SlipEstimate(g, True, None, None, force, min(1.0, max(0.0, p_slip)))
        s, speed, sigma = self._where(h, g, stopped, limit)
        # a posterior from few contacts is fragile (timing outliers, model errors)
        maturity = 1.0 - math.exp(-(h.n - 1) / self.CONF_CONTACTS)
        conf = agree * maturity / (1.0 + (sigma / self.CONF_POS_MM) ** 2)
        x = float(self._x(h, s))
        conf = min(1.0, max(0.0, float(conf)))
        if not stopped:
            return SlipEstimate(g, True, float(h.direction * speed), x, force, conf)
        return SlipEstimate(g, False, 0.0, x, force, conf)

    def _x(self, h: _Track, s: float) -> float:
        return s if h.direction > 0 else self.length - s

    def _posterior(self, g: float):
        """(valid until, chosen entry or None, P(slip), agreement, direction log odds) at g.

        entry = [score, track, stopped, evident, next ridge not reached, weight].
        Agreement: the share of the posterior that puts the edge within AGREE_MM of
        the chosen track's position (and, slipping, its speed within AGREE_SPEED).
        Direction log odds: the chosen track's score over the best slipping track's moving
        the other way (a generalised likelihood ratio: the best stories, not the whole
        posterior, which many weak clutter stories of either direction dilute).
        """
        entries: list[list[Any]] = []  # [score, track, stopped, evident, limit, weight]
        until = g + self.REFRESH_S
        best = max(h.score for h in self._tracks)
        # one-contact tracks only lose to silence: skip those that cannot matter
        best_long = max([self._null, *(h.score for h in self._tracks if h.n >= 2)])
        for h in self._tracks:
            if h.score < best - self.NEGLIGIBLE:
                continue  # weight below e^-20 whatever its silence and pulses
            if h.n == 1 and h.score + 2 * self.LOG_PULSE < best_long - self.NEGLIGIBLE:
                continue
            sched = self._schedule(h)
            adj, stopped, limit = self._state_at(sched, g)
            for entry in sched:
                if entry[0] > g:
                    until = min(until, entry[0])
                    break
            if h.n == 1:
                adj = self._log_waiting(h, g)
            evident, bonus = self._evidence(h)
            entries.append([h.score + adj + bonus, h, stopped, evident, limit, 0.0])
        top = max([self._null, *(e[0] for e in entries)])
        total = math.exp(self._null - top)
        for e in entries:
            e[5] = math.exp(e[0] - top)
            total += e[5]
        p_slip = 0.0
        best_way = {1: -math.inf, -1: -math.inf}  # best slipping score per direction
        best_slip = best_stop = None
        for e in entries:
            if not e[3]:
                continue
            if not e[2]:
                p_slip += e[5] / total
                best_way[e[1].direction] = max(best_way[e[1].direction], e[0])
                if best_slip is None or e[0] > best_slip[0]:
                    best_slip = e
            elif best_stop is None or e[0] > best_stop[0]:
                best_stop = e
        if p_slip >= 0.5 and best_slip is not None:
            chosen = best_slip
        elif best_stop is not None and best_stop[0] >= self._null:
            chosen = best_stop
        else:
            return (until, None, p_slip, 0.0, -math.inf)
        _, h, stopped, _, limit, _ = chosen
        x_ref = self._x(h, self._where(h, g, stopped, limit)[0])
        agree = 0.0
        floor = 1e-4 * total
        for e in entries:
            _, o, o_stopped, evident, o_limit, w = e
            if w < floor or not evident or o_stopped != stopped:
                continue
            if not stopped and (
                o.direction != h.direction or abs(o.v - h.v) > self.AGREE_SPEED * h.v
            ):
                continue
            if abs(self._x(o, self._where(o, g, o_stopped, o_limit)[0]) - x_ref) <= self.AGREE_MM:
                agree += w
        # the direction: how much better the best story moving this way explains the
        # contacts than the best one moving the other way (log odds)
        odds = best_way[h.direction] - best_way[-h.direction]
        return (until, chosen, p_slip, agree / total, odds)

    def _evidence(self, h: _Track) -> tuple[bool, float]:
        """Is it a slip (a contact fell back like a pulse, or many contacts and no step)?

        Also the score bonus of the pulse verdicts on its recent contacts.
        """
        if h.evidence is not None and h.evidence[0] == self._verdicts:
            return h.evidence[1]
        pulses = steps = 0
        for i in h.ids:
            verdict = self._pulse.get(i)
            if verdict:
                pulses += 1
            elif verdict is False:
                steps += 1
        # pulses tell slip from no slip, not one alignment from another (tips and
        # other extra contacts are pulses too): the first two count
        bonus = min(pulses, 2) * self.LOG_PULSE - steps * self.LOG_STEP
        result = ((h.n >= 2 and (pulses > 0 or (h.n >= 4 and steps == 0))), bonus)
        h.evidence = (self._verdicts, result)
        return result

    def _where(self, h: _Track, g: float, stopped: bool, limit: int) -> tuple[float, float, float]:
        """(travelled distance of the edge from the first ridge met, speed, sigma) at g.

        Predicted from the last contact; a stopped slip stopped before the ridge
        `limit` it never reached.
        """
        pos = self._pos[h.direction]
        s, speed, sigma = self._motion(h, g)
        if stopped:  # somewhere before the ridge it never reached: as likely anywhere
            end = float(pos[limit]) if limit < self.count else float(pos[-1]) + self._coast
            s = min(s, end)
            sigma = max(sigma, (end - float(pos[min(limit, self.count) - 1])) / math.sqrt(12.0))
        if h.ridge == self.count - 1:
            sigma += 0.2 * max(0.0, s - float(pos[-1]))
        return s, speed, sigma

    def _latency(self, v: float) -> float:
        """How late a contact is typically known: the detector needs ~1 mm of travel."""
        return min(self._max_latency, max(self._min_latency, self.DETECT_MM / v))

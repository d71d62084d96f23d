"""The thesis' ratio decoder (ch. 5.3.2): slip position and speed from peak-interval ratios.

Pipeline, as in the thesis: a 2nd-order Butterworth band-pass (one pole pair
per edge, default 0.5-30 Hz) -> peak detection with a threshold (a peak must
protrude `threshold` above its surroundings on both sides; the threshold is
max(`threshold_n`, the height the measured band-passed noise reaches
`false_peaks_per_min` times a minute: `filters.peak_threshold`) -> for the last three peaks
phi = (PK_k - PK_{k-1}) / (PK_{k-1} - PK_{k-2}) -> match phi against
delta_i = D_i / D_{i-1} within `ratio_tol` (on a log scale: |ln phi - ln delta| <
ratio_tol) -> position: the ridge the edge reached at PK_k; speed
v = (D_i + D_{i-1}) / (PK_k - PK_{k-2}). Fewer than three peaks: no answer.

Additions the thesis leaves open, kept minimal:

* Both directions: phi is also matched against reversed ratios
  D_{i-1} / D_i (the edge crossing the ridges from the last towards the
  first); the speed is then negative.
* Ties: several (i, direction) within the threshold are ranked by how many
  consecutive triples support them (a forward match at i continued by a
  forward match at i + 1, and so on), then by the match error. Confidence =
  match quality x chain support / number of distinct answers still tied,
  so an ambiguous layout (repeated ratios such as 5,10,5,10,5, or a uniform
  skin) gives low confidence, never a confident wrong answer. When tied
  answers disagree on the direction, the speed is reported without a
  direction (None) and the position as unknown if more than two positions tie.
* Between ridges the estimate is held: position extrapolated at the
  decoded speed from where the edge was at the last peak (the band-passed
  pulse peaks a little past the ridge; `filters.PeakLag` says how far),
  slip flagged until no peak came for `hold_factor` times the interval to
  the next ridge (capped by `max_hold_s`) - the hysteresis against chatter.
* Slip flag: two peaks closer than `pair_onset_s` flag slip (no speed yet);
  a ratio match flags slip when match quality x chain support reaches
  `slip_evidence` (a barely matching ratio from grip changes or drift is
  reported with its low confidence but does not raise the flag).
* A layout of one spacing has no ratios: speed from two consecutive peaks
  (D / T, no direction, confidence <= 0.4), position unknown.
* Speeds outside [`v_min`, `v_max`] mm/s are not plausible matches (they
  come from grip changes or drift, not ridges).

Accuracy and CPU per sample: docs/benchmarks/decoding.md (rows `ratio`): a
good median but a large p90 and many updates without an answer. The
faithful triple match has no notion of a missed ridge: in the simulated
signal a small spacing after a large one (3 mm after 33 mm) puts a pulse
lower than the previous pulse's decay, so it never shows, and the triple
spanning it matches a wrong ratio (with low confidence) or nothing.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from grasplink.decoding.base import DEFAULT_UPDATE_S, Decoder, SlipEstimate
from grasplink.decoding.filters import PeakLag, PulseFrontEnd, interleave, pulse_events
from grasplink.errors import ConfigError

RIDGE_SIDE_MM = 2.5  # skin node 0x2142 default (thesis ch. 5: L = 2.5 mm)
PEAK_HISTORY = 8
KEEP_ALIVE_TRUST = 0.7  # confidence factor per unmatched peak that extends an answer


@dataclass(frozen=True, slots=True)
class Answer:
    """What the last peak told: valid from t_peak until the hold runs out."""

    t_peak: float
    speed: float | None  # signed mm/s (positive when the direction is unknown)
    directed: bool  # the sign of `speed` is the direction the peaks told (else not told)
    position_at_peak: float | None  # leading edge at t_peak, mm
    confidence: float
    hold_s: float
    slip: bool  # the match is good enough to call it a slip


class RatioDecoder(Decoder):
    name = "ratio"

    def __init__(
        self,
        layout_mm: Sequence[float],
        fs_hz: float,
        *,
        update_period_s: float = DEFAULT_UPDATE_S,
        band_hz: tuple[float, float] = (0.5, 30.0),
        order: int = 1,
        threshold_n: float = 0.05,
        false_peaks_per_min: float = 1.0,
        ratio_tol: float = 0.2,
        v_min: float = 4.0,
        v_max: float = 400.0,
        hold_factor: float = 2.0,
        min_hold_s: float = 0.1,
        max_hold_s: float = 1.5,
        pair_onset_s: float = 1.0,
        slip_evidence: float = 0.15,
        ridge_side_mm: float = RIDGE_SIDE_MM,
    ):
        super().__init__(layout_mm, fs_hz, update_period_s=update_period_s)
        if not ratio_tol > 0:
            raise ConfigError(f"ratio_tol must be > 0, got {ratio_tol}")
        if not 0 < v_min < v_max:
            raise ConfigError(f"need 0 < v_min < v_max, got {v_min}, {v_max}")
        self.front = PulseFrontEnd(
            self.fs_hz,
            band_hz=band_hz,
            order=order,
            threshold_n=threshold_n,
            false_peaks_per_min=false_peaks_per_min,
        )
        self.lag = PeakLag(self.front.sos, self.fs_hz, ridge_side_mm)
        self.ratio_tol = float(ratio_tol)
        self.v_min, self.v_max = float(v_min), float(v_max)
        self.hold_factor, self.min_hold_s = float(hold_factor), float(min_hold_s)
        self.max_hold_s = float(max_hold_s)
        self.pair_onset_s = float(pair_onset_s)
        self.slip_evidence = float(slip_evidence)
        s = self.geometry.spacings_mm
        self._spacings = s
        self._log_fwd = np.log(s[1:] / s[:-1])  # crossing ridges j, j+1, j+2
        self._log_rev = -self._log_fwd  # crossing ridges j+2, j+1, j
        self._peaks: deque[float] = deque(maxlen=PEAK_HISTORY)
        self._chains: dict[tuple[int, int], int] = {}
        self._answer: Answer | None = None
        self._onset_until = -math.inf  # slip flagged by a close pair of peaks until then
        self._force: float | None = None

    # -- streaming ---------------------------------------------------------------
    def process(self, t: np.ndarray, x: np.ndarray) -> list[SlipEstimate]:
        segments = self.front(t, x)
        events = pulse_events(segments)
        force = np.concatenate([seg.force_n for seg in segments])
        out = []
        for count, g in interleave(events, self.update_points(t), self._apply):
            if count:
                self._force = float(force[count - 1])
            out.append(self._estimate(g))
        self._force = float(force[-1])
        return out

    def _apply(self, event: tuple) -> None:
        if event[1] is None:
            self._reset_history()
        else:
            self._on_peak(event[1].t_s)

    def _reset_history(self) -> None:
        self._peaks.clear()
        self._chains = {}
        self._answer = None
        self._onset_until = -math.inf

    # -- decoding ------------------------------------------------------------------
    def _on_peak(self, t_peak: float) -> None:
        peaks = self._peaks
        if peaks and t_peak - peaks[-1] > self._max_interval():
            peaks.clear()  # a pause longer than any plausible ridge interval: start over
            self._chains = {}
        peaks.append(t_peak)
        if len(peaks) >= 2 and peaks[-1] - peaks[-2] <= self.pair_onset_s:
            self._onset_until = t_peak + self._hold(None, None, peaks[-1] - peaks[-2])
        if len(self._spacings) == 1:
            self._pair_answer()
        elif len(peaks) >= 3:
            self._triple_answer()

    def _max_interval(self) -> float:
        return float(self._spacings.max()) / self.v_min

    def _pair_answer(self) -> None:
        peaks = self._peaks
        if len(peaks) < 2:
            return
        interval = peaks[-1] - peaks[-2]
        speed = float(self._spacings[0]) / interval
        if not self.v_min <= speed <= self.v_max:
            return
        hold = self._hold(None, None, interval)
        self._answer = Answer(peaks[-1], speed, False, None, 0.4, hold, True)

    def _triple_answer(self) -> None:
        p = self._peaks
        t1, t2 = p[-2] - p[-3], p[-1] - p[-2]
        if t1 <= 0 or t2 <= 0:
            return
        log_phi = math.log(t2 / t1)
        s = self._spacings
        candidates = []  # (chain, error, j, direction, speed, position at peak)
        chains: dict[tuple[int, int], int] = {}
        for direction, table in ((1, self._log_fwd), (-1, self._log_rev)):
            errors = np.abs(table - log_phi)
            for j in np.nonzero(errors < self.ratio_tol)[0].tolist():
                speed = float(s[j] + s[j + 1]) / (t1 + t2)
                if not self.v_min <= speed <= self.v_max:
                    continue
                chain = 1 + self._chains.get((j - direction, direction), 0)
                chains[(j, direction)] = chain
                ridge = j + 2 if direction > 0 else j
                reached_mm = float(self.geometry.ridges_mm[ridge])
                candidates.append(
                    (chain, float(errors[j]), j, direction, direction * speed, reached_mm)
                )
        self._chains = chains
        if not candidates:
            self._keep_alive(t2)
            return
        candidates.sort(key=lambda c: (-c[0], c[1]))
        best = candidates[0]
        tied = [c for c in candidates if c[0] == best[0]]
        answers = {(round(c[5], 1), c[3]) for c in tied}
        quality = 1.0 - best[1] / self.ratio_tol
        support = 1.0 - 0.5 ** best[0]
        confidence = max(0.0, min(1.0, quality * support / len(answers)))
        speed = best[4]
        position: float | None = best[5]
        directed = len({c[3] for c in tied}) == 1
        if not directed:
            speed = abs(speed)  # direction unknown: a magnitude, by convention positive
        if len({round(c[5], 1) for c in tied}) > 2:
            position = None
        direction = best[3]
        at_peak = None
        if position is not None:
            at_peak = position + direction * self.lag(speed)
        ridge = best[2] + 2 if direction > 0 else best[2]
        self._answer = Answer(
            self._peaks[-1],
            speed,
            directed,
            at_peak,
            confidence,
            self._hold(ridge, direction, t2),
            quality * support >= self.slip_evidence,
        )

    def _keep_alive(self, interval: float) -> None:
        """An unmatched peak during a slip: keep the answer (less trusted) a while longer."""
        answer = self._answer
        t_peak = self._peaks[-1]
        if answer is None or t_peak - answer.t_peak > answer.hold_s:
            return
        hold = (t_peak - answer.t_peak) + self._hold(None, None, interval)
        self._answer = Answer(
            answer.t_peak,
            answer.speed,
            answer.directed,
            answer.position_at_peak,
            answer.confidence * KEEP_ALIVE_TRUST,
            hold,
            answer.slip,
        )

    def _hold(self, ridge: int | None, direction: int | None, interval: float) -> float:
        """How long to keep slip flagged without a new peak.

        `hold_factor` times the time to the ridge after next at the current
        speed (a small spacing after a large one can hide its pulse in the
        previous pulse's decay), or times the last interval when the next
        ridges are unknown or the edge has passed the last one.
        """
        expected = interval
        if ridge is not None and direction is not None:
            ridges = self.geometry.ridges_mm
            last = abs(ridges[ridge] - ridges[ridge - direction])
            ahead = [ridge + direction * k for k in (1, 2)]
            ahead = [r for r in ahead if 0 <= r < len(ridges)]
            if ahead and last > 0:
                expected = interval * abs(ridges[ahead[-1]] - ridges[ridge]) / last
        return min(self.max_hold_s, max(self.min_hold_s, self.hold_factor * expected))

    def _estimate(self, g: float) -> SlipEstimate:
        answer = self._answer
        force = self._force
        if answer is not None and g - answer.t_peak <= answer.hold_s:
            position = None
            if answer.position_at_peak is not None and answer.speed is not None:
                position = answer.position_at_peak + answer.speed * (g - answer.t_peak)
            slipping = answer.slip or g <= self._onset_until
            if answer.directed:  # the direction told with the answer's confidence
                return SlipEstimate.from_velocity(
                    g, slipping, answer.speed, position, force, answer.confidence
                )
            speed = None if answer.speed is None else abs(answer.speed)
            return SlipEstimate(g, slipping, speed, position, force, answer.confidence)
        if answer is not None:
            self._answer = None
        slipping = g <= self._onset_until
        return SlipEstimate(g, slipping, None, None, force, 0.0)

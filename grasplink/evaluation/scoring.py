"""Score a decoder against a recording with ground truth.

Definitions (the benchmark states them too):

- An update is *scored* when the truth is slipping and the leading edge has
  passed the third ridge contact after onset (before that no layout can tell
  position, the *physical limit*), until the edge lies one spacing (the one
  into the last ridge) past the last ridge ahead: past it no contact can come,
  nothing observes the slip, and the tracker shows no speed there
  (`decoding.coast_bound`; as slip_reporting, which stops at the last ridge).
- Speed error: |v_est - v_true| / |v_true| (a wrong direction counts in
  full; a speed told without a direction is compared as a magnitude);
  position error: |x_est - x_true| in mm. A scored update without a speed
  counts as *missing* and is excluded from the error statistics.
- Wrong sign: share of the scored updates with a speed estimate whose told
  direction is opposite the truth's (the direction decoded the wrong way
  round; a speed without a direction, or of 0, is never a wrong sign).
- NRMSD (thesis table 5.2): RMS error divided by the range of the true
  values over the scored updates of a recording set.
- Detection: slip flagged - time of the first update with slip=True after
  onset, in ridge intervals (the time between the first two contacts);
  first good estimate - first update with speed within 10 % (and the right
  direction, if one is told), compared with the time of the third contact.
- False slip: share of updates flagged slip while the truth is not slipping.
- Cost: process time per input sample (CPU µs), peak memory (tracemalloc)
  of a separate run.
"""

from __future__ import annotations

import time
import tracemalloc
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from grasplink.decoding.base import Decoder, SlipEstimate
from grasplink.simulators.synth import SkinRecording

CHUNK = 256  # samples per feed(): the streaming path, as a gateway would call it
GOOD_SPEED = 0.10


@dataclass
class RecordingScore:
    speed_rel_err: np.ndarray  # scored updates with an estimate
    speed_abs_err: np.ndarray
    speed_true: np.ndarray
    position_err_mm: np.ndarray
    position_true: np.ndarray
    scored: int
    missing: int
    wrong_sign: int  # scored updates with a speed estimate of the opposite sign
    slip_flag_delay_intervals: float | None  # None: never flagged
    first_good_s: float | None  # time after onset of the first estimate within 10 %
    physical_limit_s: float | None  # time after onset of the third contact
    false_slip_updates: int
    static_updates: int
    cpu_us_per_sample: float
    samples: int


def run_decoder(
    make: Callable[[], Decoder], rec: SkinRecording
) -> tuple[list[SlipEstimate], float]:
    """Feed the recording in chunks; returns estimates and CPU µs per sample."""
    decoder = make()
    estimates: list[SlipEstimate] = []
    t0 = time.process_time()
    for start in range(0, len(rec.t_s), CHUNK):
        estimates += decoder.feed(
            rec.t_s[start : start + CHUNK], rec.force_n[start : start + CHUNK]
        )
    cpu = time.process_time() - t0
    return estimates, 1e6 * cpu / max(1, len(rec.t_s))


def peak_memory_kib(make: Callable[[], Decoder], rec: SkinRecording) -> float:
    tracemalloc.start()
    try:
        decoder = make()
        for start in range(0, len(rec.t_s), CHUNK):
            decoder.feed(rec.t_s[start : start + CHUNK], rec.force_n[start : start + CHUNK])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    return peak / 1024


def score(make: Callable[[], Decoder], rec: SkinRecording) -> RecordingScore:
    estimates, cpu_us = run_decoder(make, rec)
    if not estimates:
        empty = np.zeros(0)
        return RecordingScore(
            empty, empty, empty, empty, empty, 0, 0, 0, None, None, None, 0, 0, cpu_us, len(rec.t_s)
        )
    t_upd = np.array([e.t_s for e in estimates])
    slipping = np.interp(t_upd, rec.t_s, rec.slipping) > 0.5
    v_true = np.interp(t_upd, rec.t_s, rec.speed_mm_s)
    x_true = np.interp(t_upd, rec.t_s, rec.position_mm)
    onset = _onset(rec)
    contacts = rec.contact_times_s[rec.contact_times_s >= (onset or 0.0)]
    third = contacts[2] if len(contacts) >= 3 else None
    scored_mask = slipping & (t_upd >= third) if third is not None else np.zeros_like(slipping)
    scored_mask &= observed(rec.layout_mm, x_true, v_true)
    v_est, _ = along_truth(estimates, v_true)
    x_est = np.array([np.nan if e.position_mm is None else e.position_mm for e in estimates])
    flags = np.array([e.slip for e in estimates])
    have_v = scored_mask & np.isfinite(v_est)
    rel = np.abs(v_est[have_v] - v_true[have_v]) / np.maximum(np.abs(v_true[have_v]), 1e-9)
    have_x = scored_mask & np.isfinite(x_est)
    slip_delay = first_good = None
    if onset is not None and len(contacts) >= 2:
        interval = contacts[1] - contacts[0]
        after = t_upd >= onset
        flagged = np.nonzero(after & flags)[0]
        if len(flagged):
            slip_delay = (t_upd[flagged[0]] - onset) / max(interval, 1e-9)
        good = after & np.isfinite(v_est) & (np.abs(v_est - v_true) <= GOOD_SPEED * np.abs(v_true))
        good &= slipping
        good_idx = np.nonzero(good)[0]
        if len(good_idx):
            first_good = t_upd[good_idx[0]] - onset
    return RecordingScore(
        speed_rel_err=rel,
        speed_abs_err=np.abs(v_est[have_v] - v_true[have_v]),
        speed_true=v_true[have_v],
        position_err_mm=np.abs(x_est[have_x] - x_true[have_x]),
        position_true=x_true[have_x],
        scored=int(scored_mask.sum()),
        missing=int((scored_mask & ~np.isfinite(v_est)).sum()),
        wrong_sign=int((v_est[have_v] * v_true[have_v] < 0).sum()),
        slip_flag_delay_intervals=slip_delay,
        first_good_s=first_good,
        physical_limit_s=(third - onset) if third is not None and onset is not None else None,
        false_slip_updates=int((flags & ~slipping).sum()),
        static_updates=int((~slipping).sum()),
        cpu_us_per_sample=cpu_us,
        samples=len(rec.t_s),
    )


def observed(layout_mm: Sequence[float], x_true: np.ndarray, v_true: np.ndarray) -> np.ndarray:
    """Updates whose edge (at x_true, moving at v_true) lies no more than one spacing, the
    one into the last ridge ahead, past that ridge: where a speed is observable."""
    spacing = np.asarray(layout_mm, dtype=float)
    ahead = np.where(v_true >= 0, x_true - float(spacing.sum()), -x_true)
    return ahead <= np.where(v_true >= 0, spacing[-1], spacing[0])


def along_truth(
    estimates: Sequence[SlipEstimate], v_true: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per update, the estimate as a signed speed to score against `v_true`, and the
    direction told (+1, -1; 0: none) (docs/decoding.md, the output contract).

    A told direction signs the speed (`velocity_mm_s`): the wrong way counts in full. A
    speed without a direction is a speed all the same (errors, missing): it is scored
    as a magnitude, taken the truth's way (+ where the truth is at rest), so it is never
    a wrong direction. NaN: no speed.
    """
    speed = np.array([np.nan if e.speed_mm_s is None else e.speed_mm_s for e in estimates])
    direction = np.array([0 if e.direction is None else e.direction for e in estimates])
    told = direction != 0
    way = np.where(told, direction, np.where(np.asarray(v_true) < 0, -1, 1))
    return way * speed, direction


def _onset(rec: SkinRecording) -> float | None:
    moving = np.nonzero(rec.slipping > 0.5)[0]
    return float(rec.t_s[moving[0]]) if len(moving) else None


def nrmsd(errors: np.ndarray, truth: np.ndarray) -> float | None:
    if len(errors) == 0 or np.ptp(truth) == 0:
        return None
    return float(np.sqrt(np.mean(errors**2)) / np.ptp(truth))


def summarise(scores: list[RecordingScore]) -> dict:
    """The figures of a set of recordings, errors pooled over all their scored updates."""
    rel = np.concatenate([s.speed_rel_err for s in scores]) if scores else np.zeros(0)
    abs_err = np.concatenate([s.speed_abs_err for s in scores]) if scores else np.zeros(0)
    v_true = np.concatenate([s.speed_true for s in scores]) if scores else np.zeros(0)
    pos = np.concatenate([s.position_err_mm for s in scores]) if scores else np.zeros(0)
    pos_true = np.concatenate([s.position_true for s in scores]) if scores else np.zeros(0)
    scored = sum(s.scored for s in scores)
    delays = [
        s.slip_flag_delay_intervals for s in scores if s.slip_flag_delay_intervals is not None
    ]
    ratios = [
        s.first_good_s / s.physical_limit_s
        for s in scores
        if s.first_good_s is not None and s.physical_limit_s
    ]
    never = sum(1 for s in scores if s.physical_limit_s and s.first_good_s is None)
    samples = sum(s.samples for s in scores)
    return {
        "speed_median_pct": _pct(rel, 50),
        "speed_p90_pct": _pct(rel, 90),
        "speed_nrmsd": nrmsd(abs_err, v_true),
        "wrong_sign_pct": 100.0 * sum(s.wrong_sign for s in scores) / len(rel)
        if len(rel)
        else None,
        "position_median_mm": _q(pos, 50),
        "position_p90_mm": _q(pos, 90),
        "position_nrmsd": nrmsd(pos, pos_true),
        "missing_pct": 100.0 * sum(s.missing for s in scores) / scored if scored else None,
        "slip_flag_intervals": float(np.median(delays)) if delays else None,
        "slip_never_flagged": sum(
            1 for s in scores if s.slip_flag_delay_intervals is None and s.physical_limit_s
        ),
        "first_good_ratio": float(np.median(ratios)) if ratios else None,
        "never_good": never,
        "cpu_us_per_sample": sum(s.cpu_us_per_sample * s.samples for s in scores) / samples
        if samples
        else None,
    }


def wrong_sign_share(score: RecordingScore) -> float | None:
    """Share (0..1) of one recording's speed estimates with the wrong sign; None if none."""
    estimated = len(score.speed_rel_err)
    return score.wrong_sign / estimated if estimated else None


def _pct(values: np.ndarray, q: float) -> float | None:
    return float(100 * np.percentile(values, q)) if len(values) else None


def _q(values: np.ndarray, q: float) -> float | None:
    return float(np.percentile(values, q)) if len(values) else None

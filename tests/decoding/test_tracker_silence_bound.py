"""Silence bounds the speed shown between contacts (`TrackerDecoder.SILENCE_REACH`): a
track whose next ridge has not been told by now (less the detector's latency) has not yet
travelled that far since its last contact, so its mean speed since then is at most that
distance over the silent time. An acceleration measured from a few contacts and
extrapolated over a long spacing is undone as far as that bound requires (down to the
speed the contacts measured, `SILENCE_BRAKE` 0): otherwise a 20 mm/s slip was shown at
66 mm/s, over the reflex's 45 mm/s."""

from __future__ import annotations

import numpy as np

from grasplink.decoding.kernels.layout import IDS
from grasplink.decoding.tracker import TrackerDecoder, _Bank, _One
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr
from grasplink.evaluation.decoders import make_decoder

ALPHA05_MM = (5.0, 12.0, 67.0)  # ridges at 0, 5, 17, 84 mm


def one_track(v_mm_s: float, a_mm_s2: float, ridge: int, t_s: float) -> _One:
    """A slipping track at `ridge` (forward) since t_s, speed v and acceleration a, sure
    of both (no covariance)."""
    bank = _Bank.of(
        P=np.zeros((1, 4, 4)),
        X=np.array([[float(np.cumsum((0.0, *ALPHA05_MM))[ridge]), v_mm_s, a_mm_s2, 0.0]]),
        dirn=np.array([1]),
        first=np.array([0]),
        ids=np.zeros((1, IDS), np.int64),
        m=np.zeros(1),
        model=np.array([1]),
        n=np.array([3]),
        ridge=np.array([ridge]),
        run=np.array([3]),
        score=np.zeros(1),
        sig=np.zeros(1),
        stop=np.array([np.nan]),
        t=np.array([t_s]),
        before=np.zeros(1),
    )
    return _One(bank, 0)


def test_an_accelerating_track_silent_over_a_long_spacing_shows_no_more_than_silence_allows():
    """At ridge 17 mm of alpha0.5 (the next 67 mm on) with 25 mm/s and +14 mm/s^2 from
    three contacts: before, the speed shown was extrapolated to 67 mm/s 3 s later; now it
    stays at most the mean speed that would not yet have reached the next ridge (67.7 mm:
    the ridge after it is the coast end, weighted by the 1 % chance of a miss), and never
    below the 25 mm/s measured."""
    decoder = TrackerDecoder(list(ALPHA05_MM), 400.0)
    h = one_track(25.0, 14.0, 2, 0.0)
    reach = float(decoder._reach_mm[0, 2])
    assert 67.0 < reach < 68.0
    for g in np.arange(0.1, 3.5, 0.1):
        _, speed, _ = decoder._where(h, float(g), False, decoder.count)
        silent = g - decoder._silence_latency
        allowed = max(25.0, reach / silent) if silent > 0 else np.inf
        assert 25.0 - 1e-9 <= speed <= min(allowed, 25.0 + 14.0 * g) + 1e-9, (g, speed, allowed)


def test_a_slow_loop_slip_between_far_apart_contacts_is_not_shown_at_reflex_speeds():
    """The loop benchmark's 20 mm/s slip over alpha0.5 (seed 162100): three contacts
    (one a probe's, early) measured +14 mm/s^2, and between the 3rd contact (2.29 s) and
    the 4th (5.67 s, 67 mm on) the speed shown rose from 40 to 66 mm/s; now it peaks below
    50 mm/s and has fallen back to about the measured 25 mm/s before the 4th contact."""
    label, numbers = sr.VARIANTS["loop"][1]
    rec = sr.Case("loop", label, numbers, "alpha0.5", False, 162100).make()
    decoder = make_decoder("tracker", rec.truth.layout_mm, rec.fs_hz)
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    t = np.array([e.t_s for e in estimates])
    speed = np.array([e.speed_mm_s or 0.0 for e in estimates])
    gap = (t > 2.4) & (t < 5.6)  # between the 3rd and the 4th ridge contact
    assert speed[gap].max() > 0, "no speed shown in the long spacing"
    assert speed[gap].max() < 50.0, speed[gap].max()
    late = gap & (t > 5.0)
    assert late.any() and speed[late].max() < 30.0, speed[late].max()

"""Where a tail kink's pulse starts, and how well the kink bank's time tells it.

The kink bank times a contact at its hinge's peak, refined on finer scales, with a
one-sigma of a quarter of the scale that placed it. A tail kink (`tail_kinks`: a ridge
whose pulse starts on the previous pulse's falling tail) is seen by coarse scales only -
the force does not rise - and there the old pulse's decay bends the hinge (its
curvature peaks about 3 rise times after its onset, where a short spacing's kink
falls): the peak lies late. On constant slips (`tests/decoding/test_tail_onsets.py`:
4 layouts, 12-57 mm/s, both ways, 3 seeds; every contact the tail test adds, matched to
the true onset within 80 ms) it lay 12.7 ms late at the median and 27 of 46 lay outside
twice the one-sigma claimed (a quarter of the refined scale, 5-11 ms): tail contacts
15-55 ms late. The tracker read them as a spacing that does not fit: a braking slip's
speed misread (`test_tracker_braking` fibonacci-75101: median error 8.7 %, 2.8 % timed
back), a 3-4 mm pair of alpha0.1 timed as one spacing twice.

So a tail kink's onset is moved back by `LATE_SHARE` of its finding scale and its
one-sigma is `SPREAD_SHARE` of that scale (never under the kink bank's own): on the same
set the median offset is -0.5 ms and 53 of 62 lie within twice the one-sigma. A change
point fit (the tail's decay up to tau, the new pulse from there, least squares over tau)
was tried first: within 1-2 samples at the finest scales, but at the coarse ones it put
onsets at the edges of its range (the short tail leaves the decay's rise open); not
kept.
"""

from __future__ import annotations

LATE_SHARE = 0.4  # a tail kink's time lies this share of its finding scale late
SPREAD_SHARE = 0.4  # ... with this spread (one sigma), a share of that scale


def tail_placed(
    n_at: int, delta: float, placed: float, width: int, keep_time: bool = False
) -> tuple[int, float, float]:
    """A tail kink's onset as the kink bank's candidates carry it: (sample, fraction of a
    sample, the width whose quarter plus 0.3 samples is its one-sigma, `HingeBank.merge`),
    from the kink bank's own (`HingeBank._refine`) and the scale that found it (width, in
    samples): moved back and widened (module doc); `keep_time`: widened only (a tail of
    the first load's pulse, `arrival_tail`)."""
    onset = n_at + delta - (0.0 if keep_time else LATE_SHARE) * width
    n = round(onset)
    sigma = max(0.25 * placed + 0.3, SPREAD_SHARE * width)
    return n, onset - n, (sigma - 0.3) / 0.25

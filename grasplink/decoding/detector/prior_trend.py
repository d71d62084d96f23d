"""The rising trend before an onset, with the pulse before it out.

A watch takes out the rising trend of the `trend_s` before its onset (`PulseWatcher.start`:
the level's change from `trend_s` before the base to the base, over that time). When an
earlier contact's onset lies in that window, the change is that pulse's rise and tail, not
a trend: a ridge pulse 86 ms before the headline loop's stop (issue 22) made its trend
7.6 N/s where the grip rose at ~2, and with that ramp out the stop's flat step fell back
like a pulse (the watch kernel's drop of `drop_fraction`) and was told one - the stop
then read as a ridge and the slip flag held past the report's due time.

The trend before such a contact is the one its own watch measured over the `trend_s`
before *its* onset (`PulseWatcher.start`, as it measured it, before this rule): the level
before that pulse, the skin's coverage or the grip rising. The watch takes the smaller
of the two: a pulse only ever swells the change over the window (its tail, falling out
of the window's end, can shrink it instead, and the window's own then stands). In a
train of pulses every window holds one, and each earlier window does too: the two stay
alike, and the trend the train's verdicts were tuned on stands. Only contacts decided by
the onset's own decision sample count (chunking cannot change it).
"""

from __future__ import annotations

from collections.abc import Iterable


def trend_past_pulse(
    trends: Iterable[tuple[int, int, float]], index: int, emit: int, start: int, trend: float
) -> float:
    """The trend (N/sample) for an onset at `index` decided at `emit`, whose window starts at
    sample `start`: `trend`, or the trend an earlier contact measured before its own onset
    when that onset lies in (start, index - 2] and it was decided by `emit` (`trends`:
    (onset, decision sample, its trend as measured), oldest first) - the latest such, and
    the smaller of the two (module doc)."""
    for n, e, earlier in reversed(list(trends)):
        if e > emit or n > index - 2:
            continue
        if n <= start:
            return trend
        return min(trend, earlier)
    return trend

"""Where a ridge contact is expected: the windows a gated pulse probe looks in (issue 22).

At 10 dB SNR a 22 mm/s ridge pulse rises over ~57 ms, and the pulse probe's 10-40 ms
windows read only part of that rise (`benchmarks/snr10_detection_bound.py`: the detector
tells 58 % of the 22 mm/s contacts, an oracle matched filter 92 %). A wider window reads
more of it, but run everywhere it also tells more noise: 50 ms flagged 99 updates of the
one-hour held test (s27). So the wide window runs only where a contact is expected - the
decoder says where (`ContactDetector.expect`, called by the tracker while it flags a slip)
- and a held object, which the tracker never flags, never sees it.

`ExpectedWindows` holds those windows as merged sample-index intervals; a `PulseProbe`
given one (`PulseProbe.expected`) tests only the centres inside them. Sans-IO and
deterministic: the windows are sample indices, set between feeds.
"""

from __future__ import annotations

import numpy as np

WINDOWS_KEPT = 64  # intervals held at most (the oldest dropped first)


class ExpectedWindows:
    """Sample-index intervals [first, last] where a ridge contact's onset is expected,
    merged where they touch; those wholly before `forget`'s index are dropped."""

    def __init__(self) -> None:
        self.spans: list[list[int]] = []  # sorted, disjoint [first, last]

    def add(self, first: int, last: int) -> None:
        """Expect a contact's onset (a pulse's centre) between samples `first` and `last`."""
        if last < first:
            raise ValueError(f"ExpectedWindows.add: last {last} before first {first}")
        spans = self.spans
        if spans and first <= spans[-1][1] + 1 and last >= spans[-1][0]:
            # the usual case: the window of the previous update, pushed on
            spans[-1][0] = min(spans[-1][0], first)
            spans[-1][1] = max(spans[-1][1], last)
            return
        spans.append([first, last])
        spans.sort()
        merged: list[list[int]] = []
        for a, b in spans:
            if merged and a <= merged[-1][1] + 1:
                merged[-1][1] = max(merged[-1][1], b)
            else:
                merged.append([a, b])
        self.spans = merged[-WINDOWS_KEPT:]

    def forget(self, before: int) -> None:
        """Drop the intervals that end before sample `before` (centres already tested)."""
        while self.spans and self.spans[0][1] < before:
            self.spans.pop(0)

    def overlaps(self, lo: int, hi: int) -> bool:
        """Does any interval meet samples lo .. hi?"""
        return any(a <= hi and b >= lo for a, b in self.spans)

    def mask(self, lo: int, hi: int) -> np.ndarray:
        """Per sample lo .. hi: inside an interval?"""
        inside = np.zeros(hi - lo + 1, dtype=bool)
        for a, b in self.spans:
            if a <= hi and b >= lo:
                inside[max(a, lo) - lo : min(b, hi) - lo + 1] = True
        return inside

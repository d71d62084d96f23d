"""Playing a recording to one page, sans-IO: where the page is in the run (`PlaybackClock`),
and the `ViewState` fed the recording's messages up to there (`PagePlayback`).

Every call takes the wall time (seconds, the caller's monotonic clock), so the tests
drive both in virtual time. The recording's own clock is what `ViewState` sees: a
message is received at its time in the run, and the page's staleness, ages and 30 s
window are judged on that clock, paused or not.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any

from grasplink.surfaces.view.recording import TRUTH_KIND, Recording
from grasplink.surfaces.view.state import HISTORY_S, ViewState

RATES = (0.25, 1.0, 4.0)  # the page's speed choice


@dataclass
class PlaybackClock:
    """A position in the run that moves at `rate` with the wall clock unless paused;
    held within 0..duration_s (at the end it stays there)."""

    duration_s: float
    at_s: float = 0.0  # the position at `since_s`
    since_s: float = 0.0  # the wall time the position was last set
    rate: float = 1.0
    paused: bool = False

    def __post_init__(self) -> None:
        if self.rate not in RATES:
            raise ValueError(f"rate {self.rate:g}: expected one of {', '.join(map(str, RATES))}")
        self.at_s = self._held(self.at_s)

    def position(self, wall_s: float) -> float:
        moved = 0.0 if self.paused else max(0.0, wall_s - self.since_s) * self.rate
        return self._held(self.at_s + moved)

    def ended(self, wall_s: float) -> bool:
        return self.position(wall_s) >= self.duration_s

    def pause(self, wall_s: float) -> None:
        self.at_s, self.since_s, self.paused = self.position(wall_s), wall_s, True

    def play(self, wall_s: float) -> None:
        """Moving again; from the start when it had reached the end."""
        at = self.position(wall_s)
        self.at_s, self.since_s, self.paused = (0.0 if at >= self.duration_s else at), wall_s, False

    def seek(self, position_s: float, wall_s: float) -> None:
        self.at_s, self.since_s = self._held(position_s), wall_s

    def set_rate(self, rate: float, wall_s: float) -> None:
        if rate not in RATES:
            raise ValueError(f"rate {rate:g}: expected one of {', '.join(map(str, RATES))}")
        self.at_s, self.since_s, self.rate = self.position(wall_s), wall_s, rate

    def _held(self, position_s: float) -> float:
        if not math.isfinite(position_s):
            return 0.0
        return min(max(position_s, 0.0), self.duration_s)


class PagePlayback:
    """One page's view of a recording: its clock and a `ViewState` fed up to its position.

    Going back (a seek) starts a fresh state: the retained topics from the run's start
    (node states, alarms, controls, health) and everything else from one history window
    before the position, so the page's picture at a time is the one a live page had then.
    """

    def __init__(self, recording: Recording, clock: PlaybackClock) -> None:
        self.recording = recording
        self.clock = clock
        self._times = [m.t_s for m in recording.messages]
        self._truth_times = recording.truth_t_s
        self._restart(clock.position(clock.since_s))

    def _restart(self, position_s: float) -> None:
        self.state = ViewState(self.recording.gateway_id)
        self.state.broker_up(0.0)
        self.cursor: int | None = None
        start = position_s - HISTORY_S
        end = bisect.bisect_right(self._times, position_s)
        for message in self.recording.messages[:end]:
            if message.retained or message.t_s >= start:
                self.state.feed(message.topic, message.payload, message.t_s)
        self._fed = end
        self._truth_fed = int(self._truth_times.searchsorted(max(start, 0.0), side="left"))
        self._feed_truth(position_s)
        self._position = position_s

    def seek(self, position_s: float, wall_s: float) -> None:
        self.clock.seek(position_s, wall_s)
        self._restart(self.clock.position(wall_s))

    def frame(self, wall_s: float) -> dict[str, Any]:
        """What the page draws now: the live page's frame, and where the page is in the run."""
        position = self.clock.position(wall_s)
        if position < self._position:
            self._restart(position)
        messages = self.recording.messages
        end = bisect.bisect_right(self._times, position, lo=self._fed)
        for message in messages[self._fed : end]:
            self.state.feed(message.topic, message.payload, message.t_s)
        self._fed = end
        self._feed_truth(position)
        self._position = position
        body, self.cursor = self.state.frame(position, self.cursor)
        body["recording"] = {
            "folder": self.recording.folder.name,
            "position_s": round(position, 3),
            "duration_s": self.recording.duration_s,
            "rate": self.clock.rate,
            "paused": self.clock.paused,
            "ended": position >= self.recording.duration_s,
            "settings": self.recording.settings,
        }
        return body

    def _feed_truth(self, position_s: float) -> None:
        end = int(self._truth_times.searchsorted(position_s, side="right"))
        gateway = self.recording.gateway_id
        truth = self.recording.truth
        for i in range(self._truth_fed, end):
            t = float(self._truth_times[i])
            values = {name: _finite(column[i]) for name, column in truth.items()}
            self.state.add_point(gateway, TRUTH_KIND, round(t * 1000), values, t)
        self._truth_fed = max(self._truth_fed, end)


def _finite(value: Any) -> float | None:
    number = float(value)
    return number if math.isfinite(number) else None

"""Streaming ridge-contact detector: finds the ONSET of every ridge pulse in the FSR signal.

Physics (thesis ch. 5.3.1, 5.4): when the object's leading edge reaches a
ridge the FSR force starts to rise fast (over the time the edge needs to
push the ridge over, ~1.25 mm of travel) and then relaxes. Whatever the exact
pulse shape, its onset is a *kink*: the slope of the force jumps up. The
kink is also what survives when pulses merge at high speed (a new pulse
starting on the decay of the previous one) and it is blind to the slow
trends of the signal (drift, the object covering more of the sensor).

`ContactDetector` composes its parts (`grasplink.decoding.detector`), each with its own
frozen settings (`DetectorSettings` holds them all, today's defaults):

* the hinge (kink) bank (`HingeBank`, `HingeSettings`): slope jumps at 5-80 ms, their
  local maxima above a threshold in noise units, timed coarse to fine - the contacts; a
  kink the force does not rise after counts only on a pulse's falling tail
  (`tail_kinks`: a ridge after a short spacing, its pulse starting on that tail);
* the noise floor (`NoiseFloor`, `NoiseSettings`): each scale's noise per block, the
  white noise the other parts judge against;
* the pulse watcher (`PulseWatcher`, `WatchSettings`): the level after each contact,
  told a pulse (rose and fell back) or a step (rose and stayed), reported later as a
  `PulseCheck`;
* the step probe (`StepProbe`, `StepProbeSettings`): small steps the kink bank misses;
* the pulse probe (`PulseProbe`, `PulseProbeSettings`): ridge pulses the kink bank is
  blind to in heavy noise.

All filters are FIR, run sample by sample with carried state, so chunking cannot change
a single bit; the per-block numeric path runs compiled (`kernels.detector`). Events carry
`emit_index`, the index of the sample whose arrival decided them, so a caller can replay
them exactly in step with its own updates.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from grasplink.decoding.detector.events import ContactEvent, Ledger, PulseCheck
from grasplink.decoding.detector.hinges import (
    DEFAULT_SCALES_S,
    HingeBank,
    HingeSettings,
    decision_lag,
    hinge_widths,
)
from grasplink.decoding.detector.noise_floor import NoiseFloor, NoiseSettings
from grasplink.decoding.detector.pulse_probe import (
    PULSE_SCALES_S,
    PulseProbe,
    PulseProbeSettings,
)
from grasplink.decoding.detector.series import Samples
from grasplink.decoding.detector.step_probe import STEP_IDS, StepProbe, StepProbeSettings
from grasplink.decoding.detector.watch import (
    PulseWatcher,
    WatchSettings,
    level_span,
    sharp_flat_step,
    step_hold_samples,
)
from grasplink.decoding.kernels.detector import all_finite

__all__ = [
    "DEFAULT_SCALES_S",
    "PULSE_SCALES_S",
    "STEP_IDS",
    "ContactDetector",
    "ContactEvent",
    "DetectorSettings",
    "HingeSettings",
    "NoiseSettings",
    "PulseCheck",
    "PulseProbeSettings",
    "StepProbeSettings",
    "WatchSettings",
    "sharp_flat_step",
]


@dataclass(frozen=True)
class DetectorSettings:
    """The contact detector's settings: its parts' (the defaults are the shipped ones)."""

    hinges: HingeSettings = field(default_factory=HingeSettings)
    noise: NoiseSettings = field(default_factory=NoiseSettings)
    watch: WatchSettings = field(default_factory=WatchSettings)
    steps: StepProbeSettings = field(default_factory=StepProbeSettings)
    pulses: PulseProbeSettings = field(default_factory=PulseProbeSettings)


class ContactDetector:
    """Finds ridge-contact onsets in a uniformly sampled FSR stream (see module doc).

    What a caller reads besides `feed`: `lag` and `probe_lag` (how late the kink bank and
    the probes tell a contact, samples), `threshold` (the kink bank's, noise units),
    `channels` (the hinge channels, finest first), `blind` (times the sensor sat on its
    upper rail)."""

    def __init__(self, fs_hz: float, settings: DetectorSettings | None = None):
        self.fs_hz = fs = float(fs_hz)
        self.settings = settings = settings or DetectorSettings()
        widths = hinge_widths(fs, settings.hinges)
        self.lag = decision_lag(widths)  # a contact is decided at most this many samples late
        hold = step_hold_samples(fs, settings.watch)
        self.noise = NoiseFloor(fs, settings.noise, widths, self.lag, hold)
        self.block = self.noise.block
        # samples (and level) held: what the widest channel, the level and its trend read
        self._keep = self.block + 4 * max(widths) + level_span(fs, settings.watch) + 8
        # ... and the samples a tail kink's look back reads (`tail_kinks`: its peak)
        tails = settings.hinges.tails
        look = round(max(tails.look_s, tails.slow_look_s) * fs) if tails.residual_z > 0 else 0
        self._keep_x = max(self._keep, self.block + 4 * max(widths) + look + 8)
        self.samples = Samples(4 * self._keep_x)
        self._trim_at = 0  # samples received when the buffers are next trimmed (`_trim`)
        self.ledger = Ledger()
        shared = (self.noise, self.samples, self.ledger)
        self.hinges = HingeBank(fs, settings.hinges, *shared)
        self.watcher = PulseWatcher(fs, settings.watch, *shared, self.lag, 4 * self._keep)
        self.steps = StepProbe(fs, settings.steps, self.watcher, *shared, self.lag)
        self.pulses = PulseProbe(
            fs, settings.pulses, self.watcher, self.steps, *shared, self.hinges.refine_z
        )
        # the probes tell a contact later than the kink bank: a step probe once every contact
        # near it is decided (`StepProbe.events`), a pulse probe once a step probe would have
        # judged it (`PulseProbe.run`); the tracker waits this long for the contacts they find
        judged = self.watcher.step_hold + self.watcher.level_half
        self.probe_lag = max(
            self.lag + max(self.steps.widths), judged + 2 * max(self.pulses.widths, default=0)
        )

    @property
    def threshold(self) -> float:
        """The kink bank's threshold (noise units)."""
        return self.hinges.threshold

    @property
    def channels(self) -> list:
        """The hinge channels, finest first."""
        return self.hinges.channels

    @property
    def blind(self) -> deque[tuple[float, float]]:
        """Blocks of samples sitting on the sensor's upper rail (saturation), as times."""
        return self.noise.blind

    # ------------------------------------------------------------------ feeding
    def feed(self, t: np.ndarray, x: np.ndarray) -> tuple[list[ContactEvent], list[PulseCheck]]:
        """Take accepted samples; return contacts and pulse verdicts decided by them.

        Accepted: finite (`Decoder.process` drops the rest before they get here). The
        detector's buffers are written in place and its maxima assume finite z, so a NaN
        is refused here, by name, rather than spread through the history."""
        if not len(x):
            return [], []
        if not all_finite(t, x):
            raise ValueError(
                "ContactDetector.feed: samples must be finite (NaN or inf in t or x); "
                "drop them first, as Decoder.process does"
            )
        if len(x) <= self.block:
            return self._feed(t, x)
        # Longer runs (a recording decoded whole) go in pieces that end on block
        # boundaries: the channels take a feed one after the other, so over several blocks
        # a wide channel would see the finest channel's noise from samples after its own
        # centres - a contact waiting on a rail decided earlier than it could be live.
        events: list[ContactEvent] = []
        checks: list[PulseCheck] = []
        start = 0
        while start < len(x):
            end = min(len(x), start + self.block - (self.samples.n + start) % self.block)
            ev, ck = self._feed(t[start:end], x[start:end])
            events += ev
            checks += ck
            start = end
        return sorted(events, key=lambda e: (e.emit_index, e.id)), checks

    def _feed(self, t: np.ndarray, x: np.ndarray) -> tuple[list[ContactEvent], list[PulseCheck]]:
        if self.samples.n == 0:
            self._settle(float(x[0]))
        self.samples.append(t, x)
        self.noise.raw_stats(x, self.samples)
        candidates: list[tuple[int, int, int, float, float, float]] = []
        self.hinges.run(x, candidates)
        self.watcher.run_level(x)
        self.steps.run(x)
        events = self._merge(candidates)
        if events:
            self.ledger.onsets.extend((ev.index, ev.emit_index) for ev in events)
        checks = self.watcher.check(events)
        steps, step_checks = self.steps.events()
        if self.pulses.widths:
            pulses, pulse_checks = self.pulses.run()
            steps += pulses
            step_checks += pulse_checks
        self._trim()
        # block noises still needed: the last noise_blocks before the slowest channel's block
        self.noise.forget(self.hinges.channels[-1].next_n)  # (the widest lags most)
        events = sorted(events + steps, key=lambda e: (e.emit_index, e.id))
        return events, checks + step_checks

    def _settle(self, first: float) -> None:
        """The filters' taps and states, settled on the first sample (as if it had been
        held before: slopes and differences 0), for the kernels that run them in place."""
        self.hinges.settle(first)
        self.steps.settle(first)
        self.watcher.settle(first)

    def _merge(self, candidates: list) -> list[ContactEvent]:
        """The kink bank's candidates of this feed as contacts (`HingeBank.merge`); a seam
        a tracing detector (`evaluation.contact_truth`) overrides to see them all."""
        return self.hinges.merge(candidates)

    def _trim(self) -> None:
        """Each part's buffers cut back once twice what it keeps is held. None gains more
        than an entry per sample, so until the fewest samples any part has `room` for have
        come (`_trim_at`) none would cut: the trims are not asked (a feed's look at four
        parts' sizes, most feeds) - the same cuts at the same samples."""
        if self.samples.n < self._trim_at:
            return
        keep = self._keep
        self.samples.trim(self._keep_x)
        self.watcher.trim(keep, [w for w, _, _ in self.steps.probes + self.pulses.watches])
        self.steps.trim(keep)
        self.hinges.trim(keep)
        room = min(
            self.samples.room(self._keep_x),
            self.watcher.room(keep),
            self.steps.room(keep),
            self.hinges.room(keep),
        )
        self._trim_at = self.samples.n + room

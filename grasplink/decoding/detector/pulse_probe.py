"""The pulse probe: ridge pulses the kink bank is blind to in heavy noise.

Where the kink bank is blind - heavy noise, the pulses told so far under `snr`
white-noise units high at their median - the probe measures the SIZE of each rise
(after-minus-before means over 10-40 ms, ramps out): at 10 dB SNR a ridge pulse is 5-7
noise units of that and 2 of its kink. Its candidates the pulse watcher tells pulses are
ridge contacts (onset half the placing window before the rise's middle), unless the kink
bank or the step probe has them. Before any pulse is told it takes `prior_n` for their
height (open at 10 dB from a slip's first contact, at a stricter threshold); a clean
signal never opens it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from grasplink.decoding.detector.events import ContactEvent, Ledger, PulseCheck
from grasplink.decoding.detector.noise_floor import NOISE_FLOOR_N, NoiseFloor
from grasplink.decoding.detector.series import Samples
from grasplink.decoding.detector.step_probe import StepProbe
from grasplink.decoding.detector.watch import PulseWatcher, Watch

PULSE_SCALES_S = (0.01, 0.02, 0.04)  # the pulse probe's windows
PULSE_RAMP = 0.5  # the pulse probe takes out this share of the differences 2 w either side
# the pulse probe's gate before any pulse is told (`PulseProbe._gate`): a ridge pulse's
# height on the thesis skin (alpha 0.8-1.2 N times 1 - e^(-D / 10 mm): 0.8 N for D = 16 mm)
PULSE_PRIOR_N = 0.8


@dataclass(frozen=True)
class PulseProbeSettings:
    """The pulse probe's windows (s; none: off), thresholds (white-noise units) and gate."""

    scales_s: tuple[float, ...] = PULSE_SCALES_S
    threshold: float = 4.5
    snr: float = 10.0  # open while the pulses told are under this high at their median
    prior_n: float = PULSE_PRIOR_N  # their height before any is told (N)
    first_threshold: float = 5.5  # the threshold until one is told


class PulseProbe:
    """The pulse probe (see the module doc): its candidates watched, the pulses told out
    (`run`)."""

    def __init__(
        self,
        fs_hz: float,
        settings: PulseProbeSettings,
        watcher: PulseWatcher,
        steps: StepProbe,
        noise: NoiseFloor,
        samples: Samples,
        ledger: Ledger,
        refine_z: float,
    ):
        self.fs_hz = fs_hz
        self.settings = settings
        self.noise, self.watcher, self.steps = noise, watcher, steps
        self.samples, self.ledger = samples, ledger
        self.block = noise.block
        self.refine_z = refine_z  # (the kink bank's: coarse to fine alike)
        self.widths = sorted({max(2, round(s * fs_hz)) for s in settings.scales_s})
        self.threshold = float(settings.threshold)
        self.snr = float(settings.snr)
        self.prior_n = float(settings.prior_n)
        self.first_threshold = float(settings.first_threshold)
        self._next = 0  # next centre the pulse probe tests
        self.watches: list[tuple[Watch, float, int]] = []  # (watch, z, placing w)
        # told pulses, to be emitted: (emit, index, z, placing w, height)
        self._ready: list[tuple[int, int, float, int, float]] = []
        self._gates: dict[int, tuple[float, float] | None] = {}  # block -> `_gate`

    def run(self) -> tuple[list[ContactEvent], list[PulseCheck]]:
        """Ridge pulses the kink bank is blind to (issue 22, 10 dB SNR): the SIZE of a rise.

        In heavy noise a ridge pulse's kink (a slope jump) is a couple of noise units at
        its best scale, while the rise itself - the mean after less the mean before, over
        10-40 ms, less half the same difference 2 w earlier and later (a ramp is no rise;
        a quarter each: a pulse's own fall after it adds) - is 5-7. Local maxima (over
        +-w, best scale per centre) above `threshold` noise units, placed coarse to
        fine, the onset half the placing window before the centre (the rise's middle);
        watched like a contact, and told a ridge contact only when it falls back like a
        pulse. Only where the kink bank is blind (`_gate`): a clean signal's
        contacts are the kink bank's alone.
        """
        events: list[ContactEvent] = []
        checks: list[PulseCheck] = []
        ws = self.widths
        W = ws[-1]
        hi = self.samples.n - 1 - 4 * W  # z known over +-W: samples to centre + 4 W - 1
        lo = max(self._next, 4 * W)
        lo = max(lo, self.samples.start + 4 * W)  # (samples held: always, as the history is kept)
        if hi - lo + 1 >= 4 * ws[0]:  # (in batches: the sums' cost is mostly per call)
            self._next = hi + 1
            blocks = range((lo - W) // self.block, (hi + W) // self.block + 1)
            gates = {b: self._gate(b) for b in blocks}
            if any(gates[b] is not None for b in range(lo // self.block, hi // self.block + 1)):
                self._candidates(lo, hi, gates)
        if not (self.watches or self._ready):
            return events, checks  # nothing watched or told (most blocks): as below
        still = []
        for watch, z, w in self.watches:
            done = self.watcher.advance(watch)
            if done is None:
                still.append((watch, z, w))
            elif done.pulse is True:
                # told when a step probe near it would have been judged: a stop's step in
                # noise may look like a pulse early on, and the step probe tells it better
                emit = max(
                    done.emit_index,
                    watch.index + self.watcher.step_hold + self.watcher.level_half + 2 * W,
                )
                height = self.watcher.told_height(watch, done.emit_index)
                self._ready.append((emit, watch.index, z, w, height))
        self.watches = still
        waiting = []
        for emit, index, z, w, height in sorted(self._ready):
            if emit >= self.samples.n:
                waiting.append((emit, index, z, w, height))
                continue
            if (
                any(abs(index - n) <= 2 * w + 2 for n, e in self.ledger.onsets if e <= emit)
                or any(abs(index - n) <= w + v + 2 for n, _, v in self.steps.onsets)
                or any(abs(index - n) <= w + v + 2 for _, v, n, _, _, _ in self.steps.confirmed)
            ):
                continue  # the kink bank or the step probe has it
            self.ledger.onsets.append((index, emit))
            self.ledger.heights.append((emit, height))
            cid = self.ledger.take_id()
            sigma = (0.25 * w + 0.3) / self.fs_hz
            t = self.samples.time(index, 0.0)
            events.append(ContactEvent(cid, t, index, emit, z, 0.0, w / self.fs_hz, sigma))
            checks.append(PulseCheck(cid, emit, True))
        self._ready = waiting
        return events, checks

    def _gate(self, block: int) -> tuple[float, float] | None:
        """The white noise (N per sample) for the pulse probe's centres in `block` and their
        threshold (noise units), or None
        where it stays off: the noise unknown, or the contacts told pulses (decided before
        the block, over the last `history_s`) rising to `snr` noise units or more at
        their median - the kink bank sees such pulses. With none told yet the median is
        `prior_n`'s: in heavy noise the probe finds a slip's first contacts too (at
        10 dB SNR a full first pulse is 3-4 noise units: the kink bank misses half), while
        a thesis-like noise (0.02 N) keeps it shut on a held object. Until a pulse is told
        its threshold is `first_threshold`: a slip's first pulses are full ones (9
        units of the probe at their median), and one noise contact told a pulse on a held
        object would open the gate at the plain threshold for `history_s`."""
        if block in self._gates:
            return self._gates[block]
        white = self.noise.white(block)
        if white is None:
            return None
        white_n = max(white[0], NOISE_FLOOR_N)
        start = block * self.block
        span = self.noise.history_blocks * self.block
        recent = sorted(h for e, h in self.ledger.heights if start - span <= e < start)
        threshold = self.threshold
        if not recent:  # none told yet (the slip's first contacts, or none at all)
            recent = [self.prior_n]
            threshold = max(threshold, self.first_threshold)
        blind = recent[(len(recent) - 1) // 2] < self.snr * white_n
        sigma = (white_n, threshold) if blind else None
        if block < self.samples.n // self.block:  # (its white noise final by then: kept)
            self._gates[block] = sigma
            for old in [b for b in self._gates if b < block - 4]:
                del self._gates[old]
        return sigma

    def _candidates(self, lo: int, hi: int, gates: dict[int, tuple[float, float] | None]) -> None:
        """The pulse probe's candidates among centres lo .. hi (see `run`), watched."""
        ws = self.widths
        W = ws[-1]
        i0 = lo - 4 * W - self.samples.start  # samples lo - 4W .. hi + 4W - 1
        x = self.samples.x[i0 : hi + 4 * W - self.samples.start]
        m = hi - lo + 1 + 2 * W  # centres lo - W .. hi + W
        B = self.block
        gated = [gates[c // B] or (math.inf, math.inf) for c in range(lo - W, hi + W + 1)]
        sigma = np.array([g[0] for g in gated])
        threshold = np.array([g[1] for g in gated])
        z = np.empty((len(ws), m))
        size = np.empty((len(ws), m))
        for si, w in enumerate(ws):
            # sums of w samples, each in one order (chunking cannot change a bit)
            count = len(x) - w + 1
            sums = x[0:count].copy()
            for k in range(1, w):
                sums += x[k : k + count]
            d = (sums[w:] - sums[: len(sums) - w]) / w  # d[j]: centre lo - 4W + w + j
            j0 = 3 * W - w  # centre lo - W in d
            c = d[j0 : j0 + m]
            adj = c - PULSE_RAMP * (d[j0 - 2 * w : j0 - 2 * w + m] + d[j0 + 2 * w : j0 + 2 * w + m])
            z[si] = adj / (sigma * math.sqrt(2.0 / w * (1.0 + 2.0 * PULSE_RAMP * PULSE_RAMP)))
            size[si] = c
        best = z.max(axis=0)
        which = z.argmax(axis=0)
        inside = slice(W, W + hi - lo + 1)
        for j in np.flatnonzero(best[inside] >= threshold[inside]).tolist():
            j += W
            si = int(which[j])
            w = ws[si]
            if best[j] < best[j - w : j + w + 1].max() or best[j - w : j].max() == best[j]:
                continue  # not the local maximum (the first of equals)
            sig = sigma[j]
            if size[si, j] >= self.snr * sig:
                continue  # a rise the kink bank sees
            if size[si, j] < self.threshold * sig * math.sqrt(2.0 / w):
                continue  # no rise of its own: the end of a fall (a grip released)
            # coarse to fine: the finest scale that still sees it places it
            k, reach, placed = j, w, w
            for fi in range(si - 1, -1, -1):
                a, b = max(0, k - reach), min(m - 1, k + reach)
                q = a + int(np.argmax(z[fi, a : b + 1]))
                if z[fi, q] < self.refine_z or q in (a, b):
                    break
                k, reach, placed = q, ws[fi], ws[fi]
            onset = lo - W + k - placed // 2
            watch = self.watcher.start(-1, onset)
            if watch is not None:
                self.watches.append((watch, float(best[j]), placed))

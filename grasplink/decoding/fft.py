"""The thesis' spectral slip detector (ch. 4.4-4.5): f = v / D on a uniform skin.

A uniform ridged skin is a signal generator: an object slipping at v over
ridges D apart pulses the FSR at f = v / D. Every update the decoder takes
the last `window_s` seconds of raw samples (at least `min_fill` of a window
after a start or a gap), removes a straight line (DC offset, drift, the
slow rise as the object covers the sensor), applies a Hann window,
zero-pads to `nfft` (default: 4x the window, rounded up to a power of two)
and looks for the spectral line in [f_min, f_max], f_max = max(20 Hz,
1.25 `v_max` / D) below 0.45 fs - the thesis' [1, 20] Hz band, widened to
reach the speeds asked for (`v_max` 150 mm/s) - and f_min = max(`f_min_hz`,
`min_cycles` / window): a line needs 1.5 cycles in the window to be one (a
kink of a grip ramp in a 0.5 s window looks like one cycle at ~1 Hz).

Which peak: the largest of the power spectrum weighted by f^2 (the spectrum
of the derivative: the onset of a slip and the first, tall contact make a
broad hump at low frequencies that would otherwise hide the line); its
frequency is then refined on the unweighted spectrum (a parabola through
the log power of the local maximum and its neighbours), so the weighting
does not bias it.

Slip is a line that stands out: its power over the white-noise power per
bin (sigma^2 sum(w^2), sigma from the MAD of sample differences, at least
`min_noise_n`) >= `on_ratio` (100, 20 dB) turns the flag on, < `off_ratio`
(30) turns it off (hysteresis). Not a line: a peak on the band's edge (a
step or a ramp) or one wider at half power than `max_width` / window (3 Hz
for 1 s: a single pulse, not a train). While slipping: speed = f D.

What a spectrum cannot tell: the direction (a pulse train looks the same
both ways) and the position. The speed is reported as a magnitude
(positive) with confidence at most `uniform_confidence` (0.5), position
None. On a non-uniform layout the decoder still runs with the mean spacing
as D, but the answer is a guess: confidence at most `nonuniform_confidence`
(0.25). Confidence within the cap: 1 - on_ratio / (line-to-noise ratio).
Cost: one FFT of `nfft` points per update (default every 10 ms). Accuracy
(the uniform4 layout is its home ground) and CPU per sample:
docs/benchmarks/decoding.md (rows `fft`). The flag comes after a period or
two at low speed, but at high speed only once the train fills a good part
of the window.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

import numpy as np

from grasplink.decoding.base import (
    DEFAULT_UPDATE_S,
    GAP_PERIODS,
    Decoder,
    SlipEstimate,
    StaticForce,
)
from grasplink.decoding.filters import NoiseEstimator
from grasplink.errors import ConfigError


class FftDecoder(Decoder):
    name = "fft"

    def __init__(
        self,
        layout_mm: Sequence[float],
        fs_hz: float,
        *,
        update_period_s: float = DEFAULT_UPDATE_S,
        window_s: float = 1.0,
        f_min_hz: float = 1.0,
        v_max: float = 150.0,
        on_ratio: float = 100.0,
        off_ratio: float = 30.0,
        min_noise_n: float = 0.002,
        max_width: float = 3.0,
        min_fill: float = 0.5,
        min_cycles: float = 1.5,
        differentiate: bool = True,
        nfft: int | None = None,
        uniform_confidence: float = 0.5,
        nonuniform_confidence: float = 0.25,
        static_corner_hz: float = 2.0,
    ):
        super().__init__(layout_mm, fs_hz, update_period_s=update_period_s)
        if not window_s > 0:
            raise ConfigError(f"window_s must be > 0, got {window_s}")
        if not 0 < off_ratio <= on_ratio:
            raise ConfigError(f"need 0 < off_ratio <= on_ratio, got {off_ratio}, {on_ratio}")
        spacings = self.geometry.spacings_mm
        self.uniform = bool(np.ptp(spacings) <= 1e-9 * spacings.mean())
        self.spacing_mm = float(spacings.mean())
        self.window = max(8, round(window_s * self.fs_hz))
        self.min_samples = max(8, round(min_fill * self.window))
        n = nfft or 1 << int(np.ceil(np.log2(4 * self.window)))
        if n < self.window:
            raise ConfigError(f"nfft {n} is shorter than the window ({self.window} samples)")
        self.nfft = n
        self.freqs = np.fft.rfftfreq(n, 1.0 / self.fs_hz)
        f_max = min(max(20.0, 1.25 * v_max / self.spacing_mm), 0.45 * self.fs_hz)
        f_min = max(f_min_hz, min_cycles / window_s)  # a line needs cycles in the window
        self.band = np.nonzero((self.freqs >= f_min) & (self.freqs <= f_max))[0]
        if len(self.band) < 3:
            raise ConfigError(
                f"band {f_min:g}-{f_max:g} Hz is too narrow at "
                f"{self.fs_hz:g} Hz with a {window_s:g} s window"
            )
        self.on_ratio, self.off_ratio = float(on_ratio), float(off_ratio)
        self.max_width_hz = float(max_width) / window_s
        self.differentiate = bool(differentiate)
        self._f2 = self.freqs[self.band] ** 2
        self.cap = uniform_confidence if self.uniform else nonuniform_confidence
        self._hann = np.hanning(self.window)
        self._hann_energy = float(np.sum(self._hann**2))
        self.min_noise_n = float(min_noise_n)
        self.noise = NoiseEstimator(max(8, round(0.5 * self.fs_hz)))
        self._static_corner = static_corner_hz
        self._static = StaticForce(self.fs_hz, static_corner_hz)
        self._buffer = np.zeros(0)  # the last `window` samples since the last restart
        self._last_t: float | None = None
        self._slip = False
        self._force: float | None = None

    def process(self, t: np.ndarray, x: np.ndarray) -> list[SlipEstimate]:
        previous = -np.inf if self._last_t is None else self._last_t
        steps = np.diff(np.concatenate([[previous], t]))
        restarts = np.nonzero(steps > GAP_PERIODS / self.fs_hz)[0]  # first sample after a gap
        bounds = [0, *restarts.tolist(), len(t)]
        force = np.empty(len(x))
        for a, b in itertools.pairwise(bounds):
            if b <= a:
                continue
            if a in restarts:
                self._static = StaticForce(self.fs_hz, self._static_corner)
            force[a:b] = self._static.filter(x[a:b])
        combined = np.concatenate([self._buffer, x])
        offset = len(self._buffer)
        out = []
        fed = 0  # samples of this chunk given to the noise estimate and the restart logic
        for count, g in self.update_points(t):
            self._advance(x, restarts, fed, count)
            fed = max(fed, count)
            if count:
                self._force = float(force[count - 1])
                begin = self._window_begin(restarts, count, offset)
                self._buffer = combined[begin : offset + count]
            out.append(self._estimate(g))
        self._advance(x, restarts, fed, len(x))
        self._buffer = combined[self._window_begin(restarts, len(x), offset) :]
        self._force = float(force[-1])
        self._last_t = float(t[-1])
        return out

    def _window_begin(self, restarts: np.ndarray, count: int, offset: int) -> int:
        """Index in buffer+chunk where the window ending at sample `count` starts."""
        begin = offset + count - self.window
        k = int(np.searchsorted(restarts, count - 1, side="right"))
        if k:  # a restart in this chunk at or before the last sample: nothing before it
            begin = max(begin, offset + int(restarts[k - 1]))
        return max(0, begin)

    def _advance(self, x: np.ndarray, restarts: np.ndarray, start: int, stop: int) -> None:
        """Noise estimate and restarts for samples [start, stop) of the chunk."""
        if stop <= start:
            return
        inside = restarts[(restarts >= start) & (restarts < stop)].tolist()
        edges = [start, *inside, stop]
        for a, b in itertools.pairwise(edges):
            if a in inside:
                self.noise.reset(keep_history=True)
                self._slip = False
            if b > a:
                self.noise(x[a:b])

    def spectrum(self) -> np.ndarray | None:
        """Magnitude spectrum of the current window (None until it is full enough)."""
        n = len(self._buffer)
        if n < self.min_samples:
            return None
        x = self._buffer
        k = np.arange(n, dtype=np.float64) - (n - 1) / 2.0  # centred: slope and mean separate
        slope = float(k @ x) / float(k @ k)
        w = self._hann if n == self.window else np.hanning(n)
        residual = x - x.mean() - slope * k
        return np.abs(np.fft.rfft(residual * w, self.nfft))

    def _width_hz(self, power: np.ndarray, i: int) -> float:
        """Width of the spectral peak at half its power."""
        half = power[i] / 2
        below = np.nonzero(power[:i] < half)[0]
        above = np.nonzero(power[i + 1 :] < half)[0]
        if not len(below) or not len(above):
            return np.inf
        step = self.freqs[1] - self.freqs[0]
        return float((i + 1 + above[0] - below[-1]) * step)

    def _estimate(self, g: float) -> SlipEstimate:
        spectrum = self.spectrum()
        if spectrum is None:
            self._slip = False
            return SlipEstimate(g, False, None, None, self._force, 0.0)
        raw = spectrum[self.band] ** 2
        power = raw * self._f2 if self.differentiate else raw
        i = int(np.argmax(power))
        ratio = self._prominence(power, raw, i)
        self._slip = ratio >= (self.off_ratio if self._slip else self.on_ratio)
        if not self._slip:
            return SlipEstimate(g, False, None, None, self._force, 0.0)
        # refine on the unweighted spectrum (the f^2 weighting would pull the peak up)
        while 0 < i < len(raw) - 1 and raw[i + 1] > raw[i]:
            i += 1
        while 0 < i < len(raw) - 1 and raw[i - 1] > raw[i]:
            i -= 1
        delta = 0.0
        if 0 < i < len(raw) - 1:
            lo, mid, hi = np.log(raw[i - 1 : i + 2] + 1e-300)
            denom = lo - 2 * mid + hi
            delta = 0.5 * (lo - hi) / denom if denom < 0 else 0.0
        step = self.freqs[1] - self.freqs[0]
        f = float(self.freqs[self.band[i]] + delta * step)
        confidence = self.cap * float(np.clip(1.0 - self.on_ratio / ratio, 0.0, 1.0))
        # a spectrum line tells the speed, never the direction (None)
        return SlipEstimate(g, True, f * self.spacing_mm, None, self._force, confidence)

    def _prominence(self, power: np.ndarray, raw: np.ndarray, i: int) -> float:
        """How far the line stands out of the white noise: its power over the noise power.

        The noise power per bin is sigma^2 sum(w^2) for white noise of sigma (robust
        MAD estimate of the sample noise); 0 when the peak is on the band's edge (a
        step or a ramp) or broader than `max_width` / window (one pulse, not a train).
        """
        if not 0 < i < len(power) - 1 or self._width_hz(power, i) > self.max_width_hz:
            return 0.0
        sigma = self.noise.sigma
        if sigma is None:
            return 0.0
        n = len(self._buffer)
        w2 = self._hann_energy if n == self.window else float(np.sum(np.hanning(n) ** 2))
        floor = max(sigma, self.min_noise_n) ** 2 * w2
        return float(raw[i] / floor)

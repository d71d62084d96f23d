"""Surface EMG of the forearm flexor from the wearer's contraction level (thesis ch. 2.3).

The EMG node rectifies the raw signal and averages it (the envelope), then
compares the envelope with its calibration: below e_min is level 0, [e_min,
e_max] splits into four equal levels 1..4, above e_max is level 5. This
effect inverts that: a contraction level (`wearer.level`, 0..5, fractional
values interpolate) becomes a raw signal whose rectified mean lands in the
middle of that level's band.

Model (`emg.surface`, domain emg, sampled at the EMG node's rate):

    raw_uv(t) = sigma(t) * n(t)

* n(t): Gaussian white noise through a Butterworth band-pass (`band_hz`,
  `order` per edge; SOS, state carried; warmed up on noise at construction,
  so n is stationary from the first sample), scaled to unit rectified mean
  sqrt(2 / pi) of a unit Gaussian. With `regulate_s` = 0 the scale is the
  constant unit-variance gain 1 / sqrt(sum h^2): a stationary Gaussian
  process, whose 1 s rectified mean scatters by about 2.5 % (the band holds
  ~860 independent samples per second), so about 1 window in 15 misses the
  target by more than 5 %. By default (`regulate_s` = 0.25 s) the noise is
  generated in blocks of that length and each block's gain makes its
  rectified mean exactly sqrt(2 / pi); the gain is interpolated between
  block centres (it moves by a few % over a block), so every window of
  about a second or more has the target rectified mean within ~1 %, while
  the samples stay band-limited and Gaussian to the eye.
* target rectified mean e(level): level 0 -> `rest_uv`; level j = 1..4 ->
  e_min + (j - 0.5) / 4 (e_max - e_min); level 5 -> 1.25 e_max; linear between
  integer levels, clamped to [0, 5].
* sigma = e sqrt(pi / 2), since the rectified mean of a zero-mean Gaussian is
  sigma sqrt(2 / pi); smoothed by a first-order low-pass of time constant
  `onset_s` (SOS, state carried), starting settled at the first sample's value.
* fatigue (`fatigue_per_s` = phi, default 0 = off): accumulated contraction
  A(t) = integral of clip(level / 4, 0, 1.25) dt (seconds at the maximum
  comfortable contraction); f = phi A. The amplitude grows to sigma (1 + f)
  and the spectrum compresses by c = max(1 / (1 + f), 0.5): n(t) becomes a
  mix of a bank of unit-variance band-pass noises with bands band_hz x s,
  s = 1.0, 0.9, ..., 0.5, weights sqrt(1 - w), sqrt(w) between the two bands
  around c (independent bands, so the mix keeps unit variance while its
  power moves down in frequency).

Randomness: `ctx.rng("emg.surface")`, consumed in block order (one normal
per sample per band; see `NoiseBank`), so chunking does not change the signal.
"""

from __future__ import annotations

import math
from typing import ClassVar

import numpy as np
from scipy import signal

from grasplink.core.params import Params
from grasplink.simulators import signals as sig
from grasplink.simulators.core import (
    EMG,
    SHORT_CHUNK_SAMPLES,
    AheadStream,
    Context,
    Effect,
    Io,
    register,
)

LEVEL, RAW = sig.WEARER_LEVEL, sig.EMG_RAW_UV
LEVELS = 4  # e1..e4 between e_min and e_max
TOP_LEVEL = LEVELS + 1  # e5, above e_max
FATIGUE_SCALES = (1.0, 0.9, 0.8, 0.7, 0.6, 0.5)  # spectral compression bank
WARMUP_CYCLES = 40  # warm-up length in periods of the band's lower edge
DEFAULT_BLOCK_S = 0.25  # noise generation block when not regulating
RECTIFIED_MEAN_TO_SIGMA = math.sqrt(math.pi / 2)


def sosfilt_floats(sos: np.ndarray, x: np.ndarray, zi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """`scipy.signal.sosfilt(sos, x, zi=zi)` for one section, sample by sample in floats: the
    same arithmetic in the same order (transposed direct form II), the same bits, without
    sosfilt's call cost, which is most of a chunk of a few samples."""
    b0, b1, b2, _, a1, a2 = sos[0].tolist()
    z0, z1 = zi[0].tolist()
    out = []
    for value in x.tolist():
        y = b0 * value + z0
        z0 = b1 * value - a1 * y + z1
        z1 = b2 * value - a2 * y
        out.append(y)
    return np.array(out), np.array([[z0, z1]])


def sosfilt_compiled(
    sos: np.ndarray, x: np.ndarray, zi: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`scipy.signal.sosfilt(sos, x, zi=zi)` for float64 sections and samples, through the
    decoder's compiled section loop (`decoding.kernels.detector.sos_run`: sosfilt's sample
    loop operation for operation, the same bits). sosfilt's checks cost ~80-100 µs a call
    (scipy 1.17), most of a physics block of a few hundred samples: a loop scene's EMG
    (its smoothing and noise blocks) spent ~3 % of its run in them."""
    from grasplink.decoding.kernels.detector import sos_run  # numba: only when used

    state = np.array(zi, dtype=np.float64)  # sosfilt returns a new final state
    out = np.empty(len(x))
    sos_run(
        np.ascontiguousarray(sos, dtype=np.float64),
        state,
        np.ascontiguousarray(x, dtype=np.float64),
        out,
    )
    return out, state


def level_targets_uv(rest_uv: float, e_min_uv: float, e_max_uv: float) -> np.ndarray:
    """Target rectified mean for levels 0..5 (the centre of each level's band)."""
    width = (e_max_uv - e_min_uv) / LEVELS
    middle = [e_min_uv + (j - 0.5) * width for j in range(1, LEVELS + 1)]
    return np.array([rest_uv, *middle, 1.25 * e_max_uv])


def unit_variance_gain(sos: np.ndarray, length: int) -> float:
    """1 / sqrt(sum h^2): scales the filter's output to unit variance for unit white input."""
    impulse = np.zeros(length)
    impulse[0] = 1.0
    energy = float(np.sum(signal.sosfilt(sos, impulse) ** 2))
    return 1.0 / math.sqrt(energy)


class NoiseBank:
    """Unit band-limited Gaussian noises, one column per band, by absolute sample index.

    The noise does not depend on the effect's input, so it is generated ahead
    in blocks of `block` samples (all bands together: `block` x bands normals
    per block, in block order), which keeps the draws independent of how the
    caller chunks time. Each block gets a gain per band: with regulation, the
    one that makes the block's rectified mean exactly sqrt(2 / pi) (that of a
    unit Gaussian); without, the filter's unit-variance gain. The gain applied
    to a sample is interpolated linearly between the centres of the blocks
    around it, so it varies smoothly.
    """

    def __init__(
        self,
        bands: list[np.ndarray],
        rng: np.random.Generator,
        block: int,
        regulate: bool,
        warmup: int,
        impulse_length: int,
    ):
        self.bands = bands
        self.rng = rng
        self.block = block
        self.regulate = regulate
        self.unit_gains = np.array([unit_variance_gain(sos, impulse_length) for sos in bands])
        self.states = []
        draws = rng.standard_normal((warmup, len(bands)))
        for column, sos in enumerate(bands):
            _, state = signal.sosfilt(sos, draws[:, column], zi=np.zeros((sos.shape[0], 2)))
            self.states.append(state)
        self.blocks: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # index -> (data, gains)
        self.next_block = 0

    def _generate(self) -> None:
        draws = self.rng.standard_normal((self.block, len(self.bands)))
        data = np.empty_like(draws)
        for column, sos in enumerate(self.bands):
            data[:, column], self.states[column] = sosfilt_compiled(
                sos, draws[:, column], self.states[column]
            )
        if self.regulate:
            gains = math.sqrt(2.0 / math.pi) / np.mean(np.abs(data), axis=0)
        else:
            gains = self.unit_gains
        self.blocks[self.next_block] = (data, gains)
        self.next_block += 1

    def take(self, start: int, count: int) -> np.ndarray:
        """Noise for absolute samples [start, start + count): count x bands."""
        block = self.block
        index = np.arange(start, start + count)
        which, offset = np.divmod(index, block)
        while self.next_block <= which[-1] + 1:
            self._generate()
        first, last = int(which[0]), int(which[-1])
        for old in [k for k in self.blocks if k < first - 1]:
            del self.blocks[old]
        data = np.concatenate([self.blocks[k][0] for k in range(first, last + 1)])
        gains = np.stack([self.blocks[max(k, 0)][1] for k in range(first - 1, last + 2)])
        # gains[j] belongs to block first - 1 + j (block -1 borrows block 0's gain).
        half = (block - 1) / 2
        after = offset >= half
        left = np.where(after, which, which - 1) - (first - 1)
        frac = np.where(after, offset - half, offset - half + block) / block
        frac = frac[:, None]
        gain = gains[left] * (1.0 - frac) + gains[left + 1] * frac
        return data[index - first * block] * gain


@register
class SurfaceEmg(Effect):
    """Raw surface EMG (uV) whose rectified mean follows the contraction level.

    Parameters (defaults): `band_hz` ([20, 450] Hz), `order` (4, per edge),
    `rest_uv` (10), `e_min_uv` (50), `e_max_uv` (500), `onset_s` (0.05 s;
    0 = no smoothing), `fatigue_per_s` (0 per s), `regulate_s` (0.25 s; 0 =
    unregulated stationary Gaussian noise). See the module docstring.
    """

    kind: ClassVar[str] = "emg.surface"
    domain: ClassVar[str] = EMG
    inputs: ClassVar[tuple[str, ...]] = (LEVEL,)
    outputs: ClassVar[tuple[str, ...]] = (RAW,)
    summary: ClassVar[str] = (
        "band-limited Gaussian EMG whose rectified mean is the centre of "
        "the contraction level's band"
    )

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.rate_hz = ctx.rates_hz[EMG]
        nyquist = self.rate_hz / 2
        band = params.numbers("band_hz", [20.0, 450.0], low=0.0, low_open=True, min_len=2)
        if len(band) != 2 or not band[0] < band[1] < nyquist:
            raise params.error(
                "band_hz",
                f"expected [low, high] with 0 < low < high < "
                f"{nyquist:g} Hz (the EMG Nyquist frequency), "
                f"got {list(band)}",
            )
        self.band_hz = band
        self.order = params.integer("order", 4, low=1, high=8)
        self.rest_uv = params.number("rest_uv", 10.0, low=0.0)
        self.e_min_uv = params.number("e_min_uv", 50.0, low=0.0)
        self.e_max_uv = params.number("e_max_uv", 500.0, low=0.0)
        if self.e_max_uv <= self.e_min_uv:
            raise params.error(
                "e_max_uv",
                f"expected a number above e_min_uv ({self.e_min_uv:g}), got {self.e_max_uv:g}",
            )
        self.onset_s = params.number("onset_s", 0.05, low=0.0)
        self.fatigue_per_s = params.number("fatigue_per_s", 0.0, low=0.0)
        self.regulate_s = params.number("regulate_s", 0.25, low=0.0)
        block = round(self.regulate_s * self.rate_hz)
        if self.regulate_s > 0 and block < 2:
            raise params.error(
                "regulate_s",
                f"expected 0 or at least two EMG samples "
                f"({2 / self.rate_hz:g} s), got {self.regulate_s:g}",
            )
        self.targets_uv = level_targets_uv(self.rest_uv, self.e_min_uv, self.e_max_uv)

        scales = FATIGUE_SCALES if self.fatigue_per_s > 0 else FATIGUE_SCALES[:1]
        bands = [
            signal.butter(
                self.order, [band[0] * s, band[1] * s], "bandpass", fs=self.rate_hz, output="sos"
            )
            for s in scales
        ]
        lowest_hz = band[0] * scales[-1]
        self._noise = NoiseBank(
            bands,
            ctx.rng(self.kind),
            block=block or max(1, round(DEFAULT_BLOCK_S * self.rate_hz)),
            regulate=self.regulate_s > 0,
            warmup=math.ceil(WARMUP_CYCLES * self.rate_hz / lowest_hz),
            impulse_length=max(4096, math.ceil(5 * WARMUP_CYCLES * self.rate_hz / lowest_hz)),
        )
        self._sample = 0  # absolute index of the next sample the bank makes
        self._bank = AheadStream(self._take)

        self._smooth_sos = None
        if self.onset_s > 0:
            a = 1.0 - math.exp(-1.0 / (self.rate_hz * self.onset_s))
            self._smooth_sos = np.array([[a, 0.0, 0.0, 1.0, a - 1.0, 0.0]])
        self._smooth_state: np.ndarray | None = None  # set at the first sample
        self._contraction_s = 0.0  # accumulated contraction A, seconds at level 4

    def _take(self, count: int) -> np.ndarray:
        bank = self._noise.take(self._sample, count)
        self._sample += count
        return bank

    def sigma_uv(self, level: np.ndarray) -> np.ndarray:
        """Gaussian amplitude whose rectified mean is the level's target."""
        # NaN reads level 0; infinities stay (np.interp holds the end levels for them, as
        # for nan_to_num's largest floats): nan_to_num without its Python wrapper
        level = np.where(np.isnan(level), 0.0, level)
        target = np.interp(level, np.arange(TOP_LEVEL + 1), self.targets_uv)
        return target * RECTIFIED_MEAN_TO_SIGMA

    def step(self, io: Io) -> None:
        level = io.get(LEVEL)
        n = len(level)
        if n == 0:
            io.put(RAW, np.zeros(0))
            return
        sigma = self.sigma_uv(level)
        if self._smooth_sos is not None:
            if self._smooth_state is None:
                self._smooth_state = signal.sosfilt_zi(self._smooth_sos) * sigma[0]
            smooth = sosfilt_floats if n <= SHORT_CHUNK_SAMPLES else sosfilt_compiled
            sigma, self._smooth_state = smooth(self._smooth_sos, sigma, self._smooth_state)

        bank = self._bank.take(n)

        if self.fatigue_per_s > 0:
            contraction = (
                np.clip(np.nan_to_num(level, nan=0.0) / LEVELS, 0.0, TOP_LEVEL / LEVELS)
                / self.rate_hz
            )
            accumulated = np.cumsum(np.concatenate([[self._contraction_s], contraction]))[1:]
            self._contraction_s = float(accumulated[-1])
            fatigue = self.fatigue_per_s * accumulated
            compression = np.maximum(1.0 / (1.0 + fatigue), FATIGUE_SCALES[-1])
            position = (FATIGUE_SCALES[0] - compression) / (FATIGUE_SCALES[0] - FATIGUE_SCALES[1])
            lower = np.minimum(np.floor(position).astype(int), len(FATIGUE_SCALES) - 2)
            weight = np.clip(position - lower, 0.0, 1.0)
            rows = np.arange(n)
            noise = (
                np.sqrt(1.0 - weight) * bank[rows, lower] + np.sqrt(weight) * bank[rows, lower + 1]
            )
            sigma = sigma * (1.0 + fatigue)
        else:
            noise = bank[:, 0]
        io.put(RAW, sigma * noise)

"""An oracle ridge detector: how many contacts *any* detector could tell at 10 dB SNR, and
from that the least speed missing any decoder could reach (issue 22, the snr10 figure).

Why: the snr10 target (speed missing <= 20 %) is only worth chasing if the noise allows
it. The oracle knows each ridge pulse's onset time and shape (the simulator's own train,
`contact_truth.pulse_train`) and applies the matched filter there - the GLRT of "this
pulse, unknown size" against "none" in white noise with an unknown linear background
(drift, the object covering the sensor). Its statistic is N(SNR, 1) at a pulse and
N(0, 1) away from one; a real detector must scan for the time and the shape too, which
sets the false-alarm level its threshold must clear (`scan`, on held objects).

A speed needs two told contacts (`speed_possible`): of the same run, decided (the filter
reads until the template's end), in all or among the run's last three true contacts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as sp_signal

from grasplink.evaluation.contact_truth import CEILING_WINDOW_RISES, PulseTrain
from grasplink.simulators.effects import skin


@dataclass(frozen=True)
class Template:
    """One pulse's matched filter: sample offsets from the onset sample and unit weights
    orthogonal to a linear background (so a drift or level adds nothing); `norm_n` is
    the pulse's own size along them (its SNR times the white noise)."""

    offsets: np.ndarray  # int, from the onset's sample
    weights: np.ndarray  # unit norm, sum 0, orthogonal to the offsets
    norm_n: float

    @property
    def after(self) -> int:
        """Samples the filter reads after the onset: when it can be decided."""
        return int(self.offsets[-1])


def _continued(train: PulseTrain, i: int, t: np.ndarray) -> np.ndarray:
    """Contact i-1's segment continued past contact i (0 before the first)."""
    if i == 0:
        return np.zeros(len(t))
    j = i - 1
    return np.asarray(
        skin.pulse(t - train.times_s[j], train.alpha_n[j], train.rise_s[j], train.start_n[j])
    )


def template(train: PulseTrain, i: int, fs_hz: float) -> Template:
    """Pulse i's matched filter: what it adds to the previous segment continued, over
    +-span around its onset for each span of CEILING_WINDOW_RISES rises (not past the next
    contact), linear background projected out; the span with the largest norm (the oracle
    knows the shape, so it may choose)."""
    t0, rise = float(train.times_s[i]), float(train.rise_s[i])
    gap = float(train.times_s[i + 1] - t0) if i + 1 < len(train.times_s) else np.inf
    onset = int(np.ceil(t0 * fs_hz))  # the first sample at or after the onset
    best: Template | None = None
    for m in CEILING_WINDOW_RISES:
        span = int(np.floor(min(m * rise, gap) * fs_hz))
        if span < 2:
            continue
        offsets = np.arange(-span, span)
        t = (onset + offsets) / fs_hz
        tau = t - t0
        d = np.zeros(len(offsets))
        on = tau >= 0
        d[on] = skin.pulse(tau[on], train.alpha_n[i], rise, train.start_n[i]) - _continued(
            train, i, t[on]
        )
        basis = np.vander(offsets / span, 2)
        coef, *_ = np.linalg.lstsq(basis, d, rcond=None)
        perp = d - basis @ coef
        norm = float(np.linalg.norm(perp))
        if norm > 0 and (best is None or norm > best.norm_n):
            best = Template(offsets, perp / norm, norm)
    if best is None:  # onsets closer than 2 samples: no window to read
        return Template(np.arange(-1, 1), np.array([-(0.5**0.5), 0.5**0.5]), 0.0)
    return best


def statistic(x_n: np.ndarray, at: int, tmpl: Template, white_n: float) -> float:
    """The filter's output on `x_n` with its onset at sample `at`, in white-noise units
    (N(0, 1) on white noise plus any line; nan where the window leaves the signal)."""
    k = at + tmpl.offsets
    if k[0] < 0 or k[-1] >= len(x_n):
        return float("nan")
    return float(tmpl.weights @ x_n[k]) / white_n


def scan(x_n: np.ndarray, bank: list[Template], white_n: float) -> np.ndarray:
    """A scanning detector's statistic: at every onset sample, the largest output of a
    bank of templates (the times and shapes unknown). -inf where no template fits."""
    out = np.full(len(x_n), -np.inf)
    for tmpl in bank:
        w = tmpl.weights[::-1]  # correlation as a convolution
        full = sp_signal.fftconvolve(x_n, w, mode="valid") / white_n
        first = -int(tmpl.offsets[0])  # the onset sample of the first full window
        seg = out[first : first + len(full)]
        np.maximum(seg, full[: len(seg)], out=seg)
    return out


def events(stat: np.ndarray, threshold: float, fs_hz: float, merge_s: float = 0.02) -> int:
    """Crossings of `threshold` counted as contacts: runs above it closer than `merge_s`
    are one."""
    above = np.flatnonzero(stat >= threshold)
    if not len(above):
        return 0
    return 1 + int(np.sum(np.diff(above) > merge_s * fs_hz))


def speed_possible(
    t_upd_s: np.ndarray,
    contact_s: np.ndarray,
    told: np.ndarray,
    decided_s: np.ndarray,
    last: int | None = None,
) -> np.ndarray:
    """Per update: two told contacts of this run decided by then - among all the run's
    contacts so far (`last` None) or among its last `last` true contacts. `contact_s`,
    `told`, `decided_s` are the run's true contacts in time order."""
    if len(contact_s) == 0:
        return np.zeros(len(t_upd_s), bool)
    upto = np.searchsorted(contact_s, t_upd_s, side="right")  # contacts met by then
    count = np.zeros(len(t_upd_s), int)
    for j in range(len(contact_s)):
        inside = upto > j
        if last is not None:
            inside &= upto - j <= last
        count += inside & told[j] & (decided_s[j] <= t_upd_s)
    return count >= 2

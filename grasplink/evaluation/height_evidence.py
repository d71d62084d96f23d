"""Pulse heights as evidence of which ridge a contact was (issue 22, the snr10 figure): the
likelihood of each told contact's measured height under each ridge a hypothesis of
`alias_bound` may assign it (the bound without ridge identities read only contact times
and detection chances).

Why: the simulator's ridge pulse peaks at alpha = a x d x f(s), f(s) = 1 - exp(-s /
10 mm) with s the free spacing crossed before the ridge in the travel direction (the
first ridge met: a 20 mm lead-in), d an independent draw per contact, uniform in
[0.8, 1.2], and a a scale shared by the run (`skin.ridge_contacts`: 1 N; a real grip and
skin would set it, so the decoder does not know it). A 4 mm spacing gives f = 0.33, a
40 mm one 0.98: a height tells those ridges apart where the times cannot, and in travel
order the spacing before a ridge differs by direction.

The measured height is an explicit least-squares height (`HeightModel.measure`: the
oracle's, the pulse's shape and onset known, a linear background unknown) with its noise
sigma. Given the ridge's f and a scale a its density is the uniform draw convolved with
the Gaussian error (`density`); a is marginalised over a log-uniform prior on a grid
(`HeightModel.scales_n`, `prior`) - shared by every contact of the run (in the truth it
is exactly; the draws carry the per-contact variation) - or, with one grid point, known.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtr

from grasplink.simulators.effects.skin import (
    ALPHA_DRAW_N,
    LEAD_IN_MM,
    MAX_RISE_S,
    MIN_RISE_S,
    RIDGE_SIDE_MM,
    RISE_JITTER,
    SPACING_SCALE_MM,
    pulse,
)

DRAW = ALPHA_DRAW_N  # skin.ridge_contacts' per-contact height draw (N)
SIM_SCALE_N = 1.0  # the scale a that interval implies (a x d, d in DRAW): "a known"


def log_grid(low_n: float, high_n: float, points: int) -> np.ndarray:
    """`points` scales from `low_n` to `high_n`, equally spaced in log (a log-uniform prior
    on it weighs them equally)."""
    return np.geomspace(low_n, high_n, points)


@dataclass(frozen=True)
class HeightModel:
    """What a hypothesis predicts for a contact's height: the scale grid and its prior
    weights (summing to 1), the draw's interval and the shape factor's constants."""

    scales_n: np.ndarray = field(default_factory=lambda: log_grid(0.25, 4.0, 49))
    draw: tuple[float, float] = DRAW
    spacing_scale_mm: float = SPACING_SCALE_MM
    lead_in_mm: float = LEAD_IN_MM

    @property
    def prior(self) -> np.ndarray:
        """Equal weights on the grid (log-uniform over its range; one point: known)."""
        return np.full(len(self.scales_n), 1.0 / len(self.scales_n))

    def factor(self, pos_mm: np.ndarray) -> np.ndarray:
        """Per ridge in travel order (positions from the entry end): f(spacing before)."""
        before = np.concatenate([[self.lead_in_mm], np.diff(np.asarray(pos_mm, float))])
        return shape_factor(before, self.spacing_scale_mm)


def shape_factor(before_mm: np.ndarray, scale_mm: float = SPACING_SCALE_MM) -> np.ndarray:
    """The height a ridge's pulse reaches per unit scale: 1 - exp(-spacing before / scale)."""
    return 1.0 - np.exp(-np.asarray(before_mm, float) / scale_mm)


def density(
    h_n: np.ndarray, sigma_n: np.ndarray, mean_n: np.ndarray, draw: tuple[float, float]
) -> np.ndarray:
    """The density of a measured height `h_n` (error N(0, sigma_n^2)) when the true one is
    `mean_n` x d, d uniform on `draw`: (Phi((h - lo m) / sigma) - Phi((h - hi m) / sigma))
    / ((hi - lo) m). Broadcasts; 1 where the height is unknown (sigma not finite)."""
    h, sigma, m = (np.asarray(v, float) for v in (h_n, sigma_n, mean_n))
    lo, hi = draw
    known = np.isfinite(sigma) & np.isfinite(h)
    s = np.where(known, sigma, 1.0)
    hh = np.where(known, h, 0.0)
    p = (ndtr((hh - lo * m) / s) - ndtr((hh - hi * m) / s)) / ((hi - lo) * m)
    return np.where(known, p, 1.0)


def evidence(
    h_n: np.ndarray, sigma_n: np.ndarray, pos_mm: np.ndarray, model: HeightModel
) -> np.ndarray:
    """[g, j, k]: the density of told contact j's height (`h_n`, `sigma_n`, time order) if
    it was travel ridge k (positions `pos_mm` from the entry end) at scale g of the grid."""
    mean = model.scales_n[:, None, None] * model.factor(pos_mm)[None, None, :]
    return density(
        np.asarray(h_n, float)[None, :, None],
        np.asarray(sigma_n, float)[None, :, None],
        mean,
        model.draw,
    )


def _shape(tau_s: np.ndarray, rise_s: float | np.ndarray) -> np.ndarray:
    """A pulse of unit height `tau_s` after its onset (0 before it): the simulator's own
    (`skin.pulse`, u e^(1 - u), u = tau / rise), which the oracle knows."""
    return pulse(np.maximum(tau_s, 0.0), 1.0, rise_s, 0.0)


def measure(
    rest_n: np.ndarray,
    at: int,
    offsets: np.ndarray,
    alpha_n: float,
    rise_s: float,
    fs_hz: float,
    white_n: float,
    onset_s: float,
) -> tuple[float, float]:
    """The oracle's least-squares height of one pulse and its noise sigma: the pulse's own
    shape (u e^(1 - u), u = (t - onset) / rise, 0 before the onset) fitted over the
    window `at + offsets` with a linear background unknown (projected out, as the matched
    filter's), on the signal less every pulse (`rest_n`: grip, level, drift, noise) plus
    this pulse at its true `alpha_n`. sigma is for white noise of `white_n`; (nan, inf)
    where the window leaves the signal or holds no shape."""
    k = at + offsets
    if k[0] < 0 or k[-1] >= len(rest_n):
        return float("nan"), float("inf")
    g = _shape(k / fs_hz - onset_s, rise_s)
    span = max(-int(offsets[0]), 1)
    basis = np.vander(offsets / span, 2)
    coef, *_ = np.linalg.lstsq(basis, g, rcond=None)
    perp = g - basis @ coef
    norm2 = float(perp @ perp)
    if norm2 <= 0:
        return float("nan"), float("inf")
    return alpha_n + float(perp @ rest_n[k]) / norm2, white_n / norm2**0.5


def rise_sigma(
    at: int,
    offsets: np.ndarray,
    alpha_n: float,
    rise_s: float,
    fs_hz: float,
    white_n: float,
    onset_s: float,
) -> float:
    """The Cramer-Rao bound on a pulse's rise time, relative to it (sigma / rise), over the
    window `at + offsets`: the height, the rise and a linear background unknown, the onset
    known (as the oracle's) - evidence on the speed itself (rise = 1.25 mm / speed in
    `skin.ridge_contacts`) that the alias bound leaves out. inf where it holds none."""
    t = (at + offsets) / fs_hz
    u = np.maximum((t - onset_s) / rise_s, 0.0)
    g = _shape(t - onset_s, rise_s)
    d_rise = alpha_n * np.exp(1.0 - u) * (1.0 - u) * (-u / rise_s)  # d(alpha g) / d rise
    span = max(-int(offsets[0]), 1)
    x = np.column_stack([g, d_rise, np.vander(offsets / span, 2)])
    info = x.T @ x / white_n**2
    if np.linalg.matrix_rank(info) < 4:
        return float("inf")
    return float(np.sqrt(np.linalg.inv(info)[1, 1])) / rise_s


RISE_CLIP_S = (MIN_RISE_S, MAX_RISE_S)  # skin.ridge_contacts: rise = side / (2 |v|), clipped


def measure_rise(
    rest_n: np.ndarray,
    at: int,
    offsets: np.ndarray,
    alpha_n: float,
    rise_s: float,
    fs_hz: float,
    onset_s: float,
    grid_s: np.ndarray,
) -> float:
    """The oracle's least-squares rise time of one pulse: over `grid_s`, the rise whose
    shape (height and a linear background fitted) leaves the least residual on the
    window, the signal less every pulse (`rest_n`) plus this one (`alpha_n`, `rise_s`);
    the onset known. nan where the window leaves the signal."""
    k = at + offsets
    if k[0] < 0 or k[-1] >= len(rest_n):
        return float("nan")
    t = k / fs_hz - onset_s
    y = rest_n[k] + alpha_n * _shape(t, rise_s)
    span = max(-int(offsets[0]), 1)
    line = np.vander(offsets / span, 2)
    q, _ = np.linalg.qr(line)
    y_perp = y - q @ (q.T @ y)
    g = _shape(t[None, :], np.asarray(grid_s, float)[:, None])
    g_perp = g - (g @ q) @ q.T
    norm2 = np.einsum("ij,ij->i", g_perp, g_perp)
    fit = np.where(norm2 > 0, (g_perp @ y_perp) ** 2 / np.where(norm2 > 0, norm2, 1.0), -1.0)
    return float(grid_s[int(np.argmax(fit))])


def rise_density(
    rise_s: np.ndarray, sigma_s: np.ndarray, v_low_mm_s: np.ndarray, v_high_mm_s: np.ndarray
) -> np.ndarray:
    """The density of a measured rise (error N(0, sigma^2)) when the speed at the contact
    lies in [v_low, v_high] and the simulator's jitter in RISE_JITTER: the rise taken
    uniform between the range's ends (`density`'s form with explicit ends). 1 where the
    rise is unknown, 0 where the speed range is empty. Broadcasts."""
    r, s = np.asarray(rise_s, float), np.asarray(sigma_s, float)
    lo_v = np.maximum(np.asarray(v_low_mm_s, float), 1e-9)
    hi_v = np.maximum(np.asarray(v_high_mm_s, float), lo_v)
    lo = np.clip(RIDGE_SIDE_MM / (2 * hi_v), *RISE_CLIP_S) * RISE_JITTER[0]
    hi = np.clip(RIDGE_SIDE_MM / (2 * lo_v), *RISE_CLIP_S) * RISE_JITTER[1]
    known = np.isfinite(r) & np.isfinite(s)
    ss = np.where(known, s, 1.0)
    rr = np.where(known, r, 0.0)
    p = (ndtr((rr - lo) / ss) - ndtr((rr - hi) / ss)) / (hi - lo)
    p = np.where(np.isfinite(p), p, 0.0)
    return np.where(known, p, 1.0)

"""A told contact's rise time as evidence of the speed a track gives it.

Physics (thesis ch. 5.3.1, `ridge_pulses`): a ridge's pulse peaks after `RISE_MM` of the
edge's travel, so its rise time is RISE_MM / speed: a track at twice the speed predicts
half the rise. Aliases of one contact sequence differ in speed (a track that takes a
contact for a ridge further on moves faster), and the contact's own shape tells which
rise it had (issue 22, 10 dB SNR: session 30's bound with the oracle's contacts, times and
heights 35.3 % missing, adding each pulse's rise time 27.8 %).

The decoder's reading: the pulse probe's rise statistic z (`rise_evidence.RiseEvidence`:
mean after less mean before, the ramp 2 windows either side taken out, white-noise
units) at the contact's onset on each of the probe's windows (10, 20, 40 ms), from samples
held by its decision. A unit pulse of rise r reads g_w(r) on window w (`response`: the
same statistic of the pulse's own shape, u e^(1 - u), u = t / r), so z_w = h g_w(r) +
noise of unit spread, h unknown (>= 0). With h fitted, a rise r explains the z's by
(z . g)^2 / 2 |g|^2 nats (positive part); a child at speed v gains that at r = RISE_MM / v
less the log mean over a grid of speeds (`V_GRID_MM_S`: no child gains on average against
the ones taking the contact for clutter), times `WEIGHT` (the windows overlap: the z's are
not independent), clipped to +-`CLIP`. Nothing is added unless two windows are held.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from grasplink.decoding.detector.pulse_probe import PULSE_RAMP
from grasplink.decoding.kernels.layout import F_SCORE, F_V
from grasplink.decoding.ridge_pulses import RISE_MM
from grasplink.decoding.rise_evidence import OFFSET, RiseEvidence

V_GRID_MM_S = np.geomspace(2.0, 400.0, 64)  # the speeds a contact's rise is read at
WEIGHT = 0.5  # the nats a child gains, times this (the windows' z's are correlated)
CLIP = 2.0  # nats a child gains or loses at most


def response(widths: np.ndarray, rise_samples: np.ndarray) -> np.ndarray:
    """[r, w]: the probe's z (per unit noise) of a unit pulse of rise `rise_samples`
    (u e^(1 - u), u = t / r, from its onset) on each window of `widths` (samples), read as
    `RiseEvidence.z_at` reads it (centre `OFFSET` of a window after the onset)."""
    widths = np.asarray(widths, np.int64)
    r = np.asarray(rise_samples, float)
    out = np.zeros((len(r), len(widths)))
    for j, w in enumerate(widths.tolist()):
        c = round(OFFSET * w)  # the onset at sample 0
        k = np.arange(c - 3 * w, c + 3 * w)
        u = np.maximum(k, 0)[None, :] / r[:, None]
        x = u * np.exp(1.0 - u)
        sums = np.concatenate([np.zeros((len(r), 1)), np.cumsum(x, axis=1)], axis=1)
        d0, d1, d2 = (
            (sums[:, m + w] - 2.0 * sums[:, m] + sums[:, m - w]) / w for m in (w, 3 * w, 5 * w)
        )
        out[:, j] = (d1 - PULSE_RAMP * (d0 + d2)) / np.sqrt(2.0 / w * (1.0 + 2.0 * PULSE_RAMP**2))
    return out


class RiseTime:
    """Per contact, the log evidence of each speed from its rise (`gain_at`)."""

    def __init__(self, evidence: RiseEvidence, weight: float = WEIGHT, clip: float = CLIP):
        if not (weight >= 0.0 and clip >= 0.0):
            raise ValueError(f"rise time: weight {weight!r} and clip {clip!r} must be >= 0")
        self.evidence = evidence
        self.weight = float(weight)
        self.clip = float(clip)
        rise = RISE_MM / V_GRID_MM_S * evidence.fs_hz
        self._g = response(evidence.widths, rise)  # [speed, window]
        self._log_v = np.log(V_GRID_MM_S)

    def curve(self, z: np.ndarray) -> np.ndarray | None:
        """Per grid speed, the weighted, clipped log evidence of the z's (one per window;
        NaN: not held); None unless two or more are held."""
        held = np.isfinite(z)
        if held.sum() < 2:
            return None
        g = self._g[:, held]
        fit = np.maximum(g @ z[held], 0.0)
        ll = 0.5 * fit**2 / np.sum(g * g, axis=1)
        top = float(np.max(ll))
        norm = top + float(np.log(np.mean(np.exp(ll - top))))
        return np.clip(self.weight * (ll - norm), -self.clip, self.clip)

    def weigh(
        self,
        floats: np.ndarray,
        rows: np.ndarray,
        contact: tuple[float, int, int],
        blind_s: Iterable[tuple[float, float]] = (),
        relative: bool = False,
    ) -> np.ndarray:
        """Add each of `rows`' gain at its speed for a contact (onset time s, onset global
        sample, the global sample that decided it: samples before it read only); windows
        touching a rail interval of `blind_s` (s) are not read. Returns the gains (zeros
        when the rise is not read)."""
        if not len(rows):
            return np.zeros(0)
        t_s, index, emit_index = contact
        widths = self.evidence.widths
        z = self.evidence.z_at(np.full(len(widths), float(index)), widths, emit_index)
        fs = self.evidence.fs_hz
        for r0, r1 in blind_s:  # a flat rail is no evidence
            centre_s = t_s + OFFSET * widths / fs
            z[(centre_s - 3.0 * widths / fs < r1) & (centre_s + 3.0 * widths / fs > r0)] = np.nan
        curve = self.curve(z)
        if curve is None:
            return np.zeros(len(rows))
        log_v = np.log(np.clip(np.abs(floats[rows, F_V]), V_GRID_MM_S[0], V_GRID_MM_S[-1]))
        out = np.interp(log_v, self._log_v, curve)
        if relative:  # among the children that take it for a ridge: 0 on average
            out = np.clip(out - float(np.mean(out)), -self.clip, self.clip)
        floats[rows, F_SCORE] += out
        return out

"""The streaming filter the numpy detector ran (`filters.SosFilter` at 0858d90): FIR kernels
through scipy's `lfilter` (direct form II transposed, a = [1, 0]), IIR cascades through
`sosfilt`, state carried. The runtime's SosFilter now runs compiled loops
(`kernels.detector.fir_run`, `sos_run`); this is what they are checked against."""

from __future__ import annotations

import numpy as np
from scipy import signal


class SosFilter:
    """Second-order sections (or one FIR) with carried state, settled on the first sample."""

    def __init__(self, sos: np.ndarray, *, fir_taps: np.ndarray | None = None):
        self.sos = np.ascontiguousarray(np.atleast_2d(np.asarray(sos, dtype=np.float64)))
        self._fir = fir_taps
        if fir_taps is None:
            self._zi_unit = signal.sosfilt_zi(self.sos)
        else:  # a = [1, 0]: lfilter's sample loop (a = [1] would convolve, chunk-dependent)
            self._a = np.array([1.0, 0.0])
            self._zi_unit = signal.lfilter_zi(fir_taps, self._a)
        self._zi: np.ndarray | None = None

    @classmethod
    def fir(cls, taps: np.ndarray) -> SosFilter:
        """An FIR filter: y[n] = sum taps[k] x[n - k]."""
        taps = np.asarray(taps, dtype=np.float64)
        if len(taps) == 1:
            return cls(np.array([[taps[0], 0.0, 0.0, 1.0, 0.0, 0.0]]))
        sos = signal.tf2sos(taps, np.concatenate([[1.0], np.zeros(len(taps) - 1)]))
        return cls(sos, fir_taps=taps.copy())

    @property
    def sections(self) -> int:
        return len(self.sos)

    def reset(self) -> None:
        self._zi = None

    def __call__(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float64)
        if not len(x):
            return np.zeros(0)
        if self._zi is None:
            self._zi = self._zi_unit * x[0]
        if self._fir is not None:
            y, self._zi = signal.lfilter(self._fir, self._a, x, zi=self._zi)
        else:
            y, self._zi = signal.sosfilt(self.sos, x, zi=self._zi)
        return y

"""Additive noise on any sensor signal: white (high-frequency) and drift (low-frequency).

Thesis ch. 5.3.1 adds high-frequency noise and low-frequency noise to the
simulated FSR signal; the same effects serve the EMG signal.

Which signal and which domain: the `signal` parameter (default
`skin.force_n`) names the signal to modify, and its prefix picks the domain
the effect steps in (`skin.*` -> skin, `emg.*` -> emg). Because `domain`,
`inputs` and `outputs` are class variables that the scene graph reads, the
registered class (`noise.white`, `noise.drift`) is a *front*: constructing it
returns an instance of a subclass made once per signal (cached), whose class
variables name that signal and its domain. `kind` stays the registered kind,
and `isinstance(effect, WhiteNoise)` holds. The registered classes' own class
variables describe the default (`skin.force_n`, skin domain).

Randomness comes from `ctx.rng("<kind>:<signal>[:<stream>]")`, consumed in
sample order, so chunking does not change the draws; the noise is drawn (and the
drift filtered) in blocks ahead of its use, which gives the same samples. The optional `stream`
parameter separates two otherwise identical noise effects on one signal
(which would otherwise draw identical, fully correlated noise). An effect
with std 0 draws nothing.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from scipy import linalg, signal

from grasplink.core.params import Params
from grasplink.simulators import signals as sig
from grasplink.simulators.core import EMG, SKIN, AheadStream, Context, Effect, Io, register

DOMAIN_OF_PREFIX = {"skin": SKIN, "emg": EMG}
DEFAULT_SIGNAL = sig.SKIN_FORCE_N

_VARIANTS: dict[tuple[type, str], type] = {}


def signal_domain(params: Params, name: str = "signal") -> tuple[str, str]:
    """(signal, domain) from the `signal` parameter; an error names the key."""
    value = params.string(name, DEFAULT_SIGNAL)
    prefix, dot, rest = value.partition(".")
    if not dot or not rest or prefix not in DOMAIN_OF_PREFIX:
        allowed = " or ".join(f"{p}.*" for p in DOMAIN_OF_PREFIX)
        raise params.error(name, f"expected a {allowed} signal, got {value!r}")
    return value, DOMAIN_OF_PREFIX[prefix]


class SignalModifier(Effect):
    """Base of effects that modify the one signal named by their `signal` parameter."""

    domain: ClassVar[str] = SKIN
    inputs: ClassVar[tuple[str, ...]] = (DEFAULT_SIGNAL,)
    outputs: ClassVar[tuple[str, ...]] = (DEFAULT_SIGNAL,)
    front: ClassVar[type | None] = None  # the registered class a variant was made from

    def __new__(cls, params: Params, ctx: Context, *args: Any, **kwargs: Any):
        name, domain = signal_domain(params)
        front = cls.front or cls
        key = (front, name)
        if key not in _VARIANTS:
            _VARIANTS[key] = type(
                f"{front.__name__}[{name}]",
                (front,),
                {
                    "domain": domain,
                    "inputs": (name,),
                    "outputs": (name,),
                    "front": front,
                    "__module__": front.__module__,
                    "__doc__": front.__doc__,
                    "__qualname__": f"{front.__qualname__}[{name}]",
                },
            )
        return super().__new__(_VARIANTS[key])

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.signal, _ = signal_domain(params)
        stream = params.string("stream", "")
        self.rng_key = f"{self.kind}:{self.signal}" + (f":{stream}" if stream else "")
        self.rate_hz = ctx.rates_hz[self.domain]


@register
class WhiteNoise(SignalModifier):
    """Adds Gaussian white noise of standard deviation `std` (in the signal's unit).

    Parameters: `signal` (default skin.force_n), `std` (default 0.01; N for
    skin.force_n, uV for emg.raw_uv), `stream` (default "").
    """

    kind: ClassVar[str] = "noise.white"
    summary: ClassVar[str] = "Gaussian white (high-frequency) noise of std in the signal's unit"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.std = params.number("std", 0.01, low=0.0)
        self._rng = ctx.rng(self.rng_key) if self.std > 0 else None
        self._noise = AheadStream(self._draw)

    def _draw(self, count: int) -> np.ndarray:
        assert self._rng is not None
        return self.std * self._rng.standard_normal(count)

    def step(self, io: Io) -> None:
        values = io.get(self.signal)
        if self._rng is not None:
            values = values + self._noise.take(len(values))
        io.put(self.signal, values)


def stationary_state(sos_section: np.ndarray) -> tuple[np.ndarray, float]:
    """Stationary covariance of a biquad's state and its output variance, unit white input.

    scipy's sosfilt runs each section in transposed direct form II:
    y = b0 x + z0, z0' = (b1 - a1 b0) x - a1 z0 + z1, z1' = (b2 - a2 b0) x - a2 z0,
    a state-space (A, B, C = [1, 0], D = b0); the state covariance solves
    P = A P A^T + B B^T and var(y) = P[0, 0] + b0^2.
    """
    b0, b1, b2, _, a1, a2 = (float(v) for v in sos_section)
    a = np.array([[-a1, 1.0], [-a2, 0.0]])
    b = np.array([[b1 - a1 * b0], [b2 - a2 * b0]])
    cov = linalg.solve_discrete_lyapunov(a, b @ b.T)
    return cov, float(cov[0, 0] + b0 * b0)


@register
class Drift(SignalModifier):
    """Adds low-frequency drift: Gaussian noise low-passed and scaled, plus an offset.

    w_k ~ N(0, 1) -> 2nd-order Butterworth low-pass at `corner_hz` (default
    0.5 Hz; SOS, state carried) -> times g = std / sqrt(var), var the filter's
    stationary output variance for unit white input, so the drift's
    stationary standard deviation is `std` (default 0.05, the signal's
    unit). The filter starts in a state drawn from its stationary
    distribution, so the drift is stationary from the first sample. `offset`
    (default 0, the signal's unit) is added as a constant.
    """

    kind: ClassVar[str] = "noise.drift"
    summary: ClassVar[str] = (
        "low-frequency drift: white noise through a 2nd-order Butterworth "
        "low-pass at corner_hz, std in the signal's unit, plus offset"
    )

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.std = params.number("std", 0.05, low=0.0)
        nyquist = self.rate_hz / 2
        self.corner_hz = params.number("corner_hz", 0.5, low=0.0, low_open=True)
        if self.corner_hz >= nyquist:
            raise params.error(
                "corner_hz",
                f"expected a number below the {self.domain} "
                f"Nyquist frequency {nyquist:g} Hz, "
                f"got {self.corner_hz:g}",
            )
        self.offset = params.number("offset", 0.0)
        self.sos = signal.butter(2, self.corner_hz, "lowpass", fs=self.rate_hz, output="sos")
        cov, variance = stationary_state(self.sos[0])
        self.gain = self.std / math.sqrt(variance)
        self._rng = ctx.rng(self.rng_key) if self.std > 0 else None
        self._zi = np.zeros((1, 2))
        if self._rng is not None:
            root = np.linalg.cholesky(cov + 1e-15 * np.trace(cov) * np.eye(2))
            self._zi = (root @ self._rng.standard_normal(2)).reshape(1, 2)
        self._drift = AheadStream(self._filtered)

    def _filtered(self, count: int) -> np.ndarray:
        assert self._rng is not None
        drift, self._zi = signal.sosfilt(self.sos, self._rng.standard_normal(count), zi=self._zi)
        return self.gain * drift

    def step(self, io: Io) -> None:
        values = io.get(self.signal) + self.offset
        if self._rng is not None:
            values = values + self._drift.take(len(values))
        io.put(self.signal, values)

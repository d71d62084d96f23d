"""The skin node's force signal: FSR model, ridge-contact pulses, sensor non-idealities.

All effects here step on the `skin` domain clock (the skin node's sample
rate, 400 Hz by default) and produce or modify `skin.force_n`, the force the
force-sensing resistor (FSR) under the ridged silicone skin reports, in N.
A typical chain is::

    skin.fsr -> skin.ridge_contacts -> [noise.*] -> skin.hysteresis
             -> skin.saturation -> skin.adc

Geometry: ridge i sits at x_i = cumsum([0, *spacings])[i] mm (len + 1
ridges; `ctx.layout_mm` holds the spacings). `object.position_mm` is the
object's leading edge measured from the first ridge; moving forward
(`object.speed_mm_s` > 0, first ridge -> last) the object covers
[position - length, position], moving in reverse the leading edge is the
edge facing the first ridge and the object covers [position, position + length].

Models (thesis ch. 4.3, 5.3.1, 5.4.2, 3.4):

* `skin.fsr` -- M(t) = (1 - k mu) W(t) + k |P(t)| c(t) while slipping (c: the share of
  the object over the sensor, W = grip c), M = W when
  not (blended by `object.slipping`, which arrives interpolated), with
  k = cos(gamma) / (sin(gamma) + mu cos(gamma)) and W(t) the grip force times
  the share of the object's length lying over the sensor [0, sum(spacings)].
* `skin.ridge_contacts` -- the piecewise pulse train of ch. 5.3.1: a contact at
  t_i starts segment c_i, which rises from c_{i-1}(t_i) to alpha_i at
  t_i + 1/beta_i, then decays as alpha_i u e^(1 - u), u = beta_i (t - t_i),
  until the next contact; the signal is continuous, closely spaced contacts
  merge.
* `skin.hysteresis` -- a play (backlash) operator whose band narrows to zero at
  zero force.
* `skin.saturation`, `skin.adc` -- clipping to the FSR's range and ADC
  quantisation (as the skin node's calibration: counts = round(F / FS (2^bits - 1))).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from typing import ClassVar, NamedTuple

import numpy as np

from grasplink.core.params import Params
from grasplink.simulators import signals as sig
from grasplink.simulators.core import SKIN, Context, Effect, Io, register

FORCE = sig.SKIN_FORCE_N
GRIP, LOAD = sig.HAND_GRIP_N, sig.LOAD_FORCE_N
POSITION, SPEED, SLIPPING = sig.OBJECT_POSITION_MM, sig.OBJECT_SPEED_MM_S, sig.OBJECT_SLIPPING

MU_THESIS = 0.7813  # friction coefficient object/silicone (ch. 4.3)
RIDGE_ANGLE_DEG = 60.0  # equilateral ridge section (ch. 4.2)
FULL_SCALE_N = 98.067  # FSR range 10 kg; the skin node's default calibration (98067 mN)
CONTACT_RECORD = 1024  # how many recent contacts `RidgeContacts.contacts` keeps
# RidgeContacts' defaults (ch. 5.3.1), named so the evaluation's models of its pulse
# train (the snr10 bounds, the benchmark's pulse heights) read the simulator's own values
RIDGE_SIDE_MM = 2.5  # the pulse rises over ridge_side / (2 |speed|) ...
MIN_RISE_S, MAX_RISE_S = 0.002, 0.2  # ... clipped to these ...
RISE_JITTER = (0.9, 1.1)  # ... times a draw from this
ALPHA_DRAW_N = (0.8, 1.2)  # the height's draw (N), times the spacing factor:
SPACING_SCALE_MM = 10.0  # 1 - exp(-free spacing before the ridge / this)
LEAD_IN_MM = 20.0  # the spacing counted before the first ridge met
# A step between two samples longer than this many times the distance the speed
# allows is a jump of the reported edge (direction reversal), not motion.
JUMP_SLACK = 4.0
JUMP_TOLERANCE_MM = 1e-6


def ridge_factor(mu: float, gamma_deg: float) -> float:
    """k = cos(gamma) / (sin(gamma) + mu cos(gamma)) of the FSR model (thesis eq. 4.2).

    >>> round(ridge_factor(0.7813, 60.0), 4)
    0.3978
    """
    gamma = math.radians(gamma_deg)
    return math.cos(gamma) / (math.sin(gamma) + mu * math.cos(gamma))


def ridge_positions_mm(layout_mm: tuple[float, ...]) -> np.ndarray:
    """x_i of every ridge, from the first ridge (len(layout) + 1 values)."""
    return np.cumsum([0.0, *layout_mm])


def interval_param(
    params: Params,
    name: str,
    default: list[float],
    *,
    low: float | None = None,
    low_open: bool = False,
) -> tuple[float, float]:
    """A [low, high] pair with low <= high (a range random draws come from)."""
    values = params.numbers(name, default, low=low, low_open=low_open, min_len=2)
    if len(values) != 2:
        raise params.error(name, f"expected [low, high], got a list of {len(values)}")
    if values[0] > values[1]:
        raise params.error(name, f"expected low <= high, got [{values[0]:g}, {values[1]:g}]")
    return values[0], values[1]


def _forward_flags(speed: np.ndarray, last_forward: bool) -> np.ndarray:
    """Per sample: is the object moving forward (last non-zero speed > 0)?"""
    index = np.where(speed != 0, np.arange(len(speed)), -1)
    last = np.maximum.accumulate(index) if len(index) else index
    return np.where(last >= 0, speed[np.maximum(last, 0)] > 0, last_forward)


@register
class FsrForce(Effect):
    """FSR reading from grip, load and object coverage (thesis ch. 4.3, eq. 4.2).

    Parameters: `object_length_mm` (90, the thesis object 25x45x90 mm),
    `mu` (0.7813), `ridge_angle_deg` (60). Needs a skin layout (its length).
    """

    kind: ClassVar[str] = "skin.fsr"
    domain: ClassVar[str] = SKIN
    inputs: ClassVar[tuple[str, ...]] = (GRIP, LOAD, POSITION, SLIPPING, SPEED)
    outputs: ClassVar[tuple[str, ...]] = (FORCE,)
    summary: ClassVar[str] = (
        "FSR force M = (1 - k mu) W + k P while slipping, W = grip x object share over the skin"
    )

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.object_length_mm = params.number("object_length_mm", 90.0, low=0.0, low_open=True)
        self.mu = params.number("mu", MU_THESIS, low=0.0)
        self.ridge_angle_deg = params.number(
            "ridge_angle_deg", RIDGE_ANGLE_DEG, low=0.0, high=90.0, low_open=True
        )
        self.skin_length_mm = float(sum(ctx.require_layout(params, self.kind)))
        self.k = ridge_factor(self.mu, self.ridge_angle_deg)
        # The object's orientation before it first moves: which edge leads.
        self._forward = (
            params.string("direction", "forward", choices=("forward", "reverse")) == "forward"
        )

    def coverage(self, position_mm: np.ndarray, forward: np.ndarray) -> np.ndarray:
        """Share (0..1) of the object's length lying over the sensor."""
        length = self.object_length_mm
        start = np.where(forward, position_mm - length, position_mm)
        overlap = np.minimum(start + length, self.skin_length_mm) - np.maximum(start, 0.0)
        return np.clip(overlap, 0.0, None) / length

    def step(self, io: Io) -> None:
        speed = io.get(SPEED)
        forward = _forward_flags(speed, self._forward)
        if len(forward):
            self._forward = bool(forward[-1])
        share = self.coverage(io.get(POSITION), forward)
        weight_n = io.get(GRIP) * share
        slipping = np.clip(io.get(SLIPPING), 0.0, 1.0)
        # Only the ridges under the object resist it: the load acts on the sensor with
        # the same share as the grip (an object off the skin presses nothing).
        extra_n = self.k * np.abs(io.get(LOAD)) * share - self.k * self.mu * weight_n
        io.put(FORCE, weight_n + slipping * extra_n)


class Contact(NamedTuple):
    time_s: float
    ridge: int  # index of the ridge (0 = first); for a tip, the ridge the edge left
    direction: int  # +1 forward, -1 reverse
    tip: bool  # a spurious contact of the tipping front edge
    alpha_n: float
    rise_s: float


class _Points(NamedTuple):
    """Crossing points of one direction, sorted by position."""

    x_mm: np.ndarray
    ridge: np.ndarray
    tip: np.ndarray
    height: np.ndarray  # relative height (spacing factor, times tip_height for tips)


def pulse(
    tau_s: np.ndarray | float,
    alpha: np.ndarray | float,
    rise_s: np.ndarray | float,
    start: np.ndarray | float,
) -> np.ndarray:
    """c(t) of thesis ch. 5.3.1 at tau = t - t_i (>= 0).

    Rise (tau < 1/beta): start + (alpha - start) kappa tau e^(-beta tau), with
    kappa = e beta, i.e. with u = tau beta: start + (alpha - start) u e^(1 - u);
    afterwards alpha u e^(1 - u). Peak alpha at tau = 1/beta = rise_s.
    """
    u = tau_s / rise_s
    shape = u * np.exp(1.0 - u)
    return np.where(u < 1.0, start + (alpha - start) * shape, alpha * shape)


@register
class RidgeContacts(Effect):
    """Adds the ridge-contact pulse train of thesis ch. 5.3.1 to `skin.force_n`.

    A contact happens when the leading edge reaches ridge i (either
    direction; the time is interpolated between samples). Its pulse peaks at
    alpha_i after 1/beta_i and starts from the previous pulse's value, so
    close contacts merge continuously.

    Parameters (defaults):
      `ridge_side_mm` (2.5): 1/beta_i = ridge_side_mm / (2 |v(t_i)|), clipped to
        [`min_rise_s` (0.002), `max_rise_s` (0.2)], times a factor drawn from
        `rise_jitter` ([0.9, 1.1]).
      `alpha_n` ([0.8, 1.2] N): alpha_i = draw x (1 - exp(-D_before / `spacing_scale_mm`
        (10))), D_before = the free spacing crossed before the ridge in the
        travel direction; `lead_in_mm` (20) for the first ridge met.
      `tip_probability` (0), `tip_min_spacing_mm` (15), `tip_distance_mm` (5),
        `tip_height` (0.4): having crossed a ridge into a spacing longer than
        tip_min_spacing_mm, the tipping front edge adds (with that probability)
        a contact tip_distance_mm further on whose alpha is tip_height times a
        ridge contact's alpha at that ridge (own draw).

    Draws: three uniforms per contact in time order (height, width, tip) from
    `ctx.rng("skin.ridge_contacts")`, so chunking does not change them; the rng
    is not used at all when both intervals are collapsed and tip_probability
    is 0. Recent contacts: `contacts` (last 1024) and `contact_times_s`.
    """

    kind: ClassVar[str] = "skin.ridge_contacts"
    domain: ClassVar[str] = SKIN
    inputs: ClassVar[tuple[str, ...]] = (FORCE, POSITION, SPEED)
    outputs: ClassVar[tuple[str, ...]] = (FORCE,)
    summary: ClassVar[str] = "ridge-contact pulses (ch. 5.3.1) added to the FSR force"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        layout = ctx.require_layout(params, self.kind)
        self.ridge_side_mm = params.number("ridge_side_mm", RIDGE_SIDE_MM, low=0.0, low_open=True)
        self.min_rise_s = params.number("min_rise_s", MIN_RISE_S, low=0.0, low_open=True)
        self.max_rise_s = params.number("max_rise_s", MAX_RISE_S, low=self.min_rise_s)
        self.rise_jitter = interval_param(
            params, "rise_jitter", list(RISE_JITTER), low=0.0, low_open=True
        )
        self.alpha_n = interval_param(params, "alpha_n", list(ALPHA_DRAW_N), low=0.0)
        self.spacing_scale_mm = params.number(
            "spacing_scale_mm", SPACING_SCALE_MM, low=0.0, low_open=True
        )
        self.lead_in_mm = params.number("lead_in_mm", LEAD_IN_MM, low=0.0)
        self.tip_probability = params.number("tip_probability", 0.0, low=0.0, high=1.0)
        self.tip_min_spacing_mm = params.number("tip_min_spacing_mm", 15.0, low=0.0)
        self.tip_height = params.number("tip_height", 0.4, low=0.0)
        self.tip_distance_mm = params.number("tip_distance_mm", 5.0, low=0.0, low_open=True)

        random = (
            self.rise_jitter[0] != self.rise_jitter[1]
            or self.alpha_n[0] != self.alpha_n[1]
            or self.tip_probability > 0
        )
        self._rng = ctx.rng(self.kind) if random else None
        self._forward_points = self._points(layout, +1)
        self._reverse_points = self._points(layout, -1)
        # Every point either direction crosses, sorted: a chunk whose travel spans none of
        # them crosses nothing (`_crossings`), as the object rests or slides between ridges.
        self._all_points_mm = sorted(
            [*self._forward_points.x_mm.tolist(), *self._reverse_points.x_mm.tolist()]
        )
        # Carried state: the previous sample and the segment in force.
        self._last_sample: tuple[float, float, float] | None = None  # (t_s, x_mm, v_mm_s)
        self._segment: tuple[float, float, float, float] | None = None  # t, alpha, rise, start
        self._last_crossing_s = -math.inf
        self.contacts: deque[Contact] = deque(maxlen=CONTACT_RECORD)

    @property
    def contact_times_s(self) -> np.ndarray:
        return np.array([c.time_s for c in self.contacts])

    def _height(self, spacing_before_mm: np.ndarray) -> np.ndarray:
        return 1.0 - np.exp(-np.asarray(spacing_before_mm, float) / self.spacing_scale_mm)

    def _points(self, layout: tuple[float, ...], direction: int) -> _Points:
        spacings = np.asarray(layout, dtype=np.float64)
        x = ridge_positions_mm(layout)
        count = len(x)
        ridges = np.arange(count)
        if direction > 0:  # crossing into ridge i from spacing i - 1; leaving into spacing i
            before = np.concatenate([[self.lead_in_mm], spacings])
            after = np.concatenate([spacings, [0.0]])
        else:  # crossing into ridge i from spacing i; leaving into spacing i - 1
            before = np.concatenate([spacings, [self.lead_in_mm]])
            after = np.concatenate([[0.0], spacings])
        height = self._height(before)
        xs, rs, tips, hs = [x], [ridges], [np.zeros(count, bool)], [height]
        if self.tip_probability > 0:
            tipping = (after > self.tip_min_spacing_mm) & (after > self.tip_distance_mm)
            xs.append(x[tipping] + direction * self.tip_distance_mm)
            rs.append(ridges[tipping])
            tips.append(np.ones(int(tipping.sum()), bool))
            hs.append(self.tip_height * height[tipping])
        x_all = np.concatenate(xs)
        order = np.argsort(x_all, kind="stable")
        return _Points(
            x_all[order],
            np.concatenate(rs)[order],
            np.concatenate(tips)[order],
            np.concatenate(hs)[order],
        )

    def _crossings(self, t: np.ndarray, x: np.ndarray, v: np.ndarray):
        """Crossings between consecutive samples, in time order.

        Returns (time_s, ridge, direction, tip, relative height, speed) arrays or
        None. A point is crossed when the number of points at or behind the
        edge (x <= position) changes, as `object.ridge_dips` counts ridges.
        An interval counts when the speeds at both ends do not point in
        opposite directions, at least one is non-zero, and the step is not a
        jump of the reported edge (a reversal switches the leading edge).
        """
        # Either direction crosses a point only within the travel's span (low, high]: with
        # none there (most chunks), none is crossed, and nothing below would change.
        low, high = float(x.min()), float(x.max())
        if math.isfinite(low) and math.isfinite(high):
            every = self._all_points_mm
            if bisect.bisect_right(every, high) == bisect.bisect_right(every, low):
                return None
        t0, t1, x0, x1, v0, v1 = t[:-1], t[1:], x[:-1], x[1:], v[:-1], v[1:]
        direction = np.where(v0 != 0, np.sign(v0), np.sign(v1))
        with np.errstate(invalid="ignore"):
            reach = JUMP_SLACK * np.maximum(np.abs(v0), np.abs(v1)) * (t1 - t0) + JUMP_TOLERANCE_MM
            valid = (
                (v0 * v1 >= 0)
                & (direction != 0)
                & np.isfinite(x0)
                & np.isfinite(x1)
                & (np.abs(x1 - x0) <= reach)
            )
        found = []
        for sign, points in ((1, self._forward_points), (-1, self._reverse_points)):
            use = valid & (direction == sign)
            if sign > 0:  # reached x: x0 < x <= x1
                lo = np.searchsorted(points.x_mm, x0, side="right")
                hi = np.searchsorted(points.x_mm, x1, side="right")
            else:  # left x behind going down: x1 < x <= x0
                lo = np.searchsorted(points.x_mm, x1, side="right")
                hi = np.searchsorted(points.x_mm, x0, side="right")
            counts = np.where(use, np.maximum(hi - lo, 0), 0)
            total = int(counts.sum())
            if total == 0:
                continue
            interval = np.repeat(np.arange(len(counts)), counts)
            within = np.arange(total) - np.repeat(np.cumsum(counts) - counts, counts)
            index = lo[interval] + within if sign > 0 else hi[interval] - 1 - within
            found.append(
                (
                    interval,
                    within,
                    np.full(total, sign),
                    points.x_mm[index],
                    points.ridge[index],
                    points.tip[index],
                    points.height[index],
                )
            )
        if not found:
            return None
        columns = [np.concatenate(column) for column in zip(*found, strict=True)]
        order = np.lexsort((columns[1], columns[0]))  # by interval, then along the travel
        interval, _, signs, x_point, ridge, tip, height = (c[order] for c in columns)
        frac = (x_point - x0[interval]) / (x1[interval] - x0[interval])
        times = t0[interval] + frac * (t1[interval] - t0[interval])
        # Never earlier than a previous contact (rounding at sample boundaries).
        times = np.maximum.accumulate(np.concatenate([[self._last_crossing_s], times]))[1:]
        self._last_crossing_s = float(times[-1])
        speed = v0[interval] + frac * (v1[interval] - v0[interval])
        return times, ridge, signs, tip, height, speed

    def _events(self, t: np.ndarray, x: np.ndarray, v: np.ndarray):
        crossings = self._crossings(t, x, v)
        if crossings is None:
            return None
        times, ridge, sign, tip, height, speed = crossings
        if self._rng is not None:
            draws = self._rng.random((len(times), 3))
        else:
            draws = np.zeros((len(times), 3))
        keep = ~tip | (draws[:, 2] < self.tip_probability)
        a_lo, a_hi = self.alpha_n
        j_lo, j_hi = self.rise_jitter
        alpha = (a_lo + (a_hi - a_lo) * draws[:, 0]) * height
        with np.errstate(divide="ignore"):
            rise = self.ridge_side_mm / (2.0 * np.abs(speed))
        jitter = j_lo + (j_hi - j_lo) * draws[:, 1]
        rise = np.clip(rise, self.min_rise_s, self.max_rise_s) * jitter
        return times[keep], alpha[keep], rise[keep], ridge[keep], sign[keep], tip[keep]

    def step(self, io: Io) -> None:
        base = io.get(FORCE)
        t = io.t_s
        x, v = io.get(POSITION), io.get(SPEED)
        if len(t) == 0:
            io.put(FORCE, base)
            return
        if self._last_sample is not None:
            lt, lx, lv = self._last_sample
            events = self._events(
                np.concatenate([[lt], t]), np.concatenate([[lx], x]), np.concatenate([[lv], v])
            )
        else:
            events = self._events(t, x, v)
        self._last_sample = (float(t[-1]), float(x[-1]), float(v[-1]))

        # Segments in force in this chunk: the carried one, then one per contact.
        seg_t, seg_alpha, seg_rise, seg_start = ([s] for s in self._segment or (np.nan,) * 4)
        if events is not None:
            times, alpha, rise, ridge, sign, tip = events
            for i in range(len(times)):
                if self._segment is None:
                    start = 0.0
                else:
                    st, sa, sr, s0 = self._segment
                    start = float(pulse(np.float64(times[i] - st), sa, sr, s0))
                self._segment = (float(times[i]), float(alpha[i]), float(rise[i]), start)
                for column, value in zip(
                    (seg_t, seg_alpha, seg_rise, seg_start), self._segment, strict=True
                ):
                    column.append(value)
                self.contacts.append(
                    Contact(
                        float(times[i]),
                        int(ridge[i]),
                        int(sign[i]),
                        bool(tip[i]),
                        float(alpha[i]),
                        float(rise[i]),
                    )
                )
        seg_t_arr = np.asarray(seg_t)
        which = np.searchsorted(seg_t_arr[1:], t, side="right")  # 0 = the carried segment
        active = np.isfinite(seg_t_arr[which])
        values = np.zeros(len(t))
        if active.any():
            w = which[active]
            values[active] = pulse(
                t[active] - seg_t_arr[w],
                np.asarray(seg_alpha)[w],
                np.asarray(seg_rise)[w],
                np.asarray(seg_start)[w],
            )
        io.put(FORCE, base + values)


@register
class Hysteresis(Effect):
    """FSR hysteresis (thesis ch. 3.4) as a play (backlash) operator.

    y_k = clip(y_{k-1}, x_k - h(x_k), x_k + h(x_k)), h(x) = min(width_n / 2, max(x, 0)):
    rising force reads width_n / 2 low, falling force width_n / 2 high, so a
    load/unload loop is `width_n` (default 0.2 N) wide. The band narrows to
    nothing at zero force, so an unloaded FSR reads 0; the operator starts
    unloaded (y = 0). Deterministic.
    """

    kind: ClassVar[str] = "skin.hysteresis"
    domain: ClassVar[str] = SKIN
    inputs: ClassVar[tuple[str, ...]] = (FORCE,)
    outputs: ClassVar[tuple[str, ...]] = (FORCE,)
    summary: ClassVar[str] = "FSR hysteresis: play operator of width width_n"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.width_n = params.number("width_n", 0.2, low=0.0)
        self._y = 0.0

    def step(self, io: Io) -> None:
        x = io.get(FORCE)
        half = self.width_n / 2.0
        y = self._y
        out = np.empty(len(x))
        for k, xv in enumerate(x.tolist()):
            if xv != xv:  # NaN passes through, state kept
                out[k] = xv
                continue
            h = half if xv >= half else (xv if xv > 0.0 else 0.0)
            if y < xv - h:
                y = xv - h
            elif y > xv + h:
                y = xv + h
            out[k] = y
        self._y = y
        io.put(FORCE, out)


def _full_scale(params: Params) -> float:
    return params.number("full_scale_n", FULL_SCALE_N, low=0.0, low_open=True)


@register
class Saturation(Effect):
    """Clip the force to the FSR's range [0, `full_scale_n`] (default 98.067 N = 10 kg)."""

    kind: ClassVar[str] = "skin.saturation"
    domain: ClassVar[str] = SKIN
    inputs: ClassVar[tuple[str, ...]] = (FORCE,)
    outputs: ClassVar[tuple[str, ...]] = (FORCE,)
    summary: ClassVar[str] = "clip the force to [0, full_scale_n]"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.full_scale_n = _full_scale(params)

    def step(self, io: Io) -> None:
        io.put(FORCE, np.clip(io.get(FORCE), 0.0, self.full_scale_n))


@register
class Adc(Effect):
    """Quantise to `bits` (default 12) over [0, `full_scale_n`] (default 98.067 N).

    value = round(clip(F, 0, FS) / FS * (2^bits - 1)) * FS / (2^bits - 1): the
    skin node's conversion with zero offset 0; saturation is included, NaN
    reads 0 as on the node.
    """

    kind: ClassVar[str] = "skin.adc"
    domain: ClassVar[str] = SKIN
    inputs: ClassVar[tuple[str, ...]] = (FORCE,)
    outputs: ClassVar[tuple[str, ...]] = (FORCE,)
    summary: ClassVar[str] = "ADC: quantise the force to bits over [0, full_scale_n]"

    def __init__(self, params: Params, ctx: Context):
        super().__init__(params, ctx)
        self.bits = params.integer("bits", 12, low=1, high=32)
        self.full_scale_n = _full_scale(params)
        self.levels = (1 << self.bits) - 1

    def step(self, io: Io) -> None:
        force = np.clip(np.nan_to_num(io.get(FORCE), nan=0.0), 0.0, self.full_scale_n)
        counts = np.rint(force / self.full_scale_n * self.levels)
        io.put(FORCE, counts * self.full_scale_n / self.levels)

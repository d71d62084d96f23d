"""What the gateway refuses to follow: implausible process data, untrusted EMCYs, fast commands.

CANopen has no authentication: any frame on a node's TPDO COB-ID is read as
that node's data. The loop therefore checks what it is about to act on
against what the devices and the physics allow, and counts every refusal
(`Rejections`, published in the snapshot's `rejected` section):

- **inputs**: a decoded value outside its EDS limits; a skin sample above the
  ADC's range or a static force outside the FSR's; an EMG envelope above what
  a muscle produces, or one that moved more than its moving average can
  between two reports; a hand grip above its crush limit or one that moved
  faster than the hand's actuator can. A refused frame changes nothing.
- **EMCY**: a code of the kind's declared list (docs/devices.md) is named; a
  code of a CiA 301 error class the node does not declare is reported as an
  "unknown EMCY code"; a code outside every class, or an error register
  without the generic bit for a non-zero code, is no EMCY and is dropped.
- **commands** (`CommandRamp`): the grip setpoint and the belt velocity move
  by at most their slew per `command_interval_ms`, and change at most once
  per interval. Defaults and why: docs/gateway.md, Plausibility.

Sans-IO: plain objects fed values with their times.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

from grasplink.devices.emcy import DESCRIPTIONS
from grasplink.devices.factory import CODES_BY_KIND

US_PER_S = 1_000_000

#: every counter the snapshot's `rejected` section carries (telemetry declares each)
REJECTION_KEYS = (
    "tpdo_out_of_range",  # a decoded value outside its object's EDS limits
    "skin_sample_out_of_range",  # ADC counts above the ADC's range, static force outside the FSR's
    "emg_envelope_out_of_range",  # above what a muscle produces (full scale = saturation passes)
    "emg_envelope_jump",  # moved more than the moving average can between two reports
    "hand_grip_out_of_range",  # actual grip above the crush limit
    "hand_grip_jump",  # actual grip moved faster than the actuator can
    "emcy_unknown_code",  # a CiA 301 class the node does not declare: reported, not named
    "emcy_invalid",  # no CiA 301 error class, or no generic bit: dropped
    "hand_command_slew_limited",  # grip setpoints reached over several commands
    "belt_command_slew_limited",  # belt velocities reached over several commands
    "foreign_nmt",  # NMT commands (COB-ID 000h) this gateway did not send
    "second_master_heartbeat",  # heartbeats at this gateway's own node-ID
)

# CiA 301 table of emergency error codes, by high byte (CiA 402 uses 70xx-7Fxx, 80xx-8Fxx).
_CLASSES = (
    ((0x10, 0x10), "generic"),
    ((0x20, 0x23), "current"),
    ((0x30, 0x33), "voltage"),
    ((0x40, 0x42), "temperature"),
    ((0x50, 0x50), "device hardware"),
    ((0x60, 0x63), "device software"),
    ((0x70, 0x7F), "additional modules"),
    ((0x80, 0x8F), "monitoring"),
    ((0x90, 0x90), "external"),
    ((0xF0, 0xF0), "additional functions"),
    ((0xFF, 0xFF), "device specific"),
)
REG_GENERIC = 0x01


@dataclass(frozen=True, slots=True)
class PlausibilityConfig:
    """Limits on what the loop follows (`[plausibility]`; defaults from the physics)."""

    grip_slew_n_s: float = 50.0  # the hand's own grip slew (2404h): it cannot follow faster
    belt_slew_mrad_s2: float = 40_000.0  # the belt's profile acceleration (6083h)
    command_interval_ms: float = 10.0  # a drive's RPDO value changes at most every 10 ms
    emg_max_amplitude_uv: float = 10_000.0  # surface EMG stays below 10 mV
    hand_grip_margin_n: float = 1.0  # actual grip above the crush limit by more: impossible
    hand_slew_factor: float = 2.0  # actual grip faster than this x 2404h: impossible

    @property
    def command_interval_us(self) -> int:
        return max(1, round(self.command_interval_ms * 1000))


def emcy_class(code: int) -> str | None:
    """The CiA 301 error class of a non-zero code; None when it falls in none."""
    high = code >> 8
    return next((name for (lo, hi), name in _CLASSES if lo <= high <= hi), None)


@dataclass(frozen=True, slots=True)
class EmcyVerdict:
    trusted: bool  # False: not an EMCY (dropped, counted as `emcy_invalid`)
    known: bool  # the code is one the node kind declares
    text: str  # for the alarm


def judge_emcy(kind: str, code: int, register: int) -> EmcyVerdict:
    """How far an EMCY from a node of `kind` is believed (see module docstring)."""
    if code == 0:
        return EmcyVerdict(True, True, "error reset")
    cls = emcy_class(code)
    if cls is None or not register & REG_GENERIC:
        why = "no CiA 301 error class" if cls is None else "error register without generic bit"
        return EmcyVerdict(False, False, f"invalid EMCY 0x{code:04X} ({why})")
    if code in CODES_BY_KIND.get(kind, ()):
        text = f"EMCY 0x{code:04X} {DESCRIPTIONS[code]}, register 0x{register:02X}"
        return EmcyVerdict(True, True, text)
    return EmcyVerdict(
        True, False, f"unknown EMCY code 0x{code:04X} ({cls}), register 0x{register:02X}"
    )


class Rejections(Counter[str]):
    """Refusals by `REJECTION_KEYS`; `as_dict` is the snapshot's section."""

    def as_dict(self) -> dict[str, int]:
        return {key: self[key] for key in REJECTION_KEYS}


class EnvelopeCheck:
    """An EMG envelope (the mean of the rectified signal over `window_ms`, reported every
    `period_ms`) replaces period/window of its window per report, so it moves by at most
    that share of the largest rectified sample per report elapsed."""

    def __init__(
        self, max_amplitude_uv: float, window_ms: float, period_ms: float, full_scale: float
    ):
        self.max_amplitude_uv = max_amplitude_uv
        self.full_scale = full_scale
        self.period_us = period_ms * 1000
        self.step_uv = max_amplitude_uv * min(1.0, period_ms / window_ms)
        self._last: tuple[int, float] | None = None  # (t_us, envelope) last accepted

    def check(self, t_us: int, envelope_uv: float) -> str | None:
        """None when plausible (and then the new reference), else the rejection key."""
        if envelope_uv >= self.full_scale:
            return None  # saturation: the decoder's own fault handling judges it
        if not 0 <= envelope_uv <= self.max_amplitude_uv:
            return "emg_envelope_out_of_range"
        last = self._last
        if last is not None:
            reports = max(1, math.ceil((t_us - last[0]) / self.period_us))
            if abs(envelope_uv - last[1]) > self.step_uv * reports + 1:  # +1: integer µV
                return "emg_envelope_jump"
        self._last = (t_us, envelope_uv)
        return None

    def reset(self) -> None:
        self._last = None


class GripCheck:
    """The hand's actual grip: within 0..crush limit (+ margin), moving no faster than the
    actuator's slew (x factor, over the time since the last accepted report + 20 ms)."""

    JITTER_US = 20_000  # TPDO timing: inhibit time and queueing between two reports

    def __init__(self, crush_limit_n: float, slew_n_s: float, margin_n: float, factor: float):
        self.high_n = crush_limit_n + margin_n
        self.margin_n = margin_n
        self.slew_n_s = slew_n_s * factor
        self._last: tuple[int, float] | None = None

    def check(self, t_us: int, grip_n: float) -> str | None:
        if not 0 <= grip_n <= self.high_n:
            return "hand_grip_out_of_range"
        last = self._last
        if last is not None:
            dt_s = (t_us - last[0] + self.JITTER_US) / US_PER_S
            if abs(grip_n - last[1]) > self.slew_n_s * dt_s + self.margin_n:
                return "hand_grip_jump"
        self._last = (t_us, grip_n)
        return None

    def reset(self) -> None:
        self._last = None


class CommandRamp:
    """A command value that moves by at most `rate_per_s` (per command interval's worth)
    and changes at most once per `interval_us`; `next_deadline_us` says when the next
    step is due while the value is on its way to the target."""

    def __init__(self, rate_per_s: float, interval_us: int):
        self.step = rate_per_s * interval_us / US_PER_S
        self.interval_us = interval_us
        self.value: float | None = None  # the value last commanded
        self.sent_us: int | None = None
        self.target: float | None = None
        self.limited = 0  # targets that took more than one step

    def start_from(self, value: float | None) -> None:
        """Where the actuator is (a node restarted, a stop): the ramp goes on from there."""
        self.value = value
        self.target = value
        self.sent_us = None

    def output(self, target: float, t_us: int) -> float:
        """The value to command at `t_us` on the way to `target`."""
        if self.value is None:
            self.value = self.target = target
            self.sent_us = t_us
            return target
        if target != self.target:
            settled = self.target == self.value  # not already on its way: a new episode
            self.target = target
            if settled and abs(target - self.value) > self.step:
                self.limited += 1
        if target == self.value:
            return self.value
        if self.sent_us is not None and t_us < self.sent_us + self.interval_us:
            return self.value
        delta = target - self.value
        self.value = (
            target if abs(delta) <= self.step else self.value + math.copysign(self.step, delta)
        )
        self.sent_us = t_us
        return self.value

    def next_deadline_us(self) -> int | None:
        if self.target is None or self.value is None or self.target == self.value:
            return None
        return (self.sent_us or 0) + self.interval_us

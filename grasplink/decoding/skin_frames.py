"""Skin TPDO values -> force samples at their times on the node's clock: the one
front end from frames to samples, shared by the live gateway (`Gateway._on_skin`)
and offline decoding (`io.read_can_log`).

Both hand it what `profiles.pdo_codec.PdoCodec` decoded from a skin TPDO (the
mapping comes from the EDS, never laid out by hand), so a CAN log decodes as the
live gateway decodes the same frames, to the last bit. Counts become newtons with
the FSR calibration (2130h) before the samples are placed (`packets.SampleStream`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import canopen
import numpy as np

from grasplink.decoding.packets import (
    DEFAULT_LATE_US,
    SEQUENCE_MODULO,
    Released,
    SampleStream,
    StreamStats,
)
from grasplink.errors import ConfigError
from grasplink.profiles import objects as obj
from grasplink.profiles import od_default

Key = tuple[int, int]  # (index, subindex), as PdoCodec keys its values
SEQUENCE_KEY: Key = (obj.SKIN_PACKET_SEQUENCE, 0)
ADC_BITS, FULL_SCALE_MN, ZERO_COUNTS = 1, 2, 3  # 2130h sub-indices
EMPTY: Released = (np.empty(0), np.empty(0))


def sample_slot_keys(samples_per_pdo: int) -> tuple[Key, ...]:
    """The sample slots (2100h sub 1..n) a TPDO carries, in sample order."""
    return tuple((obj.SKIN_SAMPLE_SLOTS, sub) for sub in range(1, samples_per_pdo + 1))


@dataclass(frozen=True)
class SkinCalibration:
    """ADC counts -> newtons: force_mN = (counts - zero) x full_scale_mN / (2^bits - 1 - zero)."""

    adc_bits: int
    full_scale_mn: float
    zero_counts: int

    def __post_init__(self) -> None:
        if not 1 <= self.adc_bits <= 32:
            raise ConfigError(f"skin calibration: {self.adc_bits} ADC bits is not 1..32")
        if not 0 <= self.zero_counts < self.full_counts:
            raise ConfigError(
                f"skin calibration: zero offset {self.zero_counts} is not below full scale "
                f"at {self.adc_bits} bits"
            )

    @classmethod
    def from_od(cls, od: canopen.ObjectDictionary) -> SkinCalibration:
        """The calibration defaults (2130h) of a skin object dictionary."""
        return cls(
            od_default(od, obj.SKIN_FSR_CALIBRATION, ADC_BITS),
            float(od_default(od, obj.SKIN_FSR_CALIBRATION, FULL_SCALE_MN)),
            od_default(od, obj.SKIN_FSR_CALIBRATION, ZERO_COUNTS),
        )

    @property
    def full_counts(self) -> int:
        return (1 << self.adc_bits) - 1

    @property
    def n_per_count(self) -> float:
        """One ADC step in newtons."""
        return self.full_scale_mn / (self.full_counts - self.zero_counts) / 1e3

    def static_force_range_mn(self) -> tuple[float, float]:
        """What a static force (2110h) can read: the zero offset's negative to full scale,
        +-1 mN for the node's rounding."""
        per_count_mn = self.full_scale_mn / (self.full_counts - self.zero_counts)
        return (-self.zero_counts * per_count_mn - 1, self.full_scale_mn + 1)


@dataclass(frozen=True)
class SampleObjects:
    """Where a TPDO carries force samples, and how they become newtons:
    force_N = (value - zero_units) x newtons_per_unit."""

    samples: tuple[Key, ...]  # in sample order
    newtons_per_unit: float
    zero_units: float = 0.0
    sequence: Key | None = None  # a packet number: sample times from it, not from arrival

    def to_newton(self, values: Sequence[int | float] | np.ndarray) -> np.ndarray:
        if isinstance(values, list):  # a TPDO's few counts: in floats, the same numbers
            zero, per_unit = self.zero_units, self.newtons_per_unit
            return np.array([(float(v) - zero) * per_unit for v in values], dtype=np.float64)
        return (np.asarray(values, dtype=np.float64) - self.zero_units) * self.newtons_per_unit

    @classmethod
    def of_skin(cls, calibration: SkinCalibration, samples_per_pdo: int) -> SampleObjects:
        """Our skin node's: ADC counts in 2100h sub 1..n, the packet number 2101h."""
        return cls(
            sample_slot_keys(samples_per_pdo),
            calibration.n_per_count,
            calibration.zero_counts,
            SEQUENCE_KEY,
        )


class SkinFrames:
    """Decoded skin TPDOs (`feed`) -> (sample times in s, force in N) on the node's clock."""

    def __init__(
        self,
        objects: SampleObjects,
        sample_rate_hz: float,
        *,
        late_us: float = DEFAULT_LATE_US,
        reorder_packets: int = 0,
        settle_us: float = 0.0,
    ):
        self.objects = objects
        self.stream = SampleStream(
            sample_rate_hz,
            len(objects.samples),
            late_us=late_us,
            reorder_packets=reorder_packets,
            settle_us=settle_us,
        )

    @property
    def stats(self) -> StreamStats:
        return self.stream.stats

    @property
    def anchor_s(self) -> float | None:
        return self.stream.anchor_s

    def feed(
        self, t_us: float, values: Mapping[Key, int | float], number: int | None = None
    ) -> Released:
        """One TPDO's values received at `t_us`; the samples given out now (see SampleStream).
        A TPDO without sample slots (the static force alone) gives none. `number` is the
        packet's number when the caller knows it and the TPDO does not carry one (the
        SYNC a synchronous TPDO answered)."""
        objects = self.objects
        slots = [values[k] for k in objects.samples if k in values]
        if not slots:
            return EMPTY
        if objects.sequence is not None:
            carried = values.get(objects.sequence)
            number = None if carried is None else int(carried)
        sequence = None if number is None else number % SEQUENCE_MODULO
        return self.stream.feed(t_us, sequence, objects.to_newton(slots))

    def restart(self) -> None:
        """The node rebooted (its boot-up): its sample numbers start again."""
        self.stream.restart()

    def flush(self) -> Released:
        """Everything still held (settling, reorder window), at the end of a log."""
        return self.stream.flush()

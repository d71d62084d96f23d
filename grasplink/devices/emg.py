"""EMG node: samples surface EMG and reports its intensity as an envelope and a level.

The envelope is the rectified signal averaged over the configured window
(thesis ch. 2.3: "rectified and integrated"), updated every envelope period
and sent in TPDO1 with the contraction level e0..e5 computed from the
calibration (e_min, e_max split into four equal levels). TPDO2, disabled by
default, streams raw samples three per frame for offline analysis.
"""

from __future__ import annotations

import numpy as np

from grasplink.core.frames import Frame
from grasplink.core.nmt import NmtState
from grasplink.devices.app import AppServices, DeviceApp
from grasplink.devices.sampling import SampleClock
from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.devices.sources import ConstantSource, SampleSource
from grasplink.devices.store import Value
from grasplink.profiles import objects as obj

TPDO_ENVELOPE = 1
TPDO_RAW = 2
RAW_PER_PDO = 3
E_MIN, E_MAX = 1, 2
LEVELS = 4  # e1..e4 between e_min and e_max
MAX_SAMPLES_PER_ADVANCE = 1 << 20
INT16_MIN, INT16_MAX = -32768, 32767


def contraction_level(envelope_uv: float, e_min_uv: float, e_max_uv: float) -> int:
    """0 (e0, below e_min) .. 5 (e5, above e_max); e1..e4 split [e_min, e_max] evenly."""
    if not envelope_uv >= e_min_uv:  # also catches NaN
        return 0
    if envelope_uv > e_max_uv:
        return LEVELS + 1
    share = (envelope_uv - e_min_uv) / (e_max_uv - e_min_uv)
    return min(LEVELS, 1 + int(share * LEVELS))


class EmgApp(DeviceApp):
    streamed_tpdos = (TPDO_RAW,)
    packet_tpdos = (TPDO_ENVELOPE, TPDO_RAW)
    packets_on_sync = (obj.EMG_PACKETS_ON_SYNC, 0)

    def __init__(self, source: SampleSource | None = None):
        self.source = source or ConstantSource(0.0)
        self.clock: SampleClock | None = None
        self._window = np.zeros(1)
        self._pos = 0
        self._fill = 0
        self._next_envelope_us = 0
        self._raw: list[int] = []

    def attach(self, services: AppServices) -> None:
        super().attach(services)
        self.store.add_validator(obj.EMG_CALIBRATION, self._validate_calibration)
        self.store.add_listener(self._on_change, (obj.EMG_SAMPLE_RATE_HZ, obj.EMG_WINDOW_MS))

    @property
    def rate_hz(self) -> int:
        return int(self.store.get(obj.EMG_SAMPLE_RATE_HZ))

    @property
    def period_us(self) -> int:
        return int(self.store.get(obj.EMG_ENVELOPE_PERIOD_MS)) * 1000

    def _validate_calibration(self, index: int, subindex: int, value: Value) -> None:
        other = int(self.store.get(obj.EMG_CALIBRATION, E_MAX if subindex == E_MIN else E_MIN))
        e_min, e_max = (int(value), other) if subindex == E_MIN else (other, int(value))
        if e_max <= e_min:
            raise SdoAbort(
                AbortCode.MAX_LESS_THAN_MIN, f"e_max ({e_max} uV) must be above e_min ({e_min} uV)"
            )

    def _on_change(self, index: int, subindex: int, value: Value) -> None:
        if index in (obj.EMG_SAMPLE_RATE_HZ, obj.EMG_WINDOW_MS) and self.clock is not None:
            self._restart(self.services.now_us())

    def on_reset(self, t_us: int) -> None:
        self._restart(t_us)

    def _restart(self, t_us: int) -> None:
        self.clock = SampleClock(self.rate_hz, t_us)
        window_ms = int(self.store.get(obj.EMG_WINDOW_MS))
        self._window = np.zeros(max(1, self.rate_hz * window_ms // 1000))
        self._pos = self._fill = 0
        self._next_envelope_us = t_us + self.period_us
        self._raw.clear()

    def advance(self, t_us: int) -> list[Frame]:
        frames: list[Frame] = []
        while self.clock is not None and self._next_envelope_us <= t_us:
            frames += self._sample_until(self._next_envelope_us)
            frames += self._publish_envelope(self._next_envelope_us)
            self._next_envelope_us += self.period_us
        return frames

    def next_deadline_us(self) -> int | None:
        return self._next_envelope_us if self.clock is not None else None

    def _sample_until(self, t_us: int) -> list[Frame]:
        clock = self.clock
        if clock is None:  # advance() samples only once the clock runs
            return []
        count = min(clock.due_until(t_us) - clock.next_index, MAX_SAMPLES_PER_ADVANCE)
        if count <= 0:
            return []
        values = self.source.samples(clock.t0_us, clock.next_index, count, clock.rate_hz)
        # (nan_to_num's checks cost more than a period; the reduction is ndarray.all
        # without its Python wrapper)
        if not np.logical_and.reduce(np.isfinite(values)):
            values = np.nan_to_num(values)
        clock.next_index += count
        size = len(self._window)
        rectified = np.abs(values)[-size:]
        # into the ring at _pos, wrapping once at most: two slices, no index array
        head = min(len(rectified), size - self._pos)
        self._window[self._pos : self._pos + head] = rectified[:head]
        self._window[: len(rectified) - head] = rectified[head:]
        self._pos = (self._pos + len(rectified)) % size
        self._fill = min(size, self._fill + len(rectified))
        return self._stream_raw(values, t_us)

    def _publish_envelope(self, t_us: int) -> list[Frame]:
        # ndarray.mean is add.reduce divided by the count: the same bits without its Python
        # wrapper, which cost a fifth of an envelope tick.
        fill = self._fill
        envelope = float(np.add.reduce(self._window[:fill]) / fill) if fill else 0.0
        e_min = int(self.store.get(obj.EMG_CALIBRATION, E_MIN))
        e_max = int(self.store.get(obj.EMG_CALIBRATION, E_MAX))
        self.store.set(obj.EMG_ENVELOPE_UV, 0, min(0xFFFF, round(envelope)))
        self.store.set(obj.EMG_LEVEL, 0, contraction_level(envelope, e_min, e_max))
        sequence = (int(self.store.get(obj.EMG_ENVELOPE_SEQUENCE)) + 1) & 0xFF
        self.store.set(obj.EMG_ENVELOPE_SEQUENCE, 0, sequence)
        if self.services.nmt_state != NmtState.OPERATIONAL:
            return []
        return self.services.transmit_tpdo(TPDO_ENVELOPE, t_us)

    def _stream_raw(self, values: np.ndarray, t_us: int) -> list[Frame]:
        if self.services.nmt_state != NmtState.OPERATIONAL or not self.services.tpdo_enabled(
            TPDO_RAW
        ):
            return []
        frames = []
        self._raw.extend(np.clip(np.rint(values), INT16_MIN, INT16_MAX).astype(int).tolist())
        while len(self._raw) >= RAW_PER_PDO:
            for slot in range(RAW_PER_PDO):
                self.store.set(obj.EMG_RAW_SLOTS, slot + 1, self._raw[slot])
            del self._raw[:RAW_PER_PDO]
            sequence = (int(self.store.get(obj.EMG_RAW_SEQUENCE)) + 1) & 0xFF
            self.store.set(obj.EMG_RAW_SEQUENCE, 0, sequence)
            frames += self.services.transmit_tpdo(TPDO_RAW, t_us)
        return frames

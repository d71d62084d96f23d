"""Skin sensor node: samples the FSR under the ridged skin and streams it.

TPDO1 carries `samples per PDO` (1-3) consecutive ADC samples plus a packet
sequence number, so a receiver can tell a lost frame from a quiet signal.
TPDO2 (event timer) carries the static force in mN and the total sample
count, which lets a receiver re-anchor sample times after a loss.

Bus load at defaults (400 Hz, 3 samples per PDO): 133.3 TPDO1 frames/s of
7 data bytes and 50 TPDO2 frames/s of 8 bytes, about 2.4 % of 1 Mbit/s
with worst-case stuffing (see docs/benchmarks/network.md for measured figures).
TPDO1 made synchronous with 2122h = 1 keeps sampling at its rate and sends every
packet made since on the SYNC it is due on (devices/pdo.py).
"""

from __future__ import annotations

import numpy as np

from grasplink.core.frames import Frame
from grasplink.core.nmt import NmtState
from grasplink.devices import emcy as em
from grasplink.devices.app import AppServices, DeviceApp, StreamSpan
from grasplink.devices.sampling import US_PER_S, SampleClock
from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.devices.sources import ConstantSource, FinalSource, SampleSource
from grasplink.devices.store import Value
from grasplink.profiles import objects as obj
from grasplink.profiles.layouts import LAYOUTS_MM, PRESET_CODES

STATIC_WINDOW_S = 0.05  # static force = mean of the last 50 ms of samples
MN_PER_N = 1000.0
UM_PER_MM = 1000
MAX_PACKETS_PER_ADVANCE = 4096  # bound work after a stall; older packets are dropped
MAX_PACKETS_PER_SPAN = 1024  # packets told ahead in one call (a bus asks again after)
# Fewer packets due before the bus's bound (a 10 ms chunk holds one or two) tick one by
# one: a span of one costs more than the tick it replaces.
MIN_PACKETS_PER_SPAN = 4
# Samples converted to counts in one numpy pass at most, when the source has them final:
# per packet (3 samples) numpy's call overhead would cost more than the conversion.
READ_AHEAD_SAMPLES = 256
# Up to this many samples `counts_list` converts them one by one, in Python floats.
SCALAR_COUNTS_MAX = 32
TPDO_SAMPLES = 1
CAL_BITS, CAL_FULL_SCALE_MN, CAL_ZERO = 1, 2, 3


class SkinApp(DeviceApp):
    read_ahead_samples = READ_AHEAD_SAMPLES  # 0: convert each packet's samples alone
    streamed_tpdos = (TPDO_SAMPLES,)
    packet_tpdos = (TPDO_SAMPLES,)
    packets_on_sync = (obj.SKIN_PACKETS_ON_SYNC, 0)

    def __init__(self, source: SampleSource | None = None):
        self.source = source or ConstantSource(0.0)
        self.clock: SampleClock | None = None
        self._static = [0]
        self._static_sum = 0
        self._static_fill = 0
        self._ring_pos = 0
        self._loading_preset = False
        self._calibration: tuple[int, int, float] | None = None
        # Counts of samples _ahead_start.. converted ahead (read_ahead); cleared when the
        # clock restarts or the calibration changes.
        self._ahead_start = 0
        self._ahead: list[int] = []
        self.saturated_samples = 0
        self.dropped_packets = 0
        # The last span told ahead (counts, samples per packet, span), until committed.
        self._span: tuple[list[int], int, StreamSpan] | None = None

    @property
    def source(self) -> SampleSource:
        return self._source

    @source.setter
    def source(self, source: SampleSource) -> None:
        # Whether it says which samples are final, asked once: a runtime Protocol check
        # costs more than converting a packet, and the advance path needs it per chunk.
        self._source = source
        self._final: FinalSource | None = source if isinstance(source, FinalSource) else None

    def attach(self, services: AppServices) -> None:
        super().attach(services)
        self.store.add_validator(obj.SKIN_RIDGE_SPACING_UM, self._validate_spacing)
        self.store.add_validator(obj.SKIN_FSR_CALIBRATION, self._validate_calibration)
        watched = (
            obj.SKIN_LAYOUT_PRESET,
            obj.SKIN_RIDGE_SPACING_UM,
            obj.SKIN_SAMPLE_RATE_HZ,
            obj.SKIN_FSR_CALIBRATION,
        )
        self.store.add_listener(self._on_change, watched)

    # -- configuration ----------------------------------------------------------
    @property
    def rate_hz(self) -> int:
        return int(self.store.get(obj.SKIN_SAMPLE_RATE_HZ))

    @property
    def samples_per_pdo(self) -> int:
        return int(self.store.get(obj.SKIN_SAMPLES_PER_PDO))

    def layout_mm(self) -> tuple[float, ...]:
        count = int(self.store.get(obj.SKIN_RIDGE_SPACING_UM, 0))
        return tuple(
            int(self.store.get(obj.SKIN_RIDGE_SPACING_UM, s)) / UM_PER_MM
            for s in range(1, count + 1)
        )

    def full_scale_counts(self) -> int:
        return (1 << int(self.store.get(obj.SKIN_FSR_CALIBRATION, CAL_BITS))) - 1

    def _validate_spacing(self, index: int, subindex: int, value: Value) -> None:
        if subindex == 0 and int(value) == 0:
            raise SdoAbort(AbortCode.VALUE_TOO_LOW, "a skin has at least one ridge spacing")

    def _validate_calibration(self, index: int, subindex: int, value: Value) -> None:
        if subindex == CAL_ZERO:
            bits = int(self.store.get(obj.SKIN_FSR_CALIBRATION, CAL_BITS))
            if int(value) >= (1 << bits) - 1:
                raise SdoAbort(AbortCode.VALUE_TOO_HIGH, "zero offset must be below full scale")
        if subindex == CAL_BITS:
            zero = int(self.store.get(obj.SKIN_FSR_CALIBRATION, CAL_ZERO))
            if zero >= (1 << int(value)) - 1:
                raise SdoAbort(AbortCode.VALUE_TOO_LOW, "resolution leaves no range above zero")

    def _on_change(self, index: int, subindex: int, value: Value) -> None:
        if index == obj.SKIN_LAYOUT_PRESET and int(value) in PRESET_CODES:
            self._load_preset(PRESET_CODES[int(value)])
        elif index == obj.SKIN_RIDGE_SPACING_UM and not self._loading_preset:
            self.store.set(obj.SKIN_LAYOUT_PRESET, 0, 0)
        elif index == obj.SKIN_FSR_CALIBRATION:
            self._calibration = None
            self._ahead = []
        elif index == obj.SKIN_SAMPLE_RATE_HZ and self.clock is not None:
            self._restart_sampling(self.services.now_us())

    def _load_preset(self, name: str) -> None:
        spacings = LAYOUTS_MM[name]
        self._loading_preset = True
        try:
            self.store.set(obj.SKIN_RIDGE_SPACING_UM, 0, len(spacings))
            for sub, mm in enumerate(spacings, start=1):
                self.store.set(obj.SKIN_RIDGE_SPACING_UM, sub, round(mm * UM_PER_MM))
        finally:
            self._loading_preset = False

    # -- behaviour ----------------------------------------------------------------
    def on_reset(self, t_us: int) -> None:
        self._restart_sampling(t_us)

    def _restart_sampling(self, t_us: int) -> None:
        self.clock = SampleClock(self.rate_hz, t_us)
        self._static = [0] * max(1, round(self.rate_hz * STATIC_WINDOW_S))
        self._static_sum = 0
        self._static_fill = 0
        self._ring_pos = 0
        self._ahead = []

    def calibration(self) -> tuple[int, int, float]:
        """(zero counts, full-scale counts, mN per count), cached until 2130h changes."""
        if self._calibration is None:
            full = self.full_scale_counts()
            zero = int(self.store.get(obj.SKIN_FSR_CALIBRATION, CAL_ZERO))
            scale_mn = int(self.store.get(obj.SKIN_FSR_CALIBRATION, CAL_FULL_SCALE_MN))
            self._calibration = (zero, full, scale_mn / (full - zero))
        return self._calibration

    def to_counts(self, force_n: np.ndarray) -> np.ndarray:
        """ADC counts for forces (the device's linearised FSR calibration); NaN reads 0 N."""
        zero, full, mn_per_count = self.calibration()
        force_n = np.where(np.isnan(force_n), 0.0, force_n)
        counts = np.rint(zero + force_n * (MN_PER_N / mn_per_count))
        # np.clip's bounds, without its Python wrapper (a fifth of this call on a tick's
        # 4-6 samples)
        return np.minimum(np.maximum(counts, 0), full).astype(np.int64)

    def counts_list(self, force_n: np.ndarray) -> list[int]:
        """`to_counts(force_n).tolist()`, the same ints. A closed loop's node reads its
        chunk's 4-6 samples at a time (the scene finalises one chunk ahead), and there
        numpy's six calls cost ~7 us in their Python wrappers (twice that in the loop,
        from cold caches) against ~2 us for a loop over Python floats: the same IEEE
        operations (zero + f * scale, then round half to even, `round` as `np.rint`),
        the infinities and the scale's ends clipped as `to_counts` clips them."""
        counts: list[int]
        if len(force_n) > SCALAR_COUNTS_MAX:
            counts = self.to_counts(force_n).tolist()
            return counts
        zero, full, mn_per_count = self.calibration()
        scale = MN_PER_N / mn_per_count
        counts = []
        for f in force_n.tolist():
            x = zero + (0.0 if f != f else f) * scale  # NaN reads 0 N
            if x >= full:  # (and +inf, which round cannot take)
                counts.append(full)
            elif x <= 0:  # (and -inf)
                counts.append(0)
            else:
                counts.append(min(round(x), full))
        return counts

    def to_force_mn(self, counts: np.ndarray | float) -> np.ndarray:
        zero, _, mn_per_count = self.calibration()
        return (np.asarray(counts, dtype=np.float64) - zero) * mn_per_count

    def advance(self, t_us: int) -> list[Frame]:
        clock = self.clock
        if clock is None:
            return []
        per_pdo = self.samples_per_pdo
        due = clock.due_until(t_us)
        packets = (due - clock.next_index) // per_pdo
        if packets <= 0:
            return []
        if packets > MAX_PACKETS_PER_ADVANCE:
            skipped = packets - MAX_PACKETS_PER_ADVANCE
            self.dropped_packets += skipped
            clock.next_index += skipped * per_pdo
            packets = MAX_PACKETS_PER_ADVANCE
        start = clock.next_index
        counts = self._counts(clock, start, packets * per_pdo)
        self._track_saturation(counts, t_us)
        self._track_static(counts)
        frames: list[Frame] = []
        operational = self.services.nmt_state == NmtState.OPERATIONAL
        sequence = int(self.store.get(obj.SKIN_PACKET_SEQUENCE))
        for p in range(packets):
            block = counts[p * per_pdo : (p + 1) * per_pdo]
            for slot, value in enumerate(block, start=1):
                self.store.set(obj.SKIN_SAMPLE_SLOTS, slot, int(value))
            sequence = (sequence + 1) & 0xFF
            self.store.set(obj.SKIN_PACKET_SEQUENCE, 0, sequence)
            end_index = start + (p + 1) * per_pdo
            self.store.set(obj.SKIN_SAMPLE_COUNTER, 0, end_index & 0xFFFFFFFF)
            if operational:
                frames += self.services.transmit_tpdo(TPDO_SAMPLES, clock.time_of(end_index - 1))
        clock.next_index = start + packets * per_pdo
        self._set_static_force()
        return frames

    def stream_until_us(self, t_us: int) -> int | None:
        """When the last sample of the `MIN_PACKETS_PER_SPAN`-th packet not yet sent is
        due: a span told ahead holds at least that many packets (None: nothing is told)."""
        clock = self.clock
        if clock is None or self._final is None:
            return None
        return clock.time_of(clock.next_index + MIN_PACKETS_PER_SPAN * self.samples_per_pdo - 1)

    def stream_ahead(self, t_us: int, until_us: int) -> StreamSpan | None:
        """The packets due up to `until_us`, each TPDO1 at its time, told ahead
        (`core.protocol.StreamingDevice`) up to the last final sample and to the first
        packet that raises or clears the saturation EMCY (that one ticks as usual); only
        when TPDO1 goes out at once on each packet (`AppServices.direct_tpdo`) and the
        source says which samples are final (`FinalSource`). Nothing changes until
        `commit_stream`: the samples converted ahead are only a cache."""
        self._span = None
        clock = self.clock
        if clock is None or self._final is None:
            return None  # a source that does not say which samples are final: as it asks
        per_pdo = self.samples_per_pdo
        final_us = self._final.final_until_us()
        if final_us is not None:
            until_us = min(until_us, final_us)
        start = clock.next_index
        packets = min((clock.due_until(until_us) - start) // per_pdo, MAX_PACKETS_PER_SPAN)
        if packets < MIN_PACKETS_PER_SPAN:
            return None
        slots = tuple((obj.SKIN_SAMPLE_SLOTS, slot) for slot in range(1, per_pdo + 1))
        given = (*slots, (obj.SKIN_PACKET_SEQUENCE, 0), (obj.SKIN_SAMPLE_COUNTER, 0))
        static_key = (obj.SKIN_STATIC_FORCE_MN, 0)
        pack = self.services.direct_tpdo(TPDO_SAMPLES, given, (static_key,))
        if pack is None:
            return None
        counts = self._counts(clock, start, packets * per_pdo)
        zero, full, mn_per_count = self.calibration()
        saturated = self.services.error_active(em.SENSOR_SATURATED)
        sequence = int(self.store.get(obj.SKIN_PACKET_SEQUENCE))
        # The static force after each packet (a TPDO2 on its timer may carry it), from a
        # copy of the window: `_track_static` on the packets' samples, one by one.
        ring, pos, size = list(self._static), self._ring_pos, len(self._static)
        total, fill = self._static_sum, self._static_fill
        t0_us, rate_hz = clock.t0_us, clock.rate_hz
        span = StreamSpan([], [], (*given, static_key), [], 0)
        for first in range(0, packets * per_pdo, per_pdo):
            block = counts[first : first + per_pdo]
            if (full in block) != saturated:
                break  # this packet raises or clears the EMCY: it ticks through advance
            pos, total = _push_window(ring, pos, total, block[-size:])
            fill = min(size, fill + min(per_pdo, size))
            static_mn = round((total / fill - zero) * mn_per_count)
            sequence = (sequence + 1) & 0xFF
            end = start + first + per_pdo
            counter = end & 0xFFFFFFFF
            span.times_us.append(t0_us + (end - 1) * US_PER_S // rate_hz)
            span.frames.append([pack(*block, sequence, counter)])
            span.values.append((*block, sequence, counter, static_mn))
        told = len(span.times_us)
        span.next_us = clock.time_of(start + (told + 1) * per_pdo - 1)
        self._span = (counts, per_pdo, span)
        return span

    def commit_stream(self, ticks: int) -> None:
        held, self._span = self._span, None
        if held is None or not ticks:
            return
        counts, per_pdo, span = held
        clock = self.clock
        assert clock is not None and ticks <= len(span.times_us)
        done = counts[: ticks * per_pdo]
        self.saturated_samples += done.count(self.calibration()[1])
        self._track_static(done)
        for slot, value in enumerate(done[-per_pdo:], start=1):
            self.store.set(obj.SKIN_SAMPLE_SLOTS, slot, value)
        sequence = (int(self.store.get(obj.SKIN_PACKET_SEQUENCE)) + ticks) & 0xFF
        self.store.set(obj.SKIN_PACKET_SEQUENCE, 0, sequence)
        clock.next_index += ticks * per_pdo
        self.store.set(obj.SKIN_SAMPLE_COUNTER, 0, clock.next_index & 0xFFFFFFFF)
        self._set_static_force()
        self.services.sent_directly(TPDO_SAMPLES, span.times_us[ticks - 1])

    def _set_static_force(self) -> None:
        zero, _, mn_per_count = self.calibration()
        mean_counts = self._static_sum / self._static_fill
        self.store.set(obj.SKIN_STATIC_FORCE_MN, 0, round((mean_counts - zero) * mn_per_count))

    def _counts(self, clock: SampleClock, start: int, count: int) -> list[int]:
        """Counts of samples start .. start+count-1, converted ahead where the source allows."""
        end = start + count
        offset = start - self._ahead_start
        if offset < 0 or end - self._ahead_start > len(self._ahead):
            stop = end
            if self._final is not None:
                final_us = self._final.final_until_us()
                ready = start + self.read_ahead_samples
                if final_us is not None:
                    ready = min(ready, clock.due_until(final_us))
                stop = max(end, ready)
            forces = self.source.samples(clock.t0_us, start, stop - start, clock.rate_hz)
            self._ahead = self.counts_list(forces)
            self._ahead_start, offset = start, 0
        return self._ahead[offset : offset + count]

    def next_deadline_us(self) -> int | None:
        if self.clock is None:
            return None
        return self.clock.time_of(self.clock.next_index + self.samples_per_pdo - 1)

    def _track_static(self, counts: list[int]) -> None:
        """Ring buffer of the last STATIC_WINDOW_S of samples (bounded memory), with its sum.

        Counts are integers, so the running sum stays exact however long the node runs.
        """
        ring = self._static
        tail = counts[-len(ring) :]
        self._ring_pos, self._static_sum = _push_window(
            ring, self._ring_pos, self._static_sum, tail
        )
        self._static_fill = min(len(ring), self._static_fill + len(tail))

    def _track_saturation(self, counts: list[int], t_us: int) -> None:
        # Counts are clipped to full scale (to_counts): a saturated sample reads exactly it.
        saturated = counts.count(self.calibration()[1])
        self.saturated_samples += saturated
        active = self.services.error_active(em.SENSOR_SATURATED)
        if saturated and not active:
            self.services.raise_error(em.SENSOR_SATURATED, em.REG_MANUFACTURER, t_us)
        elif not saturated and active:
            self.services.clear_error(em.SENSOR_SATURATED, t_us)


def _push_window(ring: list[int], pos: int, total: int, values: list[int]) -> tuple[int, int]:
    """`values` into the ring from `pos`, oldest out: the next position and the new sum
    (the static force's window, kept by a node and copied by a span told ahead)."""
    size = len(ring)
    for value in values:
        total += value - ring[pos]
        ring[pos] = value
        pos = (pos + 1) % size
    return pos, total

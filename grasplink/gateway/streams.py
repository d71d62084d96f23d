"""Sample streams rebuilt from PDOs: each sample at its time on the node's clock.

The skin node sends its FSR samples a few per TPDO with a wrapping packet
sequence number. The gateway gives every sample the time the node took it:
the node samples on a fixed grid, so sample k of the stream lies at
t0 + k / rate, anchored at the first packet received. Lost packets (a jump
in the sequence) leave their samples out and the decoders see a gap; a
packet whose arrival disagrees with the grid by more than `resync_periods`
packet periods (the node rebooted, its clock drifted, the bus stalled)
starts a new anchor, so a time error never accumulates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SEQUENCE_MODULO = 256


@dataclass
class StreamStats:
    packets: int = 0
    samples: int = 0
    lost_packets: int = 0  # from sequence gaps
    repeated_packets: int = 0  # same sequence again (a re-publish)
    resyncs: int = 0  # new anchor: reboot, drift or a long gap


class SampleStream:
    """Packets of `per_packet` samples at `rate_hz` -> (sample times in s, values)."""

    def __init__(self, rate_hz: float, per_packet: int, *, resync_periods: float = 4.0):
        if not rate_hz > 0 or per_packet < 1:
            raise ValueError(
                f"a stream needs rate > 0 and >= 1 sample per packet, got {rate_hz}, {per_packet}"
            )
        self.rate_hz = float(rate_hz)
        self.per_packet = per_packet
        self.resync_us = resync_periods * per_packet * 1e6 / rate_hz
        self.stats = StreamStats()
        self._anchor_us: float | None = None  # time of sample index 0
        self._next_index = 0  # index of the next expected sample
        self._last_sequence: int | None = None

    def reset(self) -> None:
        """Forget the anchor (the node restarted): the next packet starts a new one."""
        self._anchor_us = None
        self._last_sequence = None

    def feed(
        self, t_us: int, sequence: int | None, values: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """One packet received at `t_us`; returns its samples' times [s] and values."""
        values = np.asarray(values, dtype=np.float64)[: self.per_packet]
        self.stats.packets += 1
        missing = 0
        if sequence is not None and self._last_sequence is not None:
            step = (sequence - self._last_sequence) % SEQUENCE_MODULO
            if step == 0:
                self.stats.repeated_packets += 1
                return np.zeros(0), np.zeros(0)
            missing = step - 1
        self._last_sequence = sequence
        period_us = 1e6 / self.rate_hz
        # The packet's last sample was taken just before it was sent.
        if self._anchor_us is not None:
            index = self._next_index + missing * self.per_packet
            expected_us = self._anchor_us + (index + len(values) - 1) * period_us
            if abs(t_us - expected_us) > self.resync_us:
                self._anchor_us = None
                self.stats.resyncs += 1
            else:
                self.stats.lost_packets += missing
                self._next_index = index
        if self._anchor_us is None:
            self._next_index = 0
            self._anchor_us = t_us - (len(values) - 1) * period_us
        indices = self._next_index + np.arange(len(values))
        self._next_index += len(values)
        self.stats.samples += len(values)
        return (self._anchor_us + indices * period_us) / 1e6, values

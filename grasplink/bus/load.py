"""CAN bus load: worst-case frame length in bits, and a sliding-window load meter.

Classic CAN base frame (11-bit identifier, ISO 11898-1), payload n bytes:

* stuffed fields: SOF 1 + identifier 11 + RTR 1 + IDE 1 + r0 1 + DLC 4
  + data 8n + CRC 15 = 34 + 8n bits. After five equal bits the transmitter
  inserts a complementary bit that itself starts the next run, so the worst
  case adds floor((34 + 8n - 1) / 4) stuff bits.
* fixed-form fields, never stuffed: CRC delimiter 1 + ACK slot 1 + ACK
  delimiter 1 + end of frame 7 = 10 bits.
* intermission (interframe space) before the next frame may start: 3 bits.

    bits(n) = 34 + 8n + floor((34 + 8n - 1) / 4) + 10 + 3
            = 47 + 8n + floor((33 + 8n) / 4)

which is the frame transmission time C = (g + 8n + 13 + floor((g + 8n - 1) / 4))
bit times of Davis, Burns, Bril and Lukkien, "Controller Area Network (CAN)
schedulability analysis: refuted, revisited and revised", Real-Time Systems
35(3), 2007, with g = 34 for 11-bit identifiers and 13 = 10 + 3 unstuffed bits.
Convention: the 3-bit intermission IS included, so an 8-byte frame counts
135 bits and an empty one 55 bits; a remote frame carries no data field
whatever its DLC. Real frames stuff fewer bits, so the load is an upper bound -
the right side to err on when budgeting a bus.
"""

from __future__ import annotations

from collections import deque

from grasplink.core.frames import Frame

STUFFED_OVERHEAD_BITS = 34  # SOF..DLC (19) + CRC (15), base format
FIXED_TAIL_BITS = 10  # CRC delimiter, ACK slot, ACK delimiter, EOF (7)
INTERMISSION_BITS = 3


def frame_bits_worst_case(dlc: int, rtr: bool = False) -> int:
    """Bits a classic base-format frame occupies on the bus, worst-case stuffing,
    including the 3-bit intermission (see the module docstring)."""
    if not 0 <= dlc <= 8:
        raise ValueError(f"a classic CAN frame carries 0..8 data bytes, not {dlc}")
    stuffed = STUFFED_OVERHEAD_BITS + (0 if rtr else 8 * dlc)
    return stuffed + (stuffed - 1) // 4 + FIXED_TAIL_BITS + INTERMISSION_BITS


def frame_time_us(dlc: int, bitrate: int = 1_000_000, rtr: bool = False) -> float:
    """Worst-case time on the bus of one frame, in microseconds."""
    return frame_bits_worst_case(dlc, rtr) * 1e6 / bitrate


class BusLoadMeter:
    """Bus load over a sliding time window, from the frames seen on the bus.

    Feed it every frame the bus carries (`record`) with its time in integer
    microseconds; `percent(now_us)` is the worst-case bits of the frames in the
    last ``window_us`` as a share of what ``bitrate`` can carry in that window.
    Memory is bounded by the frames that fit in one window.
    """

    def __init__(self, bitrate: int = 1_000_000, window_us: int = 1_000_000) -> None:
        if bitrate <= 0:
            raise ValueError(f"bitrate must be positive, not {bitrate}")
        if window_us <= 0:
            raise ValueError(f"window must be positive, not {window_us} µs")
        self.bitrate = bitrate
        self.window_us = window_us
        self._events: deque[tuple[int, int]] = deque()
        self._bits = 0
        self.total_frames = 0
        self.total_bits = 0

    def record(self, frame: Frame, t_us: int) -> None:
        self.record_bits(frame_bits_worst_case(frame.length, frame.rtr), t_us)

    def record_bits(self, bits: int, t_us: int) -> None:
        self._events.append((t_us, bits))
        self._bits += bits
        self.total_frames += 1
        self.total_bits += bits
        self._expire(t_us)

    def bits_in_window(self, now_us: int) -> int:
        self._expire(now_us)
        return self._bits

    def percent(self, now_us: int) -> float:
        """Load in percent of ``bitrate`` over the window ending at ``now_us``."""
        return self.bits_in_window(now_us) * 100 * 1e6 / (self.bitrate * self.window_us)

    def _expire(self, now_us: int) -> None:
        horizon = now_us - self.window_us
        events = self._events
        while events and events[0][0] <= horizon:
            self._bits -= events.popleft()[1]

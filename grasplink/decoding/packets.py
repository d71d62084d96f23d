"""Packets of samples -> samples at their times on the node's clock: the one front end
of the live gateway (`Gateway._on_skin`) and of offline decoding (`io.read_can_log`).

The skin node samples on a fixed grid and sends `per_packet` samples a TPDO with
an 8-bit wrapping sequence number. A sample's time comes from the sequence, never
from when its packet arrived:

* each packet's number is unwrapped to an index n; packet n holds the samples
  n*per .. n*per + per-1, sample k at (tick0 + k) / rate s (plus a slow drift
  correction, below);
* only numbers never seen are missing (`lost_packets`): the decoder bridges a
  few and resets after more (base.GAP_PERIODS). A packet that arrives late - a
  stalled host and the burst after it, an adapter's time-stamp jitter - keeps
  its place on the grid;
* a number seen again is a re-publish (`repeated_packets`, dropped): what a
  node sends when it re-enters OPERATIONAL with nothing new sampled, its current
  TPDO once more. (The shipped skin firmware never re-publishes its sample
  TPDO - devices/pdo.py, streamed TPDOs - and keeps numbering while
  PRE-OPERATIONAL, so its numbers jump after a START: counted missing. Firmware
  that publishes the packet it sampled last but never sent gives a new number;
  those samples are real and take their place.)
* a packet behind the newest is put back in place within `reorder_packets`
  (offline io.REORDER_PACKETS; live 0: in-order packets are never held, and the
  live loop never waits for a hole); later than that it is dropped (`late_packets`).

Unwrapping uses arrival time only to choose between the numbers a byte allows:
the candidate with the least lateness that is not earlier than its grid time
(`EARLY_SLACK_US`: a packet cannot arrive before it was sampled). So a stall
shorter than the wrap (256 packets, 1.92 s at 400 Hz, 3 a packet) never looks
like a wrap. The sequence is given up for a new anchor (`resyncs`) only when
the data contradict it: the best candidate is later than `late_us` (the
heartbeat consumer time: by then the node is judged lost) or earlier than the
slack, or a silence outlasts both `late_us` and half a wrap; or when the caller
knows the node restarted (its boot-up message: `restart()`). A new anchor
never puts samples before ones already given out: it starts at least a decoder
gap after them.

The anchor (tick0) is the earliest arrival consistent with the sequence, over
the packets that arrive within `settle_us` of the first (held meanwhile: a
burst after a stall then cannot set it), rounded to a whole tick: time-stamp
jitter under half a sample period moves no sample time, so a jittered log
decodes exactly as the clean one.

Clock drift: a node's crystal (+-100 ppm) drifts 60 ms from the receiver's over
10 minutes. The lower envelope of (arrival - grid time) follows it (a lower
offset sets it, it rises by at most `ENVELOPE_RISE_PPM` of the time elapsed);
once it leaves +-`DRIFT_DEADBAND_US` the grid is slewed toward it by at most
`DRIFT_SLEW_PPM` of the time elapsed (sample spacing 0.05 % shorter or longer):
no jump and no reset, however long the node runs.
"""

from __future__ import annotations

import heapq
import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from grasplink.decoding.base import GAP_PERIODS

SEQUENCE_MODULO = 256  # the skin's U8 packet sequence (0x2101) wraps
HALF_WRAP = SEQUENCE_MODULO // 2
#: Lateness tolerated when none is given: the gateway's consumer time of a node's
#: heartbeat at the default 100 ms (3 periods and the 200 ms scheduling allowance,
#: master.NmtMaster.node_consumer_us; the live gateway passes its own).
DEFAULT_LATE_US = 500_000
#: How long after a new anchor's first packet arrivals are gathered to set it: a few
#: packet periods live (a delay at start), longer offline (holding costs nothing).
LIVE_SETTLE_US = 30_000
#: How much earlier than its grid time a packet may arrive: the grid may sit up to the
#: deadband and half a tick late, a new anchor a decoder gap late.
EARLY_SLACK_US = 50_000
#: The grid is slewed only when the arrivals' lower envelope is this far from it: far
#: beyond time-stamp jitter, far below the lateness tolerated.
DRIFT_DEADBAND_US = 10_000
#: Largest slew of the grid against arrival: 5x a crystal's 100 ppm.
DRIFT_SLEW_PPM = 500.0
#: The envelope forgets a low offset at this rate (above any crystal's drift).
ENVELOPE_RISE_PPM = 1000.0
PPM = 1e-6
US = 1e-6  # s per µs


@dataclass
class StreamStats:
    packets: int = 0  # packets fed
    released: int = 0  # packets whose samples were given out
    samples: int = 0
    lost_packets: int = 0  # sequence numbers never seen
    repeated_packets: int = 0  # a number already seen, again: a re-publish (dropped)
    late_packets: int = 0  # behind what was given out already, beyond the window (dropped)
    reordered: int = 0  # arrived after a newer one, put back in place
    stray_packets: int = 0  # off the grid, and the next packet did not follow it (dropped)
    resyncs: int = 0  # new anchors the data asked for: a long silence, arrival off the grid
    restarts: int = 0  # new anchors the caller asked for (restart(): boot-up, node lost)
    slewed_us: float = 0.0  # drift correction applied to the grid so far (signed)


Released = tuple[np.ndarray, np.ndarray]  # sample times [s], values
Pending = tuple[float, int | None, np.ndarray]  # a packet off the grid: arrival s, number, values


class SampleStream:
    """Packets of `per_packet` samples at `rate_hz` -> (sample times in s, values)."""

    def __init__(
        self,
        rate_hz: float,
        per_packet: int,
        *,
        late_us: float = DEFAULT_LATE_US,
        reorder_packets: int = 0,
        settle_us: float = 0.0,
    ):
        if not rate_hz > 0 or per_packet < 1:
            raise ValueError(
                f"a stream needs rate > 0 and >= 1 sample per packet, got {rate_hz}, {per_packet}"
            )
        if not late_us > 0 or reorder_packets < 0 or settle_us < 0:
            raise ValueError(
                f"need late_us > 0, reorder_packets >= 0, settle_us >= 0; got {late_us}, "
                f"{reorder_packets}, {settle_us}"
            )
        self.rate_hz = float(rate_hz)
        self.per_packet = per_packet
        self.late_s = late_us * US
        self.reorder_packets = min(reorder_packets, HALF_WRAP - 1)
        self.settle_s = settle_us * US
        self.packet_s = per_packet / self.rate_hz
        self.wrap_s = SEQUENCE_MODULO * self.packet_s
        # A packet put back in place may come that many packet periods before its grid time.
        self.early_s = EARLY_SLACK_US * US + self.reorder_packets * self.packet_s
        # Silent this long, the node was judged lost and its number may have wrapped.
        self.silence_s = max(self.late_s, HALF_WRAP * self.packet_s)
        self.stats = StreamStats()
        self._out: list[Released] = []  # given out by the next feed() or flush()
        self._last_t_s = -math.inf  # time of the last sample given out (any anchor)
        self._forget()

    def _forget(self) -> None:
        self._tick0: int | None = None  # tick of packet 0's first sample; None: settling
        self._shift_s = 0.0  # drift correction added to every time
        self._newest: int | None = None  # newest packet index accepted
        self._newest_seq: int | None = None
        self._first_arrival_s = 0.0
        self._last_arrival_s = -math.inf
        self._first_released: int | None = None
        self._released: int | None = None  # index of the last packet given out
        # indices given out lately (the deque orders the set, the set answers `in`)
        self._recent: deque[int] = deque()
        self._recent_set: set[int] = set()
        self._held: dict[int, np.ndarray] = {}  # index -> values
        # Arrival times of the held packets: they leave in sequence order, taking these in
        # increasing order (the slots the bus delivered them in).
        self._stamps: list[float] = []
        self._envelope_s = 0.0  # lower envelope of (arrival - grid time)
        self._envelope_n = 0  # the packet index it was last updated at
        self._pending: Pending | None = None  # off the grid: the first of a new stream?

    # -- what callers use -------------------------------------------------------------
    def restart(self) -> None:
        """The node restarted (its boot-up was seen): the next packet starts a new anchor.
        Packets still held are given out by the next `feed` or `flush`."""
        if self._pending is not None:
            self.stats.stray_packets += 1
        if self._newest is not None:
            self._release_all()
            self.stats.restarts += 1
        self._forget()

    reset = restart

    @property
    def anchor_s(self) -> float | None:
        """Where the sample grid lies: the time of the anchor's packet 0's first sample
        (with the drift correction so far); None until a packet anchored it."""
        if self._tick0 is None:
            return None
        return self._tick0 / self.rate_hz + self._shift_s

    def flush(self) -> Released:
        """End of input: every packet still held, in order."""
        if self._pending is not None:
            self.stats.stray_packets += 1
            self._pending = None
        self._release_all()
        return self._take()

    def feed(self, t_us: float, sequence: int | None, values: np.ndarray) -> Released:
        """One packet received at `t_us`; returns the samples given out now (times [s],
        values): its own unless it is held (settling, reorder window), and any it frees."""
        values = np.asarray(values, dtype=np.float64)[: self.per_packet]
        self.stats.packets += 1
        t_s = t_us * US
        if self._newest is None:  # the first packet of an anchor
            self._start(t_s, sequence, values)
            return self._take()
        n = self._index(sequence, t_s)
        if n is None:
            # The sequence contradicts the arrival: a new stream (node restart, return after
            # a silence) if the next packet follows this one; a stray packet if not.
            pending, self._pending = self._pending, (t_s, sequence, values)
            if pending is not None and self._follows(pending, t_s, sequence):
                self._release_all()
                self.stats.resyncs += 1
                self._forget()
                self._start(*pending)
                self._pending = None
                n = self._index(sequence, t_s)
                assert n is not None  # settling: the nearest number
            else:
                if pending is not None:
                    self.stats.stray_packets += 1
                return self._take()
        elif self._pending is not None:
            self.stats.stray_packets += 1
            self._pending = None
        if n in self._held or n in self._recent_set:
            self.stats.repeated_packets += 1
        elif self._released is not None and n < self._released:
            self.stats.late_packets += 1
            if self._first_released is not None and n > self._first_released:
                self.stats.lost_packets -= 1  # counted missing when the numbers skipped it
        else:
            assert self._newest is not None
            if n < self._newest:
                self.stats.reordered += 1
            else:
                self._newest, self._newest_seq = n, sequence
            self._accept(n, t_s, values)
        return self._take()

    def _start(self, t_s: float, sequence: int | None, values: np.ndarray) -> None:
        self._newest, self._newest_seq, self._first_arrival_s = 0, sequence, t_s
        self._accept(0, t_s, values)

    def _follows(self, pending: Pending, t_s: float, sequence: int | None) -> bool:
        """Does this packet follow `pending` (the next number, or one the reorder window
        allows, arriving about when it was due): a stream of its own?"""
        t_p, seq_p, _ = pending
        step = 1 if sequence is None or seq_p is None else (sequence - seq_p) % SEQUENCE_MODULO
        lateness = t_s - t_p - step * self.packet_s
        return 0 < step <= self.reorder_packets + 1 and -self.early_s <= lateness <= self.late_s

    # -- inside -----------------------------------------------------------------------
    def _index(self, sequence: int | None, t_s: float) -> int | None:
        """Packet index of this number at this arrival; None: start a new anchor."""
        newest = self._newest
        if newest is None or t_s - self._last_arrival_s > self.silence_s:
            return None
        if sequence is None or self._newest_seq is None:
            n = newest + 1  # no numbers: the order of arrival stands
            if self._tick0 is None:
                return n
            lateness = t_s - self._grid_end_s(n)
            return n if -self.early_s <= lateness <= self.late_s else None
        step = (sequence - self._newest_seq) % SEQUENCE_MODULO
        if self._tick0 is None:  # settling: the nearest number
            return newest + (step + HALF_WRAP) % SEQUENCE_MODULO - HALF_WRAP
        # Candidates newest + step - 256 + 256 k, later ones arrive less late: the latest
        # that is not early is the one.
        n = newest + step - SEQUENCE_MODULO
        k = math.floor((t_s - self._grid_end_s(n) + self.early_s) / self.wrap_s)
        if k < 0:
            return None  # early for every number: not this stream
        n += k * SEQUENCE_MODULO
        return n if t_s - self._grid_end_s(n) <= self.late_s else None

    def _grid_end_s(self, n: int) -> float:
        """Time of packet n's last sample on the current grid."""
        assert self._tick0 is not None
        return (self._tick0 + (n + 1) * self.per_packet - 1) / self.rate_hz + self._shift_s

    def _accept(self, n: int, t_s: float, values: np.ndarray) -> None:
        self._held[n] = values
        heapq.heappush(self._stamps, t_s)
        self._last_arrival_s = max(self._last_arrival_s, t_s)
        if self._tick0 is None:
            if t_s - self._first_arrival_s < self.settle_s:
                return
            self._anchor()
        self._release(final=False)

    def _anchor(self) -> None:
        """tick0 from the earliest arrival the held packets allow, on a whole tick, and
        not before a decoder gap after the samples already given out."""
        per, rate = self.per_packet, self.rate_hz
        pairs = list(zip(sorted(self._held), sorted(self._stamps), strict=True))
        # The newest few may still miss a packet the window would put back before them, so
        # their time stamps are not yet theirs: left out while older ones remain.
        settled = [(n, t) for n, t in pairs if n <= pairs[-1][0] - self.reorder_packets]
        pairs = settled or pairs
        earliest = min(t - ((n + 1) * per - 1) / rate for n, t in pairs)
        tick0 = round(earliest * rate)
        if math.isfinite(self._last_t_s):
            first = min(self._held) * per
            tick0 = max(
                tick0, math.ceil(self._last_t_s * rate) + math.ceil(GAP_PERIODS) + 1 - first
            )
        self._tick0 = tick0
        self._envelope_s = min(t - self._grid_end_s(n) for n, t in pairs)
        self._envelope_n = pairs[0][0]  # the envelope follows the packets given out

    def _track_drift(self, n: int, t_s: float) -> None:
        """Lower envelope of arrival - grid; slew the grid when it leaves the deadband."""
        offset = t_s - self._grid_end_s(n)
        elapsed_s = max(0, n - self._envelope_n) * self.packet_s
        self._envelope_n = max(self._envelope_n, n)
        self._envelope_s = min(offset, self._envelope_s + ENVELOPE_RISE_PPM * PPM * elapsed_s)
        excess_s = abs(self._envelope_s) - DRIFT_DEADBAND_US * US
        if excess_s > 0 and elapsed_s > 0:
            step_s = math.copysign(
                min(excess_s, DRIFT_SLEW_PPM * PPM * elapsed_s), self._envelope_s
            )
            self._shift_s += step_s
            self._envelope_s -= step_s
            self.stats.slewed_us += step_s / US

    def _release(self, *, final: bool) -> None:
        """Give out held packets in order: the next one, or past a hole the window gave up."""
        held = self._held
        assert self._tick0 is not None and self._newest is not None
        while held:
            n = min(held)
            in_order = self._released is None or n == self._released + 1
            if not (final or in_order or n <= self._newest - self.reorder_packets):
                return
            if self._released is not None:
                self.stats.lost_packets += n - self._released - 1
            if self._first_released is None:
                self._first_released = n
            self._released = n
            self._recent.append(n)
            self._recent_set.add(n)
            if len(self._recent) > SEQUENCE_MODULO:
                self._recent_set.discard(self._recent.popleft())
            values = held.pop(n)
            self._track_drift(n, heapq.heappop(self._stamps))
            # tick / rate + shift per sample, in floats (a packet's few: numpy's numbers,
            # without its temporaries)
            first, rate, shift = self._tick0 + n * self.per_packet, self.rate_hz, self._shift_s
            stamps = [(first + k) / rate + shift for k in range(len(values))]
            times = np.array(stamps, dtype=np.float64)
            if stamps:
                self._last_t_s = stamps[-1]
            self.stats.released += 1
            self.stats.samples += len(values)
            self._out.append((times, values))

    def _release_all(self) -> None:
        if self._held:
            if self._tick0 is None:
                self._anchor()
            self._release(final=True)

    def _take(self) -> Released:
        out, self._out = self._out, []
        if not out:
            return np.zeros(0), np.zeros(0)
        if len(out) == 1:
            return out[0]
        return np.concatenate([t for t, _ in out]), np.concatenate([v for _, v in out])

"""PDO engine: TPDO/RPDO communication and mapping, SYNC consumer (CiA 301 7.2.2, 7.5.2.35-38).

TPDO transmission types: 0 (acyclic synchronous: on the SYNC after an
event), 1-240 (every n-th SYNC, honouring the SYNC start value), 254/255
(event-driven, limited by the inhibit time and repeated by the event
timer; the event is an application trigger for 254 and any change of a
mapped value for 255). The event timer elapsing is itself an event (CiA 301
7.2.2): it runs on a fixed grid from when it was (re)started, so late
`advance` calls never push later transmissions back; a transmission caused
by another event restarts it. A TPDO that carries a sample stream's packets
(`packet_tpdos`: the skin's samples, the EMG's envelope), made synchronous while
the application's manufacturer switch says so (`packets_on_sync`: skin 2122h, EMG
2213h), keeps every packet the application makes and sends them all, in order, on
the SYNC it is due on (at most `MAX_OWED_PACKETS`, the oldest dropped first): the
stream keeps its rate and its sequence numbers, only batched. Off (the default),
it is a CiA 301 synchronous TPDO: one frame per due SYNC. RPDO types 0-240 apply
their data at the next SYNC, 254/255 at once. Mapping and communication
parameters are checked as they are written, with the abort codes CiA 301
names; the mapping procedure (invalidate the PDO, sub-index 0 = 0, write
entries, sub-index 0 = n, validate) is enforced.
"""

from __future__ import annotations

import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from grasplink.core.frames import CAN_ID_MASK, SYNC_TYPE_MAX, Frame, is_restricted_can_id
from grasplink.devices import emcy as em
from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.devices.store import Entry, Key, ObjectStore, Value
from grasplink.profiles import objects as obj

COB_ID_INVALID = 0x80000000
COB_ID_NO_RTR = 0x40000000
COB_ID_EXTENDED = 0x20000000
MAX_PDO_BITS = 64
MAX_PDOS = 512
TYPE_EVENT_MANUFACTURER = 254
TYPE_EVENT_PROFILE = 255
# Packets a synchronous packet TPDO keeps for its next due SYNC; beyond, the oldest go
# (the receiver sees the sequence gap, as for a lost frame). 32 is 240 ms of the skin at
# 400 Hz, 3 samples a packet, and a burst of 32 frames holds a 1 Mbit/s bus ~4 ms.
MAX_OWED_PACKETS = 32
# Dummy objects (CiA 301 7.4.7.1): index -> size in bits.
DUMMY_BITS = {0x0002: 8, 0x0003: 16, 0x0004: 32, 0x0005: 8, 0x0006: 16, 0x0007: 32}


@dataclass(frozen=True, slots=True)
class MapEntry:
    index: int
    subindex: int
    bits: int

    @classmethod
    def decode(cls, raw: int) -> MapEntry:
        return cls((raw >> 16) & 0xFFFF, (raw >> 8) & 0xFF, raw & 0xFF)

    @property
    def is_dummy(self) -> bool:
        return self.index in DUMMY_BITS


@dataclass(slots=True)
class _Pdo:
    """Runtime state of one PDO; its parameters live in the store."""

    number: int  # 1-based
    transmit: bool
    comm_index: int
    map_index: int
    pending: bool = False  # an event (trigger, mapped value changed, OPERATIONAL) waits
    timer_due: bool = False  # the event timer elapsed; a transmission is owed
    last_tx_us: int | None = None
    timer_origin_us: int = 0  # when the event timer was last (re)started
    timer_next_us: int | None = None  # its next expiry on the grid; None: origin + period
    sync_count: int = 0
    sync_started: bool = False
    buffered: bytes | None = None  # RPDO data waiting for SYNC
    # a synchronous packet TPDO's packets made since its last due SYNC, oldest first
    owed: deque[Frame] = field(default_factory=lambda: deque(maxlen=MAX_OWED_PACKETS))
    last_rx_us: int | None = None  # RPDO deadline monitoring
    mapping: list[MapEntry] = field(default_factory=list)
    # Communication parameters as the store holds them, cached by `_read()` (which runs
    # on every change of this PDO's parameters): the hot path reads these, not the store.
    params: dict[int, int] = field(default_factory=dict)
    timer_us: int = 0  # event timer (sub-index 5), from `params`
    inhibit_us: int = 0  # inhibit time (sub-index 3), from `params`
    # struct packer for the mapped values (None if a mapped type has no fixed size),
    # and the store's entries it packs, in mapping order (kept by `_read()`).
    packer: struct.Struct | None = None
    packed: list[Entry] = field(default_factory=list)


class PdoEngine:
    def __init__(
        self,
        store: ObjectStore,
        emcy: em.EmcyProducer,
        dummy_usage: frozenset[int],
        on_rpdo: Callable[[int, int], None] | None = None,
    ):
        self.store = store
        self.emcy = emcy
        self.dummy_usage = dummy_usage
        self.on_rpdo = on_rpdo
        self.operational = False
        self.now_us = 0
        # TPDOs carrying a sample stream (set by the application): sent only with new samples.
        self.streamed_tpdos: frozenset[int] = frozenset()
        # TPDOs whose every trigger is a new packet of a stream: batched when synchronous.
        self.packet_tpdos: frozenset[int] = frozenset()
        # the application's switch for that (index, subindex); None: never batched
        self._packets_on_sync: tuple[int, int] | None = None
        self.dropped_packets = 0  # owed packets dropped for room (MAX_OWED_PACKETS)
        self.tpdos = self._discover(obj.TPDO_COMM, obj.TPDO_MAP, transmit=True)
        self.rpdos = self._discover(obj.RPDO_COMM, obj.RPDO_MAP, transmit=False)
        self._by_comm = {p.comm_index: p for p in self.tpdos + self.rpdos}
        self._by_map = {p.map_index: p for p in self.tpdos + self.rpdos}
        self._watchers: dict[tuple[int, int], list[_Pdo]] = {}
        self._event_tpdos: list[_Pdo] = []  # valid TPDOs of type 254/255, kept by reload()
        self._by_can_id: dict[int, _Pdo] = {}  # CAN-ID of each valid PDO, kept by reload()
        self._can_ids: frozenset[int] = frozenset()
        # The indices `_on_change` acts on (PDO parameters, the packets switch, objects
        # mapped into a TPDO that a change sends), kept by reload(): the store calls it
        # for these only, not for every sample a stream writes.
        self._interest: set[int] = set()
        # TPDO packings for streams told ahead, by (number, objects given), until reload.
        self._packings: dict[tuple[int, tuple[Key, ...]], Callable[..., Frame]] = {}
        for pdo in self._by_comm.values():
            store.add_validator(pdo.comm_index, self._validate_comm)
            store.add_validator(pdo.map_index, self._validate_map)
        store.add_listener(self._on_change, interest=self._interest)
        self.reload()

    def _discover(self, comm_base: int, map_base: int, transmit: bool) -> list[_Pdo]:
        return [
            _Pdo(n + 1, transmit, comm_base + n, map_base + n)
            for n in range(MAX_PDOS)
            if self.store.has(comm_base + n, 1) and self.store.has(map_base + n, 0)
        ]

    @property
    def packets_on_sync(self) -> tuple[int, int] | None:
        return self._packets_on_sync

    @packets_on_sync.setter
    def packets_on_sync(self, switch: tuple[int, int] | None) -> None:
        self._packets_on_sync = switch
        self.reload()

    # -- parameters ----------------------------------------------------------
    def cob_id(self, pdo: _Pdo) -> int:
        return pdo.params[1]

    def is_valid(self, pdo: _Pdo) -> bool:
        return not pdo.params[1] & COB_ID_INVALID

    def transmission_type(self, pdo: _Pdo) -> int:
        return pdo.params[2]

    def _param(self, pdo: _Pdo, sub: int) -> int:
        return pdo.params.get(sub, 0)

    def inhibit_us(self, pdo: _Pdo) -> int:
        return pdo.inhibit_us

    def event_timer_us(self, pdo: _Pdo) -> int:
        return pdo.timer_us

    def reload(self) -> None:
        """Re-read every mapping (after a reset or a change of the packets switch)."""
        for pdo in self._by_comm.values():
            self._read(pdo)
        self._index()

    def _read(self, pdo: _Pdo) -> None:
        """Cache one PDO's parameters and mapping as the store holds them. Only its own
        objects go into them, so a change of one PDO's parameters re-reads that PDO
        alone (a master configuring a node writes ~40 of them, one by one)."""
        pdo.params = {
            sub: int(self.store.get(pdo.comm_index, sub))
            for sub in range(1, 7)
            if self.store.has(pdo.comm_index, sub)
        }
        pdo.inhibit_us = self._param(pdo, 3) * 100
        pdo.timer_us = self._param(pdo, 5) * 1000
        pdo.mapping = self._mapping(pdo)
        if pdo.transmit:
            pdo.packer = self._packer(pdo)
            pdo.packed = (
                [self.store.entry(e.index, e.subindex) for e in pdo.mapping]
                if pdo.packer is not None
                else []
            )

    def _index(self) -> None:
        """What the PDOs read last give together: each valid CAN-ID's PDO (the first),
        the objects watched, the event-driven TPDOs and the store indices of interest."""
        self._packings.clear()
        self._watchers.clear()
        self._event_tpdos = []
        self._by_can_id = {}
        interest = {*self._by_comm, *self._by_map}
        if self._packets_on_sync is not None:
            interest.add(self._packets_on_sync[0])
        for pdo in self._by_comm.values():
            if self.is_valid(pdo):
                self._by_can_id.setdefault(self.cob_id(pdo) & CAN_ID_MASK, pdo)
            if pdo.transmit:
                for entry in pdo.mapping:
                    self._watchers.setdefault((entry.index, entry.subindex), []).append(pdo)
                if self.transmission_type(pdo) in (0, TYPE_EVENT_PROFILE):
                    interest.update(entry.index for entry in pdo.mapping)
                if self._sendable(pdo) and self.transmission_type(pdo) >= TYPE_EVENT_MANUFACTURER:
                    self._event_tpdos.append(pdo)
        self._can_ids = frozenset(self._by_can_id)
        self._interest.clear()
        self._interest.update(interest)

    def _packer(self, pdo: _Pdo) -> struct.Struct | None:
        codes = []
        for entry in pdo.mapping:
            if not self.store.has(entry.index, entry.subindex):
                return None
            var = self.store.entry(entry.index, entry.subindex).var
            if var.data_type is None:
                return None
            layout = var.STRUCT_TYPES.get(var.data_type)
            if not isinstance(layout, struct.Struct):
                return None
            codes.append(layout.format.lstrip("<"))
        return struct.Struct("<" + "".join(codes))

    def mapped_bytes(self, pdo: _Pdo) -> int:
        return sum(e.bits for e in pdo.mapping) // 8

    # -- NMT -------------------------------------------------------------------
    def set_operational(self, operational: bool, t_us: int) -> None:
        self.operational = operational
        for pdo in self._by_comm.values():
            pdo.buffered = None
            pdo.owed.clear()
            pdo.sync_count = 0
            pdo.sync_started = False
            pdo.last_rx_us = None
            pdo.last_tx_us = None
            pdo.timer_due = False
            self._restart_timer(pdo, t_us)
            # Entering OPERATIONAL publishes every event-driven TPDO once, so a
            # master sees current values without waiting for a change - except the
            # TPDOs that stream samples: old samples sent again would be read as new.
            pdo.pending = (
                operational
                and pdo.transmit
                and pdo.number not in self.streamed_tpdos
                and self.is_valid(pdo)
                and (self.transmission_type(pdo) >= TYPE_EVENT_MANUFACTURER)
            )

    # -- device side -----------------------------------------------------------
    def trigger(self, number: int, t_us: int) -> list[Frame]:
        """The application signals an event for TPDO `number`.

        Event-driven types (254/255) go out now, inhibit time permitting; an
        acyclic synchronous TPDO (type 0) goes with the next SYNC; a cyclic
        synchronous one (1-240) is sent by the SYNC alone (CiA 301 7.2.2.2). A packet
        TPDO of either synchronous kind keeps this packet for its SYNC.
        """
        pdo = self.tpdos[number - 1]
        kind = self.transmission_type(pdo)
        if kind <= SYNC_TYPE_MAX and self._batched(number):
            if self.operational and self._sendable(pdo):
                if len(pdo.owed) == MAX_OWED_PACKETS:
                    self.dropped_packets += 1
                pdo.owed.append(self._pack(pdo))
            return []
        if 0 < kind <= SYNC_TYPE_MAX:
            return []
        pdo.pending = True
        if kind == 0:
            return []
        return self._flush(pdo, t_us) if self.operational else []

    def advance(self, t_us: int) -> list[Frame]:
        self.now_us = t_us
        if not self.operational:
            return []
        frames: list[Frame] = []
        for pdo in self._event_tpdos:
            timer = pdo.timer_us
            if timer:
                deadline = self._timer_deadline(pdo, timer)
                if t_us >= deadline:
                    pdo.timer_due = True
                    # Next expiry on the grid; periods missed entirely are skipped, not
                    # sent in a burst (the timer elapsed once, as far as CiA 301 goes).
                    pdo.timer_next_us = deadline + ((t_us - deadline) // timer + 1) * timer
            if pdo.pending or pdo.timer_due:
                frames += self._flush(pdo, t_us)
        for pdo in self.rpdos:
            if pdo.last_rx_us is not None:
                self._check_rpdo_deadline(pdo, t_us)
        return frames

    def next_deadline_us(self) -> int | None:
        if not self.operational:
            return None
        # The earliest of the candidates, without building a list: asked after every
        # call that may have moved one, i.e. for every packet a stream sends.
        earliest: int | None = None
        for pdo in self._event_tpdos:
            if pdo.pending or pdo.timer_due:
                earliest = _earlier(earliest, self._inhibit_end(pdo))
            if pdo.timer_us:
                earliest = _earlier(earliest, self._timer_deadline(pdo, pdo.timer_us))
        for pdo in self.rpdos:
            if pdo.timer_us and pdo.last_rx_us is not None and self.is_valid(pdo):
                earliest = _earlier(earliest, pdo.last_rx_us + pdo.timer_us + 1)
        return earliest

    # -- bus side --------------------------------------------------------------
    def on_sync(self, counter: int | None, t_us: int) -> list[Frame]:
        if not self.operational:
            return []
        for pdo in self.rpdos:
            if pdo.buffered is not None and self.is_valid(pdo):
                self._apply(pdo, pdo.buffered, t_us)
                pdo.buffered = None
        frames = []
        for pdo in self.tpdos:
            if not self._sendable(pdo):
                continue
            kind = self.transmission_type(pdo)
            if kind <= SYNC_TYPE_MAX and self._batched(pdo.number):
                frames += self._owed(pdo, kind, counter)
            elif kind == 0:
                if pdo.pending:
                    frames.append(self._build(pdo, t_us))
            elif kind <= SYNC_TYPE_MAX and self._sync_due(pdo, kind, counter):
                frames.append(self._build(pdo, t_us))
        return frames

    def _batched(self, number: int) -> bool:
        """Whether TPDO `number`, when synchronous, carries every packet made since."""
        switch = self._packets_on_sync
        return number in self.packet_tpdos and switch is not None and bool(self.store.get(*switch))

    def _owed(self, pdo: _Pdo, kind: int, counter: int | None) -> list[Frame]:
        """A packet TPDO's packets, all of them in order, on the SYNC it is due on; with
        none made since, nothing (a packet sent again would read as a new one)."""
        pdo.pending = False
        if (kind and not self._sync_due(pdo, kind, counter)) or not pdo.owed:
            return []
        frames = list(pdo.owed)
        pdo.owed.clear()
        return frames

    def _sync_due(self, pdo: _Pdo, every: int, counter: int | None) -> bool:
        start = self._param(pdo, 6)
        if not pdo.sync_started:
            if start and counter is not None and counter != start:
                return False
            pdo.sync_started = True
            pdo.sync_count = 0
            if start and counter is not None:
                return True
        pdo.sync_count += 1
        if pdo.sync_count >= every:
            pdo.sync_count = 0
            return True
        return False

    def can_ids(self) -> frozenset[int]:
        """The CAN-IDs of the valid PDOs (the frames `on_frame` may handle); the same
        object until a reload changes them."""
        return self._can_ids

    def on_frame(self, frame: Frame, t_us: int) -> list[Frame] | None:
        """Handle a frame addressed to one of our PDOs; None if it is not ours."""
        pdo = self._by_can_id.get(frame.can_id)
        if pdo is None:
            return None
        if not pdo.transmit:
            if not frame.rtr and self.operational:
                self._receive(pdo, frame.data, t_us)
            return []
        if frame.rtr and self.operational and not self.cob_id(pdo) & COB_ID_NO_RTR:
            return [self._build(pdo, t_us)]
        return []

    def _receive(self, pdo: _Pdo, data: bytes, t_us: int) -> None:
        needed = self.mapped_bytes(pdo)
        if len(data) < needed:
            self.emcy.raise_error(
                em.PDO_LENGTH_ERROR, em.REG_COMMUNICATION, t_us, bytes([pdo.number, len(data)])
            )
            return
        if len(data) > needed:
            self.emcy.raise_error(
                em.PDO_LENGTH_EXCEEDED, em.REG_COMMUNICATION, t_us, bytes([pdo.number, len(data)])
            )
        else:
            self.emcy.clear_error(em.PDO_LENGTH_ERROR, t_us)
            self.emcy.clear_error(em.PDO_LENGTH_EXCEEDED, t_us)
        if pdo.last_rx_us is not None or self.event_timer_us(pdo):
            self.emcy.clear_error(em.RPDO_TIMEOUT, t_us)
        pdo.last_rx_us = t_us
        if self.transmission_type(pdo) <= SYNC_TYPE_MAX:
            pdo.buffered = bytes(data[:needed])
        else:
            self._apply(pdo, data, t_us)

    def _apply(self, pdo: _Pdo, data: bytes, t_us: int) -> None:
        offset = 0
        for entry in pdo.mapping:
            size = entry.bits // 8
            if not entry.is_dummy:
                var = self.store.entry(entry.index, entry.subindex).var
                self.store.set(
                    entry.index, entry.subindex, var.decode_raw(data[offset : offset + size])
                )
            offset += size
        if self.on_rpdo is not None:
            self.on_rpdo(pdo.number, t_us)

    def _check_rpdo_deadline(self, pdo: _Pdo, t_us: int) -> None:
        timer = self.event_timer_us(pdo)
        if timer and pdo.last_rx_us is not None and t_us > pdo.last_rx_us + timer:
            self.emcy.raise_error(em.RPDO_TIMEOUT, em.REG_COMMUNICATION, t_us, bytes([pdo.number]))
            pdo.last_rx_us = None

    def _mapping(self, pdo: _Pdo) -> list[MapEntry]:
        """The PDO's mapping as the store holds it; none when the file gives a count
        without its entries or maps an object the dictionary lacks (a vendor's file may):
        such a PDO carries nothing rather than failing when it is sent."""
        if not self.store.has(pdo.map_index, 0):
            return []
        count = int(self.store.get(pdo.map_index, 0))
        if not all(self.store.has(pdo.map_index, s) for s in range(1, count + 1)):
            return []
        mapping = [
            MapEntry.decode(int(self.store.get(pdo.map_index, s))) for s in range(1, count + 1)
        ]
        if not all(self.store.has(e.index, e.subindex) or e.is_dummy for e in mapping):
            return []
        return mapping

    # -- transmission ------------------------------------------------------------
    def _inhibit_end(self, pdo: _Pdo) -> int:
        return 0 if pdo.last_tx_us is None else pdo.last_tx_us + self.inhibit_us(pdo)

    def _timer_deadline(self, pdo: _Pdo, timer_us: int) -> int:
        if pdo.timer_next_us is None:
            return pdo.timer_origin_us + timer_us
        return pdo.timer_next_us

    @staticmethod
    def _restart_timer(pdo: _Pdo, t_us: int) -> None:
        pdo.timer_origin_us = t_us
        pdo.timer_next_us = None

    def _flush(self, pdo: _Pdo, t_us: int) -> list[Frame]:
        if not (pdo.pending or pdo.timer_due):
            return []
        if not self._sendable(pdo) or t_us < self._inhibit_end(pdo):
            return []
        return [self._build(pdo, t_us)]

    def _sendable(self, pdo: _Pdo) -> bool:
        """A TPDO whose mapping is disabled (0 objects) is not sent (CiA 301 7.5.2.36)."""
        return self.is_valid(pdo) and bool(pdo.mapping)

    def _pack(self, pdo: _Pdo) -> Frame:
        """The TPDO's frame with the mapped values as they are now."""
        if pdo.packer is not None:
            data = pdo.packer.pack(*[entry.value for entry in pdo.packed])
        else:
            data = b"".join(self.store.encode(e.index, e.subindex) for e in pdo.mapping)
        return Frame(self.cob_id(pdo) & CAN_ID_MASK, data)

    def _build(self, pdo: _Pdo, t_us: int) -> Frame:
        frame = self._pack(pdo)
        self._sent(pdo, t_us)
        return frame

    def _sent(self, pdo: _Pdo, t_us: int) -> None:
        if not pdo.timer_due or pdo.pending:
            # Sent for another reason than the timer alone (an event, a remote request):
            # the event timer counts again from this transmission.
            self._restart_timer(pdo, t_us)
        pdo.pending = False
        pdo.timer_due = False
        pdo.last_tx_us = t_us

    # -- streams told ahead (core.protocol.StreamingDevice) ---------------------------
    def direct_tpdo(
        self, number: int, given: tuple[Key, ...], unmapped: tuple[Key, ...] = ()
    ) -> Callable[..., Frame] | None:
        """How TPDO `number` goes out when the application triggers it right after writing
        the objects `given`, while it also writes `unmapped`: a function of the values of
        `given` (in that order) returning the frame `trigger` would send, without the
        store. None unless the trigger sends it at once and changes nothing else: an
        event-driven TPDO with no inhibit time, no event timer and nothing owed, whose
        mapping packs, and no TPDO made to send by a change (types 0, 255) mapping any of
        the objects written, nor this one mapping `unmapped`. Once frames made so went
        out, `sent_directly` tells the engine the last one's time."""
        if not (self.operational and 1 <= number <= len(self.tpdos)):
            return None
        pdo = self.tpdos[number - 1]
        if (
            not self._sendable(pdo)
            or self.transmission_type(pdo) < TYPE_EVENT_MANUFACTURER
            or pdo.inhibit_us
            or pdo.timer_us
            or pdo.pending
            or pdo.timer_due
            or pdo.packer is None
        ):
            return None
        for key in (*given, *unmapped):
            for watcher in self._watchers.get(key, ()):
                if self.transmission_type(watcher) in (0, TYPE_EVENT_PROFILE):
                    return None
        keys = [(e.index, e.subindex) for e in pdo.mapping]
        if any(key in unmapped for key in keys):
            return None
        return self._packing(pdo, given)

    def _packing(self, pdo: _Pdo, given: tuple[Key, ...]) -> Callable[..., Frame]:
        """TPDO `pdo`'s frame as a function of the values of `given`, the other mapped
        objects as they are now (nothing else writes the store until the frames went out:
        a span told ahead ends at any frame reaching the node)."""
        cached = self._packings.get((pdo.number, given))
        if cached is not None:
            return cached
        assert pdo.packer is not None
        keys = [(e.index, e.subindex) for e in pdo.mapping]
        places = [given.index(key) if key in given else -1 for key in keys]
        constants = [entry.value for entry in pdo.packed]
        pack, can_id = pdo.packer.pack, self.cob_id(pdo) & CAN_ID_MASK
        mapped = len(places)
        if places == list(range(mapped)):  # the mapping is the first given objects in order

            def frame(*values: Value) -> Frame:
                return Frame(can_id, pack(*values[:mapped]))

            self._packings[(pdo.number, given)] = frame  # no value of now in it: kept
            return frame

        if -1 not in places:

            def ordered(*values: Value) -> Frame:
                return Frame(can_id, pack(*[values[p] for p in places]))

            self._packings[(pdo.number, given)] = ordered
            return ordered

        def mixed(*values: Value) -> Frame:
            row = [values[p] if p >= 0 else c for p, c in zip(places, constants, strict=True)]
            return Frame(can_id, pack(*row))

        return mixed

    def timer_sends(
        self, until_us: int, given: tuple[Key, ...]
    ) -> list[tuple[int, Callable[..., Frame], int]] | None:
        """The event-timer transmissions due up to `until_us` if nothing else in the
        engine runs meanwhile: (time, its frame as a function of the values of `given`,
        TPDO number) in the order `advance` sends them. None when something else would
        (a TPDO pending or held by its inhibit time, RPDO deadline monitoring)."""
        sends: list[tuple[int, int, Callable[..., Frame], int]] = []
        for order, pdo in enumerate(self._event_tpdos):
            if pdo.pending or pdo.timer_due:
                return None
            timer = pdo.timer_us
            if not timer:
                continue
            due = self._timer_deadline(pdo, timer)
            if due > until_us:
                continue
            if pdo.packer is None or pdo.inhibit_us > timer or due < self._inhibit_end(pdo):
                return None
            frame = self._packing(pdo, given)
            for t_us in range(due, until_us + 1, timer):
                sends.append((t_us, order, frame, pdo.number))
        if any(pdo.timer_us and pdo.last_rx_us is not None for pdo in self.rpdos):
            return None
        sends.sort(key=lambda send: send[:2])
        return [(t_us, frame, number) for t_us, _, frame, number in sends]

    def timer_sent(self, number: int, t_us: int) -> None:
        """TPDO `number` went out on its event timer at `t_us` (told by `timer_sends`), as
        `advance` would have sent it there."""
        pdo = self.tpdos[number - 1]
        pdo.timer_next_us = t_us + pdo.timer_us
        pdo.timer_due = True
        self._sent(pdo, t_us)

    def sent_directly(self, number: int, t_us: int) -> None:
        """Frames made by `direct_tpdo`'s function went out, the last at `t_us`."""
        self._sent(self.tpdos[number - 1], t_us)

    def _on_change(self, index: int, subindex: int, value: Value) -> None:
        if index in self._by_comm or index in self._by_map:
            self._on_parameter_change(index, subindex)
            return
        if (index, subindex) == self._packets_on_sync:
            for pdo in self.tpdos:
                pdo.owed.clear()
            return
        # Type 254 events are the application's to call (trigger); types 0 and 255
        # treat any change of a mapped value as the event.
        for pdo in self._watchers.get((index, subindex), ()):
            if self.transmission_type(pdo) in (0, TYPE_EVENT_PROFILE):
                pdo.pending = True

    def _on_parameter_change(self, index: int, subindex: int) -> None:
        pdo = self._by_comm.get(index) or self._by_map[index]
        self._read(pdo)
        self._index()
        if index == pdo.comm_index:
            pdo.pending = False
            pdo.timer_due = False
            pdo.owed.clear()
            pdo.sync_count = 0
            pdo.sync_started = False
            pdo.last_tx_us = None
            self._restart_timer(pdo, self.now_us)

    # -- SDO-side checks -----------------------------------------------------------
    def _validate_comm(self, index: int, subindex: int, value: Value) -> None:
        pdo = self._by_comm[index]
        value = int(value)
        valid = self.is_valid(pdo)
        if subindex == 1:
            self._check_cob_id(pdo, value)
        elif subindex == 2:
            allowed = value <= SYNC_TYPE_MAX or value >= TYPE_EVENT_MANUFACTURER
            if not allowed:
                raise SdoAbort(
                    AbortCode.INVALID_VALUE,
                    f"transmission type {value} not supported (0-240, 254, 255)",
                )
        elif subindex in (3, 6) and pdo.transmit and valid and value != self._param(pdo, subindex):
            raise SdoAbort(
                AbortCode.INVALID_VALUE,
                f"{index:04X}h:{subindex:02X} can change only while the PDO is invalid",
            )
        if subindex == 6 and value > SYNC_TYPE_MAX:
            raise SdoAbort(AbortCode.INVALID_VALUE, "SYNC start value must be 0-240")

    def _check_cob_id(self, pdo: _Pdo, value: int) -> None:
        if value & COB_ID_EXTENDED:
            raise SdoAbort(AbortCode.INVALID_VALUE, "29-bit CAN-IDs are not supported")
        new_valid = not value & COB_ID_INVALID
        can_id = value & CAN_ID_MASK
        if not new_valid:
            return
        if self.is_valid(pdo) and can_id != self.cob_id(pdo) & CAN_ID_MASK:
            raise SdoAbort(AbortCode.INVALID_VALUE, "set bit 31 before changing a PDO's CAN-ID")
        if is_restricted_can_id(can_id):
            raise SdoAbort(AbortCode.INVALID_VALUE, f"CAN-ID 0x{can_id:03X} is restricted")
        for other in self._by_comm.values():
            if (
                other is not pdo
                and self.is_valid(other)
                and (self.cob_id(other) & CAN_ID_MASK) == can_id
            ):
                raise SdoAbort(AbortCode.INVALID_VALUE, f"CAN-ID 0x{can_id:03X} already in use")

    def _validate_map(self, index: int, subindex: int, value: Value) -> None:
        pdo = self._by_map[index]
        value = int(value)
        if self.is_valid(pdo):
            raise SdoAbort(
                AbortCode.UNSUPPORTED_ACCESS,
                "mapping can change only while the PDO is invalid (COB-ID bit 31)",
            )
        if subindex == 0:
            entries = [MapEntry.decode(int(self.store.get(index, s))) for s in range(1, value + 1)]
            for entry in entries:
                self._check_entry(pdo, entry)
            if sum(e.bits for e in entries) > MAX_PDO_BITS:
                raise SdoAbort(AbortCode.PDO_TOO_LONG, f"mapping exceeds {MAX_PDO_BITS} bits")
            return
        if int(self.store.get(index, 0)) != 0:
            raise SdoAbort(
                AbortCode.UNSUPPORTED_ACCESS, "set sub-index 0 to 0 before writing mapping entries"
            )
        if value:
            self._check_entry(pdo, MapEntry.decode(value))

    def _check_entry(self, pdo: _Pdo, entry: MapEntry) -> None:
        if entry.is_dummy:
            if pdo.transmit or entry.index not in self.dummy_usage:
                raise SdoAbort(AbortCode.NOT_MAPPABLE, f"dummy 0x{entry.index:04X} not usable here")
            if entry.bits != DUMMY_BITS[entry.index]:
                raise SdoAbort(AbortCode.PARAMETER_INCOMPATIBLE, "dummy length mismatch")
            return
        var = self.store.entry(entry.index, entry.subindex).var  # raises NO_OBJECT / NO_SUBINDEX
        if not var.pdo_mappable:
            raise SdoAbort(
                AbortCode.NOT_MAPPABLE,
                f"0x{entry.index:04X}:{entry.subindex:02X} is not PDO-mappable",
            )
        access = var.access_type
        direction_ok = (
            access in ("ro", "rw", "rwr", "const")
            if pdo.transmit
            else (access in ("wo", "rw", "rww"))
        )
        if not direction_ok:
            raise SdoAbort(
                AbortCode.NOT_MAPPABLE,
                f"0x{entry.index:04X}:{entry.subindex:02X} ({access}) cannot go into a "
                f"{'T' if pdo.transmit else 'R'}PDO",
            )
        if entry.bits != len(var):
            raise SdoAbort(
                AbortCode.PARAMETER_INCOMPATIBLE,
                f"0x{entry.index:04X}:{entry.subindex:02X} is {len(var)} bits, "
                f"mapping says {entry.bits}",
            )


def _earlier(a: int | None, b: int) -> int:
    return b if a is None or b < a else a

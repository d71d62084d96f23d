"""Conformance cases 3.1-3.33: PDO communication and mapping (CiA 301 7.2.2, 7.5.2.35-38).

TPDO cases run on every node (4 TPDOs each); RPDO cases on the belt and the hand
only (the skin and EMG node have no RPDOs). How the three groups of TPDO
configuration cases are read: 3.4-3.8 configure the first TPDO, 3.10-3.14 all
TPDOs at once, 3.16-3.20 each TPDO in turn with the others invalid.

Frames a request causes are checked deterministically with `Dut.barrier` (an SDO
round trip: the device handles frames in order); timing (event timer, inhibit
time) is checked on counts over a short window with tolerances for the real-time
bus, never on single gaps.
"""

from __future__ import annotations

import math
import struct
import time
from itertools import pairwise
from statistics import median

import pytest

from grasplink.profiles import objects as obj
from tests.conformance.conftest import (
    ABORT_NO_OBJECT,
    ABORT_NO_SUBINDEX,
    ABORT_NOT_MAPPABLE,
    ABORT_PARAMETER_INCOMPATIBLE,
    ABORT_PDO_TOO_LONG,
    ABORT_VALUE_HIGH,
    APP_TRIGGERED,
    COB_INVALID,
    COB_NO_RTR,
    EVENT_MAPPING,
    MAPPING_LOCKED,
    NMT_STOP,
    SELF_CHANGING,
    SILENCE_S,
    STATE_STOPPED,
    Dut,
    EdsEntry,
    SdoAbort,
    cause_event,
    cob,
    eds_device_info,
    mappable_objects,
    slow_app,
)
from tests.conformance.host_timing import GridTicker

WRONG_LENGTH = {ABORT_NOT_MAPPABLE, ABORT_PARAMETER_INCOMPATIBLE}
EVENT_TIMER_MS = 25
WINDOW_S = 0.25
STARVED_WAIT_S = 5.0  # how long a check waits for frames a starved device thread owes


def entry_of(e: EdsEntry) -> int:
    return e.index << 16 | e.subindex << 8 | len(e.var)


# -- scans ---------------------------------------------------------------------------------
def scan(dut: Dut, comm_base: int, map_base: int, count_key: str) -> None:
    found = []
    for index in range(comm_base, comm_base + 0x200):
        try:
            dut.read(index, 0)
        except SdoAbort as exc:
            assert exc.code == ABORT_NO_OBJECT, f"{index:04X}h: 0x{exc.code:08X}"
            assert index not in dut.od, f"{index:04X}h is in the EDS but not on the device"
            continue
        assert index in dut.od, f"{index:04X}h answers but the EDS does not list it"
        found.append(index)
    assert len(found) == int(eds_device_info(dut.kind)[count_key])
    for comm in found:
        for param in (comm, comm - comm_base + map_base):
            record = dut.od[param]
            for sub in range(0, 9):
                if sub in record.subindices:
                    var = record[sub]
                    assert dut.read(param, sub) == var.encode_raw(var.default), (
                        f"{param:04X}h:{sub:02X} differs from the EDS"
                    )
                else:
                    assert dut.abort_of(dut.read, param, sub) == ABORT_NO_SUBINDEX


def test_3_1_scan_rpdos(dut: Dut) -> None:
    """3.1 PDO 01: "Scan for RPDOs. PDO communication parameter"

    Reads 1400h-15FFh: each object the device has must be in the EDS (and
    vice versa, others abort 0x06020000), their number equals NrOfRXPDO, and
    every sub-index of the communication and mapping parameters equals the
    EDS default (absent sub-indices abort 0x06090011). On the skin and EMG
    node the scan finds no RPDO, which matches NrOfRXPDO=0.
    """
    scan(dut, 0x1400, 0x1600, "NrOfRXPDO")


def test_3_2_scan_tpdos(dut: Dut) -> None:
    """3.2 PDO 02: "Scan for the TPDOs. PDO communication parameter"

    As 3.1 for 1800h-19FFh / 1A00h-1BFFh and NrOfTXPDO (4 on every node).
    """
    scan(dut, 0x1800, 0x1A00, "NrOfTXPDO")


# -- RTR -----------------------------------------------------------------------------------
def rtr_answers(dut: Dut, can_id: int, length: int) -> list:
    """PDOs seen from 20 ms before an RTR until the device has handled it."""
    mark = dut.log.mark()
    time.sleep(0.02)  # a TPDO sent without the RTR would land here
    dut.send(can_id, rtr=True, dlc=length)
    dut.barrier()
    return dut.log.since(mark, is_pdo)


def is_pdo(m) -> bool:
    return not m.is_remote_frame and 0x180 <= m.arbitration_id < 0x580


def test_3_3_rtr_on_tpdo_operational(dut: Dut) -> None:
    """3.3 PDO 03: "NMT state Operational: RTR on TPDO, if supported."

    The EDS marks every TPDO "no RTR allowed" (COB-ID bit 30 set) and the
    device matches it. TPDO1 as acyclic synchronous (type 0; no SYNC is
    sent, so it stays quiet), the other TPDOs invalid: with bit 30 set an
    RTR gets no answer; with bit 30 cleared the RTR is answered with exactly
    one TPDO of the mapped length.
    """
    for number in dut.tpdo_numbers():
        comm = 0x1800 + number - 1
        assert dut.get(comm, 1) & COB_NO_RTR == dut.default_cob_id(comm) & COB_NO_RTR
        assert dut.default_cob_id(comm) & COB_NO_RTR
    dut.disable_tpdos(keep=(1,))
    can_id, length = dut.configure_tpdo(1, transmission_type=0, rtr=False)
    dut.start()
    dut.barrier()
    assert rtr_answers(dut, can_id, length) == []
    dut.set(0x1800, 1, can_id)  # bit 30 cleared: RTR allowed
    answers = rtr_answers(dut, can_id, length)
    assert [(m.arbitration_id, len(m.data)) for m in answers] == [(can_id, length)]


def test_3_9_rtr_on_tpdo_stopped(dut: Dut) -> None:
    """3.9 PDO 09: "NMT state Stopped: RTR on TPDO, if support"

    TPDO1 with RTR allowed answers an RTR in OPERATIONAL; in STOPPED the same
    RTR gets no answer (and no PDO is sent at all).
    """
    dut.disable_tpdos(keep=(1,))
    can_id, length = dut.configure_tpdo(1, transmission_type=0, rtr=True)
    dut.set_heartbeat()
    dut.start()
    assert len(rtr_answers(dut, can_id, length)) == 1
    dut.enter(NMT_STOP, STATE_STOPPED)
    mark = dut.log.mark()
    dut.send(can_id, rtr=True, dlc=length)
    frames = dut.log.collect(lambda m: 0x180 <= m.arbitration_id < 0x580, SILENCE_S, mark)
    assert frames == []


def test_3_15_request_tpdo_with_rtr(dut: Dut) -> None:
    """3.15 PDO 15: "Request TPDO with RTR, if supported"

    Every TPDO, configured acyclic synchronous with RTR allowed: in
    PRE-OPERATIONAL no RTR is answered; in OPERATIONAL each RTR is answered by
    exactly that TPDO, with its mapped length.
    """
    pdos = {n: dut.configure_tpdo(n, transmission_type=0, rtr=True) for n in dut.tpdo_numbers()}
    for can_id, length in pdos.values():
        assert rtr_answers(dut, can_id, length) == []
    dut.start()
    dut.barrier()
    for can_id, length in pdos.values():
        answers = rtr_answers(dut, can_id, length)
        assert [(m.arbitration_id, len(m.data)) for m in answers] == [(can_id, length)]


# -- TPDO transmission types -------------------------------------------------------------
def event_mapping(dut: Dut, number: int) -> list[int] | None:
    """TPDO1 keeps the device's own process data; the others map the kind's event object."""
    return None if number == 1 else [EVENT_MAPPING[dut.kind]]


def setup(dut: Dut, numbers: list[int], **config) -> dict[int, tuple[int, int]]:
    """Configure the TPDOs `numbers` (others invalid); {number: (CAN-ID, length)}."""
    dut.disable_tpdos(keep=tuple(numbers))
    pdos = {}
    for n in numbers:
        options = dict(config)
        if callable(options.get("sync_start")):
            options["sync_start"] = options["sync_start"](n)
        if callable(options.get("transmission_type")):
            options["transmission_type"] = options["transmission_type"](n)
        pdos[n] = dut.configure_tpdo(n, mapping=event_mapping(dut, n), **options)
    return pdos


def frames_of(dut: Dut, mark: int, can_id: int) -> list:
    return dut.log.since(mark, cob(can_id))


def check_event_driven(dut: Dut, numbers: list[int], window: float = WINDOW_S) -> None:
    """Type 255: a TPDO goes out when its mapped data changes, not otherwise; the
    inhibit time spaces the transmissions."""
    pdos = setup(dut, numbers, transmission_type=255)
    dut.start()
    if dut.kind in SELF_CHANGING:
        for can_id, length in pdos.values():
            frames = dut.log.wait_count(cob(can_id), 3)
            assert len(frames) == 3 and {len(f.data) for f in frames} == {length}
    else:
        dut.barrier()
        mark = dut.log.mark()
        statusword = cause_event(dut)
        for can_id, length in pdos.values():
            frame = dut.log.wait_for(cob(can_id), since=mark)
            assert frame is not None and len(frame.data) == length
            assert struct.unpack_from("<H", frame.data)[0] == statusword
        mark = dut.log.mark()
        dut.barrier()
        time.sleep(SILENCE_S)  # no event, event timer 0: nothing
        assert all(frames_of(dut, mark, can_id) == [] for can_id, _ in pdos.values())
    # Inhibit time 20 ms.
    pdos = setup(dut, numbers, transmission_type=255, inhibit_100us=200)
    if dut.kind in SELF_CHANGING:  # events every 7.5 / 10 ms
        mark = dut.log.mark()
        started = time.monotonic()
        time.sleep(window)
        wanted = math.ceil(window / 0.050)  # a starved thread still owes these: wait, bounded
        for can_id, _ in pdos.values():
            dut.log.wait_count(cob(can_id), wanted, STARVED_WAIT_S, since=mark)
        elapsed = time.monotonic() - started
        for can_id, _ in pdos.values():
            count = len(frames_of(dut, mark, can_id))
            assert wanted <= count <= elapsed / 0.020 + 2, f"0x{can_id:03X}: {count}"
    else:
        dut.barrier()
        time.sleep(0.025)
        mark = dut.log.mark()
        began = time.monotonic()
        for _ in range(3):
            cause_event(dut)
            statusword = cause_event(dut)
        # One frame at once, then at most one per started inhibit period.
        allowed = 2 + int((time.monotonic() - began) / 0.020)
        for can_id, _ in pdos.values():  # the last state goes out after the inhibit time

            def final(m, can_id=can_id) -> bool:
                return (
                    m.arbitration_id == can_id and struct.unpack_from("<H", m.data)[0] == statusword
                )

            assert dut.log.wait_for(final, since=mark) is not None
        time.sleep(0.03)
        for can_id, _ in pdos.values():
            frames = frames_of(dut, mark, can_id)
            assert 1 <= len(frames) <= allowed, f"0x{can_id:03X}: {len(frames)} frames"
            assert struct.unpack_from("<H", frames[-1].data)[0] == statusword


def check_event_timer(dut: Dut, numbers: list[int], window: float = WINDOW_S) -> None:
    """Type 254 with a 25 ms event timer: the TPDO comes at least every period."""
    slow_app(dut)
    pdos = setup(dut, numbers, transmission_type=254, event_timer_ms=EVENT_TIMER_MS)
    period_s = EVENT_TIMER_MS / 1000
    ticker = GridTicker(period_s)
    ticker.start()
    try:
        dut.start()
        mark = dut.log.mark()
        started = time.monotonic()
        time.sleep(window)
        # A loaded host may not run the device's thread for a while: wait (bounded) for the
        # frames the window should have held, then judge counts by the time that really passed.
        wanted = math.ceil(0.6 * window / period_s)
        for can_id, _ in pdos.values():
            dut.log.wait_count(cob(can_id), wanted, STARVED_WAIT_S, since=mark)
        expected = (time.monotonic() - started) / period_s
    finally:
        ticker.stop()
    for number, (can_id, length) in pdos.items():
        frames = frames_of(dut, mark, can_id)
        assert len(frames) >= wanted, f"TPDO{number}: {len(frames)} frames"
        assert {len(f.data) for f in frames} == {length}
        if number not in APP_TRIGGERED[dut.kind]:
            assert len(frames) <= expected + 3, f"TPDO{number}: {len(frames)} frames"
        # Silences mean a timer that stops, unless the host silenced a plain timer thread too.
        long = [
            (a.timestamp, b.timestamp)
            for a, b in pairwise(frames)
            if b.timestamp - a.timestamp > 4 * period_s
            and not ticker.silent(a.timestamp, b.timestamp, 2 * period_s)
        ]
        assert len(long) <= 1, f"TPDO{number}: silences {long} the host did not explain"
        # Not slower than the timer: the median gap against the plain timer thread's over the
        # same span (one late send is followed by a short gap, the device keeping its grid,
        # so a two-sided check failed at load 12 with a 16 ms median; the exact period is
        # checked in virtual time, tests/test_device_runtime.py).
        gap_s = median(b.timestamp - a.timestamp for a, b in pairwise(frames))
        host_s = max(period_s, ticker.median_gap(frames[0].timestamp, frames[-1].timestamp))
        assert gap_s <= 1.5 * host_s or number in APP_TRIGGERED[dut.kind], (
            f"TPDO{number}: median gap {gap_s:.3f} s, a timer thread's {host_s:.3f} s"
        )


def sync_pattern(
    dut: Dut, pdos: dict[int, tuple[int, int]], count: int, counter: bool = False
) -> dict[int, list[int]]:
    """Send `count` SYNCs (counter 1..count if `counter`); for each TPDO the SYNC
    numbers it answered. A frame without a SYNC would show as a doubled entry."""
    sent = {n: [] for n in pdos}
    for i in range(1, count + 1):
        mark = dut.log.mark()
        time.sleep(0.005)  # frames sent without a SYNC would land in this window
        dut.sync(i if counter else None)
        dut.barrier()
        for n, (can_id, length) in pdos.items():
            frames = frames_of(dut, mark, can_id)
            assert {len(f.data) for f in frames} <= {length}
            sent[n] += [i] * len(frames)
    return sent


def check_sync_cyclic(dut: Dut, numbers: list[int], every=lambda n: 2) -> None:
    pdos = setup(dut, numbers, transmission_type=every)
    dut.start()
    dut.barrier()
    sent = sync_pattern(dut, pdos, 12)
    for n, syncs in sent.items():
        period = every(n)
        assert len(syncs) == 12 // period, f"TPDO{n} (type {period}): after SYNCs {syncs}"
        assert all(b - a == period for a, b in pairwise(syncs)), syncs


def check_sync_acyclic(dut: Dut, numbers: list[int]) -> None:
    """Type 0: after an event the TPDO goes with the next SYNC, once; never without SYNC."""
    pdos = setup(dut, numbers, transmission_type=0)
    dut.start()
    dut.barrier()
    sync_pattern(dut, pdos, 1)  # flush anything pending
    if dut.kind in SELF_CHANGING:
        for _ in range(3):
            mark = dut.log.mark()
            time.sleep(0.03)  # data changes, but no SYNC: nothing
            assert all(frames_of(dut, mark, c) == [] for c, _ in pdos.values())
            sent = sync_pattern(dut, pdos, 1)
            assert all(s == [1] for s in sent.values()), sent
    else:
        assert all(s == [] for s in sync_pattern(dut, pdos, 2).values())  # no event
        mark = dut.log.mark()
        statusword = cause_event(dut)
        time.sleep(0.02)
        assert all(frames_of(dut, mark, c) == [] for c, _ in pdos.values())
        sent = sync_pattern(dut, pdos, 3)
        assert all(s == [1] for s in sent.values()), sent
        for can_id, _ in pdos.values():
            assert struct.unpack_from("<H", frames_of(dut, mark, can_id)[0].data)[0] == statusword


def check_sync_start(dut: Dut, numbers: list[int]) -> None:
    """Type 2 with SYNC start value: first transmission at the SYNC whose counter
    equals the start value, then every 2nd SYNC."""

    def start(n: int) -> int:
        return 2 + numbers.index(n)

    pdos = setup(dut, numbers, transmission_type=2, sync_start=start)
    for n in numbers:
        assert dut.get(0x1800 + n - 1, 6) == start(n)
    dut.start()
    dut.barrier()
    sent = sync_pattern(dut, pdos, 11, counter=True)
    for n, syncs in sent.items():
        assert syncs == list(range(start(n), 12, 2)), f"TPDO{n}: {syncs}"


def test_3_4_tpdo_event_driven(dut: Dut) -> None:
    """3.4 PDO 04: "Configure TPDO for event driven mode, if supported"

    TPDO1, transmission type 255, event timer 0: a change of its mapped data
    (skin: samples, EMG: envelope, drives: statusword after a controlword
    write) sends it with the current data; without a change nothing is sent.
    With a 20 ms inhibit time, bursts of events give at most one TPDO per
    inhibit period and the last state still goes out.
    """
    check_event_driven(dut, [1])


def test_3_5_tpdo_event_timer(dut: Dut) -> None:
    """3.5 PDO 05: "Configure TPDO event timer, if supported"

    TPDO1, type 254, event timer 25 ms: over 250 ms it comes at least every
    ~25 ms (>= 60 % of the expected count, about as many frames as a timer
    thread beside it ticked, no silence over four periods the host did not
    impose on that thread too) and, where the application does not trigger
    it too, not more often than the timer.
    The skin/EMG application is slowed down so that its own triggers do not
    hide the timer.
    """
    check_event_timer(dut, [1])


def test_3_6_tpdo_sync_cyclic(dut: Dut) -> None:
    """3.6 PDO 06: "Configure TPDO for sync (cyclic) mode, if supported"

    TPDO1, transmission type 2: 12 SYNCs give exactly 6 TPDOs, one on every
    2nd SYNC, none in between (also not from the application's own triggers).
    """
    check_sync_cyclic(dut, [1])


def test_3_7_tpdo_sync_acyclic(dut: Dut) -> None:
    """3.7 PDO 07: "Configure TPDO for sync (acyclic) mode, if supported"

    TPDO1, transmission type 0: no TPDO without an event; after an event the
    TPDO goes exactly once, with the next SYNC, carrying the new data.
    """
    check_sync_acyclic(dut, [1])


def test_3_8_tpdo_sync_start_value(dut: Dut) -> None:
    """3.8 PDO 08: "Configure TPDO for SYNC (cyclic) mode and configure SYNC start value, if
    supported"

    TPDO1, type 2, SYNC start value 2 (sub-index 6, written while the PDO is
    invalid): with SYNC counters 1..11 it is sent at counters 2, 4, ..., 10.
    """
    check_sync_start(dut, [1])


def test_3_10_tpdos_event_driven(dut: Dut) -> None:
    """3.10 PDO 10: "Configure TPDOs for event driven mode, if supported"

    As 3.4 with all four TPDOs at once (TPDO2-4 map the node's event object).
    """
    check_event_driven(dut, dut.tpdo_numbers())


def test_3_11_tpdos_event_timer(dut: Dut) -> None:
    """3.11 PDO 11: "Configure TPDOs for event timer, if supported"

    As 3.5 with all four TPDOs at once.
    """
    check_event_timer(dut, dut.tpdo_numbers())


def test_3_12_tpdos_sync_cyclic(dut: Dut) -> None:
    """3.12 PDO 12: "Configure TPDOs for sync (cyclic) mode, if supported"

    TPDO n gets transmission type n (1..4): 12 SYNCs give 12, 6, 4 and 3 TPDOs,
    on every n-th SYNC.
    """
    check_sync_cyclic(dut, dut.tpdo_numbers(), every=lambda n: n)


def test_3_13_tpdos_sync_acyclic(dut: Dut) -> None:
    """3.13 PDO 13: "Configure TPDOs for sync (acyclic) mode, if supported"

    As 3.7 with all four TPDOs at once.
    """
    check_sync_acyclic(dut, dut.tpdo_numbers())


def test_3_14_tpdos_sync_start_value(dut: Dut) -> None:
    """3.14 PDO 14: "Configure TPDOs for SYNC (cyclic) mode and configure SYNC start value, if
    supported"

    All TPDOs type 2 with start values 2, 3, 4, 5: each starts at its own
    counter value and then goes on every 2nd SYNC.
    """
    check_sync_start(dut, dut.tpdo_numbers())


def test_3_16_each_tpdo_event_driven(dut: Dut) -> None:
    """3.16 PDO 16: "Configure TPDO for event driven mode, if supported"

    As 3.4 for each TPDO in turn, the others invalid (150 ms windows).
    """
    for number in dut.tpdo_numbers():
        dut.enter_pre_operational()
        check_event_driven(dut, [number], window=0.15)


def test_3_17_each_tpdo_event_timer(dut: Dut) -> None:
    """3.17 PDO 17: "Configure TPDO event timer, if supported."

    As 3.5 for each TPDO in turn, the others invalid (150 ms windows).
    """
    for number in dut.tpdo_numbers():
        dut.enter_pre_operational()
        check_event_timer(dut, [number], window=0.15)


def test_3_18_each_tpdo_sync_cyclic(dut: Dut) -> None:
    """3.18 PDO 18: "Configure TPDO for sync (cyclic) mode, if supported"

    As 3.6 for each TPDO in turn (type 3 here), the others invalid.
    """
    for number in dut.tpdo_numbers():
        dut.enter_pre_operational()
        check_sync_cyclic(dut, [number], every=lambda n: 3)


def test_3_19_each_tpdo_sync_acyclic(dut: Dut) -> None:
    """3.19 PDO 19: "Configure TPDO for sync (acyclic) mode, if supported"

    As 3.7 for each TPDO in turn, the others invalid.
    """
    for number in dut.tpdo_numbers():
        dut.enter_pre_operational()
        check_sync_acyclic(dut, [number])


def test_3_20_each_tpdo_sync_start_value(dut: Dut) -> None:
    """3.20 PDO 20: "Configure TPDO for SYNC (cyclic) mode and configure SYNC start value, if
    supported"

    As 3.8 for each TPDO in turn, the others invalid.
    """
    for number in dut.tpdo_numbers():
        dut.enter_pre_operational()
        check_sync_start(dut, [number])


# -- mapping --------------------------------------------------------------------------------
def pdo_pairs(dut: Dut) -> list[tuple[int, int, bool]]:
    """(communication index, mapping index, transmit) of every PDO."""
    out = [(0x1800 + n - 1, 0x1A00 + n - 1, True) for n in dut.tpdo_numbers()]
    return out + [(0x1400 + n - 1, 0x1600 + n - 1, False) for n in dut.rpdo_numbers()]


def test_3_21_default_mapping(dut: Dut) -> None:
    """3.21 PDO 21: "Read default mapping and look for corresponding values in the object
    dictionary"

    Every PDO's mapping read from the device equals the EDS; every mapped
    object exists on the device (an SDO read gives as many bits as mapped),
    is PDO-mappable in the EDS, fits the direction (TPDO: readable, RPDO:
    writable) and a PDO carries at most 64 bits.
    """
    for _comm, mapping, transmit in pdo_pairs(dut):
        count = dut.get(mapping, 0)
        assert count == dut.od[mapping][0].default
        total = 0
        for sub in range(1, count + 1):
            raw = dut.get(mapping, sub)
            assert raw == dut.od[mapping][sub].default
            index, subindex, bits = raw >> 16, (raw >> 8) & 0xFF, raw & 0xFF
            total += bits
            entry = dut.entry(index, subindex)
            assert entry.var.pdo_mappable, str(entry)
            assert entry.readable if transmit else entry.writable, str(entry)
            assert len(dut.read(index, subindex)) * 8 == bits == len(entry.var), str(entry)
        assert total <= 64


def tpdo_mappable(dut: Dut) -> list[EdsEntry]:
    return mappable_objects(dut, accesses=("ro", "rwr", "rw", "const"))


def test_3_22_new_mapping_with_procedure(dut: Dut) -> None:
    """3.22 PDO 22: "Try to write a new correct mapping with the mapping procedure."

    python-canopen's PDO configuration does the CiA 301 procedure (COB-ID
    invalid, sub-index 0 = 0, entries, sub-index 0 = n, COB-ID valid). TPDO1
    gets 1001h in front of its default entries and type 1: accepted, read
    back from the device, and the TPDO on SYNC has the new layout, decoded
    by python-canopen. RPDO1 of the belt/hand gets the controlword, an 8-bit
    dummy and the target; an RPDO sent by python-canopen is applied.
    """
    tpdo = dut.node.tpdo[1]
    tpdo.read()
    default = [(v.index, v.subindex) for v in tpdo.map]
    tpdo.clear()
    tpdo.add_variable(obj.ERROR_REGISTER)
    for index, subindex in default:
        if tpdo.length + len(dut.entry(index, subindex).var) <= 64:
            tpdo.add_variable(index, subindex)
    tpdo.trans_type = 1
    tpdo.enabled = True
    tpdo.save()
    expected = [v.index << 16 | v.subindex << 8 | v.length for v in tpdo.map]
    assert [dut.get(0x1A00, s) for s in range(1, dut.get(0x1A00, 0) + 1)] == expected
    assert dut.get(0x1800, 2) == 1 and not dut.get(0x1800, 1) & COB_INVALID
    dut.start()
    mark = dut.log.mark()
    dut.sync()
    dut.barrier()
    frames = frames_of(dut, mark, tpdo.cob_id)
    assert len(frames) == 1 and len(frames[0].data) * 8 == tpdo.length
    assert tpdo.map[0].raw == dut.get(obj.ERROR_REGISTER)
    if not dut.has_rpdos:
        return  # the skin and EMG node have no RPDO (NrOfRXPDO=0)
    dut.enter_pre_operational()
    rpdo = dut.node.rpdo[1]
    rpdo.read()
    target = rpdo.map[1]  # default: controlword, target
    rpdo.clear()
    rpdo.add_variable(obj.CONTROLWORD)
    rpdo.add_variable(0x0005)  # Dummy0005: UNSIGNED8
    rpdo.add_variable(target.index, target.subindex)
    rpdo.enabled = True
    rpdo.save()
    assert [dut.get(0x1600, s) for s in range(0, 4)] == [
        3,
        0x60400010,
        0x00050008,
        target.index << 16 | target.subindex << 8 | 32,
    ]
    dut.start()
    rpdo.map[0].raw = 0x06
    rpdo.map[2].raw = 1234
    rpdo.transmit()
    dut.barrier()
    assert dut.get(obj.CONTROLWORD) == 0x06
    assert dut.get(target.index, target.subindex) == 1234


def mapping_of(dut: Dut, mapping: int) -> list[int]:
    return [dut.get(mapping, s) for s in range(0, 9)]


def test_3_23_new_mapping_without_procedure(dut: Dut) -> None:
    """3.23 PDO 23: "Try to write a new correct mapping without the mapping procedure}(node-ID)"

    With the PDO invalid but sub-index 0 not first set to 0, writing a
    (correct) mapping entry is refused (CiA 301 7.5.2.36; the code is not
    fixed by the standard: 0x06010000/0x08000022/0x06040043 accepted) and the
    mapping stays. Checked on TPDO1 and, on the belt/hand, RPDO1.
    """
    for comm, mapping, _transmit in pdo_pairs(dut):
        if mapping not in (0x1A00, 0x1600):
            continue
        before = mapping_of(dut, mapping)
        assert before[0] > 0
        cob_id = dut.invalidate(comm)
        code = dut.abort_of(dut.set, mapping, 1, before[1 + before[0] - 1])
        assert code in MAPPING_LOCKED, f"{mapping:04X}h: 0x{code:08X}"
        assert mapping_of(dut, mapping) == before
        dut.set(comm, 1, cob_id)


def test_3_24_new_mapping_valid_pdo(dut: Dut) -> None:
    """3.24 PDO 24: "Try to write a new correct mapping to a valid PDO without setting the related
    COB-ID entry invalid"

    With the PDO valid, writing sub-index 0 (0 or another count) and writing
    an entry are all refused (0x06010000/0x08000022/0x06040043 accepted); the
    mapping stays and the PDO stays valid. Every valid PDO of the node.
    """
    checked = 0
    for comm, mapping, _transmit in pdo_pairs(dut):
        if dut.get(comm, 1) & COB_INVALID:
            continue
        before = mapping_of(dut, mapping)
        for sub, value in ((0, 0), (0, max(1, before[0] - 1)), (1, before[1] or 0x10010008)):
            code = dut.abort_of(dut.set, mapping, sub, value)
            assert code in MAPPING_LOCKED, f"{mapping:04X}h:{sub}: 0x{code:08X}"
        assert mapping_of(dut, mapping) == before
        assert not dut.get(comm, 1) & COB_INVALID
        checked += 1
    assert checked


def test_3_25_mapping_too_many_objects(dut: Dut) -> None:
    """3.25 PDO 25: "Try to write a new incorrect mapping - too many objects"

    Eight 8-bit objects (exactly 64 bits) are accepted; a ninth is refused:
    sub-index 0 = 9 aborts (0x06090031 — the EDS HighLimit is 8 — or
    0x06040042) and sub-index 9 does not exist (0x06090011). TPDO1 with
    1001h; on the belt/hand also RPDO1 with the 8-bit dummy 0005h.
    """
    targets = [(0x1800, 0x1A00, 0x10010008)]
    if dut.has_rpdos:
        targets.append((0x1400, 0x1600, 0x00050008))
    for comm, mapping, entry in targets:
        dut.invalidate(comm)
        dut.remap(mapping, [entry] * 8)
        assert dut.get(mapping, 0) == 8
        assert dut.abort_of(dut.set, mapping, 0, 9) in {ABORT_VALUE_HIGH, ABORT_PDO_TOO_LONG}
        assert dut.abort_of(dut.write, mapping, 9, struct.pack("<I", entry)) == ABORT_NO_SUBINDEX
        assert dut.get(mapping, 0) == 8


def test_3_26_mapping_objects_too_long(dut: Dut) -> None:
    """3.26 PDO 26: "Try to write a new incorrect mapping - objects too long"

    Entries whose lengths add up to more than 64 bits: setting sub-index 0
    aborts with 0x06040042 and the PDO keeps sub-index 0 = 0. An entry whose
    length disagrees with the object (1001h as 16 bits) is refused
    (0x06040043 or 0x06040041). TPDO1, and RPDO1 on the belt/hand.
    """
    biggest = max(tpdo_mappable(dut), key=lambda e: len(e.var))
    targets = [(0x1800, 0x1A00, biggest)]
    if dut.has_rpdos:
        outputs = mappable_objects(dut, accesses=("rw", "rww", "wo"))
        targets.append((0x1400, 0x1600, max(outputs, key=lambda e: len(e.var))))
    for comm, mapping, entry in targets:
        repeat = 64 // len(entry.var) + 1
        dut.invalidate(comm)
        dut.set(mapping, 0, 0)
        for sub in range(1, repeat + 1):
            dut.set(mapping, sub, entry_of(entry))
        assert dut.abort_of(dut.set, mapping, 0, repeat) == ABORT_PDO_TOO_LONG
        assert dut.get(mapping, 0) == 0
    dut.invalidate(0x1800)
    dut.set(0x1A00, 0, 0)
    assert dut.abort_of(dut.set, 0x1A00, 1, 0x10010010) in WRONG_LENGTH


def check_maps(
    dut: Dut, comm: int, mapping: int, entries: list[EdsEntry], refused: int | None
) -> None:
    assert entries
    dut.invalidate(comm)
    dut.set(mapping, 0, 0)
    for entry in entries:
        if refused is None:
            dut.set(mapping, 1, entry_of(entry))
            dut.set(mapping, 0, 1)
            assert dut.get(mapping, 1) == entry_of(entry)
            dut.set(mapping, 0, 0)
        else:
            code = dut.abort_of(dut.set, mapping, 1, entry_of(entry))
            assert code == refused, f"{entry}: 0x{code:08X}"


def outputs(dut: Dut) -> list[EdsEntry]:
    return mappable_objects(dut, accesses=("rw", "rww", "wo"))


def inputs(dut: Dut) -> list[EdsEntry]:
    return mappable_objects(dut, accesses=("ro", "rwr", "const"))


def not_mappable(dut: Dut) -> list[EdsEntry]:
    return [e for e in dut.entries if not e.var.pdo_mappable and e.size is not None]


def test_3_27_map_output_to_rpdo(dut: Dut) -> None:
    """3.27 PDO 27: "Try to map an object with attribute PDOMapping=1 and AccessType=rww or
    AccessType=wo - try to map process output to receive PDO"

    The EDS files have no rww/wo entries; their process outputs are rw with
    PDOMapping=1 (controlword, target). Each maps into RPDO1 and is accepted.
    """
    dut.require_rpdos()
    check_maps(dut, 0x1400, 0x1600, outputs(dut), None)


def test_3_28_map_input_to_rpdo(dut: Dut) -> None:
    """3.28 PDO 28: "Try to map an object with attribute PDOMapping=1 and AccessType=rwr or
    AccessType=ro - try to map process input to receive PDO"

    Every ro/const PDO-mappable object is refused in RPDO1 with 0x06040041.
    """
    dut.require_rpdos()
    check_maps(dut, 0x1400, 0x1600, inputs(dut), ABORT_NOT_MAPPABLE)


def test_3_29_map_not_mappable_to_rpdo(dut: Dut) -> None:
    """3.29 PDO 29: "Try to map an object with attribute PDOMapping=0 - try to map an object to
    receive PDO, which is not mappable"

    Every entry with PDOMapping=0 (fixed size) is refused in RPDO1 with
    0x06040041.
    """
    dut.require_rpdos()
    check_maps(dut, 0x1400, 0x1600, not_mappable(dut), ABORT_NOT_MAPPABLE)


def test_3_30_map_input_to_tpdo(dut: Dut) -> None:
    """3.30 PDO 30: "Try to map an object with attribute PDOMapping=1 and AccessType=rwr or
    AccessType=ro - try to map process input to transmit PDO"

    Every ro/const PDO-mappable object maps into TPDO1.
    """
    check_maps(dut, 0x1800, 0x1A00, inputs(dut), None)


def test_3_31_map_output_to_tpdo(dut: Dut) -> None:
    """3.31 PDO 31: "Try to map an object with attribute PDOMapping=1 and AccessType=rww or
    AccessType=wo - try to map process output to transmit PDO"

    rww/wo objects must be refused in a TPDO (0x06040041). No grasplink EDS
    has a rww or wo entry (rw PDO-mappable objects may go either way), so the
    case does not apply.
    """
    candidates = mappable_objects(dut, accesses=("rww", "wo"))
    if not candidates:
        pytest.skip(f"{dut.kind}.eds has no PDO-mappable rww/wo entry")
    check_maps(dut, 0x1800, 0x1A00, candidates, ABORT_NOT_MAPPABLE)


def test_3_32_map_not_mappable_to_tpdo(dut: Dut) -> None:
    """3.32 PDO 32: "Try to map an object with attribute PDOMapping=0 - try to map a object to
    transmit PDO, which is not mappable"

    Every entry with PDOMapping=0 (fixed size) is refused in TPDO1 with
    0x06040041.
    """
    check_maps(dut, 0x1800, 0x1A00, not_mappable(dut), ABORT_NOT_MAPPABLE)


def test_3_33_map_dummy(dut: Dut) -> None:
    """3.33 PDO 33: "Try to write a dummy object if supported"

    Belt and hand declare Dummy0002-0007 in [DummyUsage]: each maps into
    RPDO1 with its size; Dummy0001 (not declared) and any dummy in a TPDO
    are refused. An RPDO with a dummy in front of the controlword skips the
    dummy's byte. The skin/EMG node have no RPDO and declare no dummy.
    """
    dut.require_rpdos()
    usage = dut.od
    sizes = {2: 8, 3: 16, 4: 32, 5: 8, 6: 16, 7: 32}
    dut.invalidate(0x1400)
    dut.set(0x1600, 0, 0)
    for index, bits in sizes.items():
        assert index in usage
        dut.set(0x1600, 1, index << 16 | bits)
    assert dut.abort_of(dut.set, 0x1600, 1, 0x00010001) in {ABORT_NOT_MAPPABLE, ABORT_NO_OBJECT}
    dut.invalidate(0x1800)
    dut.set(0x1A00, 0, 0)
    assert dut.abort_of(dut.set, 0x1A00, 1, 0x00050008) == ABORT_NOT_MAPPABLE
    dut.remap(0x1600, [0x00060010, 0x60400010])
    dut.set(0x1400, 1, 0x200 + dut.node_id)
    dut.start()
    dut.send(0x200 + dut.node_id, struct.pack("<HH", 0xFFFF, 0x0006))
    dut.barrier()
    assert dut.get(obj.CONTROLWORD) == 0x0006

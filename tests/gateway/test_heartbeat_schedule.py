"""The gateway's own heartbeat never waits behind decoding (issue 21, item 5).

Virtual time throughout: the runner is stepped by hand on a clock that only the devices
move (a "decoder" that costs 10 ms of clock per skin frame), and the python-can virtual
bus queues a frame in the other handle the moment it is sent. No thread, no sleep.
"""

from __future__ import annotations

import logging
import os
import threading
import time
import uuid
from collections.abc import Iterator

import can
import pytest

from grasplink.bus import NodeRunner
from grasplink.bus.priority import raise_thread_nice, raise_thread_priority
from grasplink.bus.url import frame_to_message
from grasplink.core.frames import HEARTBEAT_BASE, Frame
from grasplink.gateway.config import parse_config
from grasplink.gateway.master import HeartbeatProducer, NmtMaster
from grasplink.gateway.provisioning import Provisioner
from grasplink.profiles import objects as obj
from tests.rawcan import Listener

MS = 1000
DECODE_US = 10 * MS  # what one skin frame costs the slow decoder below
SKIN_TPDO = 0x190
BEAT = HEARTBEAT_BASE + obj.GATEWAY_NODE_ID


class Clock:
    def __init__(self) -> None:
        self.now_us = 0

    def __call__(self) -> int:
        return self.now_us


class SlowDecoder:
    """A device whose every skin frame takes DECODE_US of the runner's (virtual) clock."""

    node_id = 0x55

    def __init__(self, clock: Clock) -> None:
        self.clock = clock
        self.decoded = 0

    def start(self, t_us: int) -> list[Frame]:
        return []

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        if frame.can_id == SKIN_TPDO:
            self.clock.now_us += DECODE_US
            self.decoded += 1
        return []

    def advance(self, t_us: int) -> list[Frame]:
        return []

    def next_deadline_us(self) -> int | None:
        return None


@pytest.fixture
def buses() -> Iterator[tuple[can.BusABC, can.BusABC]]:
    channel = f"heartbeat-schedule-{uuid.uuid4().hex}"
    runner_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    node_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    yield runner_bus, node_bus
    runner_bus.shutdown()
    node_bus.shutdown()


def _backlog_step(
    buses: tuple[can.BusABC, can.BusABC], *, detach: bool
) -> tuple[NmtMaster, SlowDecoder, list[int]]:
    """A master and a slow decoder on one runner; 60 skin frames (600 ms of decoding) wait
    in the bus when the runner steps at 50 ms. Returns them and the COB-IDs the node heard."""
    runner_bus, node_bus = buses
    clock = Clock()
    master = NmtMaster(heartbeat_ms=100, autostart=False)
    decoder = SlowDecoder(clock)
    urgent = [master.detach_heartbeat()] if detach else []
    runner = NodeRunner(runner_bus, [master, decoder], clock_us=clock, urgent=urgent)
    runner.power_on()
    while node_bus.recv(0) is not None:  # the boot-up heartbeat and the NMT reset
        pass
    for i in range(60):
        node_bus.send(frame_to_message(Frame(SKIN_TPDO, bytes([i]))))
    clock.now_us = 50 * MS
    runner.step()
    heard = []
    while (msg := node_bus.recv(0)) is not None:
        heard.append(msg.arbitration_id)
    return master, decoder, heard


def test_heartbeat_deadline_is_served_before_a_backlog_of_skin_frames_is_drained(buses):
    master, decoder, heard = _backlog_step(buses, detach=True)
    assert decoder.decoded == 60  # the whole backlog in this step: 50 .. 650 ms
    beat = master.heartbeat
    # a beat at every 100 ms grid slot passed meanwhile, each at most one frame late
    assert heard.count(BEAT) == 6 and beat.beats == 6
    assert beat.max_late_us <= DECODE_US
    assert beat.late == 0 and beat.over_consumer == 0


def test_a_heartbeat_among_the_devices_timers_waits_for_the_whole_backlog(buses):
    # What the gateway did before: its heartbeat one of the master's timers, run after the
    # batch. The same 600 ms of decoding puts one beat out 550 ms late, over the old 300 ms.
    master, _, heard = _backlog_step(buses, detach=False)
    assert heard.count(BEAT) == 1
    assert master.heartbeat.max_late_us == 550 * MS


def test_urgent_timers_do_not_break_frames_first_for_the_loss_check(buses):
    # The node's heartbeat waits behind 20 TPDOs after a 1 s stall: it is still heard before
    # the master judges the node lost, with the master's heartbeat served apart.
    runner_bus, node_bus = buses
    clock = Clock()
    master = NmtMaster(heartbeat_ms=100, node_heartbeat_ms=100, autostart=False)
    runner = NodeRunner(runner_bus, [master], clock_us=clock, urgent=[master.detach_heartbeat()])
    runner.power_on()
    node_bus.send(frame_to_message(Frame(HEARTBEAT_BASE + 5, bytes([0x05]))))
    runner.step()
    clock.now_us = 1_000 * MS
    for i in range(20):
        node_bus.send(frame_to_message(Frame(0x185, bytes([i]))))
    node_bus.send(frame_to_message(Frame(HEARTBEAT_BASE + 5, bytes([0x05]))))
    runner.step()
    assert not master.nodes[5].lost
    assert master.heartbeat.beats == 1  # the grid slots missed meanwhile: one beat, not ten


def test_the_heartbeats_owner_does_not_hear_it_back_and_the_other_devices_do(buses):
    # A master hearing its own heartbeat would take it for a second master on the bus.
    runner_bus, node_bus = buses
    clock = Clock()
    owner, node = Listener(obj.GATEWAY_NODE_ID), Listener(0x20)
    producer = HeartbeatProducer(obj.GATEWAY_NODE_ID, period_us=100 * MS, consumer_us=500 * MS)
    runner = NodeRunner(runner_bus, [owner, node], clock_us=clock, urgent=[producer])
    runner.power_on()
    clock.now_us = 100 * MS
    runner.step()
    assert node_bus.recv(0).arbitration_id == BEAT
    assert node.heard == [BEAT] and owner.heard == []


# -- the producer's own account of lateness ------------------------------------------------
def test_producer_counts_late_beats_and_intervals_over_the_consumer_time(caplog):
    beat = HeartbeatProducer(0x01, period_us=100 * MS, consumer_us=500 * MS)
    beat.start(0)
    assert beat.advance(99 * MS) == []
    for t_ms in (100, 200, 305):
        assert beat.advance(t_ms * MS) == [beat.frame]
    assert (beat.late, beat.max_late_us) == (0, 5 * MS)  # 5 ms: within a quarter of 400 ms
    with caplog.at_level(logging.WARNING, logger="grasplink.gateway.master"):
        assert beat.advance(950 * MS) == [beat.frame]  # the 400 ms slot served at 950 ms
        assert beat.advance(1_150 * MS) == [beat.frame]  # the 1000 slot, 150 ms late
        assert beat.advance(1_250 * MS) == [beat.frame]  # 1100 skipped; 1200 served 50 late
    assert beat.next_deadline_us() == 1_300 * MS  # the grid holds
    assert beat.late == 2 and beat.over_consumer == 1  # 645 ms from 305 to 950
    assert beat.max_late_us == 550 * MS and beat.max_interval_us == 645 * MS
    # the first late beat is told at once; the next one within 10 s only counted
    assert len(caplog.records) == 1 and "550 ms late" in caplog.records[0].getMessage()
    beat.advance(11 * 1_000 * MS)
    assert len(caplog.records) == 2 and "2 since the last report" in caplog.records[1].getMessage()
    stats = beat.stats()
    assert stats["beats"] == 7 and stats["late"] == 3 and stats["over_consumer"] == 2
    # intervals 100, 100, 105, 645, 200, 100, 9750 ms
    assert stats["interval_p50_ms"] == 105.0 and stats["interval_max_ms"] == 9_750.0


def test_producer_needs_a_consumer_time_longer_than_its_period():
    with pytest.raises(ValueError, match="consumer_us > period_us"):
        HeartbeatProducer(0x01, period_us=100 * MS, consumer_us=100 * MS)


# -- the consumer time the nodes are given --------------------------------------------------
def _consumer_entry(config_data: dict) -> int:
    config = parse_config(config_data, "gw.toml")
    writes = Provisioner(config.nodes["belt"], config).writes()
    write = next(w for w in writes if w.index == obj.HEARTBEAT_CONSUMER)
    return int.from_bytes(write.data, "little")


def test_nodes_watch_the_gateway_heartbeat_for_three_periods_plus_an_allowance():
    entry = _consumer_entry({})
    assert entry >> 16 == obj.GATEWAY_NODE_ID
    assert entry & 0xFFFF == 3 * 100 + 200  # was 300: no room for a busy host's scheduling
    tuned = {"gateway": {"heartbeat_ms": 50, "consumer_factor": 2.0, "consumer_allowance_ms": 0}}
    assert _consumer_entry(tuned) & 0xFFFF == 100


def test_consumer_allowance_out_of_range_names_the_key():
    with pytest.raises(Exception, match=r"gw.toml: gateway.consumer_allowance_ms"):
        parse_config({"gateway": {"consumer_allowance_ms": -5}}, "gw.toml")


# -- live: the pacer thread ----------------------------------------------------------------
class Busy:
    """A device whose TRIGGER frame keeps the runner's thread busy in Python for `busy_s`
    (a decoder stuck in a long call: the GIL changes hands every 5 ms, no frame is read)."""

    node_id = 0x56
    TRIGGER = 0x123

    def __init__(self, busy_s: float) -> None:
        self.busy_s = busy_s
        self.started = threading.Event()
        self.done = threading.Event()
        self.ended_at = 0.0

    def start(self, t_us: int) -> list[Frame]:
        return []

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        if frame.can_id == self.TRIGGER:
            self.started.set()
            end = time.monotonic() + self.busy_s
            while time.monotonic() < end:
                pass
            self.ended_at = time.monotonic()
            self.done.set()
        return []

    def advance(self, t_us: int) -> list[Frame]:
        return []

    def next_deadline_us(self) -> int | None:
        return None


def _beats_while_busy(buses, busy_s: float, stall_limit_s: float) -> tuple[list[float], float]:
    """Arrival times (s, monotonic) of the master's heartbeats while the runner is busy, and
    when the busy call ended."""
    runner_bus, node_bus = buses
    master = NmtMaster(heartbeat_ms=100, autostart=False)
    busy = Busy(busy_s)
    runner = NodeRunner(
        runner_bus,
        [master, busy],
        urgent=[master.detach_heartbeat()],
        pace_urgent=True,
        stall_limit_s=stall_limit_s,
    )
    arrivals: list[float] = []
    with runner:
        node_bus.send(frame_to_message(Frame(Busy.TRIGGER, b"")))
        assert busy.started.wait(10)
        while not busy.done.is_set():
            msg = node_bus.recv(0.05)
            if msg is not None and msg.arbitration_id == BEAT:
                arrivals.append(time.monotonic())
    return [t for t in arrivals if t < busy.ended_at], busy.ended_at


@pytest.mark.slow
def test_heartbeat_keeps_coming_while_the_runner_thread_is_busy_in_a_long_call(buses):
    # 1.5 s busy: ~15 beats are due. At least 5 must come (any beat at all needs the pacer;
    # without it the runner's thread sends none until the call returns).
    arrivals, _ = _beats_while_busy(buses, busy_s=1.5, stall_limit_s=60.0)
    assert len(arrivals) >= 5


@pytest.mark.slow
def test_heartbeat_stops_when_the_runner_thread_is_stuck_beyond_the_stall_limit(buses):
    # Stuck 2.5 s with a 0.3 s stall limit: the beats stop after ~0.3 s, so the nodes'
    # consumers can see a gateway whose loop is dead. The last beat comes well before the end.
    arrivals, ended_at = _beats_while_busy(buses, busy_s=2.5, stall_limit_s=0.3)
    assert all(ended_at - t >= 1.0 for t in arrivals)


# -- what the host grants -------------------------------------------------------------------
def _in_a_thread(call):
    """Run `call` in a fresh thread (its priority dies with it); its result and the
    thread's scheduling policy and nice value afterwards."""
    out = []

    def run() -> None:
        result = call()
        tid = threading.get_native_id()
        out.append((result, os.sched_getscheduler(0), os.getpriority(os.PRIO_PROCESS, tid)))

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    return out[0]


def test_heartbeat_thread_gets_real_time_or_says_why_not():
    (granted, what), policy, _ = _in_a_thread(raise_thread_priority)
    if granted:
        assert policy == os.SCHED_FIFO and what == "SCHED_FIFO priority 10"
    else:  # an unprivileged host: a nice value or nothing, and the reason in the note
        assert policy != os.SCHED_FIFO and "refused" in what


def test_gateway_thread_gets_a_raised_nice_or_says_why_not():
    before = os.getpriority(os.PRIO_PROCESS, threading.get_native_id())
    (granted, what), policy, nice = _in_a_thread(lambda: raise_thread_nice(-5))
    assert policy == os.SCHED_OTHER  # never real-time: decoding work can grow
    if granted:
        assert nice == -5 and what == "nice -5"
    else:
        assert nice == before and "refused" in what

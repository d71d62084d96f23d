"""A node telling its ticks ahead (`StreamingDevice`) sends what ticking one by one sends.

The lock-step bus asks a streaming node for a span of ticks and delivers each tick's
frames at its time, with the node's own timers among them (its 50 Hz TPDO2 of the static
force and the sample count, its heartbeat); anything reaching the node mid-span (an SDO
read of the samples or the sequence, NMT, SYNC, a heartbeat, a reply to one of its own
frames) must find it as the per-tick path leaves it. Each test runs the same script on
a bus with `stream=False` and on one with streaming, and compares every frame every tap
saw, with its time and sender, and the node's dictionary at the end.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import NMT_COB_ID, Frame
from grasplink.core.protocol import StreamingDevice
from grasplink.devices.factory import build_node
from grasplink.devices.node import DeviceNode
from grasplink.devices.sources import FunctionSource
from grasplink.profiles import objects as obj

SKIN = 0x10
SDO_RX = 0x600 + SKIN
TPDO1 = 0x180 + SKIN
SYNC = 0x80


def upload(index: int, sub: int = 0) -> Frame:
    """An SDO upload request (a master reading an object)."""
    return Frame(SDO_RX, bytes([0x40, index & 0xFF, index >> 8, sub, 0, 0, 0, 0]))


def download(index: int, sub: int, value: int, size: int) -> Frame:
    command = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
    head = bytes([command, index & 0xFF, index >> 8, sub])
    return Frame(SDO_RX, head + value.to_bytes(4, "little"))


class Script:
    """A master that sends frames at set times and may answer the node's packets."""

    node_id = 0x01

    def __init__(
        self, at: list[tuple[int, Frame]], answer: Callable[[Frame, int], list[Frame]] | None
    ):
        self.at = sorted(at, key=lambda item: item[0])
        self.answer = answer
        self.heard = 0

    def start(self, t_us: int) -> list[Frame]:
        return []

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        if frame.can_id == TPDO1 and self.answer is not None:
            self.heard += 1
            return self.answer(frame, self.heard)
        return []

    def advance(self, t_us: int) -> list[Frame]:
        frames = [f for t, f in self.at if t <= t_us]
        self.at = [(t, f) for t, f in self.at if t > t_us]
        return frames

    def next_deadline_us(self) -> int | None:
        return self.at[0][0] if self.at else None


def force(t_s: np.ndarray) -> np.ndarray:
    """A force that saturates the FSR now and then (the saturation EMCY comes and goes)."""
    return 60.0 + 45.0 * np.sin(9.0 * t_s)  # full scale is 98 N


def run(
    stream: bool,
    at: list[tuple[int, Frame]],
    answer: Callable[[Frame, int], list[Frame]] | None = None,
    chunks_us: int = 250_000,
    end_us: int = 3_000_000,
) -> tuple[list[tuple[int, int, bytes, str]], dict, DeviceNode]:
    node = build_node("skin", SKIN, FunctionSource(force))
    script = Script([(0, Frame(NMT_COB_ID, bytes([0x01, 0]))), *at], answer)
    net = LockstepNetwork([script, node], stream=stream)
    seen: list[tuple[int, int, bytes, str]] = []
    net.taps.append(
        lambda t, f, sender: seen.append((t, f.can_id, bytes(f.data), type(sender).__name__))
    )
    net.start()
    for t in range(chunks_us, end_us + 1, chunks_us):
        net.run_until(t)
    keys = sorted(node.store.keys())
    store = {key: node.store.get(*key) for key in keys}
    return seen, store, node


def same_both_ways(
    at: list[tuple[int, Frame]], answer: Callable[[Frame, int], list[Frame]] | None = None
) -> list[tuple[int, int, bytes, str]]:
    ticked, ticked_store, _ = run(False, at, answer)
    streamed, streamed_store, node = run(True, at, answer)
    assert isinstance(node, StreamingDevice)
    assert streamed == ticked
    assert streamed_store == ticked_store
    return streamed


def test_a_quiet_stream_sends_the_frames_of_ticking_one_by_one_in_long_spans(monkeypatch):
    told: list[int] = []
    original = DeviceNode.stream_ahead

    def counting(self: DeviceNode, t_us: int, until_us: int) -> list:
        ticks = original(self, t_us, until_us)
        told.append(len(ticks))
        return ticks

    monkeypatch.setattr(DeviceNode, "stream_ahead", counting)
    seen = same_both_ways([])
    assert max(told) > 1  # spans of several ticks were told
    assert any(can_id == 0x80 + SKIN for _, can_id, _, _ in seen)  # saturation EMCYs
    assert sum(can_id == TPDO1 for _, can_id, _, _ in seen) > 300


def test_sdo_reads_of_the_samples_sequence_and_counter_mid_span_read_the_last_packet():
    at = [
        (t, upload(index, sub))
        for k, t in enumerate(range(101_000, 2_900_000, 37_300))
        for index, sub in [
            [(obj.SKIN_SAMPLE_SLOTS, 1), (obj.SKIN_PACKET_SEQUENCE, 0)],
            [(obj.SKIN_SAMPLE_COUNTER, 0), (obj.SKIN_STATIC_FORCE_MN, 0)],
        ][k % 2]
    ]
    seen = same_both_ways(at)
    assert sum(can_id == 0x580 + SKIN for _, can_id, _, _ in seen) == len(at)


def test_a_read_answering_a_packet_at_its_own_time_sees_that_packet():
    def answer(frame: Frame, heard: int) -> list[Frame]:
        return [upload(obj.SKIN_PACKET_SEQUENCE)] if heard % 5 == 0 else []

    seen = same_both_ways([], answer)
    replies = [data[4] for _, can_id, data, _ in seen if can_id == 0x580 + SKIN]
    packets = [data[6] for _, can_id, data, _ in seen if can_id == TPDO1]
    assert replies and replies == packets[4::5][: len(replies)]


def test_nmt_stop_and_start_sync_and_a_config_change_mid_span_act_as_per_tick():
    at = [
        (410_333, Frame(NMT_COB_ID, bytes([0x02, SKIN]))),  # stop
        (730_001, Frame(NMT_COB_ID, bytes([0x01, SKIN]))),  # start
        (900_000, download(obj.SKIN_PACKETS_ON_SYNC, 0, 1, 1)),
        (1_000_000, Frame(NMT_COB_ID, bytes([0x80, SKIN]))),  # pre-operational
        (1_000_500, download(0x1800, 2, 1, 1)),  # TPDO1 synchronous, every SYNC
        (1_001_000, Frame(NMT_COB_ID, bytes([0x01, SKIN]))),
        *[(t, Frame(SYNC, b"")) for t in range(1_050_000, 1_600_000, 40_000)],
        (1_650_000, Frame(NMT_COB_ID, bytes([0x80, SKIN]))),
        (1_650_500, download(0x1800, 2, 254, 1)),  # back to event-driven
        (1_651_000, Frame(NMT_COB_ID, bytes([0x01, SKIN]))),
        (1_900_000, download(obj.SKIN_SAMPLES_PER_PDO, 0, 2, 1)),
        (2_200_000, download(obj.SKIN_SAMPLE_RATE_HZ, 0, 500, 2)),
        (2_500_000, Frame(0x701, bytes([0x05]))),  # a heartbeat the node may watch
    ]
    seen = same_both_ways(at)
    assert any(can_id == TPDO1 and t > 2_300_000 for t, can_id, _, _ in seen)


def test_runs_too_short_for_a_span_tick_one_by_one_without_asking(monkeypatch):
    """A closed loop runs the bus in 10 ms chunks, fewer packets than a span holds: the
    bus asks the node how far a span must reach (`stream_until_us`) and, that being past
    the run's end, ticks it without asking for a span (which would tell nothing)."""
    asked: list[int] = []
    original = DeviceNode.stream_ahead

    def counting(self: DeviceNode, t_us: int, until_us: int) -> list:
        asked.append(t_us)
        return original(self, t_us, until_us)

    monkeypatch.setattr(DeviceNode, "stream_ahead", counting)
    ticked, ticked_store, _ = run(False, [], chunks_us=10_000, end_us=1_000_000)
    streamed, streamed_store, _ = run(True, [], chunks_us=10_000, end_us=1_000_000)
    assert streamed == ticked and streamed_store == ticked_store
    assert sum(can_id == TPDO1 for _, can_id, _, _ in streamed) > 100
    assert asked == []  # (before: asked once per run, 100 asks, each telling nothing)


def test_how_far_a_span_must_reach_is_exactly_where_the_node_tells_one():
    """`stream_until_us` is the least `until_us` at which `stream_ahead` tells anything
    (one microsecond less: nothing), at many points of a stream."""
    _, _, node = run(True, [], chunks_us=7_000, end_us=300_000)
    checked = 0
    for _ in range(40):
        t_us = node.next_deadline_us()
        assert t_us is not None
        reach_us = node.stream_until_us(t_us)
        assert reach_us is not None and reach_us > t_us
        assert node.stream_ahead(t_us, reach_us - 1) == []
        ticks = node.stream_ahead(t_us, reach_us)
        node.commit_stream(0)
        if ticks:  # (none where a saturation EMCY comes or goes: it ticks as usual)
            checked += 1
            assert ticks[-1][0] <= reach_us
        node.advance(t_us)
    assert checked > 30

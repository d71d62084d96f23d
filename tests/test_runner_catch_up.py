"""A runner far behind its bus reads the backlog at once: PDOs a newer one supersedes are
dropped and counted, every service frame is delivered in order before timers run.

Driven step by step on a frozen clock (no thread, no sleeps): the python-can virtual bus
queues a frame in the other handle the moment it is sent, so a "stall" is frames sent
while the runner does not step.
"""

from __future__ import annotations

import struct
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

import can

from grasplink.bus.runner import NodeRunner
from grasplink.bus.url import frame_to_message
from grasplink.core.frames import Frame
from grasplink.core.protocol import StreamConsumer
from grasplink.gateway.config import load_config
from grasplink.gateway.edge import GatewayEdge
from grasplink.gateway.sdo_client import SdoClient, Transfer
from grasplink.gateway.service import Gateway

NODE = 0x01
TPDO1 = 0x180 + NODE
SDO_ANSWER = 0x580 + NODE
DEVICE_TYPE = 0x1000
MS = 1000


class _Client:
    """An SDO client node (the gateway's master in small) that notes every frame it hears."""

    node_id = 0x7F

    def __init__(self) -> None:
        self.sdo = SdoClient(NODE, timeout_us=500 * MS)
        self.heard: list[Frame] = []

    def start(self, t_us: int) -> list[Frame]:
        return []

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        self.heard.append(frame)
        return self.sdo.receive(frame, t_us)

    def advance(self, t_us: int) -> list[Frame]:
        return self.sdo.advance(t_us)

    def next_deadline_us(self) -> int | None:
        return self.sdo.next_deadline_us()


@contextmanager
def _stalled(
    supersede: bool, before: int, after: int
) -> Iterator[tuple[_Client, Transfer, NodeRunner]]:
    """The client reads 1000h at 0 ms; its thread stalls to 600 ms (past the 500 ms timeout)
    while the node sends `before` TPDOs, the answer (in time), then `after` TPDOs."""
    channel = f"catch-up-{uuid.uuid4().hex}"
    runner_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    node_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    now = [0]
    client = _Client()
    runner = NodeRunner(runner_bus, [client], clock_us=lambda: now[0], supersede=supersede)
    try:
        runner.power_on()
        transfer = client.sdo.upload(DEVICE_TYPE, 0)
        runner.step()  # the request goes out at 0 ms
        assert node_bus.recv(timeout=1.0) is not None
        for i in range(before):
            node_bus.send(frame_to_message(Frame(TPDO1, struct.pack("<H", i))))
        answer = bytes([0x43]) + struct.pack("<HB", DEVICE_TYPE, 0) + struct.pack("<I", 0x191)
        node_bus.send(frame_to_message(Frame(SDO_ANSWER, answer)))
        for i in range(before, before + after):
            node_bus.send(frame_to_message(Frame(TPDO1, struct.pack("<H", i))))
        now[0] = 600 * MS
        runner.step()
        yield client, transfer, runner
    finally:
        runner_bus.shutdown()
        node_bus.shutdown()


def _tpdo_numbers(client: _Client) -> list[int]:
    return [struct.unpack("<H", f.data)[0] for f in client.heard if f.can_id == TPDO1]


def test_an_sdo_answer_behind_a_flood_of_pdos_is_heard_before_the_timeout_runs() -> None:
    with _stalled(supersede=True, before=400, after=100) as (client, transfer, runner):
        assert transfer.ok, transfer.describe()
        assert int.from_bytes(transfer.data[:4], "little") == 0x191
        stats = runner.stats
    # the first batch as it came, then only the newest TPDO: after the answer, in bus order
    numbers = _tpdo_numbers(client)
    assert numbers == [*range(128), 499]
    assert [f.can_id for f in client.heard][-2:] == [SDO_ANSWER, TPDO1]
    assert stats.superseded == 500 - 129 and stats.superseded_by_cob_id == {TPDO1: 371}
    assert stats.catch_ups == 1 and stats.frames_rx == 130


def test_without_superseding_the_answer_waits_behind_the_pdos_and_times_out() -> None:
    # what a runner that only delivers a batch per step does on a host too slow for its bus
    with _stalled(supersede=False, before=400, after=100) as (_, transfer, runner):
        assert transfer.done and not transfer.ok
        assert "TIMEOUT" in transfer.describe()
        assert runner.stats.superseded == 0


def test_a_backlog_within_one_batch_loses_nothing() -> None:
    with _stalled(supersede=True, before=100, after=20) as (client, transfer, runner):
        assert transfer.ok
        assert _tpdo_numbers(client) == list(range(120))
        assert runner.stats.superseded == 0 and runner.stats.catch_ups == 0


@contextmanager
def _backlog(client: _Client, frames: list[Frame]) -> Iterator[NodeRunner]:
    """`frames` queued while the runner (on a frozen clock) did not step, then one step."""
    channel = f"catch-up-backlog-{uuid.uuid4().hex}"
    runner_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    node_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    runner = NodeRunner(runner_bus, [client], clock_us=lambda: 0)
    try:
        runner.power_on()
        for frame in frames:
            node_bus.send(frame_to_message(frame))
        runner.step()
        yield runner
    finally:
        runner_bus.shutdown()
        node_bus.shutdown()


def test_service_frames_in_a_backlog_are_never_superseded() -> None:
    # 300 heartbeats and 300 EMCYs of one node: none is process data, every one is heard
    client = _Client()
    service = [Frame(0x700 + NODE, bytes([0x05])), Frame(0x080 + NODE, bytes(8))]
    with _backlog(client, service * 300) as runner:
        assert len(client.heard) == 600
        assert runner.stats.superseded == 0 and runner.stats.catch_ups == 1


TPDO2 = 0x280 + NODE


class _StreamClient(_Client):
    """A client taking TPDO1 as a counted stream (the gateway's skin packets)."""

    def stream_can_ids(self) -> frozenset[int]:
        return frozenset({TPDO1})


def test_a_counted_streams_pdos_are_all_delivered_state_pdos_superseded() -> None:
    # 300 packets of a stream interleaved with 300 of a state: every packet of the stream
    # comes through in order, of the state the first batch's and then only the newest
    client = _StreamClient()
    packets = [Frame(c, struct.pack("<H", i)) for i in range(300) for c in (TPDO1, TPDO2)]
    with _backlog(client, packets) as runner:
        assert _tpdo_numbers(client) == list(range(300))
        state = [struct.unpack("<H", f.data)[0] for f in client.heard if f.can_id == TPDO2]
        assert state == [*range(64), 299]
        stats = runner.stats
        assert stats.superseded_by_cob_id == {TPDO2: 300 - 65} and stats.catch_ups == 1


def test_the_gateway_takes_its_skins_sample_tpdo_as_a_stream() -> None:
    gateway = Gateway(load_config(None))
    assert isinstance(gateway, StreamConsumer)
    assert gateway.stream_can_ids() == {0x190}  # the skin's TPDO1: samples; not EMG, hand
    edge = GatewayEdge(gateway)  # what a live runner drives
    assert isinstance(edge, StreamConsumer) and edge.stream_can_ids() == {0x190}

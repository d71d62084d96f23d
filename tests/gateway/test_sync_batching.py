"""Our skin's and EMG's streams batched per SYNC: the node keeps sampling at its rate and
sends what it made on SYNC; the gateway handles a cycle's frames at once."""

from __future__ import annotations

import itertools
import re
import uuid

import numpy as np
import pytest

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import (
    NMT_COB_ID,
    SYNC_COB_ID_DEFAULT,
    TPDO_BASES,
    Frame,
)
from grasplink.devices.factory import build_node
from grasplink.devices.node import DeviceNode
from grasplink.devices.pdo import MAX_OWED_PACKETS
from grasplink.devices.sources import ConstantSource
from grasplink.errors import ConfigError
from grasplink.gateway.config import parse_config
from grasplink.gateway.live import LiveGateway
from grasplink.gateway.service import Gateway
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators.synth import slip_recording
from tests.live import operational, wait_until

SKIN, EMG = 0x10, 0x30
SKIN_TPDO1, EMG_TPDO1 = TPDO_BASES[0] + SKIN, TPDO_BASES[0] + EMG
SAMPLE_US = 2_500  # 400 Hz, 3 samples a packet
SYNCED = {
    "skin": {"sdo": {"1800sub2": 1, "2122sub0": 1}},
    "emg": {"sdo": {"1800sub2": 1, "2213sub0": 1}},
}
REST_S = 1.5  # before the slip: the gateway provisions and starts the nodes
ONSET_S = REST_S + 0.3  # slip_recording's own onset


def skin_on_sync(every_packet: bool = True) -> DeviceNode:
    """A skin node, its TPDO1 made synchronous (every SYNC) and started."""
    node = build_node("skin", SKIN, source=ConstantSource(1.0))
    node.start(0)
    node.store.sdo_write(0x1800, 2, bytes([1]))
    node.store.sdo_write(0x2122, 0, bytes([every_packet]))
    node.receive(Frame(NMT_COB_ID, bytes([1, 0])), 0)
    return node


def packets_made_by(t_us: int) -> int:
    """Packets whose last sample (index 3p + 2, at 2.5 ms a sample) is taken by t_us."""
    return (t_us // SAMPLE_US + 1) // 3


def tpdo1_until(node: DeviceNode, t_end_us: int) -> list[Frame]:
    frames = []
    while (due := node.next_deadline_us()) is not None and due <= t_end_us:
        frames += [f for f in node.advance(due) if f.can_id == SKIN_TPDO1]
    return frames


def test_a_skin_on_sync_sends_every_packet_it_made_on_the_sync_in_order():
    node = skin_on_sync()
    assert tpdo1_until(node, 50_000) == []  # sampling on, nothing sent between SYNCs
    burst = node.receive(Frame(SYNC_COB_ID_DEFAULT, b""), 50_000)
    made = packets_made_by(50_000)  # packets ending at 5, 12.5, ... 50 ms
    assert [f.can_id for f in burst] == [SKIN_TPDO1] * made
    sequences = [f.data[-1] for f in burst]
    assert sequences == list(range(sequences[0], sequences[0] + made))
    # the next SYNC carries the packets since, numbered on
    assert tpdo1_until(node, 60_000) == []
    again = node.receive(Frame(SYNC_COB_ID_DEFAULT, b""), 60_000)
    assert [f.data[-1] for f in again] == [sequences[-1] + 1]  # the one ending at 57.5 ms
    assert node.receive(Frame(SYNC_COB_ID_DEFAULT, b""), 60_500) == []  # nothing new: nothing


def test_more_than_the_node_keeps_drops_the_oldest_and_the_numbers_show_the_gap():
    node = skin_on_sync()
    made = packets_made_by(400_000)
    tpdo1_until(node, 400_000)
    burst = node.receive(Frame(SYNC_COB_ID_DEFAULT, b""), 400_000)
    sequences = [f.data[-1] for f in burst]
    assert len(burst) == MAX_OWED_PACKETS and node.pdo.dropped_packets == made - len(burst)
    assert sequences == [(made - len(burst) + 1 + k) & 0xFF for k in range(len(burst))]


def test_without_its_switch_a_synchronous_skin_tpdo_is_cia_301s_one_frame_a_sync():
    node = skin_on_sync(every_packet=False)
    tpdo1_until(node, 50_000)
    burst = node.receive(Frame(SYNC_COB_ID_DEFAULT, b""), 50_000)
    assert [f.data[-1] for f in burst] == [packets_made_by(50_000)]  # the newest packet
    assert len(node.receive(Frame(SYNC_COB_ID_DEFAULT, b""), 50_500)) == 1


def test_event_driven_stays_the_default_one_frame_a_packet():
    node = build_node("skin", SKIN, source=ConstantSource(1.0))
    node.start(0)
    node.receive(Frame(NMT_COB_ID, bytes([1, 0])), 0)
    assert len(tpdo1_until(node, 50_000)) == packets_made_by(50_000)


@pytest.mark.parametrize("role", ["skin", "emg"])
def test_a_synchronous_sample_tpdo_without_a_sync_producer_is_an_error(role):
    with pytest.raises(ConfigError) as caught:
        parse_config({"nodes": {role: SYNCED[role]}}, "gw.toml")
    assert f"gw.toml: nodes.{role}.sdo.1800sub2: transmission type 1" in str(caught.value)
    assert "sync_period_ms" in str(caught.value)


def test_our_skin_on_sync_without_every_packet_is_an_error_naming_the_switch():
    data = {"gateway": {"sync_period_ms": 10}, "nodes": {"skin": {"sdo": {"1800sub2": 1}}}}
    with pytest.raises(ConfigError, match=re.escape("nodes.skin.sdo.1800sub2: transmission")):
        parse_config(data, "gw.toml")
    data["nodes"]["skin"]["sdo"]["2122sub0"] = 1
    assert parse_config(data, "gw.toml").sync_period_us == 10_000


class SlipSource:
    """Rest, then a 60 mm/s slip across alpha0.1 (the FSR model with noise), then rest."""

    def __init__(self) -> None:
        rec = slip_recording(LAYOUTS_MM["alpha0.1"], 60.0, fs_hz=400, seed=3)
        rest = np.full(round(REST_S * 400), rec.force_n[0])
        self.values = np.concatenate([rest, rec.force_n])

    def samples(self, t0_us: int, start_index: int, count: int, rate_hz: int) -> np.ndarray:
        index = np.arange(start_index, start_index + count)
        return self.values[np.minimum(index, len(self.values) - 1)]


class SlippingSet:
    """The gateway and our four nodes in virtual time, the skin slipping once; what went
    on the bus, the decoder's updates, the times the skin's samples were given."""

    def __init__(self, sync_ms: int, seconds: float = 3.5):
        data = {"gateway": {"sync_period_ms": sync_ms}, "nodes": SYNCED} if sync_ms else {}
        self.gateway = gateway = Gateway(parse_config(data, "<test>"))
        config = gateway.config
        sources = {"skin": SlipSource(), "emg": ConstantSource(150.0)}
        nodes = [
            build_node(n.kind, n.node_id, source=sources.get(n.kind)) for n in config.nodes.values()
        ]
        network = LockstepNetwork([gateway, *nodes])
        self.frames: list[tuple[int, int, bytes]] = []
        network.taps.append(lambda t, f, _: self.frames.append((t, f.can_id, bytes(f.data))))
        self.estimates: list = []
        gateway.estimate_listeners.append(lambda t, e: self.estimates.append((t, e)))
        self.sample_times: list[np.ndarray] = []
        skin_frames = gateway.skin_frames
        assert skin_frames is not None
        feed = skin_frames.feed

        def timed(t_us, values, number=None):
            released = feed(t_us, values, number)
            self.sample_times.append(released[0])
            return released

        skin_frames.feed = timed  # type: ignore[method-assign]
        network.start()
        network.run_until(round(seconds * 1e6))

    def at(self, can_id: int) -> list[tuple[int, bytes]]:
        return [(t, d) for t, c, d in self.frames if c == can_id]


@pytest.fixture(scope="module")
def event_driven() -> SlippingSet:
    return SlippingSet(0)


@pytest.mark.parametrize("sync_ms", [10, 20])
def test_batched_per_sync_the_gateway_decodes_the_slip_as_event_driven(sync_ms, event_driven):
    run = SlippingSet(sync_ms)
    gateway, estimates = run.gateway, run.estimates
    syncs = {t for t, _ in run.at(SYNC_COB_ID_DEFAULT)}
    samples = run.at(SKIN_TPDO1)
    # only on SYNC, every packet, numbers intact
    assert samples and all(t in syncs for t, _ in samples)
    assert all(t in syncs for t, _ in run.at(EMG_TPDO1))
    numbers = [d[-1] for _, d in samples]
    assert all((b - a) & 0xFF == 1 for a, b in itertools.pairwise(numbers))
    assert gateway.skin_frames is not None and gateway.skin_frames.stats.lost_packets == 0
    assert gateway.cycles <= len(syncs) < len(samples)
    # a burst's samples keep their own times, one sample period apart
    times = np.concatenate(run.sample_times)
    assert np.allclose(np.diff(times), 1 / 400)

    base_estimates = event_driven.estimates
    speeds = [e.speed_mm_s for _, e in estimates if e.slip and e.speed_mm_s is not None]
    base_speeds = [e.speed_mm_s for _, e in base_estimates if e.slip and e.speed_mm_s]
    assert len(speeds) > 10 and np.median(speeds) == pytest.approx(np.median(base_speeds), rel=0.01)

    def onset(found: list) -> tuple[float, int]:
        """The first slip reported after the onset: its sample time, when the gateway acted."""
        t_us, estimate = next((t, e) for t, e in found if e.slip and e.t_s > ONSET_S)
        return estimate.t_s, t_us

    (sample_s, acted_us), (base_sample_s, base_acted_us) = onset(estimates), onset(base_estimates)
    period_us = sync_ms * 1000
    assert abs(sample_s - base_sample_s) <= period_us / 1e6
    # acted on within a SYNC period of the event-driven gateway, plus one decoder update
    # (10 ms) where the grid's anchor moved the update's phase; never before the update's
    # samples existed. It may act before the event-driven gateway, which acts at its own
    # next cycle after the samples came (s26, the slip flagged from its arrival: the
    # update at 2.13 s acted on at 2.130 s batched, 2.135 s event-driven)
    assert acted_us >= round(sample_s * 1e6)
    assert acted_us - base_acted_us <= period_us + 10_000


def test_a_batched_streams_grid_sits_less_than_a_sync_period_behind_the_nodes_clock():
    frames = SlippingSet(20, seconds=2.0).gateway.skin_frames
    assert frames is not None and frames.anchor_s is not None
    # anchored on the earliest arrival: a packet waits for its SYNC, at most one period
    assert 0 <= frames.anchor_s < 0.020


def test_the_gateway_decodes_and_steps_the_control_once_per_sync_cycle():
    run = SlippingSet(10, seconds=3.0)
    syncs = {t for t, _ in run.at(SYNC_COB_ID_DEFAULT)}
    acted = {t for t, _ in run.estimates}
    # in virtual time the nodes answer at the SYNC's instant, handled there, once
    assert acted and acted <= syncs
    assert len(acted) <= run.gateway.cycles <= len(syncs)


@pytest.mark.slow
def test_live_a_gateway_on_sync_handles_cycles_not_frames():
    """Through real runners on the virtual bus: the nodes answer on SYNC, the gateway
    handles their frames once per cycle (judged by counts, not by timing)."""
    config = parse_config({"gateway": {"sync_period_ms": 10}, "nodes": SYNCED}, "<test>")
    with LiveGateway(f"virtual:sync-{uuid.uuid4().hex[:12]}", config, with_nodes=True) as live:
        gateway = live.gateway
        wait_until(lambda: operational(gateway), 30.0, "every node operational")
        skin, emg = gateway.by_kind["skin"], gateway.by_kind["emg"]
        start = skin.pdos_rx + emg.pdos_rx, gateway.cycles
        wait_until(lambda: gateway.cycles - start[1] >= 100, 60.0, "100 SYNC cycles")
        frames = skin.pdos_rx + emg.pdos_rx - start[0]
        cycles = gateway.cycles - start[1]
        assert frames > cycles  # a cycle carries the skin's 1-2 packets and the envelope
        assert live.failure is None
        assert re.search(r"skin:operational", live.status_line())

"""The skin front end (decoding/packets.py): sample times from the packet sequence (issue 21,
items 2 and 3).

A packet that arrives late - a stalled host and the burst after it, an adapter's
time-stamp jitter - keeps its place on the node's grid; only missing numbers are a
gap; a node restart, a silence, an 8-bit wrap and a crystal's drift are handled
without a reset. The same front end serves `Gateway._on_skin` and `read_can_log`.
"""

from __future__ import annotations

from pathlib import Path

import can
import numpy as np
import pytest

from grasplink.cli import main
from grasplink.core.frames import Frame
from grasplink.decoding import io
from grasplink.decoding.packets import DRIFT_DEADBAND_US, SampleStream
from grasplink.decoding.registry import DEFAULT_DECODER, make_decoder
from grasplink.gateway.config import parse_config
from grasplink.gateway.service import Gateway
from grasplink.profiles.layouts import LAYOUTS_MM
from tests.decoding.test_decode_cli import skin_frames, write_log

ROOT = Path(__file__).resolve().parents[2]
HEADLINE = ROOT / "scenes" / "loop_headline.toml"
SKIN_ID = 0x190
RATE = 400.0
PACKET_US = 7_500  # 3 samples at 400 Hz


def grid(n_packets: int, t0_us: float = 1_000_000.0) -> np.ndarray:
    """Arrival of packet k exactly when its last sample was taken."""
    return t0_us + (np.arange(n_packets) * 3 + 2) * 1e6 / RATE


def run(stream: SampleStream, arrivals, sequences, values=None):
    """Feed packets; the sample times and values given out, and the stream flushed."""
    times, out = [], []
    for k, (t_us, seq) in enumerate(zip(arrivals, sequences, strict=True)):
        v = np.full(3, float(k)) if values is None else values[k]
        t, x = stream.feed(float(t_us), None if seq is None else int(seq), v)
        times.append(t)
        out.append(x)
    t, x = stream.flush()
    return np.concatenate([*times, t]), np.concatenate([*out, x])


def stalled(arrivals: np.ndarray, start: int, stall_us: float) -> np.ndarray:
    """Packets from `start` on held up to `stall_us` by a stalled host, then a burst."""
    late = arrivals.copy()
    release = arrivals[start] + stall_us
    late[start:] = np.maximum(late[start:], release)
    return late


# -- the stream -----------------------------------------------------------------------------
def test_a_packet_late_by_up_to_the_consumer_time_keeps_its_place():
    arrivals = grid(200)
    seq = (np.arange(200) + 1) % 256
    clean_t, clean_x = run(SampleStream(RATE, 3), arrivals, seq)
    stream = SampleStream(RATE, 3, late_us=300_000)
    late_t, late_x = run(stream, stalled(arrivals, 50, 290_000), seq)
    np.testing.assert_array_equal(late_t, clean_t)
    np.testing.assert_array_equal(late_x, clean_x)
    assert stream.stats.resyncs == stream.stats.lost_packets == 0
    assert np.all(np.diff(late_t) == pytest.approx(1 / RATE))


def test_only_missing_numbers_are_a_gap_even_inside_a_late_burst():
    arrivals = grid(200)
    seq = (np.arange(200) + 1) % 256
    kept = np.ones(200, dtype=bool)
    kept[[60, 61]] = False  # two packets lost while the host stalled
    stream = SampleStream(RATE, 3)
    t, _ = run(stream, stalled(arrivals, 50, 200_000)[kept], seq[kept])
    assert stream.stats.lost_packets == 2 and stream.stats.resyncs == 0
    steps = np.round(np.diff(t) * RATE).astype(int)
    assert sorted(set(steps.tolist())) == [1, 7]  # one hole of 6 samples, the rest on the grid
    decoder = make_decoder("ratio", LAYOUTS_MM["alpha0.1"], RATE)
    decoder.feed(t, np.full(len(t), 2.0))
    assert decoder.stats.gaps == 0  # two packets are bridged (base.GAP_PERIODS)


def test_a_late_burst_across_the_wrap_of_the_sequence_byte():
    arrivals = grid(600)
    seq = (np.arange(600) + 200) % 256  # wraps at packets 56, 312 and 568
    stream = SampleStream(RATE, 3)
    t, _ = run(stream, stalled(arrivals, 300, 250_000), seq)
    assert stream.stats.resyncs == stream.stats.lost_packets == 0
    assert len(t) == 1800 and np.allclose(np.diff(t), 1 / RATE)


def test_a_stall_longer_than_half_a_wrap_is_not_read_as_a_wrap():
    """1 kHz, one sample a packet: 256 packets wrap in 256 ms; a 200 ms stall is a delay."""
    n = 1000
    arrivals = 1_000_000.0 + np.arange(n) * 1000.0
    seq = (np.arange(n) + 1) % 256
    stream = SampleStream(1000, 1, late_us=300_000)
    t, _ = run(stream, stalled(arrivals, 400, 200_000), seq, values=[np.ones(1)] * n)
    assert stream.stats.resyncs == stream.stats.lost_packets == 0
    assert len(t) == n and np.allclose(np.diff(t), 1e-3)


def test_a_node_restart_starts_a_new_anchor_at_its_own_phase():
    """The node reboots: numbers start again at 1 on a new sample grid (1.1 ms off the old),
    and the host stalls 200 ms soon after: one new anchor, no other."""
    before = grid(100)
    after = before[-1] + 151_100 + np.arange(100) * PACKET_US
    seq = np.concatenate([(np.arange(100) + 1) % 256, (np.arange(100) + 1) % 256])
    stream = SampleStream(RATE, 3)
    t, _ = run(stream, stalled(np.concatenate([before, after]), 150, 200_000), seq)
    assert stream.stats.resyncs == 1 and stream.stats.lost_packets == 0
    assert len(t) == 600 and np.all(np.diff(t) > 0)
    # the new grid from the new stream's arrivals, to the nearest sample period
    np.testing.assert_allclose(t[300:][2::3], after / 1e6, atol=0.5 / RATE)


def test_a_packet_off_the_grid_that_nothing_follows_is_a_stray():
    arrivals = grid(100)
    seq = (np.arange(100) + 1) % 256
    arrivals[40] += 2_000_000  # one frame stamped 2 s off (a broken log, a bad clock read)
    stream = SampleStream(RATE, 3)
    t, _ = run(stream, arrivals, seq)
    assert stream.stats.stray_packets == 1 and stream.stats.resyncs == 0
    assert stream.stats.lost_packets == 1 and len(t) == 3 * 99


@pytest.mark.parametrize("drift_ppm", [100.0, -100.0])
def test_a_crystal_drifting_100_ppm_for_ten_minutes_never_resets(drift_ppm):
    """80,000 packets (10 min) from a node whose clock runs 100 ppm fast or slow, with
    0-4 ms of arrival jitter and a 250 ms stall every minute."""
    rng = np.random.default_rng(3)
    n = 80_000
    node_us = grid(n) * (1 + drift_ppm * 1e-6)  # the node's grid, seen by our clock
    arrivals = node_us + rng.uniform(0, 4000, n)
    for start in range(8000, n, 8000):
        arrivals = stalled(arrivals, start, 250_000)
    seq = (np.arange(n) + 1) % 256
    stream = SampleStream(RATE, 3, late_us=300_000)
    t, _ = run(stream, arrivals, seq, values=[np.zeros(3)] * n)
    assert stream.stats.resyncs == stream.stats.lost_packets == 0
    assert len(t) == 3 * n
    # slewed by at most 500 ppm of the time elapsed, never jumped
    packet_spacing = np.diff(t[2::3]) * RATE / 3
    assert np.abs(packet_spacing - 1).max() < 600e-6
    # the grid follows the node's clock: within the deadband (+ jitter) of its samples
    error_us = t[2::3] * 1e6 - node_us
    assert np.abs(error_us - error_us[0]).max() < DRIFT_DEADBAND_US + 4000
    assert abs(stream.stats.slewed_us) > 40_000  # it did follow: 60 ms over 10 minutes


# -- offline: CAN logs ------------------------------------------------------------------------
@pytest.fixture(scope="module")
def headline(tmp_path_factory) -> list[can.Message]:
    out = tmp_path_factory.mktemp("headline")
    assert main(["run", str(HEADLINE), "--out", str(out)]) == 0
    return list(can.LogReader(str(out / "can.asc")))


def jittered(frames: list[can.Message], seed: int) -> list[can.Message]:
    """0-4 ms uniform added to every time stamp but the first (the log's start, its time
    origin), order kept: as a USB-CAN adapter or a loaded host stamps frames."""
    rng = np.random.default_rng(seed)
    out, last = [], frames[0].timestamp
    for k, m in enumerate(frames):
        stamp = m.timestamp if k == 0 else max(last, m.timestamp + rng.uniform(0, 0.004))
        last = stamp
        out.append(
            can.Message(
                timestamp=stamp,
                arbitration_id=m.arbitration_id,
                data=m.data,
                is_extended_id=m.is_extended_id,
                is_remote_frame=m.is_remote_frame,
                is_error_frame=m.is_error_frame,
            )
        )
    return out


def decode_all(t: np.ndarray, x: np.ndarray) -> list:
    decoder = make_decoder(DEFAULT_DECODER, LAYOUTS_MM["alpha0.1"], RATE)
    return [
        e
        for start in range(0, len(t), 3)
        for e in decoder.feed(t[start : start + 3], x[start : start + 3])
    ]


def shown_speed(estimate) -> float | None:
    """The estimate's speed, else the floor of its range (what the belt shows)."""
    return estimate.speed_low_mm_s if estimate.speed_mm_s is None else estimate.speed_mm_s


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_jittered_log_decodes_to_the_same_samples_and_slips(tmp_path, headline, seed):
    t0, x0, clean = io.read_can_log(write_log(tmp_path / "clean.asc", headline))
    t, x, stats = io.read_can_log(write_log(tmp_path / "jitter.asc", jittered(headline, seed)))
    assert stats.packets == stats.frames == clean.packets == 800
    assert stats.dropped == stats.lost_packets == stats.resyncs == 0
    np.testing.assert_array_equal(t, t0)
    np.testing.assert_array_equal(x, x0)
    estimates, reference = decode_all(t, x), decode_all(t0, x0)
    assert estimates == reference
    # the reflex stops the headline slip after two ridge contacts: ~0.4 s with a speed or,
    # where two contacts leave it open on alpha0.1, the range's floor (what the belt shows)
    assert sum(e.slip and shown_speed(e) is not None for e in estimates) >= 30


def test_a_boot_up_in_the_log_starts_the_samples_anew(tmp_path):
    """A reboot whose new numbers happen to fit the old grid is still a reboot: the node's
    boot-up message says so, and the new samples take their own time stamps' phase."""
    first = [m for m in skin_frames((np.arange(300) * 7) % 4096) if m.arbitration_id == SKIN_ID]
    # the node reboots; its packet 1 arrives when packet 100 + 56 would have, 6 ms off
    shift = first[-1].timestamp + 57 * PACKET_US / 1e6 - first[0].timestamp + 0.006
    second = [
        can.Message(
            timestamp=m.timestamp + shift, arbitration_id=SKIN_ID, data=m.data, is_extended_id=False
        )
        for m in first
    ]
    boot = can.Message(
        timestamp=second[0].timestamp - 0.1,
        arbitration_id=0x710,
        data=b"\x00",
        is_extended_id=False,
    )
    t, _, stats = io.read_can_log(write_log(tmp_path / "reboot.asc", [*first, boot, *second]))
    assert stats.restarts == 1 and stats.lost_packets == 0 and stats.resyncs == 0
    assert len(t) == 600
    # a log's times start at its first frame; the new grid is the new frames' own
    stamps = np.array([m.timestamp for m in second]) - first[0].timestamp + t[2]
    np.testing.assert_allclose(t[300:][2::3], stamps, atol=0.5 / RATE)
    assert "1 node restarts (boot-up)" in stats.summary("reboot.asc")


def test_a_re_publish_is_told_by_its_number_not_its_spacing(tmp_path):
    """A node entering OPERATIONAL publishes the packet it sampled last but never sent
    (a new number, sent early) and later its current one again (the same number)."""
    frames = [m for m in skin_frames((np.arange(300) * 7) % 4096) if m.arbitration_id == SKIN_ID]
    early = frames[40]
    frames[40] = can.Message(  # sent at START, 5 ms before its time: its samples are real
        timestamp=early.timestamp - 0.005,
        arbitration_id=SKIN_ID,
        data=early.data,
        is_extended_id=False,
    )
    again = can.Message(
        timestamp=frames[70].timestamp + 0.001,
        arbitration_id=SKIN_ID,
        data=frames[70].data,
        is_extended_id=False,
    )
    frames.insert(71, again)
    t, _, stats = io.read_can_log(write_log(tmp_path / "start.asc", frames))
    assert stats.republished == 1 and stats.packets == 100 and stats.lost_packets == 0
    assert len(t) == 300 and np.allclose(np.diff(t), 1 / RATE)


# -- live: the gateway in virtual time ---------------------------------------------------------
def test_the_gateway_keeps_its_decoder_through_a_stall_and_a_burst(headline):
    """The headline's skin TPDOs fed to a gateway as a loaded host delivers them: a 200 ms
    stall (under the 300 ms heartbeat consumer time) every half second, then the burst.
    The decoder is never reset and reports the slip as when the frames come on time."""
    skin = [m for m in headline if m.arbitration_id == SKIN_ID]
    on_time = np.array([m.timestamp * 1e6 for m in skin])
    late = on_time.copy()
    for start_us in np.arange(1_000_000, on_time[-1], 500_000):
        start = int(np.searchsorted(on_time, start_us))
        late = stalled(late, start, 200_000)

    def feed(arrivals: np.ndarray) -> tuple[Gateway, list]:
        config = parse_config({"nodes": {"skin": {"layout": "alpha0.1"}}}, "<test>")
        gateway = Gateway(config)
        estimates: list = []
        gateway.estimate_listeners.append(lambda t_us, e: estimates.append(e))
        gateway.start(0)
        for m, t_us in zip(skin, arrivals, strict=True):
            gateway.receive(Frame(m.arbitration_id, bytes(m.data)), int(t_us))
        return gateway, estimates

    gateway, estimates = feed(late)
    _, reference = feed(on_time)
    assert gateway.decoder is not None and gateway.decoder.stats.gaps == 0
    assert gateway.skin_frames is not None and gateway.skin_frames.stats.resyncs == 0
    assert estimates == reference
    # the reflex stops the headline slip after two ridge contacts: ~0.4 s with a speed or,
    # where two contacts leave it open on alpha0.1, the range's floor (what the belt shows)
    assert sum(e.slip and shown_speed(e) is not None for e in estimates) >= 30

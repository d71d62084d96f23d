"""Gateway building blocks: configuration, provisioning, sample streams, EMG intent, drives."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.decoding.packets import SampleStream
from grasplink.devices.cia402 import DriveState
from grasplink.devices.factory import build_node
from grasplink.errors import ConfigError
from grasplink.gateway.config import load_config, parse_config
from grasplink.gateway.drives import DriveHandshake
from grasplink.gateway.emg import CalibrationRecorder, EmgCalibration, EmgIntentDecoder
from grasplink.gateway.provisioning import Provisioner
from grasplink.gateway.sdo_client import SdoClient
from grasplink.profiles import objects as obj
from tests.gateway.test_sdo_client import ClientDevice

# -- configuration -----------------------------------------------------------------------------


def test_defaults_master_all_four_nodes_at_their_profile_ids():
    config = load_config(None)
    assert {k: n.node_id for k, n in config.nodes.items()} == obj.DEFAULT_NODE_IDS


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"nodes": {"emg": {"window_ms": 90}}}, "nodes.emg.window_ms"),
        ({"nodes": {"emg": {"e_min_uv": 500, "e_max_uv": 500}}}, "nodes.emg.e_max_uv"),
        ({"nodes": {"skin": {"layout": "1e300,1"}}}, "nodes.skin.layout"),
        ({"nodes": {"skin": {"sample_rate_hz": 5000}}}, "nodes.skin.sample_rate_hz"),
        ({"nodes": {"belt": {"node_id": 0x10}}}, "already used by skin"),
        ({"nodes": {"hand": {"crush_limit_n": 1e9}}}, "nodes.hand.crush_limit_n"),
        ({"nodes": {"arm": {}}}, "nodes.arm"),
        ({"gateway": {"heartbeat": 100}}, "gateway.heartbeat"),
        ({"feedback": {"mode": "loud"}}, "feedback.mode"),
    ],
)
def test_config_error_names_the_key(data, message):
    with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
        parse_config(data, "gw.toml")


def test_config_file_that_is_not_toml_is_a_one_line_error(tmp_path):
    path = tmp_path / "gw.toml"
    path.write_bytes(b"\xff\xfe[gateway")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(path)


# -- provisioning -------------------------------------------------------------------------------


@pytest.mark.parametrize("kind", ["skin", "emg", "belt", "hand"])
def test_every_provisioning_write_is_accepted_by_the_node(kind):
    config = parse_config(
        {
            "nodes": {
                "skin": {"layout": "4,4,4,4,4", "sample_rate_hz": 500},
                "emg": {"e_min_uv": 600, "e_max_uv": 900, "window_ms": 180},
                "hand": {"crush_limit_n": 30},
            }
        },
        "gw.toml",
    )
    node_config = config.nodes[kind]
    node = build_node(kind, node_config.node_id)
    client = SdoClient(node_config.node_id)
    net = LockstepNetwork([ClientDevice(client), node])
    net.start()
    writes = Provisioner(node_config, config).writes()
    transfers = [client.download(w.index, w.subindex, w.data) for w in writes]
    net.run_until(2_000_000)
    refused = [(w.what, t.describe()) for w, t in zip(writes, transfers, strict=True) if not t.ok]
    assert refused == []
    store = node.store
    assert store.get(obj.HEARTBEAT_CONSUMER, 1) >> 16 == config.node_id
    if kind == "skin":
        assert store.get(obj.SKIN_SAMPLE_RATE_HZ) == 500
        assert store.get(obj.SKIN_RIDGE_SPACING_UM, 0) == 5
    if kind == "emg":
        assert (store.get(obj.EMG_CALIBRATION, 1), store.get(obj.EMG_CALIBRATION, 2)) == (600, 900)
    if kind == "hand":
        assert store.get(obj.HAND_CRUSH_LIMIT_MN) == 30_000


# -- sample streams -------------------------------------------------------------------------------


def test_stream_times_samples_on_the_node_grid_and_skips_lost_packets():
    stream = SampleStream(400, 3)
    t0, _ = stream.feed(10_000, 0, np.ones(3))
    # packet 1 lost; packet 2 arrives two packet periods (15 ms) later
    t2, _ = stream.feed(25_000, 2, np.ones(3))
    assert np.allclose(np.diff(t0), 1 / 400)
    assert t2[0] - t0[-1] == pytest.approx(4 / 400)
    assert stream.stats.lost_packets == 1


def test_stream_repeated_packet_gives_no_samples_and_a_late_one_resyncs():
    stream = SampleStream(400, 3)
    stream.feed(10_000, 5, np.ones(3))
    times, _ = stream.feed(11_000, 5, np.ones(3))
    assert len(times) == 0 and stream.stats.repeated_packets == 1
    times, _ = stream.feed(5_000_000, 6, np.ones(3))  # 5 s later: the node restarted or stalled
    assert len(times) == 0  # one packet off the grid: a stray, or a new stream's first?
    times, _ = stream.feed(5_007_500, 7, np.ones(3))  # the next follows it: a new stream
    assert stream.stats.resyncs == 1
    assert times[2] == pytest.approx(5.0) and times[-1] == pytest.approx(5.0075)


def test_stream_sequence_wraps():
    stream = SampleStream(400, 3)
    stream.feed(0, 255, np.ones(3))
    stream.feed(7_500, 0, np.ones(3))
    assert stream.stats.lost_packets == 0 and stream.stats.resyncs == 0


# -- EMG intent ---------------------------------------------------------------------------


def test_levels_split_the_calibrated_range_into_four():
    cal = EmgCalibration(100.0, 500.0)
    levels = [cal.level(e) for e in (0, 99, 100, 199, 200, 499.9, 500, 501, math.nan)]
    assert levels == [0, 0, 1, 1, 2, 4, 4, 5, 0]


@pytest.mark.parametrize(("e_min", "e_max"), [(500, 500), (500, 100), (-1, 10), (0, math.inf)])
def test_degenerate_calibration_is_refused(e_min, e_max):
    with pytest.raises(ConfigError):
        EmgCalibration(e_min, e_max)


def test_proportional_grip_is_clipped_and_stable_on_bad_input():
    decoder = EmgIntentDecoder(EmgCalibration(100, 300), mode="proportional", grip_max_n=10)
    grips = [decoder.update(0, e).grip_n for e in (0, 100, 200, 300, 65535)]
    assert grips == [0.0, 0.0, 5.0, 10.0, 10.0]
    assert decoder.update(0, math.nan) is None and decoder.update(0, -5) is None
    assert decoder.rejected_updates == 2
    assert decoder.saturated_updates == 1


def test_calibration_phase_sets_e_min_above_rest_and_e_max_at_the_maximum():
    rng = np.random.default_rng(1)
    recorder = CalibrationRecorder()
    recorder.begin("rest")
    for e in rng.normal(20, 3, 200):
        recorder.add(e)
    recorder.begin("maximum")
    for e in rng.normal(400, 20, 200):
        recorder.add(e)
    cal = recorder.result()
    assert 23 < cal.e_min_uv < 30 and 380 < cal.e_max_uv < 420


@pytest.mark.parametrize(
    ("rest", "top", "message"),
    [(0.0, 0.0, "flat EMG"), (300.0, 200.0, "not above rest"), (10.0, 65535.0, "saturates")],
)
def test_calibration_that_cannot_separate_rest_from_effort_is_refused(rest, top, message):
    recorder = CalibrationRecorder()
    recorder.begin("rest")
    for _ in range(50):
        recorder.add(rest)
    recorder.begin("maximum")
    for _ in range(50):
        recorder.add(top)
    with pytest.raises(ConfigError, match=message):
        recorder.result()


# -- CiA 402 handshake --------------------------------------------------------------------


def test_handshake_walks_the_drive_to_operation_enabled_from_its_statusword():
    drive = DriveHandshake()
    assert drive.controlword() == 0x06  # blind start: every drive boots SWITCH ON DISABLED
    for statusword, expected in ((0x0250, 0x06), (0x0231, 0x07), (0x0233, 0x0F), (0x0237, 0x0F)):
        drive.on_statusword(statusword)
        assert drive.controlword() == expected
    assert drive.enabled
    drive.on_statusword(0x0217)  # quick stop active (safe state)
    assert drive.state is DriveState.QUICK_STOP_ACTIVE and drive.controlword() == 0x00
    drive.on_statusword(0x0208)
    assert drive.controlword() == 0x80
    drive.reset()  # the drive rebooted: the walk starts blind again
    assert drive.state is None and drive.controlword() == 0x06


def test_configuration_reference_in_the_docs_is_the_defaults():
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "docs" / "gateway.md").read_text()
    section = text.split("\n## Configuration\n", 1)[1]  # the reference, not the examples
    block = section.split("```toml\n", 1)[1].split("```", 1)[0]
    documented = parse_config(tomllib.loads(block), "docs/gateway.md")
    defaults = load_config(None)
    documented.source = defaults.source
    assert documented == defaults


@pytest.mark.parametrize(("envelope", "why"), [(0.0, "flat"), (65535.0, "saturated")])
def test_flat_or_saturated_emg_is_a_fault_after_half_a_second(envelope, why):
    decoder = EmgIntentDecoder(EmgCalibration(50, 500))
    decoder.update(0, 30.0)
    assert decoder.fault(0) is None
    for t_ms in range(0, 700, 10):
        decoder.update(1_000_000 + t_ms * 1000, envelope)
    assert decoder.fault(1_400_000) is None
    assert why in decoder.fault(1_600_000)
    decoder.update(1_700_000, 30.0)
    assert decoder.fault(1_700_000) is None

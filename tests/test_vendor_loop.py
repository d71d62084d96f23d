"""The closed loop with vendors' modules in it (issue 24): the FSR on a CiA 401 analogue
module sampled on SYNC, the hand a CiA 402 drive configured by its DCF.

scenes/loop_vendor_modules.toml wires the headline physics to files other projects wrote
(scenes/devices/README.md); the gateway masters them from its description only.
"""

from __future__ import annotations

import itertools
import tomllib
from pathlib import Path

import numpy as np
import pytest

from grasplink.controllers import build_controllers
from grasplink.core.frames import SYNC_COB_ID_DEFAULT, Frame
from grasplink.core.params import SceneError
from grasplink.devices.cia402 import DriveState
from grasplink.errors import ConfigError
from grasplink.evaluation.hil import judge_recording
from grasplink.gateway.config import parse_config
from grasplink.gateway.sync import SyncNumbers
from grasplink.simulators import signals as sig
from grasplink.simulators.engine import Simulation
from grasplink.simulators.plots import read_csv
from grasplink.simulators.recording import Recorder
from grasplink.simulators.scene import parse_scene

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "loop_vendor_modules.toml"
FSR_TPDO2 = 0x280 + 0x10  # the module's analogue inputs (TPDO2) at the skin's node-ID
HAND_RPDO2 = 0x300 + 0x40  # the drive's RPDO2 as its DCF maps it: 6071h, 6040h
SLIP_ONSET_S = 1.0
SKIN_LENGTH_MM = 84.0  # alpha0.1


def scene_data(**head) -> dict:
    data = tomllib.loads(SCENE.read_text())
    data["scene"].update(head)
    return data


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """The scene, 3 s (the slip and its end), recorded; every frame with its time."""
    out = tmp_path_factory.mktemp("vendor_loop")
    scene = parse_scene(scene_data(duration_s=3.0), str(SCENE))
    sim = Simulation(scene, Recorder(out), controllers=build_controllers(scene))
    frames: list[tuple[int, Frame]] = []
    sim.network.taps.append(lambda t_us, frame, sender: frames.append((t_us, frame)))
    sim.run()
    return sim, frames, out


def test_the_module_answers_every_sync_with_the_fsr_input_the_physics_made(run):
    _sim, frames, out = run
    ids = [f.can_id for _, f in frames]
    first = ids.index(FSR_TPDO2)
    syncs = [i for i, can_id in enumerate(ids) if can_id == SYNC_COB_ID_DEFAULT and i > first]
    assert len(syncs) > 800  # 2.5 ms SYNC
    for a, b in itertools.pairwise(syncs):
        assert ids[a:b].count(FSR_TPDO2) == 1
    # its input 1 (INTEGER16, 1 mN a count) reads the FSR force of that moment
    skin = read_csv(out / "skin.csv", (sig.SKIN_FORCE_N,))
    times_s = np.array([t / 1e6 for t, f in frames if f.can_id == FSR_TPDO2])
    read_n = np.array(
        [
            int.from_bytes(f.data[:2], "little", signed=True) / 1000
            for _, f in frames
            if f.can_id == FSR_TPDO2
        ]
    )
    truth_n = np.interp(times_s, skin["t_s"], skin[sig.SKIN_FORCE_N])
    # within one 2.5 ms conversion of the truth: the force moves < 0.1 N in that time
    assert np.median(np.abs(read_n - truth_n)) < 0.02
    assert np.max(np.abs(read_n - truth_n)) < 0.5


def test_the_drive_is_enabled_in_torque_mode_and_told_the_grip_in_its_units(run):
    sim, frames, _ = run
    hand = sim.nodes["hand"]
    assert hand.app.drive.state is DriveState.OPERATION_ENABLED
    assert int(hand.store.get(0x6061)) == 4  # profile torque, from its DCF
    told = [
        (t / 1e6, int.from_bytes(f.data[:2], "little", signed=True) / 10.0)
        for t, f in frames
        if f.can_id == HAND_RPDO2
    ]
    before = [n for t, n in told if t < SLIP_ONSET_S]
    after = [n for t, n in told if t > SLIP_ONSET_S]
    assert before and max(before) == pytest.approx(5.0)  # the held grip, 10 units a N
    assert max(after) >= 8.0  # raised by the slip: the reflex and the wearer


def test_the_slip_is_stopped_before_the_object_leaves_the_skin(run):
    _, _, out = run
    truth = read_csv(out / "truth.csv", (sig.OBJECT_SLIPPING, sig.OBJECT_POSITION_MM))
    slipping = truth["t_s"][truth[sig.OBJECT_SLIPPING] > 0]
    assert slipping[0] == pytest.approx(SLIP_ONSET_S, abs=0.01)
    assert slipping[-1] < 2.2  # held within 1.2 s
    assert truth[sig.OBJECT_POSITION_MM][-1] < SKIN_LENGTH_MM - 40


@pytest.mark.parametrize(
    ("table", "edit", "needle"),
    [
        ("skin", {"input": {"object": "6401sub20", "units_per_n": 1.0}}, "no sub-index 32"),
        ("skin", {"input": {"object": "6401sub1"}}, "nodes.skin.input.units_per_n"),
        ("skin", {"samples_per_pdo": 3}, "a module's input carries one value"),
        ("hand", {"eds": "devices/canopendemo_demoDevice.eds", "dcf": None}, "no CiA 402 drive"),
        (
            "hand",
            {"drive": {"target": "6071sub0", "actual": "60FEsub7", "units_per_n": 1}},
            "nodes.hand.drive.actual",
        ),
        ("emg", {"eds": "devices/canopendemo_demoDevice.eds"}, "vendor's emg node is not"),
        ("belt", {"drive": {"target": "60FFsub0"}}, "give its file"),
    ],
)
def test_a_vendors_node_wired_wrong_is_refused_naming_file_and_key(table, edit, needle):
    data = scene_data()
    node = data["nodes"][table]
    for key, value in edit.items():
        if value is None:
            node.pop(key, None)
        else:
            node[key] = value
    with pytest.raises(SceneError, match=needle) as caught:
        parse_scene(data, str(SCENE))
    assert "loop_vendor_modules.toml" in str(caught.value)


# -- samples numbered by the SYNC they answer -----------------------------------------------
def test_a_reply_late_by_up_to_a_period_keeps_the_number_of_its_sync():
    numbers = SyncNumbers()
    got = []
    for index in range(6):
        numbers.sent(index)
        if index % 2:  # every other reply comes after the next SYNC went out
            continue
        got.append(numbers.answer())
        if index:
            got.append(numbers.answer())  # the late one, then its successor
    numbers.sent(6)
    got.append(numbers.answer())
    got.append(numbers.answer())
    assert got == [0, 1, 2, 3, 4, 5, 6]


def test_periods_a_stalled_host_skipped_leave_a_gap_and_an_extra_reply_repeats():
    numbers = SyncNumbers()
    numbers.sent(0)
    assert numbers.answer() == 0
    numbers.sent(7)  # the host stalled: SYNCs 1-6 never went out
    assert numbers.answer() == 7  # not squeezed in after 0
    assert numbers.answer() == 7  # a reply to no SYNC: a repeat, dropped by the stream


def test_every_nth_sync_numbers_the_replies_consecutively():
    numbers = SyncNumbers(every=4)
    answers = []
    for index in range(16):
        numbers.sent(index)
        if index % 4 == 1:  # the node's phase within the four is its own
            answers.append(numbers.answer())
    assert answers == [0, 1, 2, 3]


def config_data(**skin) -> dict:
    data = scene_data()["controller"]
    data = {k: v for k, v in data.items() if k != "type"}
    data["nodes"]["skin"] |= {"layout": "alpha0.1", "sample_rate_hz": 400} | skin
    return data


def test_samples_on_sync_are_numbered_by_it_and_need_a_producer_at_their_rate():
    config = parse_config(config_data(), str(SCENE))
    assert config.nodes["skin"].binding.sync_every == 1
    without = config_data()
    without["gateway"] = {}
    with pytest.raises(ConfigError, match=r"nodes\.skin\.samples: .*produces none"):
        parse_config(without, str(SCENE))
    with pytest.raises(ConfigError, match=r"nodes\.skin\.sample_rate_hz: 200 Hz.*400 Hz"):
        parse_config(config_data(sample_rate_hz=200), str(SCENE))
    event = config_data()
    event["nodes"]["skin"]["sdo"] = {"1801sub2": 255}
    assert parse_config(event, str(SCENE)).nodes["skin"].binding.sync_every == 0


def test_the_loop_loses_and_repeats_no_sample_on_the_virtual_bus(run):
    sim, _, _ = run
    gateway = sim.controllers[0]
    stats = gateway.skin_frames.stats
    assert stats.packets > 800
    assert (stats.lost_packets, stats.repeated_packets, stats.resyncs) == (0, 0, 0)


def test_the_recording_is_judged_through_the_vendors_drive_units(run):
    """The HIL judgement reads the hand's commands as the description binds them: the
    drive's RPDO2, 10 units a newton (before: our hand's RPDO1, so no reflex at all)."""
    _, _, out = run
    outcome = judge_recording(out)
    assert outcome.stopped and not outcome.dropped
    assert outcome.reflex_latency_s is not None and outcome.reflex_latency_s < 1.0
    assert outcome.slip_belt_latency_s is not None

"""The gateway in the loop, in virtual time: provisioning, control on the bus, degraded states."""

from __future__ import annotations

import logging
import tomllib
from pathlib import Path

import numpy as np
import pytest

from grasplink import cli
from grasplink.controllers import simulation
from grasplink.core.frames import RPDO_BASES, TPDO_BASES, Frame
from grasplink.devices.sdo_abort import AbortCode, SdoAbort
from grasplink.errors import ConfigError
from grasplink.gateway.snapshot import NodePhase
from grasplink.profiles import objects as obj
from grasplink.profiles.pdo_codec import PdoCodec
from grasplink.simulators.scene import parse_scene

ROOT = Path(__file__).resolve().parents[2]
SKIN, BELT, HAND = 0x10, 0x20, 0x40
BELT_RPDO, HAND_RPDO = RPDO_BASES[0] + BELT, RPDO_BASES[0] + HAND

SLIP_SCENE = """
[scene]
duration_s = {duration}
chunk_ms = 10
[nodes.skin]
layout = "alpha0.1"
[nodes.belt]
[nodes.hand]
[controller]
type = "gateway"
{controller}
[[effects]]
type = "hand.actuator"
initial_n = 5.0
[[effects]]
type = "load.scripted"
mass_kg = 0.2
[[effects]]
type = "object.scripted"
speed_mm_s = [[0.0, 0.0], [0.5, 0.0], [0.6, 40.0]]
start_mm = -8.0
[[effects]]
type = "skin.fsr"
[[effects]]
type = "skin.ridge_contacts"
[[effects]]
type = "noise.white"
std = 0.02
[[effects]]
type = "belt.motor"
{extra}
"""


def scene(duration: float = 2.5, controller: str = "", extra: str = ""):
    text = SLIP_SCENE.format(duration=duration, controller=controller, extra=extra)
    return parse_scene(tomllib.loads(text), "test.toml")


def run(sc):
    """Run a scene; returns (simulation, gateway, [(t_us, frame)] sent on the bus)."""
    sim = simulation(sc)
    frames: list[tuple[int, Frame]] = []
    sim.network.taps.append(lambda t_us, frame, sender: frames.append((t_us, frame)))
    sim.run()
    return sim, sim.controllers[0], frames


def belt_velocities(frames) -> list[tuple[int, int]]:
    """(t_us, target velocity) of every belt RPDO1, unpacked as the belt's EDS maps it."""
    rpdo = PdoCodec("belt", BELT).rpdo(1)
    target = next(v for v in rpdo.map if v.od.index == obj.BELT_TARGET_VELOCITY_MRAD_S)
    out = []
    for t, f in frames:
        if f.can_id == BELT_RPDO:
            rpdo.data = bytearray(f.data)
            out.append((t, int(target.raw)))
    return out


def test_gateway_provisions_and_starts_every_node_of_the_scene():
    sim, gateway, _ = run(scene(duration=1.0))
    assert {k: n.state.name for k, n in sim.nodes.items()} == dict.fromkeys(
        ("skin", "belt", "hand"), "OPERATIONAL"
    )
    assert {link.kind: link.phase for link in gateway.links.values()} == dict.fromkeys(
        ("skin", "belt", "hand"), "operational"
    )
    skin = sim.nodes["skin"].store
    assert skin.get(obj.HEARTBEAT_CONSUMER, 1) >> 16 == gateway.node_id
    assert gateway.alarms == {}


def test_belt_rpdo_turns_the_slip_belt_once_the_object_slips():
    _, gateway, frames = run(scene())
    velocities = belt_velocities(frames)
    onset_us = 750_000  # the leading edge reaches the first ridge
    before = [v for t, v in velocities if t < onset_us]
    after = [v for t, v in velocities if t > onset_us + 800_000]
    assert before and all(v >= 0 for v in before), "no slip shown before the slip"
    assert after and all(v < 0 for v in after), "the slip belt runs while it slips"
    assert gateway.last_estimate is not None and gateway.last_estimate.slip


def test_lost_skin_stops_the_belt_holds_the_hand_and_recovers():
    power = (
        '[[effects]]\ntype = "bus.faults"\n'
        'power_loss = [{ node = "skin", at_s = 1.5, restore_s = 2.5 }]'
    )
    sim, gateway, frames = run(scene(duration=4.0, extra=power))
    consumer_us = gateway.node_heartbeat_us * 3
    velocities = belt_velocities(frames)
    stopped = [t for t, v in velocities if t > 1_500_000 and v == 0]
    assert stopped and stopped[0] <= 1_500_000 + consumer_us + 100_000
    hand = [(t, f.data) for t, f in frames if f.can_id == HAND_RPDO]
    during = {data[2:] for t, data in hand if 1_500_000 + consumer_us + 100_000 < t < 2_500_000}
    assert len(during) <= 1, "the hand's grip command is held while the skin is lost"
    assert gateway.by_kind["skin"].phase == "operational", "back after it boots again"
    assert sim.nodes["skin"].state.name == "OPERATIONAL"
    assert "skin.lost" not in gateway.alarms


def test_a_sensing_node_lost_while_the_grip_ramps_holds_the_grip_and_time_goes_on():
    """The EMG node loses power while the hand's grip is on its slew-limited way: the grip
    is held where the ramp was, and the ramp stops there (before, its next step stayed due
    for ever: the lock-step network stopped, "devices make no progress")."""
    text = (ROOT / "scenes" / "loop_headline.toml").read_text() + (
        '\n[[effects]]\ntype = "bus.faults"\n'
        'power_loss = [{ node = "emg", at_s = 4.0, restore_s = 4.8 }]\n'
    )
    sim, gateway, frames = run(parse_scene(tomllib.loads(text), "loop_headline.toml"))
    lost_us = 4_000_000 + gateway.node_heartbeat_us * 3 + 100_000
    held = {f.data[2:] for t, f in frames if f.can_id == HAND_RPDO and lost_us < t < 4_800_000}
    assert len(held) <= 1, "the hand's grip command is held while the EMG node is lost"
    assert gateway.by_kind["emg"].phase is NodePhase.OPERATIONAL, "back after it boots again"
    assert sim.t_us >= round(sim.scene.duration_s * 1e6)


def test_a_node_whose_heartbeat_stops_is_lost_and_one_that_leaves_operational_absent():
    """The phase comes from the path that saw it go (consumer time, or its own heartbeat
    saying another state), never from the alarm's text."""
    from grasplink.core.frames import HEARTBEAT_BASE

    power = (
        '[[effects]]\ntype = "bus.faults"\n'
        'power_loss = [{ node = "skin", at_s = 1.5, restore_s = 2.5 }]'
    )
    sim = simulation(scene(duration=4.0, extra=power))
    gateway = sim.controllers[0]
    sim.network.start()
    go_on(sim, 2.2)
    assert gateway.snapshot().nodes["skin"].phase is NodePhase.LOST
    assert gateway.alarms["skin.lost"] == "heartbeat lost"
    go_on(sim, 1.5)
    assert gateway.snapshot().nodes["skin"].phase is NodePhase.OPERATIONAL
    gateway.receive(Frame(HEARTBEAT_BASE + BELT, bytes([0x04])), gateway.now_us)  # STOPPED
    assert gateway.snapshot().nodes["belt"].phase is NodePhase.ABSENT
    assert gateway.alarms["belt.lost"] == "left OPERATIONAL (STOPPED)"


def test_garbage_tpdo_is_dropped_and_counted_never_decoded():
    sc = scene(duration=1.0)
    sim = simulation(sc)
    gateway = sim.controllers[0]
    sim.run()
    before = gateway.by_kind["skin"].pdos_rx
    for data in (b"", bytes(3), bytes(8)):
        gateway.receive(Frame(TPDO_BASES[0] + SKIN, data), gateway.now_us)
    link = gateway.by_kind["skin"]
    assert sum(link.pdos_dropped.values()) == 3
    assert link.pdos_rx == before


def test_refused_provisioning_is_an_alarm_and_the_node_is_not_started():
    sc = scene(duration=1.0)
    sim = simulation(sc)

    def refuse(index, subindex, value):
        raise SdoAbort(AbortCode.HARDWARE_ERROR, "test")

    sim.nodes["skin"].store.add_validator(obj.SKIN_SAMPLE_RATE_HZ, refuse)
    gateway = sim.controllers[0]
    sim.run()
    assert gateway.by_kind["skin"].phase == "failed"
    assert "HARDWARE_ERROR" in gateway.alarms["skin.provisioning"]
    assert sim.nodes["skin"].state.name == "PRE_OPERATIONAL"
    assert sim.nodes["belt"].state.name == "OPERATIONAL"


def test_command_beyond_the_profile_is_clamped_with_an_alarm():
    _, gateway, _ = run(scene(duration=0.5))
    frames = gateway._rpdo(gateway.by_kind["belt"], 99_999, True)
    assert int.from_bytes(frames[0].data[2:6], "little", signed=True) == 8000
    assert "belt.clamped" in gateway.alarms


@pytest.mark.parametrize(
    ("controller", "key"),
    [
        ("[controller.feedback]\nmode = 'loud'", "controller.feedback.mode"),
        ("[controller.nodes.skin]\nnode_id = 5", "controller.nodes.skin.node_id"),
        ("[controller.reflex]\nthreshold_mm_s = -1", "controller.reflex.threshold_mm_s"),
    ],
)
def test_bad_gateway_options_in_a_scene_name_the_key(controller, key):
    from grasplink.controllers import build_controllers

    with pytest.raises(ConfigError, match=key.replace(".", r"\.")):
        build_controllers(scene(controller=controller))


def test_gateway_config_error_exits_before_the_bus_is_touched(tmp_path, capsys):
    bad = tmp_path / "gw.toml"
    bad.write_text("[feedback]\nmode = 'loud'\n")
    # A bus URL that could not be opened: the config error must come first.
    code = cli.main(["gateway", "--config", str(bad), "--bus", "remote:ws://127.0.0.1:1/"])
    assert code == 1
    err = capsys.readouterr().err
    assert "feedback.mode" in err and "127.0.0.1" not in err


# -- run-time commands ----------------------------------------------------------------------


def loop_gateway(duration: float = 1.0):
    """A gateway after `duration` of the shipped closed-loop scene (EMG included)."""
    from grasplink.simulators.scene import load_scene

    sim = simulation(load_scene(ROOT / "scenes" / "loop_headline.toml"))
    sim.network.start()
    go_on(sim, duration)
    return sim, sim.controllers[0]


def go_on(sim, seconds: float) -> None:
    """Advance a started simulation chunk by chunk (run() would boot it again)."""
    end_us = sim.t_us + round(seconds * 1e6)
    while sim.t_us < end_us:
        sim.step(min(sim.t_us + sim.scene.chunk_us, end_us))


def test_commands_are_applied_or_refused_with_the_reason():
    from grasplink.gateway.commands import Command

    _, gateway = loop_gateway()
    ok, _ = gateway.execute(Command("feedback_mode", "slip_speed"), gateway.now_us)
    assert ok.accepted and gateway.feedback.mode.value == "slip_speed"
    ok, _ = gateway.execute(Command("feedback_mode", 0), gateway.now_us)
    assert ok.accepted and gateway.feedback.mode.value == "off"
    for bad in (
        Command("feedback_mode", "loud"),
        Command("reflex_threshold_mm_s", -3),
        Command("reflex_threshold_mm_s", float("nan")),
        Command("emg_calibration", {"e_min_uv": 500, "e_max_uv": 100}),
        Command("restart_node", "arm"),
        Command("self_destruct", True),
    ):
        before = (gateway.feedback.mode, gateway.arbiter.reflex.config)
        result, frames = gateway.execute(bad, gateway.now_us)
        assert not result.accepted and result.detail and frames == []
        assert (gateway.feedback.mode, gateway.arbiter.reflex.config) == before


def edge_gateway(duration: float = 1.0):
    """The shipped closed-loop scene's gateway driven through its live edge (the mailbox
    that takes commands from other threads), after `duration`."""
    from grasplink.controllers import build_controllers
    from grasplink.gateway.edge import GatewayEdge
    from grasplink.simulators.engine import Simulation
    from grasplink.simulators.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "loop_headline.toml")
    edge = GatewayEdge(build_controllers(scene)[0])
    sim = Simulation(scene, controllers=[edge])
    sim.network.start()
    go_on(sim, duration)
    return sim, edge


def test_emg_calibration_command_reaches_the_node_over_sdo():
    from grasplink.gateway.commands import Command

    sim, edge = edge_gateway()
    gateway = edge.gateway
    future = edge.post(Command("emg_calibration", {"e_min_uv": 80, "e_max_uv": 900}))
    go_on(sim, 0.2)
    assert future.result(timeout=0).accepted
    store = sim.nodes["emg"].store
    assert (store.get(obj.EMG_CALIBRATION, 1), store.get(obj.EMG_CALIBRATION, 2)) == (80, 900)
    assert gateway.emg_decoder.calibration.e_max_uv == 900


def test_posted_restart_resets_the_node_and_the_gateway_brings_it_back():
    from grasplink.gateway.commands import Command

    sim, edge = edge_gateway()
    gateway = edge.gateway
    boots = gateway.nodes[HAND].boots
    future = edge.post(Command("restart_node", "hand"))
    go_on(sim, 0.5)
    assert future.result(timeout=0).accepted
    assert gateway.nodes[HAND].boots == boots + 1
    assert gateway.by_kind["hand"].phase is NodePhase.OPERATIONAL


def test_loop_headline_recording_shows_the_loop_on_the_bus(tmp_path, caplog):
    """The shipped closed-loop scene: belt and hand RPDOs react to the slip, the object held."""
    from grasplink.evaluation.loop_plot import describe_loop, read_loop

    out = tmp_path / "loop"
    assert cli.main(["run", str(ROOT / "scenes" / "loop_headline.toml"), "--out", str(out)]) == 0
    trace = read_loop(out)
    onset = float(trace.truth["t_s"][np.argmax(trace.truth["object.slipping"] > 0)])
    assert np.all(trace.belt_target_mrad_s[trace.belt_t_s < onset] >= 0)
    assert np.any(trace.belt_target_mrad_s[trace.belt_t_s > onset] < 0), "slip belt runs"
    grip_before = trace.hand_target_n[trace.hand_t_s < onset]
    assert np.max(trace.hand_target_n[trace.hand_t_s > onset]) > np.max(grip_before) + 1
    position = trace.truth["object.position_mm"]
    assert position[-1] < 84.0, "held before it crossed the skin"
    assert trace.truth["object.slipping"][-1] == 0
    with caplog.at_level(logging.WARNING):
        lines = describe_loop(out)
    assert any("held" in line for line in lines)
    # the raise is told up to the grip the ramp reached, not its first 0.5 N step
    (raised,) = [line for line in lines if "grip raised" in line]
    reached_n = float(raised.split("-> ")[1].split(" N")[0])
    assert reached_n > np.max(grip_before) + 3
    # the replay listens to the skin: the recorded master is no second master to it
    assert not [r for r in caplog.records if "another master" in r.getMessage()]


def test_a_node_whose_heartbeat_stops_is_lost_on_time_while_its_tpdos_keep_coming():
    """Process data is no heartbeat: the hand is lost one consumer time after its last
    heartbeat however many TPDOs it sends (the gateway keeps its network deadlines
    across TPDOs, which move only the control's)."""
    import struct

    _, gateway = loop_gateway()
    hand, values = gateway.nodes[HAND], gateway.by_kind["hand"].values
    lost_at = hand.last_seen_us + gateway.node_consumer_us + 1
    tpdo = Frame(TPDO_BASES[0] + HAND, struct.pack("<HI", values[(0x6041, 0)], values[(0x2401, 0)]))
    t_us = gateway.now_us
    while t_us < lost_at + 20_000:
        t_us += 1000
        gateway.receive(tpdo, t_us)
        due = gateway.next_deadline_us()
        if due is not None and due <= t_us:
            gateway.advance(t_us)
        assert hand.lost == (t_us >= lost_at), t_us
    assert gateway.alarms["hand.lost"] == "heartbeat lost"


@pytest.mark.parametrize("name", ["loop_headline", "loop_fast_reflex"])
def test_the_deadlines_the_gateway_keeps_are_those_its_parts_give_now(name):
    """The gateway keeps its network's and its control's earliest deadlines until a call
    that can move them: after every call of a closed loop (a slip, the reflex, EMG
    intents, command ramps) its deadline is what each part says when asked afresh."""
    from grasplink.simulators.scene import load_scene

    sim = simulation(load_scene(ROOT / "scenes" / f"{name}.toml"))
    gateway = sim.controllers[0]
    checked = []

    def fresh() -> int | None:
        parts = (
            gateway._network_deadline_us(),
            gateway.feedback.next_deadline_us(),
            gateway.arbiter.next_deadline_us(),
            gateway._next_ramp_us(),
        )
        return min((d for d in parts if d is not None), default=None)

    def checking(call):
        def checked_call(*args):
            frames = call(*args)
            assert gateway.next_deadline_us() == fresh(), (call.__name__, args)
            checked.append(call.__name__)
            return frames

        return checked_call

    for method in ("start", "receive", "advance"):
        setattr(gateway, method, checking(getattr(gateway, method)))
    sim.run()
    assert checked.count("receive") > 1000 and gateway.counters["percepts"] > 100

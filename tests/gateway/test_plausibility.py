"""Implausible input does not drive the hand; every refusal is counted (virtual time).

CANopen has no authentication: anything on a node's TPDO COB-ID reads as that node's data.
These tests replay garbage and forged frames at the nodes' TPDO and EMCY COB-IDs, and
frames only another master sends, into the closed-loop scene and check what the gateway
follows, what it commands and what it counts.
"""

from __future__ import annotations

import json
import logging
import random
import struct
from pathlib import Path

import pytest

from grasplink.controllers import simulation
from grasplink.core.frames import EMCY_BASE, RPDO_BASES, TPDO_BASES, Frame
from grasplink.errors import ConfigError, PdoError
from grasplink.gateway.config import parse_config
from grasplink.gateway.plausibility import REJECTION_KEYS, CommandRamp, judge_emcy
from grasplink.simulators.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
EMG, HAND = 0x30, 0x40
HAND_RPDO = RPDO_BASES[0] + HAND
INPUT_KEYS = tuple(k for k in REJECTION_KEYS if "command" not in k and "master" not in k)


def loop_gateway(scene: str = "loop_headline.toml", seconds: float = 1.0):
    sim = simulation(load_scene(ROOT / "scenes" / scene))
    sim.network.start()
    go_on(sim, seconds)
    return sim, sim.controllers[0]


def go_on(sim, seconds: float) -> None:
    end_us = sim.t_us + round(seconds * 1e6)
    while sim.t_us < end_us:
        sim.step(min(sim.t_us + sim.scene.chunk_us, end_us))


def tpdo_length(codec, can_id: int) -> int:
    """The frame length a TPDO's mapping needs (the one length that decodes)."""
    for length in range(9):
        try:
            codec.decode(can_id, bytes(length))
        except PdoError:
            continue
        return length
    raise AssertionError(f"0x{can_id:03X} decodes at no length")


def emg_tpdo1(envelope_uv: int, level: int, sequence: int) -> Frame:
    """EMG TPDO1 as its EDS maps it: envelope U16 (2200h), level U8 (2201h), sequence U8."""
    return Frame(TPDO_BASES[0] + EMG, struct.pack("<HBB", envelope_uv, level, sequence))


def hand_tpdo1(statusword: int, grip_mn: int) -> Frame:
    """Hand TPDO1: statusword U16 (6041h), actual grip U32 (2401h, mN)."""
    return Frame(TPDO_BASES[0] + HAND, struct.pack("<HI", statusword, grip_mn))


def hand_targets(frames) -> list[tuple[int, int]]:
    """(t_us, target grip mN) of every hand RPDO1 (controlword, then 2400h as U32)."""
    return [(t, struct.unpack_from("<I", f.data, 2)[0]) for t, f in frames if f.can_id == HAND_RPDO]


def test_garbage_on_every_tpdo_cob_id_keeps_the_hand_target_in_slew_and_is_counted():
    sim, gateway = loop_gateway()
    rng = random.Random(21)
    # every TPDO the gateway decodes, with the length its mapping needs: garbage that decodes
    targets = [
        (link, can_id, tpdo_length(link.codec, can_id))
        for link in gateway.links.values()
        for can_id in link.codec.tpdo_can_ids()
    ]
    sent: list[tuple[int, Frame]] = []
    legit = 0

    def tap(t_us, frame, sender):
        nonlocal legit
        sent.append((t_us, frame))
        if (
            sender is not None
            and sender is not gateway
            and any(frame.can_id == c for _, c, _ in targets)
        ):
            legit += 1

    sim.network.taps.append(tap)
    before_rx = {k: link.pdos_rx for k, link in gateway.by_kind.items()}
    before_rejected = sum(gateway.rejected[k] for k in INPUT_KEYS)
    injected = 0
    for _ in range(250):  # a garbage frame every 2 ms for 0.5 s
        _link, can_id, length = rng.choice(targets)
        sim.network.inject(Frame(can_id, rng.randbytes(length)))
        injected += 1
        go_on(sim, 0.002)
    rx = sum(link.pdos_rx - before_rx[k] for k, link in gateway.by_kind.items())
    rejected = sum(gateway.rejected[k] for k in INPUT_KEYS) - before_rejected
    assert rejected > 0 and rx + rejected == legit + injected, "every frame followed or counted"
    snapshot = gateway.snapshot().rejected
    assert sum(getattr(snapshot, k) for k in INPUT_KEYS) == sum(
        gateway.rejected[k] for k in INPUT_KEYS
    )
    # the hand target: never faster than the hand's 50 N/s, in steps >= 10 ms apart
    grip = hand_targets(sent)
    assert grip, "the hand is still commanded"
    changes = [(t, v) for (t, v), (_, p) in zip(grip[1:], grip, strict=False) if v != p]
    previous = grip[0]
    for t, v in changes:
        dt_s = max(t - previous[0], 10_000) / 1e6
        assert abs(v - previous[1]) <= 50_000 * 0.01 + 1, (previous, (t, v))
        assert abs(v - previous[1]) / dt_s <= 50_000 + 100, (previous, (t, v))
        previous = (t, v)
    spread = max(v for _, v in grip) - min(v for _, v in grip)
    assert spread <= 50_000 * 0.5 + 500, "bounded by the slew over the attack's 0.5 s"


def test_forged_emg_jump_and_hand_grip_jump_are_refused_and_counted():
    sim, gateway = loop_gateway()
    intent = gateway.last_intent
    t = sim.t_us
    # a plausible value (under 10 mV) that the 200 ms moving average cannot reach in 10 ms
    assert gateway.receive(emg_tpdo1(round(intent.envelope_uv) + 5000, 5, 0), t + 1) == []
    assert gateway.rejected["emg_envelope_jump"] == 1 and gateway.last_intent is intent
    assert gateway.receive(emg_tpdo1(20_000, 5, 0), t + 2) == []  # no muscle reads 20 mV
    assert gateway.rejected["emg_envelope_out_of_range"] == 1 and gateway.last_intent is intent
    grip_before = gateway.hand_grip_n
    statusword = gateway.by_kind["hand"].values[(0x6041, 0)]
    gateway.receive(hand_tpdo1(statusword, 40_000), t + 3)  # 5 -> 40 N in 3 us
    assert gateway.rejected["hand_grip_jump"] == 1 and gateway.hand_grip_n == grip_before
    gateway.receive(hand_tpdo1(statusword, 90_000), t + 4)
    assert gateway.rejected["hand_grip_out_of_range"] == 1  # above the 40 N crush limit
    assert gateway.hand_grip_n == grip_before


def test_reflex_still_raises_the_grip_5_to_8_8_n_within_0_7_s():
    """The slew limit is the hand's own 50 N/s: the fast slip's reflex is not slowed."""
    sim = simulation(load_scene(ROOT / "scenes" / "loop_fast_reflex.toml"))
    frames: list[tuple[int, Frame]] = []
    sim.network.taps.append(lambda t, f, s: frames.append((t, f)))
    sim.run()
    grip = hand_targets(frames)
    start = next(t for (t, v), (_, p) in zip(grip[1:], grip, strict=False) if v > p)
    assert next(v for t, v in grip if t < start) == 5000
    reached = next(t for t, v in grip if v >= 8800)
    assert reached - start <= 700_000
    assert sim.controllers[0].snapshot().rejected.hand_grip_jump == 0


def test_command_ramp_steps_once_per_interval_and_counts_episodes():
    ramp = CommandRamp(50_000, 10_000)  # 50 N/s in mN, 10 ms
    assert ramp.output(5000, 0) == 5000
    assert ramp.output(40_000, 1_000) == 5000  # within the interval: waits
    assert ramp.next_deadline_us() == 10_000
    assert ramp.output(40_000, 10_000) == 5500
    assert ramp.output(0, 20_000) == 5000 and ramp.limited == 1  # one episode
    ramp.start_from(0)
    assert ramp.output(300, 20_001) == 300 and ramp.next_deadline_us() is None


@pytest.mark.parametrize(
    ("kind", "code", "register", "trusted", "known", "text"),
    [
        ("skin", 0xFF01, 0x81, True, True, "EMCY 0xFF01 FSR at full scale"),
        ("hand", 0x8130, 0x11, True, True, "heartbeat of a monitored node lost"),
        ("skin", 0x8210, 0x11, True, False, "unknown EMCY code 0x8210 (monitoring)"),
        ("belt", 0x4210, 0x09, True, False, "unknown EMCY code 0x4210 (temperature)"),
        ("emg", 0xDDE9, 0xCB, False, False, "no CiA 301 error class"),
        ("emg", 0x8130, 0x10, False, False, "without generic bit"),
        ("emg", 0x0000, 0x00, True, True, "error reset"),
    ],
)
def test_emcy_codes_are_named_only_when_the_node_declares_them(
    kind, code, register, trusted, known, text
):
    verdict = judge_emcy(kind, code, register)
    assert (verdict.trusted, verdict.known) == (trusted, known) and text in verdict.text


def test_random_emcy_codes_are_not_named_alarms():
    sim, gateway = loop_gateway()
    rng = random.Random(8)
    for _ in range(50):
        sim.network.inject(Frame(EMCY_BASE + EMG, rng.randbytes(8)))
    alarm = gateway.alarms.get("emg.emcy", "")
    assert not alarm or alarm.startswith("unknown EMCY code")
    counted = gateway.rejected["emcy_invalid"] + gateway.rejected["emcy_unknown_code"]
    assert counted == 50


def test_a_second_master_is_an_alarm_a_log_line_and_counted(caplog):
    sim, gateway = loop_gateway()
    with caplog.at_level(logging.WARNING, logger="grasplink.gateway.service"):
        sim.network.inject(Frame(0x000, bytes([0x01, 0x20])))
        sim.network.inject(Frame(0x700 + gateway.node_id, bytes([0x05])))
        sim.network.inject(Frame(0x700 + gateway.node_id, rtr=True, dlc=1))  # not a master's
    assert "another master on the bus" in gateway.alarms["gateway.second_master"]
    assert [r.message for r in caplog.records if "another master" in r.message]
    snap = gateway.snapshot().rejected
    assert (snap.foreign_nmt, snap.second_master_heartbeat) == (1, 1)
    go_on(sim, 5.2)
    assert "gateway.second_master" not in gateway.alarms, "clears after 5 s unheard"
    assert gateway.by_kind["hand"].phase == "operational"


def test_plausibility_config_names_the_key_and_defaults_to_the_hand_rate():
    config = parse_config({"nodes": {"hand": {"grip_rate_n_s": 20.0}}}, "gw.toml")
    assert config.plausibility.grip_slew_n_s == 20.0
    with pytest.raises(ConfigError, match=r"gw\.toml: plausibility\.command_interval_ms"):
        parse_config({"plausibility": {"command_interval_ms": 0}}, "gw.toml")


def test_rejections_reach_the_json_health_topic_and_sparkplug_metrics():
    from grasplink.surfaces.telemetry.buffer import Sample
    from grasplink.surfaces.telemetry.json_tree import JsonTree
    from grasplink.surfaces.telemetry.sparkplug import ALIASES

    sim, gateway = loop_gateway(seconds=0.5)
    sim.network.inject(Frame(EMCY_BASE + EMG, bytes([0xE9, 0xDD, 0xCB, 0, 0, 0, 0, 0])))
    tree = JsonTree("gw")
    messages = tree.update([Sample(1_000, gateway.snapshot())], {})
    health = next(m for m in messages if m.topic.endswith("/health"))
    assert json.loads(health.payload)["rejected"]["emcy_invalid"] == 1
    assert all(f"Rejected/{key}" in ALIASES[None] for key in REJECTION_KEYS)


def test_each_tpdo_is_judged_by_its_own_mapped_objects_whatever_arrives_before():
    """The gateway works out each TPDO's checks once (service.TpdoRoute): the EMG level's
    EDS range (0..5), the skin's ADC full scale on its sample slots only, and a TPDO
    COB-ID of a configured node that its file does not map is dropped, not decoded."""
    sim, gateway = loop_gateway(seconds=0.5)
    skin = gateway.by_kind["skin"]
    full = gateway.skin_binding.max_units
    rejected = dict(gateway.rejected)
    dropped = sum(skin.pdos_dropped.values())
    sim.network.inject(emg_tpdo1(100, 6, 1))  # level e6: beyond 2201h's high limit
    assert gateway.rejected["tpdo_out_of_range"] == rejected.get("tpdo_out_of_range", 0) + 1
    sim.network.inject(Frame(TPDO_BASES[0] + 0x10, struct.pack("<HHHB", 1, full + 1, 2, 9)))
    assert (
        gateway.rejected["skin_sample_out_of_range"]
        == rejected.get("skin_sample_out_of_range", 0) + 1
    )
    # the static force and sample count (TPDO2) carry no sample slot: full scale is no limit
    before_rx = skin.pdos_rx
    sim.network.inject(Frame(TPDO_BASES[1] + 0x10, struct.pack("<iI", 2000, 2 * full)))
    assert skin.pdos_rx == before_rx + 1
    sim.network.inject(Frame(TPDO_BASES[3] + 0x10, bytes(8)))  # TPDO4: not in its file
    assert sum(skin.pdos_dropped.values()) == dropped + 1

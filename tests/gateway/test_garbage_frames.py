"""Garbage on the nodes' TPDO COB-IDs does not slew the hand faster than it can move.

Issue 21, item 8, as the issue saw it: random frames on every TPDO COB-ID the gateway
decodes, in the closed-loop scene, moved the hand target 0 -> 40 N -> 0 within 62 ms.
This test uses only what the gateway had before the fix (the scene, its network and the
hand's RPDO1 on the bus), so it shows the defect on that code and the bound after it;
tests/gateway/test_plausibility.py checks the counting and each rule.
"""

from __future__ import annotations

import itertools
import random
import struct
from pathlib import Path

from grasplink.controllers import simulation
from grasplink.core.frames import RPDO_BASES, Frame
from grasplink.errors import PdoError
from grasplink.simulators.scene import load_scene

ROOT = Path(__file__).resolve().parents[2]
HAND_RPDO1 = RPDO_BASES[0] + 0x40
HAND_SLEW_MN_S = 50_000  # the hand's grip slew (2404h default): what its actuator can follow


def _step(sim, seconds: float) -> None:
    end_us = sim.t_us + round(seconds * 1e6)
    while sim.t_us < end_us:
        sim.step(min(sim.t_us + sim.scene.chunk_us, end_us))


def _decoding_length(codec, can_id: int) -> int | None:
    for length in range(9):
        try:
            codec.decode(can_id, bytes(length))
        except PdoError:
            continue
        return length
    return None


def test_random_tpdo_frames_never_move_the_hand_target_faster_than_the_hand_can() -> None:
    sim = simulation(load_scene(ROOT / "scenes" / "loop_headline.toml"))
    sim.network.start()
    _step(sim, 1.0)
    gateway = sim.controllers[0]
    targets = [
        (can_id, length)
        for link in gateway.links.values()
        for can_id in link.codec.tpdo_can_ids()
        if (length := _decoding_length(link.codec, can_id)) is not None
    ]
    hand_mn: list[tuple[int, int]] = []  # (t_us, target grip) of every hand RPDO1
    sim.network.taps.append(
        lambda t_us, frame, _sender: (
            hand_mn.append((t_us, struct.unpack_from("<I", frame.data, 2)[0]))
            if frame.can_id == HAND_RPDO1
            else None
        )
    )
    rng = random.Random(8)
    for _ in range(250):  # a garbage frame every 2 ms for 0.5 s
        can_id, length = rng.choice(targets)
        sim.network.inject(Frame(can_id, rng.randbytes(length)))
        _step(sim, 0.002)
    assert len(hand_mn) > 1, "the hand is still commanded"
    # over any two commands at least 10 ms apart, no faster than the hand's own slew
    # (a 1 mN allowance for rounding to the object's unit)
    for (t0, v0), (t1, v1) in itertools.pairwise(hand_mn):
        dt_s = max(t1 - t0, 10_000) / 1e6
        assert abs(v1 - v0) <= HAND_SLEW_MN_S * dt_s + 1, f"{v0} -> {v1} mN in {t1 - t0} us"

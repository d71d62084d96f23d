"""A master that commands the belt and hand from time profiles (until the feedback loop lands).

It is the NMT master plus a stand-in controller: every command period it
sends RPDO1 to the belt (controlword, target velocity mrad/s) and to the
hand (controlword, target grip mN), walking each drive through the CiA 402
enable sequence from the statusword its TPDOs report (`drives.DriveHandshake`),
so a drive still quick-stopping when it is started again is brought out of
that state rather than sent an enable it ignores. Profiles are step
functions of time since start.
Only a drive the master may command gets RPDOs (`NmtMaster.commandable`):
OPERATIONAL, its heartbeat not lost, not held by a consumer fault.
"""

from __future__ import annotations

import bisect
from collections.abc import Mapping, Sequence
from typing import Any

from grasplink.core.frames import Frame
from grasplink.core.params import Params
from grasplink.errors import PdoError
from grasplink.gateway.drives import DriveHandshake
from grasplink.gateway.master import NmtMaster
from grasplink.profiles import object_limits
from grasplink.profiles import objects as obj
from grasplink.profiles.pdo_codec import PdoCodec

COMMAND_PERIOD_US = 50_000
STATUSWORD_KEY = (obj.STATUSWORD, 0)

Profile = Sequence[tuple[float, float]]  # (t_s, value), step-wise


def step_value(profile: Profile | None, t_s: float) -> float | None:
    """The value of a step profile at t_s (None before its first point or without profile)."""
    if not profile:
        return None
    times = [t for t, _ in profile]
    index = bisect.bisect_right(times, t_s) - 1
    return profile[index][1] if index >= 0 else None


class ScriptedMaster(NmtMaster):
    def __init__(
        self,
        *,
        belt_id: int | None = None,
        hand_id: int | None = None,
        belt_mrad_s: Profile | None = None,
        hand_grip_n: Profile | None = None,
        command_period_us: int = COMMAND_PERIOD_US,
        **master_options: Any,  # NmtMaster's
    ):
        super().__init__(**master_options)
        self.belt_id, self.hand_id = belt_id, hand_id
        self.belt_profile, self.hand_profile = belt_mrad_s, hand_grip_n
        self.command_period_us = command_period_us
        self._next_command_us: int | None = None
        self._started_us = 0
        self._codecs = {
            node_id: PdoCodec(kind, node_id)
            for kind, node_id in (("belt", belt_id), ("hand", hand_id))
            if node_id is not None
        }
        self._handshakes = {node_id: DriveHandshake() for node_id in self._codecs}
        self._tpdo_node = {
            can_id: node_id
            for node_id, codec in self._codecs.items()
            for can_id in codec.tpdo_can_ids()
        }
        self.tpdos_dropped = 0  # drive TPDOs that did not fit their mapping

    @classmethod
    def from_scene(cls, options: Params, nodes: Mapping[str, Mapping[str, Any]]) -> ScriptedMaster:
        """A scene's `[controller] type = "scripted"`: step profiles for the belt and the hand.

        Profile values are bounded by what the commanded object accepts (its EDS limits), so
        a scene can never ask for a command its RPDO cannot carry.
        """
        profiles: dict[str, Profile | None] = {"belt_mrad_s": None, "hand_grip_n": None}
        targets = {
            "belt_mrad_s": ("belt", obj.BELT_TARGET_VELOCITY_MRAD_S, 1.0),
            "hand_grip_n": ("hand", obj.HAND_TARGET_GRIP_MN, 1000.0),
        }
        for key, (kind, index, per_unit) in targets.items():
            if not options.has(key):
                continue
            if kind not in nodes:
                raise options.error(key, f"commands a {kind}, but the scene has no [nodes.{kind}]")
            low, high = object_limits(kind, index)
            profiles[key] = options.pairs(key, low=low / per_unit, high=high / per_unit)
        options.finish()
        return cls(
            belt_id=nodes["belt"]["node_id"] if "belt" in nodes else None,
            hand_id=nodes["hand"]["node_id"] if "hand" in nodes else None,
            belt_mrad_s=profiles["belt_mrad_s"],
            hand_grip_n=profiles["hand_grip_n"],
        )

    def start(self, t_us: int) -> list[Frame]:
        self._started_us = t_us
        if self.belt_profile or self.hand_profile:
            self._next_command_us = t_us + self.command_period_us
        return super().start(t_us)

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        node_id = self._tpdo_node.get(frame.can_id)
        if node_id is None or frame.rtr:
            return super().receive(frame, t_us)
        try:
            values = self._codecs[node_id].decode(frame.can_id, bytes(frame.data))
        except PdoError:
            self.tpdos_dropped += 1
            return []
        if STATUSWORD_KEY in values:
            self._handshakes[node_id].on_statusword(int(values[STATUSWORD_KEY]))
        return []

    def advance(self, t_us: int) -> list[Frame]:
        frames = super().advance(t_us)
        if self._next_command_us is not None and t_us >= self._next_command_us:
            self._next_command_us += self.command_period_us
            frames += self.commands((t_us - self._started_us) / 1e6)
        return frames

    def next_deadline_us(self) -> int | None:
        deadlines = (super().next_deadline_us(), self._next_command_us)
        return min((d for d in deadlines if d is not None), default=None)

    def commands(self, t_s: float) -> list[Frame]:
        """RPDO1 to each commanded drive, packed through its EDS mapping."""
        frames = []
        belt = step_value(self.belt_profile, t_s)
        if belt is not None and self.belt_id is not None and self.commandable(self.belt_id):
            target = (obj.BELT_TARGET_VELOCITY_MRAD_S, 0)
            frames.append(self._rpdo1(self.belt_id, target, round(belt)))
        grip_n = step_value(self.hand_profile, t_s)
        if grip_n is not None and self.hand_id is not None and self.commandable(self.hand_id):
            target = (obj.HAND_TARGET_GRIP_MN, 0)
            frames.append(self._rpdo1(self.hand_id, target, max(0, round(grip_n * 1000))))
        return frames

    def _rpdo1(self, node_id: int, target: tuple[int, int], value: int) -> Frame:
        codec = self._codecs[node_id]
        values = {(obj.CONTROLWORD, 0): self._controlword(node_id), target: value}
        can_id, data = codec.encode(1, values)
        return Frame(can_id, data)

    def on_node_restart(self, node_id: int) -> None:
        # Rebooted or back from a fault: forget the drive state until its statusword says.
        if node_id in self._handshakes:
            self._handshakes[node_id].reset()

    def _controlword(self, node_id: int) -> int:
        """The controlword that moves the drive one step towards OPERATION ENABLED."""
        return self._handshakes[node_id].controlword()

"""One binding per node kind: how the simulation and a device node meet.

A binding says what a node of its kind reads from the scene (a sensor
signal it samples, or the actual value of the motor or actuator it drives),
what it writes back (its actuator command), which scene options it takes,
and how scene settings become the node's stored parameters. The engine only
talks to bindings, so a new node kind (kinds.py) means a new binding here,
not an edit of the engine.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from grasplink.core.params import Params
from grasplink.devices.app import DeviceApp
from grasplink.devices.belt import BeltApp
from grasplink.devices.factory import build_node
from grasplink.devices.hand import HandApp
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import per_kind
from grasplink.profiles.layouts import PRESET_CODES, spacings_um
from grasplink.simulators import signals as sig
from grasplink.simulators.core import EMG, PHYSICS, SKIN, Endpoint

if TYPE_CHECKING:
    from grasplink.simulators.scene import NodeSpec, Scene

RING_SECONDS = 2.0
MN_PER_N = 1000.0


class SceneSource:
    """A node's SampleSource fed by a sensor domain: a bounded ring of recent samples."""

    def __init__(self, rate_hz: int):
        self.period_us = -(-1_000_000 // rate_hz)
        self.capacity = max(16, int(rate_hz * RING_SECONDS))
        self.times_us = np.zeros(0, dtype=np.int64)
        self.values = np.zeros(0)

    def append(self, times_us: np.ndarray, values: np.ndarray) -> None:
        self.times_us = np.concatenate([self.times_us, times_us])[-self.capacity :]
        self.values = np.concatenate([self.values, values])[-self.capacity :]

    def samples(self, t0_us: int, start_index: int, count: int, rate_hz: int) -> np.ndarray:
        index = np.arange(start_index, start_index + count, dtype=np.int64)
        times = t0_us + index * 1_000_000 // rate_hz
        if not len(self.times_us):
            return np.zeros(count)
        # A node reset mid-scene restarts its clock off the scene's grid; its last
        # sample may then fall less than one period after the last scene sample
        # (held). Further ahead would be an engine bug.
        if times[-1] >= self.times_us[-1] + self.period_us:
            raise RuntimeError("a node sampled ahead of the simulation")
        return np.interp(times, self.times_us, self.values)


class NodeBinding:
    """Base binding: a node that neither senses nor actuates anything in the scene."""

    kind: ClassVar[str]
    # (signal, domain) the node samples, if it is a sensor.
    sensor: ClassVar[tuple[str, str] | None] = None
    # Physics signal that is the node's actual value (motor velocity, grip force).
    actual: ClassVar[str | None] = None
    # Signal the node's command drives (physics domain).
    command: ClassVar[str | None] = None

    def __init__(self, spec: NodeSpec, scene: Scene, produced: Iterable[str]):
        self.spec = spec
        self.scene = scene
        produced = set(produced)
        self.source: SceneSource | None = None
        if self.sensor is not None and self.sensor[0] in produced:
            self.source = SceneSource(scene.rate_hz(self.sensor[1]))
        self.actual_simulated = self.actual is not None and self.actual in produced
        self.node = build_node(spec.kind, spec.node_id, self.source, self.make_app())
        self.configure(self.node.store.nvm)

    # -- what the scene file says ---------------------------------------------------------
    @classmethod
    def parse_options(cls, p: Params, spec: NodeSpec) -> None:
        """Read this kind's options of `[nodes.KIND]` into `spec` (node_id is already read)."""

    @classmethod
    def endpoint(cls) -> Endpoint:
        reads = tuple(s for s in (cls.sensor[0] if cls.sensor else None, cls.actual) if s)
        writes = (cls.command,) if cls.command else ()
        domain = cls.sensor[1] if cls.sensor else PHYSICS
        return Endpoint(cls.kind, reads=reads, writes=writes, domain=domain)

    # -- building the node --------------------------------------------------------------------
    def make_app(self) -> DeviceApp | None:
        """The application, or None for the kind's default one."""
        return None

    def configure(self, nvm: dict) -> None:
        """Scene settings become stored parameters (NVM), so they survive the node's resets."""

    # -- each chunk ------------------------------------------------------------------------------
    def feed_sensor(self, times_us: np.ndarray, values: np.ndarray) -> None:
        if self.source is not None:
            self.source.append(times_us, values)

    def command_value(self) -> float:
        """The actuator command, held over the next chunk (zero-order hold)."""
        raise KeyError(f"{self.kind} commands nothing")

    def report_actual(self, value: float) -> None:
        """The simulated actual value at the chunk end."""


class SkinBinding(NodeBinding):
    kind = "skin"
    sensor = (sig.SKIN_FORCE_N, SKIN)

    @classmethod
    def parse_options(cls, p: Params, spec: NodeSpec) -> None:
        spec.sample_rate_hz = p.integer(
            "sample_rate_hz", DEFAULT_RATES_HZ["skin"], low=80, high=1000
        )
        spec.samples_per_pdo = p.integer("samples_per_pdo", 3, low=1, high=3)
        spec.layout = p.string("layout", None)

    def configure(self, nvm: dict) -> None:
        nvm[(obj.SKIN_SAMPLE_RATE_HZ, 0)] = self.spec.sample_rate_hz
        nvm[(obj.SKIN_SAMPLES_PER_PDO, 0)] = self.spec.samples_per_pdo
        layout = self.scene.layout_mm or ()
        preset = next(
            (code for code, name in PRESET_CODES.items() if name == self.scene.layout_name), 0
        )
        nvm[(obj.SKIN_LAYOUT_PRESET, 0)] = preset
        if not preset and layout:
            nvm[(obj.SKIN_RIDGE_SPACING_UM, 0)] = len(layout)
            for sub, um in enumerate(spacings_um(layout), start=1):
                nvm[(obj.SKIN_RIDGE_SPACING_UM, sub)] = um


class EmgBinding(NodeBinding):
    kind = "emg"
    sensor = (sig.EMG_RAW_UV, EMG)

    @classmethod
    def parse_options(cls, p: Params, spec: NodeSpec) -> None:
        spec.sample_rate_hz = p.integer(
            "sample_rate_hz", DEFAULT_RATES_HZ["emg"], low=500, high=4000
        )

    def configure(self, nvm: dict) -> None:
        nvm[(obj.EMG_SAMPLE_RATE_HZ, 0)] = self.spec.sample_rate_hz


class BeltBinding(NodeBinding):
    kind = "belt"
    actual = sig.BELT_VELOCITY_MRAD_S
    command = sig.BELT_COMMAND_MRAD_S

    def make_app(self) -> BeltApp:
        return BeltApp(external_motor=self.actual_simulated)

    def command_value(self) -> float:
        """Without power the belt motor stops."""
        app = self.node.app
        assert isinstance(app, BeltApp)
        return float(app.setpoint_mrad_s) if self.node.powered else 0.0

    def report_actual(self, value: float) -> None:
        app = self.node.app
        assert isinstance(app, BeltApp)
        app.measure_velocity(value)


class HandBinding(NodeBinding):
    kind = "hand"
    actual = sig.HAND_GRIP_N
    command = sig.HAND_TARGET_N

    def make_app(self) -> HandApp:
        # A scene may start with the object already held: the node boots holding it.
        initial_n = next(
            (getattr(e, "initial_n", 0.0) for e in self.scene.effects if self.actual in e.outputs),
            0.0,
        )
        return HandApp(
            external_actuator=self.actual_simulated, initial_grip_mn=initial_n * MN_PER_N
        )

    def command_value(self) -> float:
        """Without power the hand's gear holds its grip."""
        app = self.node.app
        assert isinstance(app, HandApp)
        return (app.setpoint_mn if self.node.powered else app.grip_mn) / MN_PER_N

    def report_actual(self, value: float) -> None:
        app = self.node.app
        assert isinstance(app, HandApp)
        app.measure_grip(value * MN_PER_N)


DEFAULT_RATES_HZ = {"skin": 400, "emg": 1500}
BINDINGS: dict[str, type[NodeBinding]] = per_kind(
    "simulators/bindings.py BINDINGS",
    {b.kind: b for b in (SkinBinding, EmgBinding, BeltBinding, HandBinding)},
)


def bind(spec: NodeSpec, scene: Scene, produced: Iterable[str]) -> NodeBinding:
    return BINDINGS[spec.kind](spec, scene, produced)

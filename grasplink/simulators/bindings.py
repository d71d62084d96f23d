"""One binding per node kind: how the simulation and a device node meet.

A binding says what a node of its kind reads from the scene (a sensor
signal it samples, or the actual value of the motor or actuator it drives),
what it writes back (its actuator command), which scene options it takes,
and how scene settings become the node's stored parameters. The engine only
talks to bindings, so a new node kind (kinds.py) means a new binding here,
not an edit of the engine.

A node may also be a vendor's, built from its EDS/DCF (`[nodes.KIND] eds = ...`): a
skin is then an analogue input module the FSR is wired to (`[nodes.skin.input]`), a
belt or hand a CiA 402 drive whose target is the command and whose actual value the
physics sets (`[nodes.hand.drive]`). The scene wires the physics only; the master
configures the node as it would on a bench (docs/scenes.md, "A vendor's node").
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import canopen
import numpy as np

from grasplink.core.params import Params
from grasplink.devices.analogue import AnalogueInputApp
from grasplink.devices.app import DeviceApp
from grasplink.devices.belt import BeltApp
from grasplink.devices.factory import build_from_file, build_node
from grasplink.devices.generic import GenericDriveApp, is_drive
from grasplink.devices.hand import HandApp
from grasplink.errors import ConfigError
from grasplink.profiles import find_variable, object_key, variable_limits
from grasplink.profiles import objects as obj
from grasplink.profiles.field import load_object_dictionary
from grasplink.profiles.kinds import per_kind
from grasplink.profiles.layouts import PRESET_CODES, spacings_um
from grasplink.simulators import signals as sig
from grasplink.simulators.core import EMG, PHYSICS, SKIN, Endpoint

if TYPE_CHECKING:
    from grasplink.simulators.scene import NodeSpec, Scene

RING_SECONDS = 2.0
MN_PER_N = 1000.0
MRAD_PER_RAD = 1000.0


@dataclass(frozen=True)
class InputWiring:
    """A sensor on a vendor module's analogue input: the object, and its counts per unit."""

    key: tuple[int, int]
    units_per_n: float
    zero: float = 0.0


@dataclass(frozen=True)
class DriveWiring:
    """A vendor's CiA 402 drive as an actuator: the command is read from `target`, the
    simulated actual value written to `actual`, both `units_per_signal` per scene unit."""

    target: tuple[int, int]
    actual: tuple[int, int]
    units_per_signal: float


class SceneSource:
    """A node's SampleSource fed by a sensor domain: a bounded ring of recent samples.

    `times_us` and `values` are the last `capacity` samples appended (fewer at first),
    views into buffers twice as long: a chunk is written after the last one, and only
    when the buffers are full are the samples kept moved to their front, so a chunk
    costs copying its own samples, not the whole ring.
    """

    def __init__(self, rate_hz: int):
        self.rate_hz = rate_hz  # the domain's: its samples fall at k * 1e6 // rate_hz
        self.period_us = -(-1_000_000 // rate_hz)
        self.capacity = max(16, int(rate_hz * RING_SECONDS))
        self._times_us = np.zeros(2 * self.capacity, dtype=np.int64)
        self._values = np.zeros(2 * self.capacity)
        self._end = 0  # samples held in the buffers
        self.times_us = self._times_us[:0]
        self.values = self._values[:0]

    def append(self, times_us: np.ndarray, values: np.ndarray) -> None:
        count = min(len(times_us), self.capacity)
        times_us, values = times_us[len(times_us) - count :], values[len(values) - count :]
        if self._end + count > len(self._times_us):  # full: keep the last ones at the front
            kept = min(self._end, self.capacity - count)
            self._times_us[:kept] = self._times_us[self._end - kept : self._end]
            self._values[:kept] = self._values[self._end - kept : self._end]
            self._end = kept
        end = self._end + count
        self._times_us[self._end : end] = times_us
        self._values[self._end : end] = values
        self._end = end
        start = max(0, end - self.capacity)
        self.times_us = self._times_us[start:end]
        self.values = self._values[start:end]

    def samples(self, t0_us: int, start_index: int, count: int, rate_hz: int) -> np.ndarray:
        if t0_us == 0 and rate_hz == self.rate_hz and count > 0 and len(self.times_us):
            held = self._held(start_index, count)
            if held is not None:
                return held
        index = np.arange(start_index, start_index + count, dtype=np.int64)
        times = t0_us + index * 1_000_000 // rate_hz
        if not len(self.times_us):
            return np.zeros(count)
        # A node reset mid-scene restarts its clock off the scene's grid; its last
        # sample may then fall less than one period after the last scene sample
        # (held). Further ahead would be an engine bug.
        if times[-1] >= self.times_us[-1] + self.period_us:
            raise RuntimeError("a node sampled ahead of the simulation")
        # np.interp reads, for each time, the held samples at or before and after it (or an
        # end), but converts all it is handed to float first: the whole ring (2 s, 3000 EMG
        # samples) for a tick's 3-20. It gets the samples from the last at or before the
        # first time to the first after the last one, the same ones it reads: same bits.
        held = self.times_us
        a = max(0, int(held.searchsorted(times[0], "right")) - 1)
        b = int(held.searchsorted(times[-1], "right")) + 1
        return np.interp(times, held[a:b], self.values[a:b])

    def _held(self, start_index: int, count: int) -> np.ndarray | None:
        """A node sampling on the domain's own grid (its rate, from 0: every scene node
        until a reset) reads held samples themselves: the ring's slice from its first
        time, a copy - what np.interp gives for times equal to held ones (their values as
        they are), without the times' and the interpolation's arrays (EMG and skin, once
        per tick). None when the ring does not hold all of them; the caller interpolates
        (and tells a node sampling ahead)."""
        first_us = start_index * 1_000_000 // self.rate_hz
        last_us = (start_index + count - 1) * 1_000_000 // self.rate_hz
        held = self.times_us
        a = int(held.searchsorted(first_us))
        b = a + count
        # a sorted ring of grid times holding the first and the last with count - 1
        # between them holds every one between
        if b > len(held) or held[a] != first_us or held[b - 1] != last_us:
            return None
        return self.values[a:b].copy()

    def final_until_us(self) -> int | None:
        """Up to the last scene sample: later times would be held, not interpolated."""
        return int(self.times_us[-1]) if len(self.times_us) else -1


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
        if spec.file is None:
            self.node = build_node(spec.kind, spec.node_id, self.source, self.make_app())
            self.configure(self.node.store.nvm)
        else:
            self.node, _ = build_from_file(spec.file, spec.node_id, app=self.make_file_app)

    # -- what the scene file says ---------------------------------------------------------
    @classmethod
    def parse_options(cls, p: Params, spec: NodeSpec) -> None:
        """Read this kind's options of `[nodes.KIND]` into `spec` (node_id and the file of
        a vendor's node are already read)."""
        if spec.file is not None:
            raise p.error(
                "eds" if p.has("eds") else "dcf",
                f"a vendor's {spec.kind} node is not modelled: ours only",
            )

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

    def make_file_app(self, od: canopen.ObjectDictionary) -> DeviceApp:
        """The application of a vendor's node built from its file (its wiring to the scene)."""
        raise NotImplementedError(f"{self.kind}: no vendor node")

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
        spec.layout = p.string("layout", None)
        if spec.file is None:
            spec.samples_per_pdo = p.integer("samples_per_pdo", 3, low=1, high=3)
            if p.has("input"):
                raise p.error("input", "wires a vendor's module: give its file (eds = or dcf =)")
            return
        if p.has("samples_per_pdo"):
            raise p.error("samples_per_pdo", "is our skin's: a module's input carries one value")
        t = p.table_of("input")
        key = _object(t, "object", spec.file, spec.node_id)
        spec.wiring = InputWiring(
            key,
            t.number("units_per_n", low=0.0, low_open=True),
            t.number("zero", 0.0),
        )
        t.finish()

    def make_file_app(self, od: canopen.ObjectDictionary) -> DeviceApp:
        wiring = self.spec.wiring
        assert isinstance(wiring, InputWiring) and self.spec.sample_rate_hz
        limits = variable_limits(find_variable(od, *wiring.key))
        return AnalogueInputApp(
            wiring.key,
            self.spec.sample_rate_hz,
            wiring.units_per_n,
            wiring.zero,
            limits,
            self.source,
        )

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
        super().parse_options(p, spec)  # (ours only)
        spec.sample_rate_hz = p.integer(
            "sample_rate_hz", DEFAULT_RATES_HZ["emg"], low=500, high=4000
        )

    def configure(self, nvm: dict) -> None:
        nvm[(obj.EMG_SAMPLE_RATE_HZ, 0)] = self.spec.sample_rate_hz


class DriveBinding(NodeBinding):
    """A belt or hand: ours, or a vendor's CiA 402 drive wired by `[nodes.KIND.drive]`."""

    # the drive table's scale key, and scene units (of `command`) per unit it names
    scale_key: ClassVar[str]
    signal_per_scale_unit: ClassVar[float]

    def __init__(self, spec: NodeSpec, scene: Scene, produced: Iterable[str]):
        self.held = 0.0  # what a vendor's drive does while not enabled (scene units)
        super().__init__(spec, scene, produced)

    @classmethod
    def parse_options(cls, p: Params, spec: NodeSpec) -> None:
        if spec.file is None:
            if p.has("drive"):
                raise p.error("drive", "wires a vendor's drive: give its file (eds = or dcf =)")
            return
        od = _dictionary(p, spec.file, spec.node_id)
        if not is_drive(od):
            raise p.error("drive", f"{spec.file.name} is no CiA 402 drive (no controlword 6040h)")
        t = p.table_of("drive")
        target = _object(t, "target", spec.file, spec.node_id, od)
        actual = _object(t, "actual", spec.file, spec.node_id, od)
        scale = t.number(cls.scale_key, low=0.0, low_open=True)
        t.finish()
        spec.wiring = DriveWiring(target, actual, scale / cls.signal_per_scale_unit)

    def make_file_app(self, od: canopen.ObjectDictionary) -> DeviceApp:
        wiring = self.wiring
        measured = frozenset({wiring.actual[0]}) if self.actual_simulated else frozenset()
        return GenericDriveApp(od, measured)

    @property
    def wiring(self) -> DriveWiring:
        assert isinstance(self.spec.wiring, DriveWiring)
        return self.spec.wiring

    def vendor_command(self) -> float:
        """A vendor's drive follows its target while enabled, else does what `held` says."""
        app = self.node.app
        assert isinstance(app, GenericDriveApp)
        if not (self.node.powered and app.enabled):
            return self.held
        target = float(self.node.store.get(*self.wiring.target))
        return target / self.wiring.units_per_signal

    def vendor_actual(self, value: float) -> None:
        app = self.node.app
        assert isinstance(app, GenericDriveApp)
        app.measure(self.wiring.actual[0], value * self.wiring.units_per_signal)


class BeltBinding(DriveBinding):
    kind = "belt"
    actual = sig.BELT_VELOCITY_MRAD_S
    command = sig.BELT_COMMAND_MRAD_S
    scale_key = "units_per_rad_s"
    signal_per_scale_unit = MRAD_PER_RAD

    def make_app(self) -> BeltApp:
        return BeltApp(external_motor=self.actual_simulated)

    def command_value(self) -> float:
        """Without power (or, a vendor's, not enabled) the belt motor stops."""
        if self.spec.file is not None:
            return self.vendor_command()
        app = self.node.app
        assert isinstance(app, BeltApp)
        return float(app.setpoint_mrad_s) if self.node.powered else 0.0

    def report_actual(self, value: float) -> None:
        if self.spec.file is not None:
            self.vendor_actual(value)
            return
        app = self.node.app
        assert isinstance(app, BeltApp)
        app.measure_velocity(value)


class HandBinding(DriveBinding):
    kind = "hand"
    actual = sig.HAND_GRIP_N
    command = sig.HAND_TARGET_N
    scale_key = "units_per_n"
    signal_per_scale_unit = 1.0

    def initial_grip_n(self) -> float:
        """A scene may start with the object already held: the node boots holding it."""
        return next(
            (getattr(e, "initial_n", 0.0) for e in self.scene.effects if self.actual in e.outputs),
            0.0,
        )

    def make_app(self) -> HandApp:
        return HandApp(
            external_actuator=self.actual_simulated,
            initial_grip_mn=self.initial_grip_n() * MN_PER_N,
        )

    def make_file_app(self, od: canopen.ObjectDictionary) -> DeviceApp:
        self.held = self.initial_grip_n()
        return super().make_file_app(od)

    def command_value(self) -> float:
        """Without power (or, a vendor's, not enabled) the hand's gear holds its grip."""
        if self.spec.file is not None:
            return self.vendor_command()
        app = self.node.app
        assert isinstance(app, HandApp)
        return (app.setpoint_mn if self.node.powered else app.grip_mn) / MN_PER_N

    def report_actual(self, value: float) -> None:
        if self.spec.file is not None:
            self.held = value
            self.vendor_actual(value)
            return
        app = self.node.app
        assert isinstance(app, HandApp)
        app.measure_grip(value * MN_PER_N)


def _dictionary(p: Params, path: Path, node_id: int) -> canopen.ObjectDictionary:
    try:
        return load_object_dictionary(path, node_id)[0]
    except ConfigError as exc:
        raise p.error("eds" if p.has("eds") else "dcf", str(exc)) from None


def _object(
    t: Params,
    name: str,
    path: Path,
    node_id: int,
    od: canopen.ObjectDictionary | None = None,
) -> tuple[int, int]:
    """The object `t[name]` names ("6401sub1"), checked against the node's file."""
    text = t.string(name)
    try:
        key = object_key(text)
        find_variable(od if od is not None else _dictionary(t, path, node_id), *key)
    except ConfigError as exc:
        raise t.error(name, f"{path.name}: {exc}") from None
    return key


DEFAULT_RATES_HZ = {"skin": 400, "emg": 1500}
BINDINGS: dict[str, type[NodeBinding]] = per_kind(
    "simulators/bindings.py BINDINGS",
    {b.kind: b for b in (SkinBinding, EmgBinding, BeltBinding, HandBinding)},
)


def bind(spec: NodeSpec, scene: Scene, produced: Iterable[str]) -> NodeBinding:
    return BINDINGS[spec.kind](spec, scene, produced)

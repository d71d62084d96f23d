"""Run a scene: its effects, its nodes on a virtual-time CAN network, and a recorder.

Time advances in chunks (`[scene] chunk_ms`, default 10 ms). For each chunk
the physics domain steps first (its last sample lands exactly on the chunk
end, so sensor domains can interpolate it), then the skin and EMG domains;
then the network runs to the chunk end, the nodes sampling what the sensor
domains produced. Actuator commands flow back from the nodes at chunk
boundaries. Virtual time runs as fast as the machine allows; real time
paces each chunk to the wall clock (same code, same results).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from grasplink.bus.faults import FaultyLink
from grasplink.bus.lockstep import LockstepNetwork
from grasplink.devices.factory import build_node
from grasplink.devices.node import DeviceNode
from grasplink.devices.sampling import SampleClock
from grasplink.gateway.scripted import ScriptedMaster
from grasplink.profiles import objects as obj
from grasplink.profiles.layouts import PRESET_CODES, spacings_um
from grasplink.simulators import signals as sig
from grasplink.simulators.core import DOMAINS, EMG, PHYSICS, SKIN, Io
from grasplink.simulators.recording import Recorder
from grasplink.simulators.scene import Scene

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


@dataclass
class DomainState:
    name: str
    clock: SampleClock
    signals: list[str]
    times_us: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    values: dict[str, np.ndarray] = field(default_factory=dict)
    last: dict[str, tuple[int, float]] = field(default_factory=dict)


class Simulation:
    """A scene ready to run. `measure=True` accounts CPU time per effect and for the network."""

    def __init__(self, scene: Scene, recorder: Recorder | None = None, *, measure: bool = False):
        self.scene = scene
        self.recorder = recorder
        self.measure = measure
        self.cost_s: dict[str, float] = {}  # effect kind (or "network") -> process time
        # Work done, a deterministic measure of cost: samples computed per domain and
        # effect steps, frames on the bus.
        self.samples: dict[str, int] = {}
        self.effect_steps = 0
        self.nodes: dict[str, DeviceNode] = {}
        self.domain_of = scene.domain_of
        self.effects = {d: [e for e in scene.ordered if e.domain == d] for d in DOMAINS}
        self._endpoints_by_domain = {
            d: [e for e in scene.endpoints if e.domain == d] for d in DOMAINS
        }
        self.sources: dict[str, SceneSource] = {}
        produced = {name for e in scene.effects for name in e.outputs}
        for kind, signal, domain in (
            ("skin", sig.SKIN_FORCE_N, SKIN),
            ("emg", sig.EMG_RAW_UV, EMG),
        ):
            if kind in scene.nodes and signal in produced:
                self.sources[kind] = SceneSource(scene.rate_hz(domain))
        self._build_nodes(produced)
        self.master = self._build_master()
        link = None
        if scene.bus is not None:
            b = scene.bus
            link = FaultyLink(
                scene.context.rng("bus.faults"),
                latency_us=b.latency_us,
                jitter_us=b.jitter_us,
                drop_probability=b.drop_probability,
                error_frames_per_s=b.error_frames_per_s,
            )
        devices = ([self.master] if self.master else []) + list(self.nodes.values())
        self.network = LockstepNetwork(devices, link)
        self.domains: dict[str, DomainState] = {}
        for domain in DOMAINS:
            signals = sorted({n for n, d in self.domain_of.items() if d == domain})
            if signals:
                self.domains[domain] = DomainState(
                    domain, SampleClock(scene.rate_hz(domain), 0), signals
                )
        if recorder is not None:
            for domain, state in self.domains.items():
                recorder.open_domain(domain, state.signals)
            self.network.taps.append(recorder.tap)
        self._power_events = sorted(
            [
                (round(p.at_s * 1e6), "off", p.node)
                for p in (scene.bus.power_loss if scene.bus else [])
            ]
            + [
                (round(p.restore_s * 1e6), "on", p.node)
                for p in (scene.bus.power_loss if scene.bus else [])
                if p.restore_s is not None
            ]
        )
        self.t_us = 0

    # -- construction --------------------------------------------------------------
    def _build_nodes(self, produced: set[str]) -> None:
        for kind, spec in self.scene.nodes.items():
            node = build_node(kind, spec.node_id, self.sources.get(kind))
            self._configure(node, spec)
            self.nodes[kind] = node
        if "belt" in self.nodes:
            self.nodes["belt"].app.simulated_motor = sig.BELT_VELOCITY_MRAD_S in produced
        if "hand" in self.nodes:
            hand = self.nodes["hand"].app
            hand.simulated_actuator = sig.HAND_GRIP_N in produced
            # A scene may start with the object already held: the node boots holding it.
            initial_n = next(
                (
                    getattr(e, "initial_n", 0.0)
                    for e in self.scene.effects
                    if e.kind == "hand.actuator"
                ),
                0.0,
            )
            hand.grip_mn = initial_n * MN_PER_N

    def _configure(self, node: DeviceNode, spec) -> None:
        """Scene settings become the node's stored parameters (they survive its resets)."""
        nvm = node.store.nvm
        if spec.kind == "skin":
            nvm[(obj.SKIN_SAMPLE_RATE_HZ, 0)] = spec.sample_rate_hz
            nvm[(obj.SKIN_SAMPLES_PER_PDO, 0)] = spec.samples_per_pdo
            layout = self.scene.layout_mm or ()
            preset = next(
                (code for code, name in PRESET_CODES.items() if name == self.scene.layout_name), 0
            )
            nvm[(obj.SKIN_LAYOUT_PRESET, 0)] = preset
            if not preset and layout:
                nvm[(obj.SKIN_RIDGE_SPACING_UM, 0)] = len(layout)
                for sub, um in enumerate(spacings_um(layout), start=1):
                    nvm[(obj.SKIN_RIDGE_SPACING_UM, sub)] = um
        elif spec.kind == "emg":
            nvm[(obj.EMG_SAMPLE_RATE_HZ, 0)] = spec.sample_rate_hz

    def _build_master(self) -> ScriptedMaster | None:
        gateway = self.scene.gateway
        if not gateway.enabled:
            return None
        ids = {k: n.node_id for k, n in self.nodes.items()}
        return ScriptedMaster(
            belt_id=ids.get("belt"),
            hand_id=ids.get("hand"),
            belt_mrad_s=gateway.belt_mrad_s,
            hand_grip_n=gateway.hand_grip_n,
        )

    # -- running ---------------------------------------------------------------------
    def run(self, *, realtime: bool = False) -> dict:
        """Run the whole scene; returns the summary (also written by the recorder)."""
        wall0 = time.monotonic()
        cpu0 = time.process_time()
        self.network.start()
        duration_us = self.scene.duration_us
        while self.t_us < duration_us:
            t_end = min(self.t_us + self.scene.chunk_us, duration_us)
            self.step(t_end)
            if realtime:
                delay = wall0 + t_end / 1e6 - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
        summary = self.summary()
        if self.recorder is not None:
            self.recorder.close(summary)
        self.wall_s = time.monotonic() - wall0
        self.cpu_s = time.process_time() - cpu0
        return summary

    def step(self, t_end_us: int) -> None:
        """Advance signals and network from self.t_us to t_end_us."""
        for domain in DOMAINS:
            state = self.domains.get(domain)
            if state is not None:
                # Physics includes the sample at t_end so sensors can interpolate up to it.
                self._step_domain(state, t_end_us if domain == PHYSICS else t_end_us - 1)
        self._read_actuators()
        t0 = time.process_time() if self.measure else 0.0
        self._run_network(t_end_us)
        if self.measure:
            self._charge("network (nodes + bus)", t0)
        self.t_us = t_end_us

    def _charge(self, what: str, since: float) -> None:
        self.cost_s[what] = self.cost_s.get(what, 0.0) + time.process_time() - since

    def _step_domain(self, state: DomainState, t_last_us: int) -> None:
        clock = state.clock
        end = clock.due_until(t_last_us)
        index = np.arange(clock.next_index, end, dtype=np.int64)
        clock.next_index = end
        times = index * 1_000_000 // clock.rate_hz
        for name, values in state.values.items():
            if len(values):  # the previous chunk's last sample, for interpolation across chunks
                state.last[name] = (int(state.times_us[-1]), float(values[-1]))
        state.times_us = times
        state.values = {}
        for endpoint in self._endpoints_by_domain[state.name]:
            for name in endpoint.writes:
                state.values[name] = np.full(len(times), self._command(name))
        io = Io(
            times,
            lambda name, at, s=state: self._read(s, name, at),
            lambda name, values, s=state: s.values.__setitem__(name, values),
        )
        if len(times):
            self.samples[state.name] = self.samples.get(state.name, 0) + len(times)
            for effect in self.effects[state.name]:
                self.effect_steps += 1
                if self.measure:
                    t0 = time.process_time()
                    effect.step(io)
                    self._charge(effect.kind, t0)
                else:
                    effect.step(io)
        for kind, source in self.sources.items():
            signal = sig.SKIN_FORCE_N if kind == "skin" else sig.EMG_RAW_UV
            if self.domain_of.get(signal) == state.name and signal in state.values:
                source.append(times, state.values[signal])
        if self.recorder is not None:
            self.recorder.write_chunk(
                state.name,
                times,
                {n: state.values.get(n, np.full(len(times), np.nan)) for n in state.signals},
            )

    def _read(self, state: DomainState, name: str, at_us: np.ndarray) -> np.ndarray:
        home = self.domain_of[name]
        if home == state.name:
            return state.values[name]
        source = self.domains[home]
        times, values = source.times_us, source.values[name]
        if name in source.last:
            t_prev, v_prev = source.last[name]
            times = np.concatenate([[t_prev], times])
            values = np.concatenate([[v_prev], values])
        return np.interp(at_us, times, values)

    # -- node coupling ------------------------------------------------------------------
    def _command(self, name: str) -> float:
        """A node's actuator command, held over the chunk (zero-order hold).

        Without power the belt motor stops; the hand's gear holds its grip.
        """
        if name == sig.BELT_COMMAND_MRAD_S:
            belt = self.nodes["belt"]
            return float(belt.app.setpoint_mrad_s) if belt.powered else 0.0
        if name == sig.HAND_TARGET_N:
            hand = self.nodes["hand"]
            mn = hand.app.setpoint_mn if hand.powered else hand.app.grip_mn
            return float(mn) / MN_PER_N
        raise KeyError(name)

    def _read_actuators(self) -> None:
        physics = self.domains.get(PHYSICS)
        if physics is None:
            return
        velocity = physics.values.get(sig.BELT_VELOCITY_MRAD_S)
        if "belt" in self.nodes and velocity is not None and len(velocity):
            self.nodes["belt"].app.velocity_mrad_s = float(velocity[-1])
            self.nodes["belt"].app.publish_actual()
        grip = physics.values.get(sig.HAND_GRIP_N)
        if "hand" in self.nodes and grip is not None and len(grip):
            self.nodes["hand"].app.grip_mn = float(grip[-1]) * MN_PER_N
            self.nodes["hand"].app.publish_actual()

    def _run_network(self, t_end_us: int) -> None:
        """Run the bus to just before t_end, applying power events at their exact time."""
        while self._power_events and self._power_events[0][0] < t_end_us:
            at_us, action, kind = self._power_events.pop(0)
            self.network.run_until(at_us - 1)
            self.network.t_us = at_us  # the event happens at its own time, before others at it
            node = self.nodes[kind]
            if action == "off":
                node.power_off()
            else:
                self.network.start_device(node)
        self.network.run_until(t_end_us - 1)

    def summary(self) -> dict:
        scene = self.scene
        return {
            "scene": scene.name,
            "path": scene.path,
            "description": scene.description,
            "seed": scene.seed,
            "duration_s": scene.duration_s,
            "clock": scene.clock,
            "rates_hz": {d: scene.rate_hz(d) for d in self.domains},
            "layout": scene.layout_name or (list(scene.layout_mm) if scene.layout_mm else None),
            "nodes": {
                k: {"node_id": n.node_id, "state": n.state.name} for k, n in self.nodes.items()
            },
            "gateway": scene.gateway.enabled,
            "effects": [e.kind for e in scene.effects],
            "bus_faults": vars(scene.bus) | {"power_loss": [vars(p) for p in scene.bus.power_loss]}
            if scene.bus
            else None,
        }

"""Run a scene: its effects, its nodes on a CAN network, and a recorder.

Time advances in chunks (`[scene] chunk_ms`, default 10 ms). For each chunk
the physics domain steps first (its last sample lands exactly on the chunk
end, so sensor domains can interpolate it), then the skin and EMG domains;
then the network runs to the chunk end, the nodes sampling what the sensor
domains produced. Actuator commands flow back from the nodes at chunk
boundaries. The network is pluggable: the lock-step network runs in virtual
time, as fast as the machine allows, or paced to the wall clock (same code,
same results); a live bus (`simulators/live.py`) runs the nodes in real time
on a python-can bus beside other participants (an external master), and
steps the same per-chunk physics from its own clock as each chunk begins.

In virtual time a closed loop's physics runs ahead: while the nodes' commands have
gone as guessed for a while (held, or a ramp's repeating steps continued: `trends`),
it steps many chunks at once with the guessed commands, then hands them to the network
chunk by chunk; a command that differs from its guess at a chunk end rolls the physics
back to that chunk end (effect snapshots). Every chunk still gets the commands of its
start, so results are the same as chunk by chunk.
Effects that share no signal (the hand's grip and skin, the belt's wearer and EMG)
form independent parts: each runs ahead as far as its own commands have gone as guessed
and is rolled back only by a wrong guess of its own commands.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from grasplink.bus.faults import FaultyLink
from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.protocol import SansIoDevice
from grasplink.devices.node import DeviceNode
from grasplink.devices.sampling import SampleClock
from grasplink.errors import BusError, ConfigError
from grasplink.simulators.bindings import NodeBinding, bind
from grasplink.simulators.core import DOMAINS, PHYSICS, Effect, Endpoint, Io, independent_parts
from grasplink.simulators.live import LiveBus, LiveNetwork
from grasplink.simulators.recording import Recorder
from grasplink.simulators.scene import Scene
from grasplink.simulators.trends import HISTORY, continue_steps

# A scene whose physics hears nothing from the nodes steps in chunks this long at least:
# every effect gives the same samples however time is chunked, and the bus runs exactly
# to any chunk end, so only the per-chunk overhead changes (docs/scenes.md, Chunks).
UNCOUPLED_STEP_US = 500_000
# A coupled scene's physics runs ahead at most this far, and only as far as its
# commands have gone as guessed (a rollback throws away what was run past a wrong guess).
RUN_AHEAD_US = 320_000


@dataclass
class DomainState:
    """A domain's samples: a part's last computed block (stepped by its clock), or the
    chunk the nodes and the recorder last got (`Simulation.domains`: every part's)."""

    name: str
    clock: SampleClock
    signals: list[str]
    times_us: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    values: dict[str, np.ndarray] = field(default_factory=dict)
    last: dict[str, tuple[int, float]] = field(default_factory=dict)


@dataclass
class Part:
    """Effects that share signals with no others (`core.independent_parts`), the nodes whose
    commands drive them, their domains' samples, and how far they have run ahead."""

    effects: dict[str, list[Effect]]  # by domain, in step order
    endpoints: dict[str, list[Endpoint]]  # the command endpoints, by domain
    command_nodes: list[str]
    domains: dict[str, DomainState]
    horizon_us: int = 0  # computed up to here (the last block's end)
    quiet_us: int = 0  # how long its commands have gone as guessed, up to now
    start_us: int = 0  # the last block's start
    # The commands of each chunk of the last block, and the guess for the chunk after it.
    schedule: list[list[float]] = field(default_factory=list)
    # The commands it was given, a chunk's each, newest last (what the guesses continue).
    history: deque[list[float]] = field(default_factory=lambda: deque(maxlen=HISTORY))
    snapshot: list[Callable[[], None]] | None = None  # back to the last block's start


class Simulation:
    """A scene ready to run. `measure=True` accounts CPU time per effect and for the network.

    `controllers` are the sans-IO participants besides the scene's nodes (the NMT master,
    the gateway, extra devices): the caller builds them (see `grasplink.controllers`), the
    engine only puts them on the bus first, in the order given.

    With `live`, the participants run on that bus in real time (`simulators/live.py`);
    with no controllers there, the loop is closed by whatever master is on the bus.

    A scene already given to a Simulation is parsed again (`Scene.fresh`): `self.scene` is
    the one this run steps, so a parsed scene can be run any number of times.
    """

    def __init__(
        self,
        scene: Scene,
        recorder: Recorder | None = None,
        *,
        controllers: Sequence[SansIoDevice] = (),
        measure: bool = False,
        live: LiveBus | None = None,
    ):
        if scene.claimed:  # run before: its effects hold where that run ended
            scene = scene.fresh()
        scene.claimed = True
        self.scene = scene
        self.recorder = recorder
        self.measure = measure
        self.cost_s: dict[str, float] = {}  # effect kind (or "network") -> process time
        # Work done, a deterministic measure of cost: samples computed per domain and
        # effect steps, frames on the bus.
        self.samples: dict[str, int] = {}
        self.effect_steps = 0
        self.controllers = list(controllers)
        self.domain_of = scene.domain_of
        produced = {name for e in scene.effects for name in e.outputs}
        self.bindings: dict[str, NodeBinding] = {
            kind: bind(spec, scene, produced) for kind, spec in scene.nodes.items()
        }
        self.nodes: dict[str, DeviceNode] = {k: b.node for k, b in self.bindings.items()}
        link = None
        if scene.bus is not None and live is not None:
            raise ConfigError(
                f"{scene.path}: bus.faults (link faults, power loss) are simulated by the "
                "in-process bus; on a real bus (--bus) they cannot apply"
            )
        if scene.bus is not None:
            b = scene.bus
            link = FaultyLink(
                scene.context.rng("bus.faults"),
                latency_us=b.latency_us,
                jitter_us=b.jitter_us,
                drop_probability=b.drop_probability,
                error_frames_per_s=b.error_frames_per_s,
            )
        participants = [*self.controllers, *self.nodes.values()]
        self.network: LockstepNetwork | LiveNetwork
        if live is None:
            self.network = LockstepNetwork(participants, link)
        else:
            self.network = LiveNetwork(
                live,
                participants,
                self.step_physics,
                chunk_us=scene.chunk_us,
                duration_us=scene.duration_us,
                name=f"scene {scene.name} on {live.url}",
            )
        # What the nodes and the recorder get, chunk by chunk; the parts compute it.
        self.domains = self._domain_states(set(self.domain_of))
        self.parts = [
            self._part(e, p) for e, p in independent_parts(scene.ordered, scene.endpoints)
        ]
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
        self.step_us = scene.chunk_us
        if not self.coupled:
            self.step_us *= max(1, UNCOUPLED_STEP_US // scene.chunk_us)
        # How far a coupled scene's physics may run ahead of the network (0: chunk by chunk).
        self.run_ahead_us = RUN_AHEAD_US if self.coupled and live is None else 0
        self.rollbacks = 0  # run-aheads cut short by a command that changed

    def _domain_states(self, signals: set[str]) -> dict[str, DomainState]:
        """A state for each domain some of `signals` belong to, at sample 0."""
        states = {}
        for domain in DOMAINS:
            names = sorted(n for n in signals if self.domain_of[n] == domain)
            if names:
                clock = SampleClock(self.scene.rate_hz(domain), 0)
                states[domain] = DomainState(domain, clock, names)
        return states

    def _part(self, effects: list[Effect], endpoints: list[Endpoint]) -> Part:
        signals = {n for e in effects for n in e.outputs} | {n for e in endpoints for n in e.writes}
        return Part(
            {d: [e for e in effects if e.domain == d] for d in DOMAINS},
            {d: [e for e in endpoints if e.domain == d] for d in DOMAINS},
            [e.node for e in endpoints],
            self._domain_states(signals),
        )

    @property
    def coupled(self) -> bool:
        """Whether nodes feed the physics: a command it holds per chunk or an actual value
        it reports per chunk. Only then does the chunk size change what is simulated."""
        return any(e.writes for e in self.scene.endpoints) or any(
            b.actual_simulated for b in self.bindings.values()
        )

    # -- running ---------------------------------------------------------------------
    def run(
        self,
        *,
        realtime: bool = False,
        progress: Callable[[int, int], None] | None = None,
        should_stop: Callable[[], bool] | None = None,
    ) -> dict:
        """Run the scene; returns the summary (also written by the recorder).

        `progress(t_us, duration_us)` is called after every chunk. When `should_stop()`
        turns true the run ends after the current chunk: every file is complete up to
        that time and the summary says `"complete": false` with the time reached. On a
        live bus the run is real time whatever `realtime` says, and `progress` is called
        from this thread while the bus's thread steps the physics: it gets times only.
        """
        wall0 = time.monotonic()
        cpu0 = time.process_time()
        live = isinstance(self.network, LiveNetwork)
        self.network.start()
        duration_us = self.scene.duration_us
        lost: BusError | None = None
        try:
            # Paced runs keep the scene's chunk: the wall clock is met per chunk.
            ahead = self.run_ahead_us and not realtime
            chunks = (
                self._chunks_ahead(duration_us) if ahead else self._chunks(duration_us, realtime)
            )
            if should_stop is None or not should_stop():
                for t_end in chunks:
                    if progress is not None:
                        progress(self.t_us, duration_us)
                    if realtime and not live:
                        delay = wall0 + t_end / 1e6 - time.monotonic()
                        if delay > 0:
                            time.sleep(delay)
                    if should_stop is not None and should_stop():
                        break
        except BusError as exc:  # a live bus lost for good: the files up to then are kept
            lost = exc
        finally:
            if isinstance(self.network, LiveNetwork):
                self.network.stop()  # before the files close: the bus's thread writes them
        summary = self.summary()
        if self.recorder is not None:
            self.recorder.close(summary)
        self.wall_s = time.monotonic() - wall0
        self.cpu_s = time.process_time() - cpu0
        if lost is not None:
            raise lost
        return summary

    def _chunks(self, duration_us: int, realtime: bool) -> Iterator[int]:
        """Step by step to the end; yields each step's end."""
        while self.t_us < duration_us:
            step_us = self.scene.chunk_us if realtime else self.step_us
            t_end = min(self.t_us + step_us, duration_us)
            self.step(t_end)
            yield t_end

    def _chunks_ahead(self, duration_us: int) -> Iterator[int]:
        """Chunk by chunk to the end, each part's physics running ahead while its commands
        go as guessed; yields each chunk's end once the network has run to it.

        A part runs ahead as far as its commands have gone as guessed so far (up to
        `run_ahead_us`): a change nothing foretold runs chunk by chunk, a quiet stretch or
        a ramp of repeating steps in ever longer blocks, and a rollback throws away at
        most what the guesses before it bought.
        """
        chunk_us = self.scene.chunk_us
        while self.t_us < duration_us:
            t0 = self.t_us
            t_end = min(t0 + chunk_us, duration_us)
            for part in self.parts:
                if part.horizon_us < t_end:  # its last block is used up: the next from t0
                    self._run_ahead(part, t0, duration_us)
            self._publish_until(t_end)
            self._read_actuators()
            self._network_to(t_end)
            yield t_end
            for part in self.parts:
                commands = self._commands(part)
                part.history.append(commands)
                done = (t_end - part.start_us) // chunk_us  # chunks of the block run so far
                if commands == part.schedule[done]:
                    part.quiet_us += chunk_us
                    continue
                part.quiet_us = 0
                if t_end < part.horizon_us:
                    # what ran past t_end had a wrong guess: back to the block's start, then
                    # to t_end with the commands its chunks had
                    assert part.snapshot is not None
                    self.rollbacks += 1
                    for restore in part.snapshot:
                        restore()
                    self._compute(part, part.start_us, t_end, part.schedule[:done])

    def _run_ahead(self, part: Part, t0_us: int, duration_us: int) -> None:
        """Compute `part` from t0 as far ahead as its commands have gone as guessed (whole
        chunks: the chunk ends stay on the scene's grid), keeping how to come back to t0."""
        chunk_us = self.scene.chunk_us
        ahead_us = max(chunk_us, min(part.quiet_us, self.run_ahead_us) // chunk_us * chunk_us)
        horizon = min(t0_us + ahead_us, duration_us)
        part.snapshot = self._snapshot(part) if horizon > t0_us + chunk_us else None
        now = self._commands(part)
        if not part.history or part.history[-1] != now:  # (the first block; a NaN)
            part.history.append(now)
        chunks = -(-(horizon - t0_us) // chunk_us)
        history = list(part.history)
        guesses = [continue_steps([c[i] for c in history], chunks) for i in range(len(now))]
        part.start_us = t0_us
        part.schedule = (
            [now, *map(list, zip(*guesses, strict=True))] if now else [now] * (chunks + 1)
        )
        self._compute(part, t0_us, horizon, part.schedule[:chunks])

    def _commands(self, part: Part) -> list[float]:
        return [self.bindings[node].command_value() for node in part.command_nodes]

    def _snapshot(self, part: Part) -> list[Callable[[], None]]:
        """How to come back to now: each effect's state and each domain's last block."""
        effects = [e for domain in DOMAINS for e in part.effects[domain]]
        restores: list[Callable[[], None]] = [e.snapshot().restore for e in effects]
        for state in part.domains.values():
            saved = (state.clock.next_index, state.times_us, state.values, dict(state.last))

            def restore(s: DomainState = state, saved: tuple = saved) -> None:
                s.clock.next_index, s.times_us, s.values, last = saved
                s.last = dict(last)

            restores.append(restore)
        return restores

    def _publish_until(self, t_end_us: int) -> None:
        """The chunk ending at t_end_us reaches the nodes and the recorder: every part's
        samples of it, physics up to and including t_end, the sensors to t_end - 1."""
        for domain, state in self.domains.items():
            side: Literal["left", "right"] = "right" if domain == PHYSICS else "left"
            first = state.times_us[-1] if len(state.times_us) else -1
            state.values = {}
            for part in self.parts:
                computed = part.domains.get(domain)
                if computed is None:
                    continue
                times = computed.times_us
                a = int(times.searchsorted(first, "right"))
                b = int(times.searchsorted(t_end_us, side))
                if a == 0 and b == len(times):  # the block is this chunk (chunk by chunk)
                    state.times_us = times
                    state.values.update(computed.values)
                else:
                    state.times_us = times[a:b]
                    state.values.update({n: v[a:b] for n, v in computed.values.items()})
            self._publish(state)

    def step(self, t_end_us: int) -> None:
        """Advance signals and network from self.t_us to t_end_us.

        On a live bus the physics is stepped by the bus's thread as its time passes
        (`live.PhysicsStepper`); here the engine waits for the bus to get to t_end_us.
        """
        if isinstance(self.network, LiveNetwork):
            self.network.run_until(t_end_us - 1)
            self.t_us = t_end_us
            return
        self.step_physics(t_end_us)
        self._network_to(t_end_us)

    def _network_to(self, t_end_us: int) -> None:
        t0 = time.process_time() if self.measure else 0.0
        self._run_network(t_end_us)
        if self.measure:
            self._charge("network (nodes + bus)", t0)
        self.t_us = t_end_us

    def step_physics(self, t_end_us: int) -> None:
        """Step every domain of one chunk, up to t_end_us, and tell the nodes the actual
        values at its end: the one per-chunk physics step, in virtual and in real time."""
        for part in self.parts:
            self._compute(part, self.t_us, t_end_us, [self._commands(part)])
        self._publish_until(t_end_us)
        self._read_actuators()

    def _compute(self, part: Part, t0_us: int, t_end_us: int, schedule: list[list[float]]) -> None:
        """Step a part's effects, domain by domain, from t0_us up to t_end_us, each chunk
        with its commands of `schedule` (nothing reaches the nodes yet)."""
        for domain in DOMAINS:
            state = part.domains.get(domain)
            if state is not None:
                # Physics includes the sample at t_end so sensors can interpolate up to it.
                t_last_us = t_end_us if domain == PHYSICS else t_end_us - 1
                self._step_domain(part, state, t_last_us, t0_us, schedule)
        part.horizon_us = t_end_us

    def _charge(self, what: str, since: float) -> None:
        self.cost_s[what] = self.cost_s.get(what, 0.0) + time.process_time() - since

    def _step_domain(
        self,
        part: Part,
        state: DomainState,
        t_last_us: int,
        t0_us: int,
        schedule: list[list[float]],
    ) -> None:
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
        for endpoint in part.endpoints[state.name]:
            for name in endpoint.writes:
                state.values[name] = self._held(part, state, times, t0_us, schedule, endpoint.node)

        # An earlier domain's signal at this chunk's sample times is interpolated once
        # however many effects read it; read-only, as every signal an effect is handed.
        interpolated: dict[str, np.ndarray] = {}

        def read(name: str, at_us: np.ndarray, s: DomainState = state) -> np.ndarray:
            if at_us is not times or self.domain_of[name] == s.name:
                return self._read(part, s, name, at_us)
            if name not in interpolated:
                values = self._read(part, s, name, at_us)
                values.flags.writeable = False
                interpolated[name] = values
            return interpolated[name]

        def write(name: str, values: np.ndarray, s: DomainState = state) -> None:
            s.values[name] = values

        io = Io(times, read, write)
        if len(times):
            self.samples[state.name] = self.samples.get(state.name, 0) + len(times)
            for effect in part.effects[state.name]:
                self.effect_steps += 1
                if self.measure:
                    t0 = time.process_time()
                    effect.step(io)
                    self._charge(effect.kind, t0)
                else:
                    effect.step(io)

    def _held(
        self,
        part: Part,
        state: DomainState,
        times: np.ndarray,
        t0_us: int,
        schedule: list[list[float]],
        node: str,
    ) -> np.ndarray:
        """A node's command at each sample: its chunk's, zero-order held (a chunk's samples
        are those chunk by chunk computes with it: physics up to and including its end,
        the sensors to its end - 1)."""
        i = part.command_nodes.index(node)
        values = [commands[i] for commands in schedule]
        if values.count(values[0]) == len(values):
            return np.full(len(times), values[0])
        ends = t0_us + self.scene.chunk_us * np.arange(1, len(values), dtype=np.int64)
        side: Literal["left", "right"] = "left" if state.name == PHYSICS else "right"
        return np.asarray(values)[ends.searchsorted(times, side)]

    def _publish(self, state: DomainState) -> None:
        """A domain's chunk reaches the sensor nodes and the recorder."""
        times = state.times_us
        for binding in self.bindings.values():
            sensor = binding.sensor
            if sensor and self.domain_of.get(sensor[0]) == state.name and sensor[0] in state.values:
                binding.feed_sensor(times, state.values[sensor[0]])
        if self.recorder is not None:
            self.recorder.write_chunk(
                state.name,
                times,
                {n: state.values.get(n, np.full(len(times), np.nan)) for n in state.signals},
            )

    def _read(self, part: Part, state: DomainState, name: str, at_us: np.ndarray) -> np.ndarray:
        home = self.domain_of[name]
        if home == state.name:
            return state.values[name]
        source = part.domains[home]
        times, values = source.times_us, source.values[name]
        if name in source.last:
            t_prev, v_prev = source.last[name]
            times = np.concatenate([[t_prev], times])
            values = np.concatenate([[v_prev], values])
        return np.interp(at_us, times, values)

    # -- node coupling ------------------------------------------------------------------
    def _read_actuators(self) -> None:
        """Each node with a simulated actuator hears its actual value at the chunk end."""
        physics = self.domains.get(PHYSICS)
        if physics is None:
            return
        for binding in self.bindings.values():
            actual = physics.values.get(binding.actual) if binding.actual else None
            if actual is not None and len(actual):
                binding.report_actual(float(actual[-1]))

    def _run_network(self, t_end_us: int) -> None:
        """Run the bus to just before t_end, applying power events at their exact time."""
        assert isinstance(self.network, LockstepNetwork)
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
        rates = {
            kind: {"sample_rate_hz": node["sample_rate_hz"]}
            for kind, node in scene.node_settings().items()
            if "sample_rate_hz" in node
        }
        live = self.network if isinstance(self.network, LiveNetwork) else None
        summary = {
            "scene": scene.name,
            "path": scene.path,
            "description": scene.description,
            "seed": scene.seed,
            "duration_s": scene.duration_s,
            "simulated_s": self.t_us / 1e6,
            "complete": self.t_us >= scene.duration_us,
            "clock": scene.clock,
            "rates_hz": {d: scene.rate_hz(d) for d in self.domains},
            "layout": scene.layout_name or (list(scene.layout_mm) if scene.layout_mm else None),
            "nodes": {
                k: {"node_id": n.node_id, "state": n.state.name} | rates.get(k, {})
                for k, n in self.nodes.items()
            },
            "controller": scene.controller.name if self.controllers or not live else "external",
            # the [controller] table as run: a replay of the log needs the same settings,
            # whatever the scene file says later
            "controller_options": scene.controller.options if scene.controller.name else None,
            "effects": [e.kind for e in scene.effects],
            "bus_faults": vars(scene.bus) | {"power_loss": [vars(p) for p in scene.bus.power_loss]}
            if scene.bus
            else None,
        }
        if live is not None:
            # what ran on which bus, and how well real time was kept (a lock-step run's
            # summary is a pure function of the scene: it has no such entry)
            summary["bus"] = {
                "url": live.url,
                "master": "scene" if self.controllers else "external",
                "realtime": live.timing(),
            }
        return summary

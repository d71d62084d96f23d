"""The closed loop in silico, trial by trial: does the feedback (and the reflex) stop the slip?

One *trial* is the loop of `scenes/loop_headline.toml` — skin → gateway →
belt → virtual wearer → EMG → gateway → hand → object — with one feedback
mode, the reflex on or off, one slip speed and one seed (the wearer's
reaction times, identifications and scatter, the ridge dips, the noise).
Its physics is that scene's: an object held at 5 N (contraction level e1)
is pulled out of the hand with at most 9 N, so it stops once the grip
exceeds 9 N / (2 · 0.7813) = 5.76 N; e2 (8 N) or the reflex's first step
holds it.

The *outcome* of a trial comes from the physics signals (the truth) and the
bus: the belt and hand RPDOs and the EMG envelope TPDOs, unpacked through
the nodes' EDS mappings (`PdoCodec`), so it says what went over the wire,
not what the gateway thought it sent. Both are collected in memory while
the scene runs (a network tap and the physics domain after each chunk),
bounded by the trial's length; a dropped object ends its trial.

`run_report` runs the grid (mode × reflex × speed × seed) on every local core
or a Dask cluster (`grasplink.evaluation.workers`) and writes loop.md,
loop.json and loop.png. Drivers: `grasplink bench loop` and
benchmarks/bench_loop.py.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from grasplink.bus.faults import ErrorFrame
from grasplink.core.frames import Frame
from grasplink.core.protocol import SansIoDevice
from grasplink.errors import ConfigError, PdoError
from grasplink.evaluation import least_force
from grasplink.gateway import roles
from grasplink.gateway.config import EmgConfig, GatewayConfig, scene_config
from grasplink.gateway.emg import EmgCalibration, EmgIntentDecoder
from grasplink.gateway.feedback import FeedbackConfig
from grasplink.gateway.levels import DEFAULT_FORCE_ENTRIES
from grasplink.gateway.plausibility import PlausibilityConfig
from grasplink.gateway.reflex import ReflexConfig
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.profiles.pdo_codec import PdoCodec
from grasplink.simulators import signals as sig
from grasplink.simulators.core import PHYSICS
from grasplink.simulators.engine import Simulation
from grasplink.simulators.scene import Scene, parse_scene
from grasplink.simulators.synth import LOAD_KG

#: Builds the sans-IO participants a scene's `[controller]` names (grasplink.controllers).
ControllerFactory = Callable[[Scene], Sequence[SansIoDevice]]

US_PER_S = 1_000_000
MN_PER_N = 1000.0

# -- the trial ---------------------------------------------------------------------------

#: Feedback modes in report order, with the names the report uses.
MODES: dict[str, str] = {
    "off": "none",
    "slip_occurrence": "slip occurrence",
    "slip_speed": "slip speed",
    "grip_force": "grip force",
    "force_and_slip": "force + slip",
}
# The nodes the closed loop senses and drives, in scene order (the network's frame order):
# the loop's own choice, not every registered kind (a gateway masters only a scene's nodes).
LOOP_KINDS = ("skin", "emg", "belt", "hand")
LAYOUT = "alpha0.1"
SKIN_END_MM = float(sum(LAYOUTS_MM[LAYOUT]))  # 84 mm: the leading edge past it has left the hand
START_S = 1.0  # the pull starts (loop_headline.toml)
START_MM = -8.0  # the leading edge 8 mm before the first ridge (loop_headline.toml)
# After a slip that was not stopped would have dropped: long enough for the reflex to hold
# (2 s), release (2 N/s from at most 5 + 0.1 * 150 = 20 N: 7.5 s even with no floor) and
# the object to slip again if that release went too far; see `Trial.duration_s`.
SETTLE_S = 12.0
TASKS = ("pulled", least_force.DRY_TASK, least_force.WET_TASK)
THESIS_THRESHOLD_MM_S = 45.0  # ReflexConfig default: the human limit on an 80 mm skin
MIN_REST_S = 0.1  # a rest shorter than this (a ridge dip touching 0 mm/s) is not a stop
REFLEX = ReflexConfig()
OCCURRENCE_MRAD_S = FeedbackConfig().occurrence_velocity_mrad_s  # a slip of unknown speed
#: A belt value held this long ended its ramp: two of the gateway's command intervals.
SETTLED_HOLD_S = 2 * PlausibilityConfig().command_interval_ms / 1000
RELAX_FORCE_LEVEL = 3  # wearer.virtual's default: from this force level it relaxes
PHYSICS_SIGNALS = (
    sig.OBJECT_POSITION_MM,
    sig.OBJECT_SLIPPING,
    sig.HAND_GRIP_N,
    sig.HAND_CRUSHED,
)


@dataclass(frozen=True)
class Trial:
    """One closed-loop run: a feedback mode, the reflex on or off, a slip speed, a seed."""

    mode: str
    reflex: bool
    speed_mm_s: float
    seed: int
    threshold_mm_s: float = THESIS_THRESHOLD_MM_S
    settle_s: float = SETTLE_S
    task: str = "pulled"  # or "least_force", "least_force_wet" (evaluation/least_force.py)

    @property
    def duration_s(self) -> float:
        """Until an unstopped slip has certainly left the skin, then `settle_s` to see the
        object stay put; a wet object's also until the wearer has answered the wetting."""
        crossing_s = (SKIN_END_MM - START_MM) / self.speed_mm_s
        end_s = START_S + crossing_s
        if self.task == least_force.WET_TASK:
            wet = least_force.TaskObject(self.speed_mm_s, wet=True)
            end_s = max(end_s, wet.wetting_s(START_S) + least_force.AFTER_WETTING_S)
        return round(end_s + self.settle_s, 3)


def scene_data(trial: Trial) -> dict:
    """The scene of a trial: loop_headline.toml's nodes and physics, the trial's settings;
    the least-force task swaps the object, its load and the wearer's training."""
    if trial.task not in TASKS:
        raise ConfigError(f"task: expected one of {', '.join(TASKS)}, got {trial.task!r}")
    data = _headline_scene(trial)
    if trial.task != "pulled":
        wet = trial.task == least_force.WET_TASK
        return least_force.adapt(data, trial.speed_mm_s, START_S, START_MM, wet=wet)
    return data


def _headline_scene(trial: Trial) -> dict:
    return {
        "scene": {
            "name": f"loop-{trial.mode}-{'reflex' if trial.reflex else 'noreflex'}"
            f"-{trial.speed_mm_s:g}mm_s-seed{trial.seed}",
            "description": "grasplink bench loop trial",
            "seed": trial.seed,
            "duration_s": trial.duration_s,
        },
        "nodes": {kind: {} for kind in LOOP_KINDS} | {"skin": {"layout": LAYOUT}},
        "controller": {
            "type": "gateway",
            "nodes": {"emg": {"grip_levels_n": [0.0, 5.0, 8.0, 11.0, 14.0, 20.0]}},
            "feedback": {"mode": trial.mode},
            "reflex": {"enabled": trial.reflex, "threshold_mm_s": trial.threshold_mm_s},
        },
        "effects": [
            {"type": "hand.actuator", "initial_n": 5.0, "crush_limit_n": 25.0},
            {"type": "load.scripted", "mass_kg": LOAD_KG},
            {
                "type": "object.pulled",
                "speed_mm_s": float(trial.speed_mm_s),
                "pull_n": 9.0,
                "start_s": START_S,
                "start_mm": START_MM,
            },
            {"type": "object.ridge_dips", "depth_mm_s": [4.0, 15.0], "recovery_s": 0.05},
            {"type": "belt.motor"},
            {"type": "wearer.virtual", "rest_level": 1},
            {"type": "skin.fsr"},
            {"type": "skin.ridge_contacts"},
            {"type": "skin.hysteresis"},
            {"type": "noise.white", "std": 0.02},
            {"type": "noise.drift", "std": 0.05, "corner_hz": 0.3},
            {"type": "skin.saturation"},
            {"type": "emg.surface"},
        ],
    }


# -- what a trial records ------------------------------------------------------------------


@dataclass
class Series:
    """(time, value) pairs appended as they come; arrays on demand."""

    t_s: list[float] = field(default_factory=list)
    value: list[float] = field(default_factory=list)

    def add(self, t_s: float, value: float) -> None:
        self.t_s.append(t_s)
        self.value.append(value)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.t_s, dtype=float), np.asarray(self.value, dtype=float)


class BusLog:
    """A network tap keeping what the outcome needs from the bus, unpacked as the gateway
    configuration binds it (roles.py): the belt's target velocity and the hand's target
    grip from the RPDOs the loop writes (ours, or a vendor's drive in its units); the EMG
    envelope from its TPDO and, replayed through the gateway's own EMG calibration in bus
    order, the voluntary grip the gateway knew when each hand RPDO went out.
    """

    def __init__(self, config: GatewayConfig):
        emg = config.nodes["emg"]
        assert isinstance(emg, EmgConfig)
        self.belt = Series()  # mrad/s
        self.hand = Series()  # N commanded
        self.voluntary_n: list[float] = []  # what the wearer's EMG asked for, per hand RPDO
        self.envelope = Series()  # µV
        self._intent = EmgIntentDecoder(
            EmgCalibration(emg.e_min_uv, emg.e_max_uv),
            mode=emg.grip_mode,
            grip_levels_n=emg.grip_levels_n,
            grip_max_n=emg.grip_max_n,
        )
        self.calibration = self._intent.calibration
        self._voluntary_n = math.nan
        self._rpdos = {}
        for kind in ("belt", "hand"):
            node = config.nodes[kind]
            codec = PdoCodec.from_od(node.dictionary(), node.node_id)
            binding = node.binding
            if not isinstance(binding, roles.DriveBinding):
                binding = roles.own_drive(kind, codec)
            rpdo = codec.rpdo(binding.rpdo)
            var = next(v for v in rpdo.map if (v.od.index, v.od.subindex) == binding.target)
            self._rpdos[rpdo.cob_id] = (kind, rpdo, var, binding.units_per_command)
        envelope = emg.binding if isinstance(emg.binding, roles.EmgBinding) else roles.OWN_EMG
        self._envelope = envelope
        self._emg = PdoCodec.from_od(emg.dictionary(), emg.node_id)
        self._emg_ids = self._emg.tpdo_can_ids()

    def outcome(self, physics: dict[str, np.ndarray], skin_end_mm: float) -> Outcome:
        """The trial's `outcome` from its physics and the traffic this log kept."""
        return outcome(
            physics,
            belt=self.belt.arrays(),
            hand=self.hand.arrays(),
            voluntary_n=np.asarray(self.voluntary_n, dtype=float),
            envelope=self.envelope.arrays(),
            calibration=self.calibration,
            skin_end_mm=skin_end_mm,
        )

    def tap(self, t_us: int, frame: Frame | ErrorFrame, sender: object) -> None:
        if isinstance(frame, ErrorFrame):
            return  # no CAN-ID, no data
        can_id = frame.can_id
        if can_id in self._emg_ids:
            try:
                values = self._emg.decode(can_id, frame.data)
            except PdoError:
                return  # the gateway drops it too
            raw = values.get(self._envelope.envelope)
            if raw is not None:
                envelope = float(raw) * self._envelope.uv_per_unit
                self.envelope.add(t_us / US_PER_S, envelope)
                intent = self._intent.update(t_us, envelope)
                if intent is not None:
                    self._voluntary_n = intent.grip_n
            return
        target = self._rpdos.get(can_id)
        if target is None:
            return
        kind, rpdo, var, units_per_command = target
        if len(frame.data) != (rpdo.length + 7) // 8:
            return
        rpdo.data = bytearray(frame.data)
        command = float(var.raw) / units_per_command  # the loop's units: mrad/s, mN
        if kind == "belt":
            self.belt.add(t_us / US_PER_S, command)
        else:
            self.hand.add(t_us / US_PER_S, command / MN_PER_N)
            self.voluntary_n.append(self._voluntary_n)


class PhysicsLog:
    """The physics signals the outcome needs, chunk by chunk; notices a drop to end the run."""

    def __init__(self, sim: Simulation, skin_end_mm: float):
        self.sim = sim
        self.skin_end_mm = skin_end_mm
        self.t_us: list[np.ndarray] = []
        self.values: dict[str, list[np.ndarray]] = {name: [] for name in PHYSICS_SIGNALS}
        self.dropped = False

    def chunk(self, t_us: int, duration_us: int) -> None:
        state = self.sim.domains[PHYSICS]
        self.t_us.append(state.times_us.copy())
        for name in PHYSICS_SIGNALS:
            self.values[name].append(np.asarray(state.values[name], dtype=float).copy())
        position = state.values[sig.OBJECT_POSITION_MM]
        self.dropped = self.dropped or bool(len(position) and np.max(position) > self.skin_end_mm)

    def arrays(self) -> dict[str, np.ndarray]:
        out = {"t_s": np.concatenate(self.t_us) / US_PER_S if self.t_us else np.zeros(0)}
        for name, parts in self.values.items():
            out[name] = np.concatenate(parts) if parts else np.zeros(0)
        return out


# -- the outcome -----------------------------------------------------------------------------


@dataclass
class Outcome:
    """What happened in one trial. Times in s from the start of the run; None: it did not."""

    stopped: bool  # at rest (for MIN_REST_S or more) at the end, never past the skin's end
    dropped: bool  # the leading edge passed the skin's end
    crushed: bool  # hand.crushed latched
    slip_episodes: int  # times the object started sliding (a re-slip after a stop counts)
    end_s: float  # the last sample (a drop ends a trial early)
    onset_s: float | None = None  # first sample with object.slipping
    first_stop_s: float | None = None  # start of the first rest after onset (even if lost)
    first_stop_mm: float | None = None  # where the leading edge was then
    stop_s: float | None = None  # start of the final rest (stopped trials)
    slip_distance_mm: float | None = None  # travel from onset to the final rest (stopped)
    time_to_stop_s: float | None = None  # stop_s - onset_s
    grip_mean_n: float | None = None  # mean hand.grip_n from onset to the end of the trial
    i_emg: float | None = None  # mean EMG intensity over the same span (see `i_emg`)
    belt_latency_s: float | None = None  # first belt RPDO after onset changing the display
    belt_first_mrad_s: float | None = None  # the velocity that change's ramp settles at
    slip_belt_latency_s: float | None = None  # first slip-belt RPDO (velocity < 0) after onset
    force_belt_max_mrad_s: float | None = None  # fastest force-belt RPDO after onset
    slip_belt_max_mrad_s: float | None = None  # fastest slip-belt RPDO after onset (magnitude)
    slip_shown_after_stop_s: float | None = None  # last slip-belt RPDO after the final stop
    reflex_latency_s: float | None = None  # first hand RPDO after onset above voluntary grip


def stops(t_s: np.ndarray, slipping: np.ndarray, min_rest_s: float) -> list[tuple[int, int]]:
    """(first, last index) of each run of rest samples lasting at least `min_rest_s`."""
    rest = (slipping < 0.5).astype(np.int8)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], rest, [0]))))
    runs = zip(edges[::2], edges[1::2] - 1, strict=True)
    return [(int(a), int(b)) for a, b in runs if t_s[b] - t_s[a] >= min_rest_s]


def i_emg(envelope_uv: np.ndarray, calibration: EmgCalibration) -> float | None:
    """Thesis eq. 2.1's effort: I_EMG = (1/T) Σ (e(i) − e_min) / (e_max − e_min).

    e(i) is the EMG node's envelope (the rectified, integrated EMG the thesis used) at
    each update, with the gateway's calibration; below e_min counts 0 (rest is no effort),
    above e_max counts as it is (an e5 contraction costs more than e4).
    """
    if not len(envelope_uv):
        return None
    span = calibration.e_max_uv - calibration.e_min_uv
    return float(np.mean(np.maximum(envelope_uv - calibration.e_min_uv, 0.0) / span))


def outcome(
    physics: dict[str, np.ndarray],
    *,
    belt: tuple[np.ndarray, np.ndarray],
    hand: tuple[np.ndarray, np.ndarray],
    voluntary_n: np.ndarray,
    envelope: tuple[np.ndarray, np.ndarray],
    calibration: EmgCalibration,
    skin_end_mm: float = SKIN_END_MM,
    min_rest_s: float = MIN_REST_S,
) -> Outcome:
    """The outcome of one trial from its physics signals and its bus traffic.

    `physics` holds `t_s` and PHYSICS_SIGNALS; `belt` and `hand` are (t_s, target) of the
    RPDOs (mrad/s, N), `voluntary_n` the wearer's EMG grip at each hand RPDO, `envelope`
    (t_s, µV) the EMG TPDOs. Stopped means: never past `skin_end_mm`, and the last sample
    ends a rest of at least `min_rest_s`; the stop is the start of that final rest, so a
    re-slip after an earlier stop counts in distance and time.
    """
    t = physics["t_s"]
    position = physics[sig.OBJECT_POSITION_MM]
    slipping = physics[sig.OBJECT_SLIPPING]
    end_s = float(t[-1]) if len(t) else 0.0
    crushed = bool(len(t) and np.max(physics[sig.HAND_CRUSHED]) > 0.5)
    dropped = bool(len(t) and np.max(position) > skin_end_mm)
    moving = np.flatnonzero(slipping >= 0.5)
    if not len(moving):
        return Outcome(False, dropped, crushed, 0, end_s)
    first = int(moving[0])
    onset_s = float(t[first])
    rests = [(a, b) for a, b in stops(t, slipping, min_rest_s) if a > first]
    episodes = 1 + sum(1 for a, b in rests if b < len(t) - 1)
    stopped = not dropped and bool(rests) and rests[-1][1] == len(t) - 1
    first_stop_s = float(t[rests[0][0]]) if rests else None
    first_stop_mm = float(position[rests[0][0]]) if rests else None
    stop_s = distance = time_to_stop = None
    if stopped:
        stop = rests[-1][0]
        stop_s = float(t[stop])
        distance = float(position[stop] - position[max(first - 1, 0)])
        time_to_stop = stop_s - onset_s
    after = slice(first, None)
    grip_mean = float(np.mean(physics[sig.HAND_GRIP_N][after]))
    env_t, env = envelope
    effort = i_emg(env[env_t >= onset_s], calibration)
    belt_latency, belt_first = first_change(*belt, onset_s)
    if belt_latency is not None:
        belt_first = settled_value(*belt, belt_latency)
    belt_t, belt_v = belt
    slip_belt = np.flatnonzero((belt_t >= onset_s) & (belt_v < 0))
    slip_belt_latency = float(belt_t[slip_belt[0]] - onset_s) if len(slip_belt) else None
    force_belt = belt_v[(belt_t >= onset_s) & (belt_v > 0)]
    force_belt_max = float(np.max(force_belt)) if len(force_belt) else None
    slip_belt_max = float(-np.min(belt_v[slip_belt])) if len(slip_belt) else None
    shown_after_stop = None
    if stop_s is not None:
        late = belt_t[(belt_t >= stop_s) & (belt_v < 0)]
        shown_after_stop = float(late[-1] - stop_s) if len(late) else 0.0
    hand_t, hand_n = hand
    # a command that rose above the wearer's grip: the grip command is slew-limited, so a
    # command still ramping down to a grip the wearer relaxed to is above it, yet no reflex
    previous_n = np.concatenate([[-np.inf], hand_n[:-1]])
    raised = np.flatnonzero(
        (hand_t >= onset_s)
        & np.isfinite(voluntary_n)
        & (hand_n > voluntary_n + 0.5 / MN_PER_N)
        & (hand_n > previous_n)
    )
    reflex_latency = float(hand_t[raised[0]] - onset_s) if len(raised) else None
    return Outcome(
        stopped=bool(stopped),
        dropped=dropped,
        crushed=crushed,
        slip_episodes=episodes,
        end_s=end_s,
        onset_s=onset_s,
        first_stop_s=first_stop_s,
        first_stop_mm=first_stop_mm,
        stop_s=stop_s,
        slip_distance_mm=distance,
        time_to_stop_s=time_to_stop,
        grip_mean_n=grip_mean,
        i_emg=effort,
        belt_latency_s=None if belt_latency is None else belt_latency - onset_s,
        belt_first_mrad_s=belt_first,
        slip_belt_latency_s=slip_belt_latency,
        force_belt_max_mrad_s=force_belt_max,
        slip_belt_max_mrad_s=slip_belt_max,
        slip_shown_after_stop_s=shown_after_stop,
        reflex_latency_s=reflex_latency,
    )


def first_change(
    t_s: np.ndarray, value: np.ndarray, onset_s: float
) -> tuple[float | None, float | None]:
    """(time, value) of the first command at or after onset that differs from the one before.

    Commands are refreshed periodically, so a repeat is not news; before any command the
    display was still (0).
    """
    before = value[t_s < onset_s]
    shown = float(before[-1]) if len(before) else 0.0
    later = np.flatnonzero((t_s >= onset_s) & (value != shown))
    if not len(later):
        return None, None
    return float(t_s[later[0]]), float(value[later[0]])


def settled_value(
    t_s: np.ndarray, value: np.ndarray, from_s: float, hold_s: float = SETTLED_HOLD_S
) -> float:
    """The value the commands from `from_s` on settle at: the first one held `hold_s`.

    The gateway slews belt commands (`belt_slew_mrad_s2`), one step per command interval
    at most, so a new display goes out as a ramp and the display the wearer feels is
    where the ramp ends: the first value that outlasts a step. A ramp still moving at
    the end of the log settles at its last command.
    """
    later = slice(int(np.searchsorted(t_s, from_s)), None)
    t, v = t_s[later], value[later]
    starts = np.flatnonzero(np.concatenate(([True], v[1:] != v[:-1])))
    ends_s = np.append(t[starts[1:]], np.inf)
    held = np.flatnonzero(ends_s - t[starts] >= hold_s)
    return float(v[starts[held[0]]] if len(held) else v[-1])


def run_trial(trial: Trial, controllers_for: ControllerFactory) -> Outcome:
    """Run one trial in virtual time and judge it."""
    return judge(parse_scene(scene_data(trial), f"<trial {trial}>"), controllers_for)


def judge(scene: Scene, controllers_for: ControllerFactory) -> Outcome:
    """Run a closed-loop scene (skin, EMG, belt and hand nodes, a gateway) and judge it.

    A drop ends the run at once: nothing after it changes the outcome.
    """
    sim = Simulation(scene, None, controllers=list(controllers_for(scene)))
    if scene.controller.name != "gateway" or not set(LOOP_KINDS) <= set(scene.nodes):
        kinds = f"{', '.join(LOOP_KINDS[:-1])} and {LOOP_KINDS[-1]}"
        raise ConfigError(
            f"{scene.path}: a closed-loop scene needs {kinds} nodes and "
            '[controller] type = "gateway"'
        )
    bus = BusLog(scene_config(scene.controller.params(), scene.node_settings()))
    sim.network.taps.append(bus.tap)
    skin_end_mm = float(sum(scene.layout_mm or ()))
    physics = PhysicsLog(sim, skin_end_mm)
    sim.run(progress=physics.chunk, should_stop=lambda: physics.dropped)
    return bus.outcome(physics.arrays(), skin_end_mm)


# -- the grid ----------------------------------------------------------------------------------

SPEEDS_MM_S = (10, 20, 30, 40, 45, 60, 90, 120, 150)
QUICK_SPEEDS_MM_S = (20, 60, 150)
SEEDS = tuple(range(1, 11))
QUICK_SEEDS = (1,)
HEADLINE_THRESHOLD_MM_S = 30.0  # loop_headline.toml's reflex threshold
# The fastest slip this loop's wearer stops (loop_headline.toml): shown after the second
# ridge contact (the first spacing, 19 mm, on alpha0.1), reaction 1.75 s (ch. 2.4.4) plus
# ~0.35 s of EMG envelope, motor delay and hand: (84 - 19) / (1.75 + 0.35) ≈ 31 mm/s. An
# object sliding onto the skin is flagged at its arrival (0 mm in: ≈ 40 mm/s); the bands
# keep the limit of an object already on the skin, which shows no arrival.
FIRST_SPACING_MM = float(LAYOUTS_MM[LAYOUT][0])
WEARER_LIMIT_MM_S = (SKIN_END_MM - FIRST_SPACING_MM) / (1.75 + 0.35)


def grid(quick: bool) -> list[Trial]:
    """Every mode with and without the reflex (thesis threshold), every speed and seed; and
    force + slip with loop_headline's 30 mm/s threshold, for the gap between the two."""
    speeds = QUICK_SPEEDS_MM_S if quick else SPEEDS_MM_S
    seeds = QUICK_SEEDS if quick else SEEDS
    trials = [
        Trial(mode, reflex, speed, seed)
        for mode in MODES
        for reflex in (False, True)
        for speed in speeds
        for seed in seeds
    ]
    trials += [
        Trial("force_and_slip", True, speed, seed, HEADLINE_THRESHOLD_MM_S)
        for speed in speeds
        for seed in seeds
    ]
    return trials


def row_key(trial: Trial) -> str:
    """The report row a trial belongs to: mode, reflex and (when not the thesis's) threshold."""
    label = f"{MODES[trial.mode]}, {'reflex' if trial.reflex else 'no reflex'}"
    if trial.reflex and trial.threshold_mm_s != THESIS_THRESHOLD_MM_S:
        label += f" at {trial.threshold_mm_s:g} mm/s"
    return label


def speed_band(speed_mm_s: float, threshold_mm_s: float = THESIS_THRESHOLD_MM_S) -> str:
    if speed_mm_s <= WEARER_LIMIT_MM_S:
        return "wearer"
    return "gap" if speed_mm_s < threshold_mm_s else "reflex"


BANDS = {
    "wearer": f"≤ {WEARER_LIMIT_MM_S:.0f} mm/s (a wearer can)",
    "gap": f"{WEARER_LIMIT_MM_S:.0f}–{THESIS_THRESHOLD_MM_S:g} mm/s (between)",
    "reflex": f"≥ {THESIS_THRESHOLD_MM_S:g} mm/s (the reflex's)",
}


def trial_job(trial: Trial, controllers_for: ControllerFactory) -> dict:
    """One trial in a worker process: the trial and its outcome as plain values."""
    return {**asdict(trial), **asdict(run_trial(trial, controllers_for))}


def run_trials(
    trials: Sequence[Trial],
    controllers_for: ControllerFactory,
    workers: int | None = None,
    log: Callable[[str], None] = print,
    dask: str | None = None,
) -> list[dict]:
    """Every trial on `workers` local processes (None: all cores; 1: in this process) or on
    the Dask scheduler at `dask`; results in trial order (a trial's seed is its own)."""
    import functools
    import time

    from grasplink.evaluation import workers as wk

    started = time.monotonic()

    def progress(done: int, total: int) -> None:
        if done % 50 == 0 or done == total:
            log(f"  {done}/{total} trials, {time.monotonic() - started:.0f} s")

    if dask is None:
        workers = max(1, min(wk.local_cores() if workers is None else workers, len(trials)))
    with wk.open_workers(workers, dask) as pool:
        job = functools.partial(trial_job, controllers_for=controllers_for)
        rows = pool.map(job, trials, progress if pool.count > 1 else None)
        log(f"{len(trials)} trials in {time.monotonic() - started:.1f} s on {pool.describe()}")
    return rows


# -- figures -----------------------------------------------------------------------------------


def median_of(values: Sequence[float | None]) -> float | None:
    """The median of the values measured (None: not measured); None if there are none."""
    finite = [v for v in values if v is not None]
    return float(np.median(finite)) if finite else None


def mean_of(values: Sequence[float | None]) -> float | None:
    finite = [v for v in values if v is not None]
    return float(np.mean(finite)) if finite else None


def pct_of(flags: Sequence[bool]) -> float | None:
    """The share of true flags in %; None for no flags."""
    return 100.0 * sum(flags) / len(flags) if flags else None


def summarise(rows: Sequence[dict]) -> dict:
    """The figures of a group of trials (empty group: n = 0 and None everywhere)."""
    stopped = [r for r in rows if r["stopped"]]
    effort = mean_of([r["i_emg"] for r in rows])
    stopped_pct = pct_of([r["stopped"] for r in rows])
    return {
        "n": len(rows),
        "stopped_pct": stopped_pct,
        "first_stop_pct": pct_of([r["first_stop_s"] is not None for r in rows]),
        "dropped_pct": pct_of([r["dropped"] for r in rows]),
        "crushed": sum(r["crushed"] for r in rows),
        "reslip_pct": pct_of([r["slip_episodes"] > 1 for r in rows]),
        "slip_distance_median_mm": median_of([r["slip_distance_mm"] for r in stopped]),
        "time_to_stop_median_s": median_of([r["time_to_stop_s"] for r in stopped]),
        "grip_mean_n": mean_of([r["grip_mean_n"] for r in rows]),
        "i_emg": effort,
        "success_to_effort": None
        if stopped_pct is None or not effort
        else stopped_pct / 100.0 / effort,
        "belt_latency_median_s": median_of([r["belt_latency_s"] for r in rows]),
        "slip_belt_latency_median_s": median_of([r.get("slip_belt_latency_s") for r in rows]),
        "reflex_pct": pct_of([r["reflex_latency_s"] is not None for r in rows]),
        "reflex_latency_median_s": median_of([r["reflex_latency_s"] for r in rows]),
    }


def aggregate(rows: Sequence[dict]) -> dict:
    """Figures per row (mode × reflex), per row and band, per row and speed."""
    by_row: dict[str, list[dict]] = {}
    for r in rows:
        by_row.setdefault(row_key(trial_of(r)), []).append(r)
    out: dict = {"rows": {}, "bands": {}, "speeds": {}}
    for key, members in by_row.items():
        out["rows"][key] = summarise(members)
        out["bands"][key] = {
            band: summarise([r for r in members if speed_band(r["speed_mm_s"]) == band])
            for band in BANDS
        }
        speeds = sorted({r["speed_mm_s"] for r in members})
        out["speeds"][key] = {
            f"{v:g}": summarise([r for r in members if r["speed_mm_s"] == v]) for v in speeds
        }
    return out


def trial_of(row: dict) -> Trial:
    """The trial a result row (trial and outcome fields, as in loop.json) came from; a field
    added since the row was written takes its default (loop.json from before `task`)."""
    return Trial(**{f.name: row[f.name] for f in fields(Trial) if f.name in row})


def compare(a: dict, b: dict) -> tuple[str, float | None]:
    """Does group `a` stop more slips than `b`? ('beats' / 'loses' / 'ties', difference in
    points): a difference counts when it exceeds twice its binomial standard error."""
    if not a["n"] or not b["n"]:
        return "ties", None
    pa, pb = a["stopped_pct"] / 100.0, b["stopped_pct"] / 100.0
    se = math.sqrt(pa * (1 - pa) / a["n"] + pb * (1 - pb) / b["n"])
    diff = 100.0 * (pa - pb)
    if abs(pa - pb) > 2 * se and pa != pb:
        return ("beats" if pa > pb else "loses"), diff
    return "ties", diff


# -- the report --------------------------------------------------------------------------------


def run_report(
    out: Path,
    *,
    controllers_for: ControllerFactory,
    quick: bool = False,
    workers: int | None = None,
    log: Callable[[str], None] = print,
    trials: Sequence[Trial] | None = None,
    dask: str | None = None,
) -> dict:
    """Run the grid (or `trials`) and write loop.md, loop.json and loop.png into `out`."""
    grid_name = ("quick" if quick else "full") + " grid" if trials is None else "as given"
    trials = grid(quick) if trials is None else list(trials)
    log(f"closed-loop trials: {len(trials)} ({grid_name})")
    rows = run_trials(trials, controllers_for, workers, log, dask)
    results: dict[str, Any] = {
        "quick": quick,
        "grid": {
            "modes": list(MODES),
            "speeds_mm_s": sorted({t.speed_mm_s for t in trials}),
            "seeds": sorted({t.seed for t in trials}),
            "threshold_mm_s": THESIS_THRESHOLD_MM_S,
            "headline_threshold_mm_s": HEADLINE_THRESHOLD_MM_S,
            "wearer_limit_mm_s": WEARER_LIMIT_MM_S,
            "skin_end_mm": SKIN_END_MM,
            "settle_s": SETTLE_S,
            "trials": len(trials),
        },
        "figures": aggregate(rows),
        "trials": rows,
    }
    results["verdict"] = verdict(results["figures"])
    results["mechanisms"] = mechanisms(rows)
    out.mkdir(parents=True, exist_ok=True)
    (out / "loop.json").write_text(dump_json(results))
    plot_report(results, out / "loop.png")
    (out / "loop.md").write_text(render(results))
    return results


def dump_json(results: dict) -> str:
    """loop.json: the figures indented, the trials one compact row a line (µs/µm precision)."""
    head = {k: v for k, v in results.items() if k != "trials"}
    text = json.dumps(head, indent=1, sort_keys=True)
    rows = ",\n".join(
        json.dumps(
            {k: round(v, 6) if isinstance(v, float) else v for k, v in row.items()},
            sort_keys=True,
        )
        for row in results.get("trials", [])
    )
    return text[:-2] + ',\n "trials": [\n' + rows + "\n ]\n}\n"


def report_to(
    *,
    quick: bool,
    out: Path | None,
    controllers_for: ControllerFactory,
    workers: int | None = None,
    log: Callable[[str], None] = print,
    dask: str | None = None,
) -> tuple[dict, Path]:
    """What the drivers call: docs/benchmarks/ of the checkout unless `out`; (results, out)."""
    from grasplink.evaluation.decoding_bench import default_out_dir
    from grasplink.evaluation.workers import open_workers

    open_workers(workers, dask).close()  # a bad count or an unreachable scheduler fails now
    out = out if out is not None else default_out_dir()
    results = run_report(
        out, controllers_for=controllers_for, quick=quick, workers=workers, log=log, dask=dask
    )
    return results, out


def _row(mode: str, reflex: bool, threshold: float = THESIS_THRESHOLD_MM_S) -> str:
    return row_key(Trial(mode, reflex, 1.0, 0, threshold))


def verdict(figures: dict) -> dict:
    """The thesis's two claims against the figures, per speed band."""
    bands = figures["bands"]
    speed_vs_occurrence = {}
    for reflex in (False, True):
        a, b = _row("slip_speed", reflex), _row("slip_occurrence", reflex)
        if a in bands and b in bands:
            speed_vs_occurrence["reflex" if reflex else "no reflex"] = {
                band: dict(
                    zip(
                        ("result", "diff_points"),
                        compare(bands[a][band], bands[b][band]),
                        strict=True,
                    )
                )
                for band in BANDS
            }
    reflex_rescues = {}
    for mode in MODES:
        a, b = _row(mode, True), _row(mode, False)
        if a in bands and b in bands:
            result, diff = compare(bands[a]["reflex"], bands[b]["reflex"])
            reflex_rescues[mode] = {
                "result": result,
                "diff_points": diff,
                "first_stop_with_pct": bands[a]["reflex"]["first_stop_pct"],
                "stopped_with_pct": bands[a]["reflex"]["stopped_pct"],
                "stopped_without_pct": bands[b]["reflex"]["stopped_pct"],
            }
    return {"slip_speed_vs_occurrence": speed_vs_occurrence, "reflex_rescues": reflex_rescues}


def mechanisms(rows: Sequence[dict]) -> dict:
    """Facts from the trials that explain the figures (see the report's Mechanisms)."""
    speed_rows = [r for r in rows if r["mode"] == "slip_speed" and r["belt_first_mrad_s"]]
    force_rows = [r for r in rows if r["mode"] in ("grip_force", "force_and_slip")]
    relax_mrad_s = DEFAULT_FORCE_ENTRIES[RELAX_FORCE_LEVEL - 1][1]
    fast = [
        r
        for r in rows
        if r["reflex"]
        and r["threshold_mm_s"] == THESIS_THRESHOLD_MM_S
        and speed_band(r["speed_mm_s"]) == "reflex"
    ]
    acted = [r for r in fast if r["reflex_latency_s"] is not None]  # the reflex's own stops
    blind = [r for r in acted if r["mode"] in ("off", "grip_force")]
    told = [r for r in acted if r["mode"] not in ("off", "grip_force")]
    reslipped = [r for r in blind if r["slip_episodes"] > 1]
    thesis_reflex = [
        r for r in rows if r["reflex"] and r["threshold_mm_s"] == THESIS_THRESHOLD_MM_S
    ]
    at = [r for r in thesis_reflex if r["speed_mm_s"] == THESIS_THRESHOLD_MM_S]
    below = [r for r in thesis_reflex if r["speed_mm_s"] < THESIS_THRESHOLD_MM_S]
    fired_below = sorted({r["speed_mm_s"] for r in below if r["reflex_latency_s"] is not None})
    return {
        "reflex_at_threshold": {
            "trials": len(at),
            "reflex_pct": pct_of([r["reflex_latency_s"] is not None for r in at]),
        },
        "reflex_below_threshold": {
            "trials": len(below),
            "reflex_pct": pct_of([r["reflex_latency_s"] is not None for r in below]),
            "speeds_mm_s": fired_below,
        },
        "slip_speed_trials_with_display": len(speed_rows),
        "slip_speed_first_shown_as_occurrence_pct": pct_of(
            [r["belt_first_mrad_s"] == -OCCURRENCE_MRAD_S for r in speed_rows]
        ),
        "force_trials": len(force_rows),
        "force_display_at_relax_level_pct": pct_of(
            [(r.get("force_belt_max_mrad_s") or 0) >= relax_mrad_s for r in force_rows]
        ),
        "force_belt_max_median_mrad_s": median_of(
            [r.get("force_belt_max_mrad_s") for r in force_rows]
        ),
        "reflex_without_slip_display": {
            "trials": len(blind),
            "first_stop_pct": pct_of([r["first_stop_s"] is not None for r in blind]),
            "reslip_pct": pct_of([r["slip_episodes"] > 1 for r in blind]),
            "dropped_after_reslip_pct": pct_of([r["dropped"] for r in reslipped]),
            "first_stop_median_mm": median_of([r.get("first_stop_mm") for r in blind]),
        },
        "reflex_with_slip_display": {
            "trials": len(told),
            "reslip_pct": pct_of([r["slip_episodes"] > 1 for r in told]),
            "stopped_pct": pct_of([r["stopped"] for r in told]),
        },
    }


def console_table(results: dict) -> str:
    """The per mode × reflex figures as plain text, for the terminal."""
    header = (
        f"{'mode, reflex':<38} {'n':>4} {'stopped%':>8} {'1st stop%':>9} {'dist mm':>7} "
        f"{'stop s':>6} {'grip N':>6} {'I_EMG':>5} {'fast%':>5}"
    )
    lines = [header]
    for key, s in results["figures"]["rows"].items():
        fast = results["figures"]["bands"][key]["reflex"]
        lines.append(
            f"{key:<38} {s['n']:>4} {_f(s['stopped_pct'], 0):>8} "
            f"{_f(s['first_stop_pct'], 0):>9} {_f(s['slip_distance_median_mm']):>7} "
            f"{_f(s['time_to_stop_median_s'], 2):>6} {_f(s['grip_mean_n']):>6} "
            f"{_f(s['i_emg'], 2):>5} {_f(fast['stopped_pct'], 0):>5}"
        )
    lines.append(f"fast% = stopped % at >= {THESIS_THRESHOLD_MM_S:g} mm/s")
    return "\n".join(lines)


def _f(value: float | None, digits: int = 1, unit: str = "") -> str:
    if value is None:
        return "-"
    return f"{value:.{digits}f}{unit}"


def render(results: dict) -> str:
    """loop.md: what was run, the verdict, the mechanisms, the tables."""
    g = results["grid"]
    figures = results["figures"]
    rows, bands = figures["rows"], figures["bands"]
    seeds = len(g["seeds"])
    speeds = ", ".join(f"{v:g}" for v in g["speeds_mm_s"])
    lines = [
        "# The closed loop in silico: does the feedback stop the slip?",
        "",
        "Generated by `grasplink bench loop` or `benchmarks/bench_loop.py`",
        "(grasplink/evaluation/loop.py); do not edit by hand."
        + (" **Quick run** (reduced grid: not the report's figures)." if results["quick"] else ""),
        "",
        "Each trial is the loop of `scenes/loop_headline.toml` in virtual time: skin node →",
        "gateway (decoder `tracker`, feedback, reflex) → haptic belt → virtual wearer",
        "(`wearer.virtual`, thesis defaults) → EMG node → gateway → hand → object. Its physics",
        "is that scene's: the object, held at 5 N (the wearer resting at e1), is pulled out of",
        "the hand with at most 9 N, so any grip above 9 N / (2 × 0.7813) = 5.76 N holds it;",
        "the wearer's levels e0..e5 ask for 0, 5, 8, 11, 14, 20 N (e2 already holds); the",
        "hand crushes the object above 25 N. The pull starts at 1 s with the leading edge",
        f"8 mm before the first ridge of the alpha0.1 skin; past its end ({g['skin_end_mm']:g} mm)",
        "the object is dropped.",
        "",
        f"Grid: {len(MODES)} feedback modes × reflex off/on (thesis threshold "
        f"{g['threshold_mm_s']:g} mm/s) × slip speeds {speeds} mm/s × {seeds} seed(s), and",
        f"force + slip with loop_headline's reflex threshold ({g['headline_threshold_mm_s']:g} "
        f"mm/s): {g['trials']} trials. A seed fixes the wearer (reaction times, level",
        "identifications, contraction scatter), the ridge dips and the noise; every row uses",
        "the same seeds, so rows differ by their settings only. A trial lasts until an",
        f"unstopped slip would have left the skin, plus {g['settle_s']:g} s (the reflex's 2 s",
        "hold and its release at 2 N/s from up to 20 N towards its floor, then a re-slip if",
        "that went too far); a drop ends it.",
        "",
        "**Figures.** *stopped*: the object is at rest at the end of the trial (for ≥ "
        f"{MIN_REST_S:g} s) and never passed the skin's end; *first stop*: it came to rest at",
        "least once (a stop can be lost again); *re-slip*: it slid again after a stop;",
        "*distance* and *time to stop*: from the onset to the final rest, medians over the",
        "stopped trials; *grip*: mean applied grip from the onset to the end of the trial;",
        "*I_EMG*: thesis eq. 2.1, the mean of (e − e_min)/(e_max − e_min) over the EMG node's",
        "envelope TPDOs from the onset on, with the gateway's calibration (e1 at rest ≈ 0.13),",
        "and *success/effort* = stopped share / I_EMG (the thesis's success-to-EMG-intensity",
        "ratio); *belt*: first belt RPDO after onset changing the display (*slip belt*: the",
        "first one running the slip belt), median latency; *reflex*: share",
        "of trials with a hand RPDO after onset rising above the grip the wearer's EMG asked for",
        "(the EMG TPDOs replayed through the gateway's calibration) and its median latency.",
        "Belt and hand RPDOs and EMG TPDOs are unpacked through the nodes' EDS mappings.",
        f"Speed bands: the wearer's ≤ {g['wearer_limit_mm_s']:.0f} mm/s (loop_headline.toml's "
        "design limit: slip shown at the second ridge contact, 19 mm in; 1.75 s reaction + "
        "0.35 s EMG, motor and hand: "
        f"(84 − 19) / 2.1 s), the gap up to {g['threshold_mm_s']:g} mm/s, the reflex's above.",
        "",
        "## Does it reproduce the thesis?",
        "",
    ]
    lines += render_verdict(results)
    lines += render_mechanisms(results)
    lines += [
        "## Per feedback mode and reflex, all speeds",
        "",
        "| mode, reflex | trials | stopped % | first stop % | re-slip % | dropped % | crushed "
        "| distance mm | time to stop s | grip N | I_EMG | success/effort | belt s | slip belt s "
        "| reflex % | reflex s |",
        "|---|" + "---:|" * 15,
    ]
    for key, s in rows.items():
        lines.append(
            f"| {key} | {s['n']} | {_f(s['stopped_pct'], 0)} | {_f(s['first_stop_pct'], 0)} | "
            f"{_f(s['reslip_pct'], 0)} | {_f(s['dropped_pct'], 0)} | {s['crushed']} | "
            f"{_f(s['slip_distance_median_mm'])} | {_f(s['time_to_stop_median_s'], 2)} | "
            f"{_f(s['grip_mean_n'])} | {_f(s['i_emg'], 2)} | "
            f"{_f(s['success_to_effort'], 2)} | {_f(s['belt_latency_median_s'], 2)} | "
            f"{_f(s['slip_belt_latency_median_s'], 2)} | {_f(s['reflex_pct'], 0)} | "
            f"{_f(s['reflex_latency_median_s'], 2)} |"
        )
    lines += [
        "",
        "## Per speed band: stopped % · median distance mm · median time to stop s · I_EMG",
        "",
        "| mode, reflex | " + " | ".join(BANDS.values()) + " |",
        "|---|" + "---:|" * len(BANDS),
    ]
    for key, by_band in bands.items():
        cells = [
            f"{_f(b['stopped_pct'], 0)} · {_f(b['slip_distance_median_mm'], 0)} · "
            f"{_f(b['time_to_stop_median_s'], 2)} · {_f(b['i_emg'], 2)}"
            if b["n"]
            else "-"
            for b in by_band.values()
        ]
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    speed_keys = [f"{v:g}" for v in g["speeds_mm_s"]]
    lines += [
        "",
        "## Per slip speed: stopped % (first stop %)",
        "",
        "| mode, reflex | " + " | ".join(f"{v} mm/s" for v in speed_keys) + " |",
        "|---|" + "---:|" * len(speed_keys),
    ]
    for key, by_speed in figures["speeds"].items():
        cells = [
            f"{_f(by_speed[v]['stopped_pct'], 0)} ({_f(by_speed[v]['first_stop_pct'], 0)})"
            if v in by_speed
            else "-"
            for v in speed_keys
        ]
        lines.append(f"| {key} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "![stopped share, slip distance and effort against slip speed per mode](loop.png)",
        "",
    ]
    return "\n".join(lines)


def render_verdict(results: dict) -> list[str]:
    g = results["grid"]
    v = results["verdict"]
    bands = results["figures"]["bands"]
    lines = []
    svo = v["slip_speed_vs_occurrence"].get("no reflex", {})
    occ, spd = _row("slip_occurrence", False), _row("slip_speed", False)
    if svo and occ in bands and spd in bands:
        parts = []
        for band, label in BANDS.items():
            result = svo[band]
            parts.append(
                f"{label}: slip speed {_f(bands[spd][band]['stopped_pct'], 0)} % against "
                f"occurrence {_f(bands[occ][band]['stopped_pct'], 0)} % stopped — "
                f"**{result['result']}**"
            )
        outcomes = {svo[band]["result"] for band in BANDS}
        if "beats" in outcomes and "loses" not in outcomes:
            claim = "reproduced"
        elif "loses" in outcomes and "beats" not in outcomes:
            claim = "reversed"
        elif outcomes == {"ties"}:
            claim = "not reproduced: the two modes tie"
        else:
            claim = "mixed"
        spd_r, occ_r = _row("slip_speed", True), _row("slip_occurrence", True)
        efforts = [
            (spd, occ, "wearer", "slow band without the reflex"),
            (spd_r, occ_r, "reflex", "fast band with the reflex"),
        ]
        effort_parts = [
            f"in the {label} I_EMG {_f(bands[a][band]['i_emg'], 2)} (slip speed) against "
            f"{_f(bands[b][band]['i_emg'], 2)} (occurrence), success/effort "
            f"{_f(bands[a][band]['success_to_effort'], 2)} against "
            f"{_f(bands[b][band]['success_to_effort'], 2)}: "
            + _efficiency(bands[a][band]["success_to_effort"], bands[b][band]["success_to_effort"])
            for a, b, band, label in efforts
            if a in bands and b in bands and bands[a][band]["n"]
        ]
        with_reflex = v["slip_speed_vs_occurrence"].get("reflex", {}).get("reflex")
        reflex_part = ""
        if with_reflex and spd_r in bands and occ_r in bands:
            fast_s, fast_o = bands[spd_r]["reflex"], bands[occ_r]["reflex"]
            reflex_part = (
                f" With the reflex, where the wearer has to take over from it, slip speed "
                f"stops {_f(fast_s['stopped_pct'], 0)} % of the fast slips against "
                f"{_f(fast_o['stopped_pct'], 0)} % with occurrence (**{with_reflex['result']}**; "
                f"re-slips after the reflex let go {_f(fast_s['reslip_pct'], 0)} % against "
                f"{_f(fast_o['reslip_pct'], 0)} %)"
                + (
                    ": the thesis's direction, and the only place it shows here."
                    if with_reflex["result"] == "beats"
                    else ": the thesis's direction, though within twice its standard error."
                    if (with_reflex["diff_points"] or 0) > 0
                    else "."
                )
            )
        lines += [
            "**1. Slip-speed feedback beats slip occurrence at high speeds (ch. 2, 9.3): "
            + claim
            + " without the reflex.** Per speed band: "
            + "; ".join(parts)
            + ". (*beats* and *loses* need a difference over twice its binomial standard "
            "error; otherwise *ties*.)"
            + reflex_part
            + " Effort (the thesis found slip speed the more efficient at the higher speeds, "
            "success-to-EMG-intensity, fig. 2.4): " + "; ".join(effort_parts) + ". See Mechanisms.",
            "",
        ]
    rescue = v["reflex_rescues"]
    if rescue:
        parts = [
            f"{MODES[mode]} {_f(r['stopped_without_pct'], 0)} → {_f(r['stopped_with_pct'], 0)} %"
            f" (first stop {_f(r['first_stop_with_pct'], 0)} %, {r['result']})"
            for mode, r in rescue.items()
        ]
        held = [m for m, r in rescue.items() if r["result"] == "beats"]
        lines += [
            "**2. The reflex rescues slips a human cannot stop (ch. 2.4.4, 9.3): "
            + (
                "reproduced"
                if len(held) == len(rescue)
                else ("reproduced for " + ", ".join(MODES[m] for m in held) if held else "not")
            )
            + f".** Stopped at ≥ {g['threshold_mm_s']:g} mm/s without → with the reflex: "
            + "; ".join(parts)
            + ". "
            + _hand_back_sentence(results["mechanisms"]),
            "",
        ]
    gap_rows = (
        (_row("force_and_slip", True), f"{g['threshold_mm_s']:g} mm/s"),
        (
            _row("force_and_slip", True, g["headline_threshold_mm_s"]),
            f"loop_headline's {g['headline_threshold_mm_s']:g} mm/s",
        ),
    )
    gap = [
        f"{_f(bands[key]['gap']['stopped_pct'], 0)} % with the threshold at {label}"
        for key, label in gap_rows
        if key in bands and bands[key]["gap"]["n"]
    ]
    if gap:
        lines += [
            f"**3. The gap ({g['wearer_limit_mm_s']:.0f}–{g['threshold_mm_s']:g} mm/s).** The "
            f"thesis's {g['threshold_mm_s']:g} mm/s assumes an 80 mm skin and a reaction "
            "time only; this loop's wearer also waits for the decoder (second contact, "
            "19 mm in) and for EMG, motor and hand (~0.35 s), so it stops slips up to "
            f"≈ {g['wearer_limit_mm_s']:.0f} mm/s. Of the slips in between, force + slip "
            "with the reflex stops " + " and ".join(gap) + ". That is what loop_headline.toml's "
            f"{g['headline_threshold_mm_s']:g} mm/s threshold is about: the reflex has to "
            "start at the human limit of *this* loop, not at the thesis's figure."
            + _gap_alone(bands),
            "",
        ]
    crushes = sum(s["crushed"] for s in results["figures"]["rows"].values())
    why = (
        "The wearer's top level asks for 20 N, below the 25 N crush limit, and the reflex "
        "adds 0.1 N per mm/s to the grip the slip began with (at most 5 + 15 N at 150 mm/s "
        "from e1); the thesis's crushes came from an e5 contraction that meant crushing by "
        "definition (ch. 2.3.3), which this hand model does not copy."
        if not crushes
        else "See the tables for the rows."
    )
    lines += [f"**4. Crushes: {crushes}** in {g['trials']} trials. {why}", ""]
    return lines


def _efficiency(speed: float | None, occurrence: float | None) -> str:
    """Slip speed's success-to-effort against occurrence's, in words (5 % either way: same)."""
    if not speed or not occurrence:
        return "no comparison"
    if speed > 1.05 * occurrence:
        return "slip speed more efficient"
    if speed < occurrence / 1.05:
        return "slip speed less efficient"
    return "about as efficient"


def _hand_back_sentence(m: dict) -> str:
    """Whether the reflex's stop lasts with and without a slip display (hand-back)."""
    blind, told = m["reflex_without_slip_display"], m["reflex_with_slip_display"]
    if not blind["trials"] or not told["trials"]:
        return ""
    lost = blind["reslip_pct"] or 0.0
    if lost > (told["reslip_pct"] or 0.0):
        return (
            f"The reflex's stop lasts where the wearer is told of the slip and takes over "
            f"before the reflex lets go (hand-back): {_f(told['reslip_pct'], 0)} % re-slipped "
            f"with a slip display, {_f(lost, 0)} % without one (none, grip force)."
        )
    return (
        f"Re-slips after the reflex let go: {_f(told['reslip_pct'], 0)} % with a slip display, "
        f"{_f(lost, 0)} % without one."
    )


def _gap_alone(bands: dict) -> str:
    """What the wearer alone stops in the gap band: more than the design limit allows
    once the decoder flags a slip at its first contact onto the unloaded skin."""
    alone = bands.get(_row("slip_speed", False), {}).get("gap", {})
    if not alone.get("n") or not alone.get("stopped_pct"):
        return ""
    return (
        f" Without the reflex, slip speed alone stops {_f(alone['stopped_pct'], 0)} % of "
        f"them (median slip belt {_f(alone['slip_belt_latency_median_s'], 2)} s): the decoder "
        "flags a slip at its first contact onto the unloaded skin (`decoding/arrival_flag.py`), "
        "before the second contact this limit assumes, so the limit is conservative."
    )


def render_mechanisms(results: dict) -> list[str]:
    g = results["grid"]
    m = results["mechanisms"]
    rows = results["figures"]["rows"]
    blind, told = m["reflex_without_slip_display"], m["reflex_with_slip_display"]
    relax_n, relax_mrad_s = DEFAULT_FORCE_ENTRIES[RELAX_FORCE_LEVEL - 1]
    grip_force = rows.get(_row("grip_force", False), {}).get("stopped_pct")
    return [
        "## Mechanisms",
        "",
        "- **Why slip speed and slip occurrence tie without the reflex.** (a) The decoder "
        "reports slip from its first contact onto the unloaded skin (the arrival, "
        "`decoding/arrival_flag.py`; else the second ridge contact) but a speed only from "
        "the third ridge contact, and the "
        "gateway shows a slip of unknown speed as occurrence: "
        f"{_f(m['slip_speed_first_shown_as_occurrence_pct'], 0)} % of the "
        f"{m['slip_speed_trials_with_display']} slip-speed trials with a display began with "
        f"the occurrence display ({OCCURRENCE_MRAD_S} mrad/s), so the wearer's first cue is "
        "mostly the same in both modes. (b) `wearer.virtual` answers any felt slip with at "
        "least one level more than it holds (e1 → e2), whatever level it read, and "
        "`object.pulled` stops at any grip above 5.76 N: e2 (8 N) stops the slip as surely "
        "as e4. What the display says changes how hard the wearer squeezes (a fast slip "
        "shown at slip level 4 asks for e4), not whether or when the slip stops. In the "
        "thesis each contraction level *slowed* the object by a set amount (ch. 2.3.3), so "
        "the right level mattered and a wrong one failed or crushed. (c) The model draws "
        "the same reaction time (1.51–1.75 s) in both modes; the thesis measured 1.51 s "
        "with occurrence and 1.75 s with slip-speed feedback (ch. 2.4.4), which would favour "
        "occurrence here, where only time matters.",
        _hand_back_by_mode(results),
        "- **Why force + slip equals slip speed.** While the object slips the belt shows "
        "slip speed; otherwise it shows the skin's static force, the FSR's share of the "
        f"grip (median top command {_f(m['force_belt_max_median_mrad_s'], 0)} mrad/s over "
        f"the {m['force_trials']} force-mode trials), which reached force level "
        f"{RELAX_FORCE_LEVEL} ({relax_n:g} N, {relax_mrad_s} mrad/s), where the wearer "
        f"starts relaxing, in {_f(m['force_display_at_relax_level_pct'], 0)} % of them: "
        "the force display changes nothing the wearer does. Grip force alone never tells "
        f"the wearer of a slip: without the reflex it stopped {_f(grip_force, 0)} %.",
        _reflex_alone(blind, told),
        _threshold_bullet(m),
        f"- **The wearer's limit is ≈ {g['wearer_limit_mm_s']:.0f} mm/s, not 45, for an "
        "object already on the skin.** The design assumes a slip shown at the second ridge "
        "contact (19 mm on alpha0.1), the decoder's first sight of an object that covers "
        "the skin when it starts to slide; identified and answered 1.51–1.75 s later, plus "
        "≈ 0.35 s of EMG window, motor delay and hand lag, that leaves 84 − 19 mm of skin. "
        "These trials' objects slide onto the skin from 8 mm before it, and the decoder "
        "flags that arrival (0 mm in), which moves their limit to ≈ 84 / 2.1 = 40 mm/s "
        "(finding 3). loop_headline.toml's threshold stays at 30 mm/s: the limit of the "
        "slip the wearer cannot be shown early.",
        "",
    ]


def _hand_back_by_mode(results: dict) -> str:
    """Why slip speed keeps more of the reflex's stops than occurrence (or does not)."""
    bands = results["figures"]["bands"]
    spd, occ = _row("slip_speed", True), _row("slip_occurrence", True)
    if spd not in bands or occ not in bands or not bands[spd]["reflex"]["n"]:
        return "- **Hand-back by mode.** No fast trials with the reflex."
    s, o = bands[spd]["reflex"], bands[occ]["reflex"]
    return (
        "- **Where the display's level matters: the hand-back.** After the reflex's stop "
        "the wearer's own contraction has to hold once the reflex lets go. Occurrence is "
        f"shown at {OCCURRENCE_MRAD_S} mrad/s, between slip levels 2 and 3, and asks for e2 "
        "or e3; a fast slip shown by slip speed reads as level 4 and asks for e4. The "
        "wearer's scatter (one level low 15 %, two levels low 5 %, ch. 2.4.3 shape) turns an "
        "e2 into e1 (5 N, which does not hold) far more often than an e4: in the fast band "
        f"I_EMG {_f(s['i_emg'], 2)} (slip speed) against {_f(o['i_emg'], 2)} (occurrence), "
        f"re-slips {_f(s['reslip_pct'], 0)} % against {_f(o['reslip_pct'], 0)} %, stopped "
        f"{_f(s['stopped_pct'], 0)} % against {_f(o['stopped_pct'], 0)} %. The harder grip "
        "is what buys the safer hand-back."
    )


def _threshold_bullet(m: dict) -> str:
    at, below = m["reflex_at_threshold"], m["reflex_below_threshold"]
    parts = []
    if at["trials"]:
        parts.append(
            f"At exactly {THESIS_THRESHOLD_MM_S:g} mm/s the reflex acted in "
            f"{_f(at['reflex_pct'], 0)} % of {at['trials']} trials: the object slows by "
            "4–15 mm/s at every ridge (ch. 5.5.1, `object.ridge_dips`) and the decoder "
            "measures the mean speed between contacts, below the nominal pull speed, so a "
            "slip at the threshold reads as one below it."
        )
    if below["trials"]:
        speeds = ", ".join(f"{v:g}" for v in below["speeds_mm_s"]) or "none"
        parts.append(
            f"Below the threshold it acted in {_f(below['reflex_pct'], 0)} % of "
            f"{below['trials']} trials (at {speeds} mm/s), where the decoder read the slip "
            "too fast early on (a wrong match of the first contact intervals to the layout, "
            "which places the object too far along the skin); such a false alarm stops a "
            "slip the wearer might have lost, and costs a harder grip."
        )
    if not parts:
        return "- **The reflex at its threshold.** No trials at or below it."
    return "- **The reflex at and below its threshold.** " + " ".join(parts)


def _reflex_alone(blind: dict, told: dict) -> str:
    head = (
        "Fast slips (≥ the threshold) in which the reflex acted, without a slip display "
        f"(none, grip force; {blind['trials']} trials): the reflex stopped "
        f"{_f(blind['first_stop_pct'], 0)} % (leading edge at a median "
        f"{_f(blind['first_stop_median_mm'], 0)} mm) and "
        f"{_f(blind['reslip_pct'], 0)} % slid again"
    )
    if not blind["trials"] or not blind["reslip_pct"]:
        return f"- **The reflex alone.** {head}."
    return (
        f"- **Why the reflex alone does not hold.** {head} "
        f"({_f(blind['dropped_after_reslip_pct'], 0)} % of those were dropped): after the "
        f"2 s hold the reflex releases at 2 N/s to its floor, the wearer's 5 N plus "
        f"{REFLEX.release_floor_share:g} of the raise; where that is below the 5.76 N that "
        "holds, the pull wins again, and the reflex grips again only if the decoder reports "
        "the new slip: past 51 mm the alpha0.1 skin has one 33 mm spacing and then its end, "
        "too few ridge contacts to report it in time. "
        f"With a slip display ({told['trials']} trials) the wearer, who felt even the brief "
        "slip, contracts (≥ e2) during the hold and the reflex hands back to a grip that "
        f"holds: {_f(told['reslip_pct'], 0)} % re-slipped, {_f(told['stopped_pct'], 0)} % "
        "stopped."
    )


def plot_report(results: dict, path: Path) -> None:
    """loop.png: stopped share, slip distance and I_EMG against slip speed, per row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figures = results["figures"]["speeds"]
    g = results["grid"]
    colours = dict(
        zip(MODES, ("0.45", "tab:orange", "tab:green", "tab:blue", "tab:purple"), strict=True)
    )
    offsets = dict(
        zip(MODES, (-0.04, -0.02, 0.0, 0.02, 0.04), strict=True)
    )  # log-x nudges: no overlap
    fig, axes = plt.subplots(1, 3, figsize=(15, 6), dpi=100)
    panels = (
        ("stopped_pct", "slips stopped [%]"),
        ("slip_distance_median_mm", "slip distance, stopped trials (median) [mm]"),
        ("i_emg", "I_EMG (thesis eq. 2.1), mean"),
    )
    for ax, (field_name, label) in zip(axes, panels, strict=True):
        for key, by_speed in figures.items():
            first = next(iter(by_speed.values()), None)
            if first is None:
                continue
            mode = next(m for m, name in MODES.items() if key.startswith(name + ","))
            reflex = "no reflex" not in key
            headline = " at " in key
            speeds = np.array([float(v) for v in by_speed])
            values = np.array(
                [np.nan if s[field_name] is None else s[field_name] for s in by_speed.values()]
            )
            ax.plot(
                speeds * 10 ** offsets[mode],
                values,
                color="black" if headline else colours[mode],
                ls=":" if headline else ("-" if reflex else "--"),
                marker="s" if headline else ("o" if reflex else "x"),
                ms=4,
                lw=1.2,
                label=key,
            )
        ax.axvline(g["wearer_limit_mm_s"], color="0.6", lw=0.8, ls="-.")
        ax.axvline(g["threshold_mm_s"], color="red", lw=0.8, ls="-.")
        ax.set_xscale("log")
        ax.set_xticks(g["speeds_mm_s"], [f"{v:g}" for v in g["speeds_mm_s"]], fontsize=7)
        ax.minorticks_off()
        ax.set_xlabel("slip speed [mm/s] (wearer's limit, reflex threshold dash-dotted)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    axes[0].set_ylim(-3, 103)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle(
        "Closed loop in silico: solid = reflex at 45 mm/s, dashed = no reflex, "
        "dotted black = force + slip with reflex at 30 mm/s (modes nudged apart on x)",
        fontsize=10,
    )
    fig.tight_layout(rect=(0, 0.13, 1, 1))
    fig.savefig(path)
    plt.close(fig)

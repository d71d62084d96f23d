"""Gateway benchmark, the measuring half: loop latency, slip onset, capacity, memory.

`measure` runs the four parts below and returns the figures `gateway_render` turns into
docs/benchmarks/gateway.md: the samples and counts of every run, the setup it ran with,
the machine, the library versions and the decoder's detection delays, all read here.

1. loop latency in real time on the python-can virtual bus: the gateway in one
   `NodeRunner`, the four device nodes in another on a second handle of the
   channel, the skin slipping; a third handle listens and times each skin TPDO
   to the belt/hand RPDOs it caused (bus timestamps), beside the gateway's
   own processing time (`Gateway.loop_latency_us`);
2. slip onset to the first slip-belt command in virtual time, scenes with the
   gateway in the loop over every shipped layout, four speeds, both
   directions and several start positions, against the physical limit (the
   second ridge contact after onset);
3. capacity: the gateway's CPU per prosthesis set in virtual time (with a
   profile of where it goes), then N gateways in one process in real time,
   each on its own link to a second process that runs the N sets of nodes;
4. memory over 10 simulated minutes of a slipping skin (RSS, in a fresh
   process), confirmed by the RSS of the real-time runs of 1;
5. batching per SYNC: the same set in virtual time event-driven and with the skin's
   and EMG's samples on a 5, 10 and 20 ms SYNC (every packet on it), interleaved: the
   gateway's CPU, calls and wake-ups per simulated second, and first ridge contact to
   the first slip-belt command and the reflex's first raise (`sync_batching`, alone:
   `bench_gateway.py --only sync`).

The skin plays repeated grasp-slip-release cycles (60 mm/s across alpha0.1, the
gateway's default layout); EMG reads a steady level-1 contraction.

The node process of 3 and the memory runs of 4 are this module run as a script
(`--serve-nodes FDS`, `--memory SECONDS SAMPLE_S VARIANT`).
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import functools
import json
import logging
import os
import pstats
import random
import select
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time
import tomllib
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path

import can
import figures_json
import numpy as np
from figures_json import percentile

from grasplink.bus import MultiRunner, NodeRunner, open_bus
from grasplink.bus.faults import ErrorFrame
from grasplink.bus.lockstep import LockstepNetwork
from grasplink.controllers import simulation
from grasplink.core.frames import RPDO_BASES, TPDO_BASES, Frame
from grasplink.decoding.contacts import ContactDetector
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.devices.factory import build_node
from grasplink.devices.node import DeviceNode
from grasplink.devices.sources import ConstantSource, SampleSource
from grasplink.gateway import provisioning as provisioning_module
from grasplink.gateway.config import GatewayConfig, parse_config
from grasplink.gateway.edge import GatewayEdge
from grasplink.gateway.live import prepare_to_go_live
from grasplink.gateway.service import Gateway
from grasplink.profiles import load_profile
from grasplink.profiles import objects as obj
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.profiles.pdo_codec import PdoCodec
from grasplink.simulators.effects.skin import RidgeContacts
from grasplink.simulators.scene import load_scene, parse_scene
from grasplink.simulators.synth import NOISE_WHITE_N, slip_recording

ROOT = Path(__file__).resolve().parents[1]
S = 1_000_000
SKIN, EMG, BELT, HAND = (obj.DEFAULT_NODE_IDS[k] for k in ("skin", "emg", "belt", "hand"))
SKIN_TPDO1 = TPDO_BASES[0] + SKIN
BELT_RPDO1, HAND_RPDO1 = RPDO_BASES[0] + BELT, RPDO_BASES[0] + HAND
COMMANDS = (BELT_RPDO1, HAND_RPDO1)

LAYOUT = "alpha0.1"
SLIP_MM_S = 60.0  # above the reflex threshold (45 mm/s): the hand's grip moves too
REST_S = 0.8  # released between cycles
EMG_UV = 150.0  # level e1 of the default calibration (50..500 uV)

TARGET_P99_US = 2000.0
TARGET_EXCESS_MS = 30.0
TARGET_SETS = 16
FLAT_MIB_PER_MIN = 0.05  # "flat": RSS drifts less than 3 MiB an hour
MAX_CPU_PERCENT = 100.0  # a memory run stops when one set needs more than a core
# A skin stream resyncs when a packet arrives > 30 ms off its grid (the gateway or the
# node ran that late): the decoder sees a jump in time. Keeping up allows one a minute.
MAX_RESYNCS_PER_SET_MIN = 1.0
LATE_S = 0.030  # the stream's resync threshold: 4 packet periods of 7.5 ms
TPDO_PERIOD_S = 0.0075  # the skin node's TPDO1: 3 samples at 400 Hz
LINK_BUFFER_BYTES = 1 << 24  # real-time capacity links: tens of thousands of frames
NODE_TICK_S = 0.001  # the node process's timer tick (a node's TPDOs jitter by at most this)
SO_SNDBUFFORCE = getattr(socket, "SO_SNDBUFFORCE", 32)  # Linux
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
ONSET_SPEEDS = (20.0, 40.0, 60.0, 120.0)
ONSET_S = 1.0


# -- workload ------------------------------------------------------------------------------
class SlipCycle:
    """The skin's signal: grasp, slip across the skin, release; repeated (a SampleSource).

    One cycle is `synth.slip_recording` (the FSR model, ridge pulses, white noise and
    drift at 400 Hz) followed by `REST_S` released; cycles repeat by sample index, and
    `offset` shifts the phase so sets sharing a process do not slip in step.
    """

    def __init__(self, offset: int = 0, seed: int = 1):
        rec = slip_recording(LAYOUTS_MM[LAYOUT], SLIP_MM_S, fs_hz=400, seed=seed)
        noise = np.random.default_rng(seed).normal(0.0, NOISE_WHITE_N, round(REST_S * rec.fs_hz))
        rest = float(rec.force_n[0]) + noise  # released: the sensor's noise on its rest level
        self.values = np.concatenate([rec.force_n, rest])
        self.period_s = len(self.values) / rec.fs_hz
        self.offset = offset

    def samples(self, t0_us: int, start_index: int, count: int, rate_hz: int) -> np.ndarray:
        index = np.arange(start_index, start_index + count) + self.offset
        return self.values[index % len(self.values)]


def gateway_config() -> GatewayConfig:
    """The defaults `grasplink gateway` runs with (all four nodes, alpha0.1, tracker)."""
    return parse_config({}, "<bench>")


def set_nodes(config: GatewayConfig, offset: int = 0) -> list[DeviceNode]:
    sources: dict[str, SampleSource] = {"skin": SlipCycle(offset), "emg": ConstantSource(EMG_UV)}
    return [
        build_node(n.kind, n.node_id, source=sources.get(n.kind)) for n in config.nodes.values()
    ]


class MeteredGateway(Gateway):
    """The gateway with meters the benchmark reads (the service itself is unchanged).

    `busy_ns`: this thread's CPU in every call; per skin TPDO its CPU and wall time;
    `caused`: each skin TPDO that returned RPDOs, with them; with `stamp_bus` (a
    `PairBus`) the latency from the TPDO's send stamp to each of those RPDOs' send.
    """

    def __init__(self, config: GatewayConfig):
        super().__init__(config)
        self.busy_ns = 0
        self.tpdo_cpu_us: list[float] = []
        self.tpdo_wall_us: list[float] = []
        self.tpdo_at: list[float] = []  # time.time() of each
        self.caused_cpu_us: list[float] = []  # CPU of the skin TPDOs that returned frames
        self.pace_s = 0.0  # sleep this long before each skin TPDO (virtual time, paced as live)
        self.caused: list[tuple[float, bytes, list[tuple[int, bytes]]]] = []
        self.meter_parts = False  # record `_PARTS` per skin TPDO (inside `decoder_meter`)
        self.tpdo_parts: list[dict[str, int]] = []
        self.stamp_bus: PairBus | None = None
        self.stamped_us: list[float] = []
        self.late_tpdos = 0
        self._stamp = 0.0
        self._pending = 0

    def _metered(self, call: Callable[[], list[Frame]]) -> list[Frame]:
        t0 = time.thread_time_ns()
        try:
            return call()
        finally:
            self.busy_ns += time.thread_time_ns() - t0

    def start(self, t_us: int) -> list[Frame]:
        return self._metered(lambda: super(MeteredGateway, self).start(t_us))

    def advance(self, t_us: int) -> list[Frame]:
        return self._metered(lambda: super(MeteredGateway, self).advance(t_us))

    def next_deadline_us(self) -> int | None:
        t0 = time.thread_time_ns()
        deadline = super().next_deadline_us()
        self.busy_ns += time.thread_time_ns() - t0
        return deadline

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        if frame.can_id != SKIN_TPDO1:
            return self._metered(lambda: super(MeteredGateway, self).receive(frame, t_us))
        _PARTS.clear()
        if self.pace_s:
            time.sleep(self.pace_s)
        if self.stamp_bus is not None and time.time() - self.stamp_bus.last_stamp > LATE_S:
            self.late_tpdos += 1  # this gateway took it up > 30 ms after the node sent it
        wall0, cpu0 = time.perf_counter_ns(), time.thread_time_ns()
        out = super().receive(frame, t_us)
        cpu = time.thread_time_ns() - cpu0
        if self.meter_parts:
            self.tpdo_parts.append(dict(_PARTS))
        self.busy_ns += cpu
        self.tpdo_cpu_us.append(cpu / 1000)
        self.tpdo_wall_us.append((time.perf_counter_ns() - wall0) / 1000)
        self.tpdo_at.append(time.time())
        if out:
            self.caused_cpu_us.append(cpu / 1000)
            self.caused.append((time.time(), frame.data, [(f.can_id, f.data) for f in out]))
            if self.stamp_bus is not None:
                self._stamp, self._pending = self.stamp_bus.last_stamp, len(out)
        return out

    def on_sent(self, now: float) -> None:
        """The runner sent a frame: the RPDOs a skin TPDO returned go out right after it."""
        if self._pending:
            self._pending -= 1
            self.stamped_us.append((now - self._stamp) * 1e6)

    def operational(self) -> bool:
        return all(link.phase == "operational" for link in self.links.values())


def rss_mib() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def proc_cpu_s(pid: int) -> float:
    """User + system CPU of a process so far, from /proc."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


# -- 1. loop latency in real time on the virtual bus ---------------------------------------
def realtime_loop(seconds: float) -> dict:
    """One gateway and one set of nodes in real time; a listener times TPDO -> RPDO."""
    channel = f"bench-gateway-{os.getpid()}-{time.monotonic_ns()}"
    buses = [open_bus(f"virtual:{channel}") for _ in range(3)]
    gw_bus, nodes_bus, tap_bus = buses
    config = gateway_config()
    gateway = MeteredGateway(config)
    log: list[tuple[float, int, bytes]] = []
    stop = threading.Event()

    def listen() -> None:
        while not stop.is_set():
            msg = tap_bus.recv(0.05)
            if msg is not None and (
                msg.arbitration_id == SKIN_TPDO1 or msg.arbitration_id in COMMANDS
            ):
                log.append((msg.timestamp, msg.arbitration_id, bytes(msg.data)))

    listener = threading.Thread(target=listen, name="bench-listener", daemon=True)
    listener.start()
    nodes = NodeRunner(nodes_bus, set_nodes(config), name="bench-nodes")
    # through its live edge, which measures the loop latency (`loop_latency_us`)
    runner = NodeRunner(gw_bus, [GatewayEdge(gateway)], name="bench-gateway")
    rss: list[tuple[float, float]] = []
    prepare_to_go_live([gateway])  # as `LiveGateway.start` does before its runners start
    try:
        nodes.start()
        runner.start()
        _wait(gateway.operational, 10.0, lambda: "nodes not operational: " + _phases([gateway]))
        boots0 = _boots([gateway])
        thread_cpu0, busy0, frames0 = thread_cpu_s(runner), gateway.busy_ns, runner.stats.frames_rx
        t0 = time.time()
        end = t0 + seconds
        while time.time() < end:
            rss.append((time.time() - t0, rss_mib()))
            time.sleep(min(2.0, max(0.0, end - time.time())))
        rss.append((time.time() - t0, rss_mib()))
        thread_s = thread_cpu_s(runner) - thread_cpu0
        frames = runner.stats.frames_rx - frames0
        runner_us = (thread_s - (gateway.busy_ns - busy0) / 1e9) / max(1, frames) * 1e6
    finally:
        runner.stop()
        nodes.stop()
        stop.set()
        listener.join(1)
        for bus in buses:
            bus.shutdown()
    caused = [c for c in gateway.caused if c[0] >= t0]
    bus_us = _match(caused, [e for e in log if e[0] >= t0 - 0.1])
    own = list(gateway.loop_latency_us)
    cpu = [c for c, at in zip(gateway.tpdo_cpu_us, gateway.tpdo_at, strict=True) if at >= t0]
    wall = [c for c, at in zip(gateway.tpdo_wall_us, gateway.tpdo_at, strict=True) if at >= t0]
    return {
        "seconds": seconds,
        "caused": len(caused),
        "bus_us": bus_us,
        "own_us": own,
        "tpdo_cpu_us": cpu,
        "tpdo_wall_us": wall,
        "rss": rss,
        "lost_packets": gateway.skin_frames.stats.lost_packets if gateway.skin_frames else 0,
        "boots": _boots([gateway]) - boots0,
        "tracks": len(getattr(gateway.decoder, "_tracks", ())),
        "thread_percent": 100 * thread_s / seconds,
        "frames_per_s": frames / seconds,
        "runner_us_per_frame": runner_us,
    }


def thread_cpu_s(runner: NodeRunner) -> float:
    """CPU seconds of a runner's thread so far (its whole thread, read from outside it)."""
    thread = runner._thread
    assert thread is not None and thread.ident is not None
    return time.clock_gettime(time.pthread_getcpuclockid(thread.ident))


def _wait(condition: Callable[[], bool], timeout_s: float, why: Callable[[], str]) -> None:
    end = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() > end:
            raise RuntimeError(why())
        time.sleep(0.05)


def _phases(gateways: list[MeteredGateway]) -> str:
    """Where each gateway's nodes are, for an error message."""
    return "; ".join(
        " ".join(f"{link.kind}:{link.phase}" for link in g.links.values())
        + (f" alarms {g.alarms}" if g.alarms else "")
        for g in gateways
    )


def _match(
    caused: list[tuple[float, bytes, list[tuple[int, bytes]]]], log: list[tuple[float, int, bytes]]
) -> list[float]:
    """Bus latency [µs] of each caused RPDO: its listener timestamp minus its TPDO's.

    Both lists are in sending order, so a cursor walks the listener's log: the TPDO
    with the caused entry's data, then each RPDO it returned (first match after it).
    """
    out: list[float] = []
    cursor = 0
    for _, tpdo_data, frames in caused:
        j = next(
            (
                k
                for k in range(cursor, len(log))
                if log[k][1] == SKIN_TPDO1 and log[k][2] == tpdo_data
            ),
            None,
        )
        if j is None:
            continue
        cursor = j + 1
        for can_id, data in frames:
            window = range(j + 1, min(len(log), j + 1000))  # it went out right after the TPDO
            k = next((k for k in window if log[k][1:] == (can_id, data)), None)
            if k is not None:
                out.append((log[k][0] - log[j][0]) * 1e6)
    return out


# -- 2. slip onset to the first slip-belt command, virtual time ------------------------------
ONSET_SCENE = """
[scene]
name = "bench-onset"
seed = {seed}
duration_s = {duration:.3f}
[nodes.skin]
layout = "{layout}"
[nodes.belt]
[nodes.hand]
[controller]
type = "gateway"
[[effects]]
type = "hand.actuator"
initial_n = 5.0
[[effects]]
type = "load.scripted"
mass_kg = 0.2
[[effects]]
type = "object.scripted"
speed_mm_s = [[0.0, 0.0], [{onset:.3f}, {speed}]]
interpolation = "step"
direction = "{direction}"
start_mm = {start:.3f}
[[effects]]
type = "skin.fsr"
direction = "{direction}"
[[effects]]
type = "skin.ridge_contacts"
[[effects]]
type = "skin.hysteresis"
[[effects]]
type = "noise.white"
std = 0.02
[[effects]]
type = "noise.drift"
std = 0.05
corner_hz = 0.3
[[effects]]
type = "skin.saturation"
[[effects]]
type = "belt.motor"
"""


def travel_ridges(layout: str, direction: str) -> np.ndarray:
    """Ridge positions along the direction of travel (0 = the first ridge met), ascending."""
    ridges = np.concatenate([[0.0], np.cumsum(LAYOUTS_MM[layout])])
    return ridges if direction == "forward" else ridges[-1] - ridges[::-1]


def start_positions(layout: str, direction: str, count: int, rng: random.Random) -> list[float]:
    """Travel distances of the leading edge at rest: 4 mm before the skin, then random ones
    on it that leave at least two ridges ahead (an object resting on the skin)."""
    ahead_of_last_two = float(travel_ridges(layout, direction)[-2])
    return [-4.0] + [rng.uniform(0.5, ahead_of_last_two - 0.5) for _ in range(count - 1)]


def _belt_velocity() -> Callable[[bytes], int]:
    rpdo = PdoCodec("belt", BELT).rpdo(1)
    target = next(v for v in rpdo.map if v.od.index == obj.BELT_TARGET_VELOCITY_MRAD_S)

    def velocity(data: bytes) -> int:
        rpdo.data = bytearray(data)
        return int(target.raw)

    return velocity


def onset_run(scene_text: str | None = None, *, path: Path | None = None, onset_s: float) -> dict:
    """One scene: onset -> second ridge contact (the limit) and -> first slip-belt command."""
    scene = load_scene(path) if path else parse_scene(tomllib.loads(scene_text or ""), "<bench>")
    sim = simulation(scene)
    velocity = _belt_velocity()
    commands: list[tuple[int, int]] = []

    def tap(t_us: int, frame: Frame | ErrorFrame, sender: object) -> None:
        if isinstance(frame, Frame) and frame.can_id == BELT_RPDO1:
            commands.append((t_us, velocity(frame.data)))

    sim.network.taps.append(tap)
    sim.run()
    contacts = sorted(
        c.time_s
        for e in scene.effects
        if isinstance(e, RidgeContacts)
        for c in e.contacts
        if not c.tip and c.time_s >= onset_s
    )
    slip = [t / S for t, v in commands if v < 0]
    after = [t for t in slip if t >= onset_s]
    return {
        "limit_s": contacts[1] - onset_s if len(contacts) >= 2 else None,
        "command_s": after[0] - onset_s if after else None,
        "false_before_onset": any(t < onset_s for t in slip),
    }


def onset_matrix(starts: int, speeds: tuple[float, ...]) -> dict:
    rng = random.Random(2)
    rows = []
    seed = 100
    for layout in LAYOUTS_MM:
        for speed in speeds:
            for direction in ("forward", "reverse"):
                ridges = travel_ridges(layout, direction)
                length = float(ridges[-1])
                for along in start_positions(layout, direction, starts, rng):
                    second = float(ridges[ridges > along][1]) - along  # to the 2nd ridge ahead
                    seed += 1
                    text = ONSET_SCENE.format(
                        seed=seed,
                        duration=ONSET_S + second / speed + 1.5,
                        layout=layout,
                        onset=ONSET_S,
                        speed=speed,
                        direction=direction,
                        start=along if direction == "forward" else length - along,
                    )
                    run = onset_run(text, onset_s=ONSET_S)
                    run |= {"layout": layout, "speed": speed, "direction": direction}
                    run["start_travel_mm"] = along
                    rows.append(run)
    headline = onset_run(path=ROOT / "scenes" / "loop_headline.toml", onset_s=1.0)
    return {"runs": rows, "headline": headline}


# -- 5. batching per SYNC ------------------------------------------------------------------
SYNC_PERIODS_MS = (5, 10, 20)
SYNC_WARM_S = 1.5  # provisioned, started and the decoder anchored before the meters run


def sync_config(period_ms: int) -> GatewayConfig:
    """The defaults, or the skin's and EMG's sample TPDOs on a `period_ms` SYNC with every
    packet on it (docs/gateway.md, SYNC producer)."""
    if not period_ms:
        return gateway_config()
    nodes = {
        "skin": {"sdo": {"1800sub2": 1, "2122sub0": 1}},
        "emg": {"sdo": {"1800sub2": 1, "2213sub0": 1}},
    }
    return parse_config({"gateway": {"sync_period_ms": period_ms}, "nodes": nodes}, "<bench>")


class CallCountingGateway(MeteredGateway):
    """Also counts every call that hands the gateway work (a frame, a due timer) and the
    distinct instants of them: a live runner serves the calls of one instant in one wake."""

    def __init__(self, config: GatewayConfig):
        super().__init__(config)
        self.calls = 0
        self.instants = 0
        self.decoder_calls = 0
        self._last_t: int | None = None

    def _count(self, t_us: int) -> None:
        self.calls += 1
        if t_us != self._last_t:
            self.instants += 1
            self._last_t = t_us

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        self._count(t_us)
        return super().receive(frame, t_us)

    def advance(self, t_us: int) -> list[Frame]:
        self._count(t_us)
        return super().advance(t_us)


def _rpdo_value(kind: str, node_id: int, index: int) -> Callable[[bytes], int]:
    rpdo = PdoCodec(kind, node_id).rpdo(1)
    target = next(v for v in rpdo.map if v.od.index == index)

    def value(data: bytes) -> int:
        rpdo.data = bytearray(data)
        return int(target.raw)

    return value


def sync_run(period_ms: int, seconds: float) -> dict:
    """One set in virtual time, event-driven (0) or batched per SYNC: the gateway's CPU,
    calls and wake-ups per simulated second after the warm-up, and per slip of the skin the
    time from its first ridge contact to the first slip-belt command and to the reflex's
    first raise (the first slip's: the grip it reaches is held through the later ones).
    Virtual time: the latencies are the same in every round, the CPU is not."""
    config = sync_config(period_ms)
    gateway = CallCountingGateway(config)
    net = LockstepNetwork([gateway, *set_nodes(config)])
    assert gateway.decoder is not None
    feed = gateway.decoder.feed

    def counted(t_s: np.ndarray, force_n: np.ndarray) -> list:
        gateway.decoder_calls += 1
        return feed(t_s, force_n)

    gateway.decoder.feed = counted  # type: ignore[method-assign]
    belt, grip = _belt_velocity(), _rpdo_value("hand", HAND, obj.HAND_TARGET_GRIP_MN)
    commands: list[tuple[int, int, int]] = []  # (t_us, can_id, value)

    def tap(t_us: int, frame: Frame | ErrorFrame, sender: object) -> None:
        if isinstance(frame, Frame) and frame.can_id in COMMANDS:
            decode = belt if frame.can_id == BELT_RPDO1 else grip
            commands.append((t_us, frame.can_id, decode(frame.data)))

    net.taps.append(tap)
    net.start()
    net.run_for(round(SYNC_WARM_S * S))
    gateway.busy_ns = gateway.calls = gateway.instants = gateway.decoder_calls = 0
    cycles0, percepts0 = gateway.cycles, gateway.counters["percepts"]
    net.run_for(round(seconds * S))
    cycle = SlipCycle()
    # the slip starts 0.3 s into each cycle (synth.slip_recording) and reaches the first
    # ridge LEAD_MM later; the skin's clock starts at 0 with the network
    contact_s = 0.3 + 6.0 / SLIP_MM_S
    first_belt, first_raise = [], []
    for m in range(int((SYNC_WARM_S + seconds) / cycle.period_s) + 1):
        contact_us = round((m * cycle.period_s + contact_s) * S)
        if contact_us > (SYNC_WARM_S + seconds - 1.0) * S:
            continue
        before = [v for t, c, v in commands if c == HAND_RPDO1 and t < contact_us]
        held = before[-1] if before else 0
        belt_t = next(
            (t for t, c, v in commands if c == BELT_RPDO1 and v < 0 and t >= contact_us), None
        )
        raise_t = next(
            (t for t, c, v in commands if c == HAND_RPDO1 and v > held and t >= contact_us),
            None,
        )
        first_belt.append(None if belt_t is None else (belt_t - contact_us) / 1000)
        first_raise.append(None if raise_t is None else (raise_t - contact_us) / 1000)
    frames = gateway.skin_frames
    return {
        "period_ms": period_ms,
        "seconds": seconds,
        "gateway_cpu_s": gateway.busy_ns / 1e9,
        "calls": gateway.calls,
        "instants": gateway.instants,
        "decoder_calls": gateway.decoder_calls,
        "cycles": gateway.cycles - cycles0,
        "percepts": gateway.counters["percepts"] - percepts0,
        "lost_packets": frames.stats.lost_packets if frames is not None else None,
        "belt_ms": first_belt,
        "hand_ms": first_raise,
    }


def voluntary_switches(runner: NodeRunner) -> int:
    """How often a runner's thread has blocked so far (each wait that slept; read from
    /proc): its wake-ups."""
    thread = runner._thread
    assert thread is not None and thread.native_id is not None
    with open(f"/proc/self/task/{thread.native_id}/status") as f:
        line = next(x for x in f if x.startswith("voluntary_ctxt_switches:"))
    return int(line.split()[1])


def sync_live(period_ms: int, seconds: float) -> dict:
    """The gateway in a `NodeRunner` thread, the nodes in another, on the python-can virtual
    bus in real time: its thread's CPU (gateway, runner and python-can) and wake-ups per s."""
    channel = f"bench-sync-{os.getpid()}-{time.monotonic_ns()}"
    gw_bus, nodes_bus = (open_bus(f"virtual:{channel}") for _ in range(2))
    config = sync_config(period_ms)
    gateway = MeteredGateway(config)
    devices = set_nodes(config)
    nodes = NodeRunner(nodes_bus, devices, name="bench-sync-nodes")
    runner = NodeRunner(gw_bus, [gateway], name="bench-sync-gateway")
    prepare_to_go_live([gateway])
    try:
        nodes.start()
        runner.start()
        _wait(gateway.operational, 10.0, lambda: "nodes not operational: " + _phases([gateway]))
        time.sleep(1.0)  # the decoder anchored, the first slip's start behind
        lost0 = gateway.skin_frames.stats.lost_packets if gateway.skin_frames else 0
        dropped0 = sum(d.pdo.dropped_packets for d in devices)
        skipped0 = gateway.sync.skipped if gateway.sync is not None else 0
        cpu0, busy0 = thread_cpu_s(runner), gateway.busy_ns
        wakes0, frames0 = voluntary_switches(runner), runner.stats.frames_rx
        t0 = time.monotonic()
        time.sleep(seconds)
        elapsed = time.monotonic() - t0
        cpu_s = thread_cpu_s(runner) - cpu0
        wakes = voluntary_switches(runner) - wakes0
        frames = runner.stats.frames_rx - frames0
        lost = (gateway.skin_frames.stats.lost_packets if gateway.skin_frames else 0) - lost0
        dropped = sum(d.pdo.dropped_packets for d in devices) - dropped0
        skipped = (gateway.sync.skipped if gateway.sync is not None else 0) - skipped0
    finally:
        runner.stop()
        nodes.stop()
        gw_bus.shutdown()
        nodes_bus.shutdown()
    return {
        "period_ms": period_ms,
        "seconds": elapsed,
        "thread_percent": 100 * cpu_s / elapsed,
        "gateway_percent": 100 * (gateway.busy_ns - busy0) / 1e9 / elapsed,
        "wakes_per_s": wakes / elapsed,
        "frames_per_s": frames / elapsed,
        "lost_packets": lost,
        # packets the nodes dropped with more owed than they keep (a SYNC > 240 ms late)
        "node_dropped": dropped,
        "skipped_syncs": skipped,
        "boots": _boots([gateway]),
    }


def sync_batching(seconds: float, rounds: int, live_s: float) -> dict:
    """Event-driven against batched per 5, 10 and 20 ms SYNC, in virtual time and (10 and
    20 ms) in real time, the modes interleaved round by round so a change in the machine's
    load falls on all of them."""
    code = code_version()  # now: the code imported, not what the tree holds at the end
    runs: dict[str, list[dict]] = {}
    live: dict[str, list[dict]] = {}
    for _ in range(rounds):
        for period_ms in (0, *SYNC_PERIODS_MS):
            runs.setdefault(str(period_ms), []).append(sync_run(period_ms, seconds))
        for period_ms in (0, 10, 20):
            live.setdefault(str(period_ms), []).append(sync_live(period_ms, live_s))
    return {
        "runs": runs,
        "live": live,
        "setup": {
            "warm_s": SYNC_WARM_S,
            "slip_mm_s": SLIP_MM_S,
            "layout": LAYOUT,
            "emg_uv": EMG_UV,
            "rounds": rounds,
        },
        "code": code,
        "date": time.strftime("%Y-%m-%d"),
        "loadavg": os.getloadavg()[0],
    }


# -- 3. capacity ---------------------------------------------------------------------------
_PARTS: dict[str, int] = {}  # CPU [ns] per tracker part within the current skin TPDO
METERED_PARTS = (
    (TrackerDecoder, "_add_contact", "new contact"),
    (ContactDetector, "feed", "detector"),
    (TrackerDecoder, "_report", "estimate"),
)


@contextlib.contextmanager
def decoder_meter() -> Iterator[None]:
    """Time the tracker's parts per skin TPDO: the class methods are wrapped, then restored."""
    saved = [(cls, name, cls.__dict__[name]) for cls, name, _ in METERED_PARTS]

    def metered(method: Callable, label: str) -> Callable:
        def call(self: object, *args: object) -> object:
            t0 = time.thread_time_ns()
            try:
                return method(self, *args)
            finally:
                _PARTS[label] = _PARTS.get(label, 0) + time.thread_time_ns() - t0

        return call

    for (cls, name, label), (_, _, method) in zip(METERED_PARTS, saved, strict=True):
        setattr(cls, name, metered(method, label))
    try:
        yield
    finally:
        for cls, name, method in saved:
            setattr(cls, name, method)


def provisioning_cost() -> dict:
    """What provisioning a node costs: at a boot, on the gateway's thread (queuing the SDO
    writes built with the gateway), and once per process (parsing the node's EDS)."""
    config = gateway_config()
    gateway = Gateway(config)
    boot_us, parse_ms, build_ms = [], [], []
    for link in gateway.links.values():
        t0 = time.perf_counter_ns()
        gateway._provision(link, 0)
        boot_us.append((time.perf_counter_ns() - t0) / 1e3)
        t0 = time.perf_counter_ns()
        load_profile(link.kind, link.node_id)  # uncached: what a boot cost before
        parse_ms.append((time.perf_counter_ns() - t0) / 1e6)
        t0 = time.perf_counter_ns()
        provisioning_module.Provisioner(link.config, config).writes()
        build_ms.append((time.perf_counter_ns() - t0) / 1e6)
    return {
        "boot_us": statistics.mean(boot_us),
        "parse_ms": statistics.mean(parse_ms),
        "build_ms": statistics.mean(build_ms),
    }


def lockstep_set() -> tuple[MeteredGateway, LockstepNetwork]:
    """A fresh default gateway and one set of nodes, started on a `LockstepNetwork`."""
    config = gateway_config()
    gateway = MeteredGateway(config)
    net = LockstepNetwork([gateway, *set_nodes(config)])
    net.start()
    return gateway, net


def virtual_set(
    seconds: float, *, profile: bool = False, bounded: bool = False, warm_s: float = 1.0
) -> dict:
    """One set in virtual time: the gateway's CPU per simulated second (fresh gateway).

    `bounded`: the tracker's per-start quota off (PER_START = 0), as a diagnosis.
    """
    per_start = TrackerDecoder.PER_START
    if bounded:
        TrackerDecoder.PER_START = 0
    try:
        gateway, net = lockstep_set()
        net.run_for(round(warm_s * S))
        gateway.busy_ns = 0
        gateway.tpdo_cpu_us.clear()
        gateway.tpdo_parts.clear()
        profiler = cProfile.Profile() if profile else None
        cpu0 = time.process_time()
        if profiler is not None:
            profiler.enable()
            net.run_for(round(seconds * S))
            profiler.disable()
        else:
            gateway.meter_parts = True
            with decoder_meter():
                net.run_for(round(seconds * S))
        total = time.process_time() - cpu0
    finally:
        TrackerDecoder.PER_START = per_start
    out = {
        "seconds": seconds,
        "gateway_percent": 100 * gateway.busy_ns / 1e9 / seconds,
        "total_percent": 100 * total / seconds,
        "tpdo_cpu_us": list(gateway.tpdo_cpu_us),
        "tracks": len(getattr(gateway.decoder, "_tracks", ())),
    }
    if profiler is not None:
        out["profile"] = profile_breakdown(pstats.Stats(profiler))
    else:
        out["slowest"] = slowest_tpdos(gateway.tpdo_cpu_us, gateway.tpdo_parts)
    return out


def paced_cost(seconds: float, rounds: int = 2) -> dict:
    """Why real time costs more CPU than virtual time: the same gateway and skin TPDOs in
    virtual time, back to back and with the gateway's thread asleep for a TPDO period
    before each (as live, where it waits for the next frame), rounds interleaved. The
    work and outputs are the same; only what the thread finds in the caches differs."""
    out: dict[str, dict[str, list[float]]] = {}
    for _ in range(rounds):
        for label, pace_s in (("back_to_back", 0.0), ("paced", TPDO_PERIOD_S)):
            gateway, net = lockstep_set()
            net.run_for(S)  # operational, decoder warm
            gateway.tpdo_cpu_us.clear()
            gateway.caused_cpu_us.clear()
            gateway.pace_s = pace_s
            net.run_for(round(seconds * S))
            run = out.setdefault(label, {"caused_cpu_us": [], "tpdo_cpu_us": []})
            run["caused_cpu_us"] += gateway.caused_cpu_us
            run["tpdo_cpu_us"] += gateway.tpdo_cpu_us
    return out


def slowest_tpdos(cpu_us: list[float], parts: list[dict[str, int]]) -> dict:
    """The slowest 1 % of skin TPDOs: mean CPU, mean per tracker part, how many took a contact."""
    order = sorted(range(len(cpu_us)), key=lambda i: -cpu_us[i])[: max(1, len(cpu_us) // 100)]
    if not order or len(parts) != len(cpu_us):
        return {}
    return {
        "count": len(order),
        "mean_us": statistics.mean(cpu_us[i] for i in order),
        "parts_us": {
            label: statistics.mean(parts[i].get(label, 0) / 1000 for i in order)
            for _, _, label in METERED_PARTS
        },
        "with_contact": sum(1 for i in order if parts[i].get("new contact")) / len(order),
    }


# What the gateway's time goes to, by the function that owns it (cumulative time).
PROFILE_PARTS = (
    ("skin TPDO, total", "service.py", "_on_skin"),
    ("  skin decoder (tracker)", "base.py", "feed"),
    ("    contacts: detector + new contacts", "tracker.py", "_run_detector"),
    ("      contact detector", "contacts.py", "feed"),
    ("      new contact: branch every hypothesis", "tracker.py", "_add_contact"),
    ("    estimate (posterior, report)", "tracker.py", "_report"),
    ("  sample times (skin frames)", "skin_frames.py", "feed"),
    ("  feedback + reflex", "service.py", "_control"),
    ("  RPDOs (commands)", "service.py", "_commands"),
    ("PDO unpacking (all TPDOs)", "pdo_codec.py", "decode"),
    ("EMG intent", "service.py", "_on_emg"),
    ("timers (advance)", "service.py", "advance"),
    ("  snapshot (20 Hz)", "service.py", "snapshot"),
    ("next deadline", "service.py", "next_deadline_us"),
    ("NMT master (heartbeats)", "master.py", "receive"),
)


def profile_breakdown(stats: pstats.Stats) -> list[tuple[str, float]]:
    """Share [%] of the gateway's profiled time per part (cumulative, so parts nest)."""
    table = stats.stats  # type: ignore[attr-defined]
    cum: dict[tuple[str, str], float] = {}
    for (filename, _, name), (_, _, _, ct, _) in table.items():
        key = (Path(filename).name, name)
        if "/grasplink/" in filename:
            cum[key] = cum.get(key, 0.0) + ct
    whole = sum(
        cum.get(("service.py", name), 0.0)
        for name in ("receive", "advance", "next_deadline_us", "start")
    )
    # The metering wrapper's calls are the gateway's entry points; nested parts below.
    whole = max(whole, 1e-9)
    return [(label, 100 * cum.get((f, n), 0.0) / whole) for label, f, n in PROFILE_PARTS]


class PairBus(can.BusABC):
    """One end of a stream socket pair as a python-can bus.

    A CAN link between two processes with one kernel hop and no relay, as SocketCAN
    gives a deployed gateway (the hub's websockets would load the gateway process
    with relaying). Fixed-size records: the sender's time.time() (what python-can
    calls the timestamp), the CAN-ID, the length, 8 data bytes. A stream with a large
    buffer, so a reader that falls behind loses nothing and never stalls the sender
    (a Unix datagram queue holds ten frames, a default stream buffer under 300 small
    writes); a full link drops the frame at once, as a CAN controller's full queue.
    """

    RECORD = struct.Struct("<dHB8s")

    def __init__(self, sock: socket.socket, gateway: MeteredGateway | None = None):
        super().__init__(channel=f"pair{sock.fileno()}")
        self.sock = sock
        self.sock.setblocking(True)  # sends are checked for room first; reads select first
        for force, plain in (
            (SO_SNDBUFFORCE, socket.SO_SNDBUF),
            (SO_RCVBUFFORCE, socket.SO_RCVBUF),
        ):
            try:  # beyond net.core.wmem_max/rmem_max: needs CAP_NET_ADMIN
                sock.setsockopt(socket.SOL_SOCKET, force, LINK_BUFFER_BYTES)
            except OSError:
                sock.setsockopt(socket.SOL_SOCKET, plain, LINK_BUFFER_BYTES)
        self.last_stamp = 0.0
        self.gateway = gateway
        self._buffer = bytearray()
        self._ready: deque[can.Message] = deque()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        _, writable, _ = select.select([], [self.sock], [], 0.0)
        if not writable:  # the other side stopped reading: drop, as a CAN controller would
            raise can.CanOperationError("link full")
        now = time.time()
        data = bytes(msg.data)
        self.sock.sendall(self.RECORD.pack(now, msg.arbitration_id, len(data), data))
        if self.gateway is not None:
            self.gateway.on_sent(now)

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        if not self._ready:
            ready, _, _ = select.select([self.sock], [], [], timeout)
            if not ready:
                return None, False
            chunk = self.sock.recv(1 << 16)
            if not chunk:
                raise can.CanOperationError("the other process closed the link")
            self._buffer += chunk
            size = self.RECORD.size
            whole = len(self._buffer) - len(self._buffer) % size
            for offset in range(0, whole, size):
                stamp, can_id, length, data = self.RECORD.unpack_from(self._buffer, offset)
                self._ready.append(
                    can.Message(
                        timestamp=stamp,
                        arbitration_id=can_id,
                        data=data[:length],
                        is_extended_id=False,
                    )
                )
            del self._buffer[:whole]
            if not self._ready:
                return None, False
        msg = self._ready.popleft()
        self.last_stamp = msg.timestamp
        return msg, False

    def fileno(self) -> int:
        """The socket: a `MultiRunner` waits on it like on a SocketCAN socket."""
        return self.sock.fileno()

    def drain(self) -> None:
        """Drop what arrived so far: a CAN socket opened now hears only frames from now on."""
        while select.select([self.sock], [], [], 0.0)[0]:
            if not self.sock.recv(1 << 16):
                break
        self._buffer.clear()
        self._ready.clear()

    def shutdown(self) -> None:
        super().shutdown()
        self.sock.close()


def serve_nodes(fds: list[int]) -> int:
    """Child process: one set of four nodes per link until stdin closes."""
    logging.getLogger("grasplink").setLevel(logging.ERROR)  # links dropping at the end
    config = gateway_config()
    runners, buses = [], []
    for i, fd in enumerate(fds):
        bus = PairBus(socket.socket(fileno=fd))
        period = len(SlipCycle().values)
        nodes = set_nodes(config, offset=(i * period) // max(1, len(fds)))
        runners.append(NodeRunner(bus, nodes, name=f"bench-nodes-{i}"))
        buses.append(bus)
    # One thread on a 1 ms timer tick for every set: the sets' TPDO timers that fall due
    # within a tick go out in one wake-up, so the node side costs a fraction of a thread
    # per set waking for each TPDO and does not starve the gateway process it loads.
    serving = MultiRunner(runners, name="bench-nodes", tick_s=NODE_TICK_S).start()
    print("ready", flush=True)
    sys.stdin.read()
    serving.stop()
    for bus in buses:
        bus.shutdown()
    return 0


def realtime_capacity(
    sets: int, seconds: float, *, together: bool = False, multi: bool = False
) -> dict:
    """N gateways in this process, each with its own link to a child process of nodes.

    Threads (`multi` False): a `NodeRunner` thread per gateway, started one after
    another, each once the previous has its nodes operational. `multi`: one
    `MultiRunner` thread serves every link, as `grasplink gateway --bus A --bus B ...`
    does; its gateways all start at once. `together`: threads all started at once, to see
    whether they come up at all (no measurement).
    """
    return _realtime_capacity(sets, seconds, together=together, multi=multi)


def _realtime_capacity(sets: int, seconds: float, *, together: bool, multi: bool) -> dict:
    pairs = [socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM) for _ in range(sets)]
    child_fds = [theirs.fileno() for _, theirs in pairs]
    child = subprocess.Popen(
        [sys.executable, __file__, "--serve-nodes", ",".join(map(str, child_fds))],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        pass_fds=child_fds,
        text=True,
    )
    for _, theirs in pairs:
        theirs.close()
    gateways: list[MeteredGateway] = []
    runners: list[NodeRunner] = []
    buses: list[PairBus] = []
    serving: MultiRunner | None = None
    result: dict = {"sets": sets, "multi": multi}
    try:
        assert child.stdout is not None
        if child.stdout.readline().strip() != "ready":
            raise RuntimeError("the node process did not start")
        # Build every gateway before any runs: building (EDS parsing) holds the GIL long.
        for mine, _ in pairs:
            gateway = MeteredGateway(gateway_config())
            bus = PairBus(mine, gateway)
            gateway.stamp_bus = bus
            gateways.append(gateway)
            buses.append(bus)
        prepare_to_go_live(gateways)  # as `LiveGateway.start` does before its runners start
        up0 = time.monotonic()
        if multi:
            for i, (gateway, bus) in enumerate(zip(gateways, buses, strict=True)):
                bus.drain()  # the nodes ran before this gateway listened
                runners.append(NodeRunner(bus, [gateway], name=f"bench-gateway-{i}"))
            serving = MultiRunner(runners, name="bench-gateways").start()
            _wait(
                lambda: all(g.operational() for g in gateways),
                30.0,
                functools.partial(_phases, gateways),
            )
            result["up_s"] = time.monotonic() - up0
        for i, (gateway, bus) in enumerate(zip(gateways, buses, strict=True)):
            if multi:
                break
            bus.drain()  # the nodes ran before this gateway listened
            runners.append(NodeRunner(bus, [gateway], name=f"bench-gateway-{i}").start())
            if not together:
                _wait(gateway.operational, 20.0, functools.partial(_phases, [gateway]))
        if together:
            try:
                _wait(lambda: all(g.operational() for g in gateways), 20.0, lambda: "")
                result["up_s"] = time.monotonic() - up0
            except RuntimeError:
                result["up_s"] = None
            result["boots"] = sum(s.boots for g in gateways for s in g.nodes.values())
            return result
        time.sleep(2.0)
        for g in gateways:
            g.stamped_us.clear()
            g.tpdo_wall_us.clear()
            g.busy_ns = 0
        streams = [g.skin_frames for g in gateways]
        packets0 = [st.stats.packets for st in streams if st]
        lost0 = [st.stats.lost_packets for st in streams if st]
        resyncs0 = [st.stats.resyncs for st in streams if st]
        late0 = sum(g.late_tpdos for g in gateways)
        boots0 = _boots(gateways)
        t0, own0, child0 = time.monotonic(), os.times(), proc_cpu_s(child.pid)
        load0 = os.getloadavg()[0]
        time.sleep(seconds)
        wall = time.monotonic() - t0
        own1, child1 = os.times(), proc_cpu_s(child.pid)
        stamped = [x for g in gateways for x in g.stamped_us]
        processing = [x for g in gateways for x in g.tpdo_wall_us]
        packets = [st.stats.packets - p for st, p in zip(streams, packets0, strict=True) if st]
        lost = [st.stats.lost_packets - p for st, p in zip(streams, lost0, strict=True) if st]
        resyncs = [st.stats.resyncs - p for st, p in zip(streams, resyncs0, strict=True) if st]
        result |= {
            "seconds": wall,
            "cpu_percent": 100 * (own1.user + own1.system - own0.user - own0.system) / wall,
            "gateway_percent": 100 * sum(g.busy_ns for g in gateways) / 1e9 / wall,
            "child_percent": 100 * (child1 - child0) / wall,
            "loadavg": (load0 + os.getloadavg()[0]) / 2,
            "caused": len(stamped),
            "p50_us": percentile(stamped, 50),
            "p99_us": percentile(stamped, 99),
            "max_us": max(stamped, default=float("nan")),
            "processing_p99_us": percentile(processing, 99),
            "skin_rate_share": min(packets) / wall / (400 / 3),
            "lost_packets": sum(lost),
            "resyncs": sum(resyncs),
            "late_tpdos": sum(g.late_tpdos for g in gateways) - late0,
            "resyncs_per_set_min": sum(resyncs) / sets / (wall / 60),
            "boots": _boots(gateways) - boots0,
            "tracks": max(len(getattr(g.decoder, "_tracks", ())) for g in gateways),
        }
        result["keeps_up"] = (
            result["cpu_percent"] < 100.0
            and result["skin_rate_share"] >= 0.95
            and result["resyncs_per_set_min"] <= MAX_RESYNCS_PER_SET_MIN
        )
        result["passes"] = result["keeps_up"] and result["p99_us"] <= TARGET_P99_US
    except RuntimeError as exc:  # a gateway that never got its nodes up: this N fails
        result |= {"error": str(exc)[:300], "passes": False, "keeps_up": False}
    finally:
        if serving is not None:
            serving.stop()
        for runner in runners:
            runner.stop()
        if child.stdin is not None:
            child.stdin.close()
        try:
            child.wait(10)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
        for bus in buses:
            bus.shutdown()
    return result


def _boots(gateways: list[MeteredGateway]) -> int:
    """Node boots the gateways have seen (a node reset after being lost boots again)."""
    return sum(status.boots for g in gateways for status in g.nodes.values())


def capacity_steps(seconds: float, steps: tuple[int, ...], *, multi: bool = False) -> list[dict]:
    """Real-time runs at growing N; stops after two steps in a row that do not keep up."""
    out = []
    for n in steps:
        result = realtime_capacity(n, seconds, multi=multi)
        out.append(result)
        how = "one thread" if multi else "threads"
        if "error" in result:
            print(f"  {n} sets ({how}): {result['error']}", file=sys.stderr, flush=True)
        else:
            print(
                f"  {n} sets ({how}): CPU {result['cpu_percent']:.0f} %, "
                f"p99 {result['p99_us']:.0f} us, "
                f"skin rate {100 * result['skin_rate_share']:.0f} %",
                file=sys.stderr,
                flush=True,
            )
        if not result["keeps_up"] and len(out) >= 2 and not out[-2]["keeps_up"]:
            break
    return out


# -- 4. memory over 10 simulated minutes -----------------------------------------------------
def memory_virtual(seconds: float, sample_s: float, bounded: bool = False) -> dict:
    """RSS, the tracker's hypotheses and the gateway's CPU, every `sample_s` simulated.

    The run ends early once the gateway needs more than `MAX_CPU_PERCENT` of a core
    for a minute: in real time it would fall behind its bus from there on, and what
    virtual time shows beyond that point could not happen (the cost also grows with
    the square of the run's length). `bounded`: the diagnosis run, with the tracker's
    per-start quota off (PER_START = 0).
    """
    if bounded:
        TrackerDecoder.PER_START = 0
    gateway, net = lockstep_set()
    series = []
    t = 0.0
    busy0 = 0
    while t < seconds:
        net.run_for(round(sample_s * S))
        t += sample_s
        window = gateway.tpdo_cpu_us[:]
        # The meters' own lists would grow RSS: keep only this window's.
        for meter in (gateway.tpdo_cpu_us, gateway.tpdo_wall_us, gateway.tpdo_at, gateway.caused):
            meter.clear()
        series.append(
            {
                "t_s": t,
                "rss_mib": rss_mib(),
                "tracks": len(getattr(gateway.decoder, "_tracks", ())),
                "gateway_percent": 100 * (gateway.busy_ns - busy0) / 1e9 / sample_s,
                "tpdo_cpu_p50_us": percentile(window, 50),
                "tpdo_cpu_max_us": max(window, default=float("nan")),
            }
        )
        busy0 = gateway.busy_ns
        last_minute = series[-max(1, round(60 / sample_s)) :]
        if t >= 60 and min(p["gateway_percent"] for p in last_minute) > MAX_CPU_PERCENT:
            break
    return {"seconds": seconds, "bounded": bounded, "series": series, "stopped_s": t}


YARDSTICK_RATE_HZ = 440  # a set's frames per second at the gateway


def bus_yardstick_us(seconds: float = 5.0) -> float:
    """CPU per frame of a thread doing nothing but python-can's `recv` on the virtual bus,
    fed at a set's frame rate by another thread: how fast this machine wakes and receives."""
    channel = f"bench-yardstick-{os.getpid()}-{time.monotonic_ns()}"
    sender, receiver = (can.Bus(interface="virtual", channel=channel) for _ in range(2))
    stop = threading.Event()
    got: dict[str, float] = {}

    def receive() -> None:
        frames, cpu0 = 0, time.thread_time()
        while not stop.is_set():
            if receiver.recv(0.02) is not None:
                frames += 1
        got["cpu_s"], got["frames"] = time.thread_time() - cpu0, frames

    thread = threading.Thread(target=receive, name="bench-yardstick", daemon=True)
    thread.start()
    msg = can.Message(arbitration_id=SKIN_TPDO1, data=bytes(8), is_extended_id=False)
    try:
        end, period = time.monotonic() + seconds, 1.0 / YARDSTICK_RATE_HZ
        while time.monotonic() < end:
            sender.send(msg)
            time.sleep(period)
    finally:
        stop.set()
        thread.join(1.0)
        sender.shutdown()
        receiver.shutdown()
    return got["cpu_s"] / max(1, got["frames"]) * 1e6


def memory_child(seconds: float, sample_s: float, variant: str) -> subprocess.Popen:
    """A memory run in a fresh interpreter (its own RSS); JSON on its stdout."""
    return subprocess.Popen(
        [sys.executable, __file__, "--memory", str(seconds), str(sample_s), variant],
        stdout=subprocess.PIPE,
        text=True,
    )


def collect(child: subprocess.Popen) -> dict:
    stdout, _ = child.communicate()
    if child.returncode != 0:
        raise RuntimeError(f"memory run failed with exit code {child.returncode}")
    return json.loads(stdout)


def measure(quick: bool) -> dict:
    """Every part, in the order that keeps the real-time ones alone: the figures."""
    started = time.monotonic()
    say = _say(started)
    load0 = os.getloadavg()
    # Real time first, alone: nothing of this benchmark competes with it for the cores.
    loop_s, repeats = (10.0, 1) if quick else (60.0, 3)
    say("0. machine speed: python-can's own receive loop")
    yardstick = [bus_yardstick_us(3.0 if quick else 10.0)]
    say(f"1. loop latency: {repeats} x {loop_s:.0f} s in real time")
    loops = [realtime_loop(loop_s) for _ in range(repeats)]
    say("1. the same TPDOs in virtual time, back to back and paced as live")
    paced = paced_cost(5.0 if quick else 20.0)
    steps = (1, 2) if quick else (1, 2, 4, 6, 8, 12, 16, 24, 32)
    say("3. capacity in real time: a thread per gateway")
    capacity = capacity_steps(5.0 if quick else 20.0, steps)
    say("3. capacity in real time: one thread for every gateway (MultiRunner)")
    capacity_multi = capacity_steps(5.0 if quick else 20.0, steps, multi=True)
    together = realtime_capacity(2 if quick else 8, 0.0, together=True)
    yardstick.append(bus_yardstick_us(3.0 if quick else 10.0))
    # Virtual time: CPU is counted per thread, so the runs may share the cores.
    minutes = 0.5 if quick else 10.0
    sample_s = 2.0 if quick else 5.0
    say(f"4. memory: {minutes:g} simulated minutes (two processes), meanwhile 2. and 3.")
    children = {v: memory_child(minutes * 60, sample_s, v) for v in ("default", "bounded")}
    onset = onset_matrix(1 if quick else 4, (40.0,) if quick else ONSET_SPEEDS)
    say("3. gateway CPU per set in virtual time, and its profile")
    fresh = virtual_set(10.0 if quick else 60.0)
    fresh_bounded = virtual_set(10.0 if quick else 60.0, bounded=True)
    profiled = virtual_set(10.0 if quick else 30.0, profile=True)
    provisioning = provisioning_cost()
    say("5. batching per SYNC against event-driven")
    sync = sync_batching(5.0 if quick else 30.0, 1 if quick else 3, 5.0 if quick else 20.0)
    memory = {v: collect(child) for v, child in children.items()}
    say("measured")
    return {
        "loops": loops,
        "paced": paced,
        "onset": onset,
        "fresh": fresh,
        "fresh_bounded": fresh_bounded,
        "profiled": profiled,
        "provisioning": provisioning,
        "sync": sync,
        "capacity": capacity,
        "capacity_multi": capacity_multi,
        "together": together,
        "yardstick_us": yardstick,
        "memory": memory,
        "wall_s": time.monotonic() - started,
        "code": code_version(),
        "loadavg": (load0[0], os.getloadavg()[0]),
        "quick": quick,
        **context(),
    }


def context() -> dict:
    """What the render shows beside the figures: the setup the parts ran with, the machine,
    python-can's version and the decoder's detection delays (read here, not when rendering)."""
    return {
        "setup": setup(),
        "environment": figures_json.environment(**{"python-can": can.__version__}),
        "detector": detector_delays(),
    }


def setup() -> dict:
    """The workload, the targets and the parts' parameters, as this code runs them."""
    return {
        "layout": LAYOUT,
        "layouts": list(LAYOUTS_MM),
        "slip_mm_s": SLIP_MM_S,
        "rest_s": REST_S,
        "cycle_s": SlipCycle().period_s,
        "emg_uv": EMG_UV,
        "onset_s": ONSET_S,
        "tpdo_period_s": TPDO_PERIOD_S,
        "node_tick_s": NODE_TICK_S,
        "yardstick_rate_hz": YARDSTICK_RATE_HZ,
        "max_cpu_percent": MAX_CPU_PERCENT,
        "max_resyncs_per_set_min": MAX_RESYNCS_PER_SET_MIN,
        "target_p99_us": TARGET_P99_US,
        "target_excess_ms": TARGET_EXCESS_MS,
        "target_sets": TARGET_SETS,
        "flat_mib_per_min": FLAT_MIB_PER_MIN,
    }


def code_version() -> str:
    """The commit the measured code is at, and whether grasplink/ differs from it."""
    try:
        commit = subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        changed = subprocess.run(
            ["git", "-C", str(ROOT), "status", "--porcelain", "--", "grasplink"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown commit"
    return f"commit {commit}" + (" with uncommitted changes in grasplink/" if changed else "")


def _say(started: float) -> Callable[[str], None]:
    def say(text: str) -> None:
        print(f"[{time.monotonic() - started:6.0f} s] {text}", file=sys.stderr, flush=True)

    return say


def detector_delays() -> dict:
    """How late the default tracker learns of a contact at the skin's 400 Hz."""
    tracker = TrackerDecoder(LAYOUTS_MM[LAYOUT], 400)
    return {
        "min_ms": round(tracker._min_latency * 1e3, 1),
        "max_ms": round(tracker._max_latency * 1e3, 1),
        "detect_mm": tracker.DETECT_MM,
        "block_ms": round(tracker._block / 400 * 1e3, 1),
    }


def child_main(argv: list[str] | None = None) -> int:
    """This module as a script: the node process of 3, or one memory run of 4."""
    parser = argparse.ArgumentParser(description="bench_gateway's child processes")
    parser.add_argument("--serve-nodes", help="fds of the links, comma-separated")
    parser.add_argument("--memory", nargs=3, metavar=("SECONDS", "SAMPLE_S", "VARIANT"))
    args = parser.parse_args(argv)
    if args.serve_nodes:
        return serve_nodes([int(fd) for fd in args.serve_nodes.split(",")])
    if args.memory:
        seconds, sample_s, variant = args.memory
        print(json.dumps(memory_virtual(float(seconds), float(sample_s), variant == "bounded")))
        return 0
    parser.error("--serve-nodes or --memory")


if __name__ == "__main__":
    sys.exit(child_main())

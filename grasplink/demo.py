"""`grasplink demo`: boot a whole prosthesis network and report what the bus carried.

A device node of each kind and an NMT master run on one bus (the embedded
virtual bus by default). The master resets and starts the nodes, then drives the
belt and the hand through their RPDOs, stepping through the thesis display
levels, while a separate bus handle watches like a bus analyser: node
states, PDO rates, heartbeat jitter, and bus load with worst-case stuffing.
"""

from __future__ import annotations

import itertools
import os
import statistics
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field

import can

from grasplink.bus import NodeRunner, frame_bits_worst_case, message_to_frame, open_bus
from grasplink.core.frames import function_of
from grasplink.devices.factory import build_node
from grasplink.gateway.scripted import ScriptedMaster
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import BY_NODE_ID, node_kind

BITRATE = 1_000_000
# services sent on events, not in a cycle: their rate is over the whole run
EVENT_SERVICES = frozenset({"NMT", "EMCY", "SDO tx", "SDO rx", "LSS master", "LSS slave"})
COMMAND_PERIOD_US = 50_000
LEVEL_DWELL_US = 500_000
# Force belt levels (rad/s, ch. 8) then the slip belt levels (negative velocity).
BELT_LEVELS_MRAD_S = (3500, 5000, 6500, 8000, -2000, -3700, -5300, -7000)


def demo_master(kinds: dict[int, str]) -> ScriptedMaster:
    """The NMT master plus a stand-in controller: steps belt levels and ramps the grip."""
    dwell_s = LEVEL_DWELL_US / 1e6
    belt_profile = [(i * dwell_s, float(v)) for i, v in enumerate(BELT_LEVELS_MRAD_S * 4)]
    grip_profile = [(t / 10, min(30.0, t)) for t in range(0, 31)]  # 10 N/s up to 30 N
    ids = {kind: node_id for node_id, kind in kinds.items()}
    return ScriptedMaster(
        belt_id=ids.get("belt"),
        hand_id=ids.get("hand"),
        belt_mrad_s=belt_profile,
        hand_grip_n=grip_profile,
        command_period_us=COMMAND_PERIOD_US,
    )


@dataclass
class BusWatch:
    """What a bus analyser on a second handle saw."""

    frames: Counter[int] = field(default_factory=Counter)
    bytes: Counter[int] = field(default_factory=Counter)
    bits: int = 0
    first_us: int | None = None
    last_us: int | None = None
    heartbeat_times: dict[int, list[float]] = field(default_factory=dict)
    spans_us: dict[int, tuple[int, int]] = field(default_factory=dict)  # first, last per ID

    def rate_per_s(self, can_id: int, overall_s: float) -> float:
        """Frames per second of one COB-ID: a cyclic one's while it flows (a TPDO starts
        only once its node is started: the whole run's span would understate it by the
        boot time), an event's over the whole run (the boot's NMT commands come within
        milliseconds: their own span would read thousands per second)."""
        first, last = self.spans_us.get(can_id, (0, 0))
        count = self.frames[can_id]
        if count < 2 or last <= first or function_of(can_id)[0] in EVENT_SERVICES:
            return count / overall_s
        return (count - 1) / ((last - first) / 1e6)

    def record(self, msg: can.Message) -> None:
        frame = message_to_frame(msg)
        if frame is None:
            return
        t_us = int(msg.timestamp * 1e6)
        self.first_us = t_us if self.first_us is None else self.first_us
        self.last_us = t_us
        self.frames[frame.can_id] += 1
        first, _ = self.spans_us.get(frame.can_id, (t_us, t_us))
        self.spans_us[frame.can_id] = (first, t_us)
        self.bytes[frame.can_id] += len(frame.data)
        self.bits += frame_bits_worst_case(frame.length, frame.rtr)
        function, node_id = function_of(frame.can_id)
        if function == "heartbeat" and node_id and frame.data and frame.data[0] != 0:
            self.heartbeat_times.setdefault(node_id, []).append(msg.timestamp)


def _watch(bus: can.BusABC, watch: BusWatch, stop: threading.Event) -> None:
    while not stop.is_set():
        msg = bus.recv(0.05)
        if msg is not None:
            watch.record(msg)


def describe(can_id: int, kinds: dict[int, str]) -> str:
    function, node_id = function_of(can_id)
    if function in ("NMT", "SYNC"):
        return function
    kind = kinds.get(node_id, "gateway" if node_id == obj.GATEWAY_NODE_ID else f"node {node_id}")
    return f"{kind} {function}"


def run_demo(
    duration_s: float = 3.0, bus_url: str | None = None, out: Callable[[str], None] = print
) -> dict:
    """Run the demo; returns the figures it printed (for tests)."""
    url = bus_url or f"virtual:grasplink-demo-{os.getpid()}"
    kinds = {node_kind(k).node_id: k for k in BY_NODE_ID}
    nodes = [build_node(kind, node_id) for node_id, kind in kinds.items()]
    master = demo_master(kinds)
    watch, stop = BusWatch(), threading.Event()
    node_bus, watch_bus = open_bus(url), open_bus(url)
    watcher = threading.Thread(target=_watch, args=(watch_bus, watch, stop), daemon=True)
    try:
        watcher.start()
        # The master starts first: its reset-communication reaches nodes not yet
        # powered, so each node boots once and is started on its boot-up.
        with NodeRunner(node_bus, [master, *nodes]):
            time.sleep(duration_s)
        stop.set()
        watcher.join(1.0)
    finally:
        stop.set()
        node_bus.shutdown()
        watch_bus.shutdown()
    return _report(url, duration_s, kinds, nodes, master, watch, out)


def _report(url, duration_s, kinds, nodes, master, watch, out) -> dict:
    span_s = max(1e-6, ((watch.last_us or 0) - (watch.first_us or 0)) / 1e6)
    out(f"grasplink demo: {len(nodes)} nodes and an NMT master on {url}, {duration_s:.1f} s")
    out("")
    out(f"{'node':<6}{'id':>6}  {'state':<16}{'boots':>6}  heartbeat period")
    states = {}
    for node in nodes:
        status = master.nodes.get(node.node_id)
        state = status.state.name if status and status.state is not None else "silent"
        states[kinds[node.node_id]] = state
        beats = watch.heartbeat_times.get(node.node_id, [])
        periods = [(b - a) * 1e3 for a, b in itertools.pairwise(beats)]
        beat = (
            f"{statistics.mean(periods):6.1f} ms ± {statistics.pstdev(periods):.2f} ms"
            if len(periods) > 1
            else "-"
        )
        boots = status.boots if status else 0
        out(f"{kinds[node.node_id]:<6}{node.node_id:#6x}  {state:<16}{boots:>6}  {beat}")
    out("")
    out(f"{'COB-ID':<8}{'what':<18}{'frames':>8}{'per s':>9}{'bytes/frame':>13}")
    rates = {}
    for can_id in sorted(watch.frames):
        count = watch.frames[can_id]
        name = describe(can_id, kinds)
        rates[name] = watch.rate_per_s(can_id, span_s)
        out(
            f"{can_id:#05x}   {name:<18}{count:>8}{rates[name]:>9.1f}"
            f"{watch.bytes[can_id] / count:>13.1f}"
        )
    load = 100.0 * watch.bits / span_s / BITRATE
    total = sum(watch.frames.values())
    out("")
    out(
        f"bus load: {load:.2f} % of 1 Mbit/s ({total} frames, {total / span_s:.0f} frames/s, "
        "worst-case bit stuffing)"
    )
    belt = next(n for n in nodes if kinds[n.node_id] == "belt")
    hand = next(n for n in nodes if kinds[n.node_id] == "hand")
    out(
        f"belt: {belt.app.velocity_mrad_s / 1000:+.2f} rad/s "
        f"(tap {int(belt.store.get(obj.BELT_TAP_FREQUENCY_MHZ)) / 1000:.2f} Hz, "
        f"slip belt {int(belt.store.get(obj.BELT_SURFACE_SPEED_MM_S))} mm/s); "
        f"hand grip {hand.app.grip_mn / 1000:.1f} N"
    )
    return {"states": states, "rates_per_s": rates, "bus_load_percent": load, "frames": total}

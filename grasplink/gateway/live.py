"""The gateway on a live bus: the sans-IO `Gateway` inside a real-time runner.

`LiveGateway` opens the bus a URL names, runs the gateway on it (and, for
the embedded bus, optionally the four device nodes beside it), reopens a
lost bus with back-off, and offers the gateway's latest snapshot and a
one-line status for whoever watches (the CLI, telemetry). The runners drive each
gateway through its `edge.GatewayEdge` (`edges`): the mailbox for commands from
other threads and the wall-clock loop latency; surfaces are handed the edges.

Start-up comes in two steps so a failure sends nothing: `open` opens every bus and
readies the decoder without a frame, the caller binds its surfaces (Modbus, MQTT), and
only `go` starts the runners - the reset, provisioning and heartbeat that follow are
what a running gateway owes its nodes. `start` does both.

The gateway's own heartbeat is served apart from its decoding: the master hands it to
the runner as an urgent timer (`NmtMaster.detach_heartbeat`), which a pacer thread at
real-time priority (where the host allows it) sends on time while the runner's thread
decodes, and which that thread also serves between two received frames. The runner's
thread itself runs at nice -10 where allowed, so decoding keeps up beside busy processes.

It can master several buses at once (``more_buses``): one `Gateway` per bus,
each its own CANopen network with the configured node-IDs, all served by one
thread (`MultiRunner`) rather than one thread per bus, so gateways sharing a
process do not pass the GIL back and forth at every frame.
"""

from __future__ import annotations

import functools
import gc
from collections.abc import Iterable, Sequence

import can

from grasplink.bus import MultiRunner, NodeRunner, open_bus
from grasplink.bus.reconnect import DEFAULT_RECONNECT_TIMEOUT_S
from grasplink.bus.runner import DEFAULT_STALL_LIMIT_S, RunnerStats
from grasplink.devices.factory import build_from_file, build_node
from grasplink.errors import BusError
from grasplink.gateway.config import GatewayConfig
from grasplink.gateway.edge import GatewayEdge
from grasplink.gateway.service import Gateway
from grasplink.gateway.snapshot import SkinSnapshot, Snapshot

# The gateway's runner thread runs ahead of ordinary work (decoding must keep up with the
# bus on a busy host), but not real-time: its work grows with the traffic it is sent.
GATEWAY_NICE = -10


def prepare_to_go_live(gateways: Iterable[Gateway]) -> None:
    """What a gateway's loop must not meet once live, done before its runners start:

    - its decoder's kernels loaded (or compiled): the first call would stall a second or
      more (`Decoder.warm_up`);
    - everything built so far (modules, object dictionaries, decoder tables) moved out of
      the garbage collector's generations: a full collection in the loop then scans only
      what the loop made, a pause of well under a millisecond instead of a few ms on the
      skin TPDO that happens to trigger it (CPython's `gc.freeze`).
    """
    for gateway in gateways:
        if gateway.decoder is not None:
            gateway.decoder.warm_up()
    gc.collect()
    gc.freeze()


class LiveGateway:
    """Run a `Gateway` on `bus_url` (and on each of ``more_buses``) in a background thread;
    a context manager. `gateways` are in bus order, `edges` theirs (what surfaces are
    handed); `gateway` and `edge` are the first bus's."""

    def __init__(
        self,
        bus_url: str,
        config: GatewayConfig,
        *,
        with_nodes: bool = False,
        reconnect_timeout_s: float = DEFAULT_RECONNECT_TIMEOUT_S,
        more_buses: Sequence[str] = (),
        stall_limit_s: float = DEFAULT_STALL_LIMIT_S,
    ):
        self.bus_url = bus_url
        self.bus_urls = [bus_url, *more_buses]
        if len(set(self.bus_urls)) != len(self.bus_urls):
            raise BusError(f"a bus is named twice: {', '.join(self.bus_urls)}")
        self.config = config
        self.gateways = [Gateway(config) for _ in self.bus_urls]
        self.gateway = self.gateways[0]
        self.edges = [GatewayEdge(g) for g in self.gateways]
        self.edge = self.edges[0]
        self.with_nodes = with_nodes
        self.reconnect_timeout_s = reconnect_timeout_s
        self.stall_limit_s = stall_limit_s
        self._opened = False
        self._node_runners: list[NodeRunner] = []
        self._buses: list[can.BusABC] = []
        self._runners: list[NodeRunner | MultiRunner] = []
        self._gateway_runners: list[NodeRunner] = []

    def __enter__(self) -> LiveGateway:
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.stop()

    def start(self) -> None:
        """`open`, then `go`."""
        self.open()
        self.go()

    @property
    def up(self) -> bool:
        """Whether `go` has started the runners (the network is being mastered)."""
        return bool(self._runners)

    def open(self) -> None:
        """Open every bus and ready the gateways to go live, sending no frame: a BusError
        here (or anything the caller fails at before `go`) leaves the network untouched."""
        if self._opened:
            raise RuntimeError("LiveGateway.open() twice")
        self._opened = True
        node_runners = self._node_runners
        for url, edge in zip(self.bus_urls, self.edges, strict=True):
            gateway = edge.gateway
            bus = open_bus(url)
            self._buses.append(bus)
            if self.with_nodes:
                # The four device nodes on their own handle of the same bus, as if in other boxes.
                nodes_bus = open_bus(url)
                self._buses.append(nodes_bus)
                nodes = [
                    build_node(n.kind, n.node_id)
                    if n.eds is None
                    else build_from_file(n.eds, n.node_id)[0]  # a vendor's: protocol only
                    for n in self.config.nodes.values()
                ]
                node_runners.append(NodeRunner(nodes_bus, nodes, name=f"grasplink-nodes {url}"))
            self._gateway_runners.append(
                NodeRunner(
                    bus,
                    [edge],
                    name=f"grasplink-gateway {url}",
                    reopen=functools.partial(open_bus, url),
                    reconnect_timeout_s=self.reconnect_timeout_s,
                    urgent=[gateway.detach_heartbeat()],
                    pace_urgent=True,
                    stall_limit_s=self.stall_limit_s,
                    nice=GATEWAY_NICE,
                )
            )
        prepare_to_go_live(self.gateways)
        for gateway in self.gateways:
            # What a surface connected before `go` reports first (a Sparkplug NBIRTH, the
            # Modbus registers): the gateway as configured, no node live yet - not nulls.
            if gateway.latest is None:
                gateway.latest = gateway.snapshot()

    def go(self) -> None:
        """Start the runners: the gateway resets, provisions and starts its nodes."""
        if not self._opened:
            raise RuntimeError("LiveGateway.go() before open()")
        if self._runners:
            raise RuntimeError("LiveGateway.go() twice")
        node_runners = self._node_runners
        if len(self.bus_urls) == 1:
            self._runners += [r.start() for r in node_runners]
            self._runners.append(self._gateway_runners[0].start())
            return
        if node_runners:
            self._runners.append(MultiRunner(node_runners, name="grasplink-nodes").start())
        self._runners.append(
            MultiRunner(self._gateway_runners, name="grasplink-gateways", nice=GATEWAY_NICE).start()
        )

    def stop(self) -> None:
        for runner in reversed(self._runners):
            runner.stop()
        for bus in self._buses:
            bus.shutdown()
        self._runners.clear()
        self._gateway_runners.clear()
        self._node_runners.clear()
        self._buses.clear()

    @property
    def failure(self) -> BusError | None:
        """Why a gateway's runner gave up on its bus (the first such), or None."""
        return next((r.failure for r in self._gateway_runners if r.failure is not None), None)

    @property
    def heartbeat_priority(self) -> str | None:
        """What the host granted the thread sending the gateway's heartbeat (None: not yet)."""
        return next((r.pacer_priority for r in self._gateway_runners if r.pacer_priority), None)

    @property
    def runner_priority(self) -> str | None:
        """What the host granted the thread running the gateway (None: not started)."""
        return self._runners[-1].priority if self._runners else None  # the gateways' is last

    def snapshot(self) -> Snapshot | None:
        return self.gateway.latest

    def status_line(self) -> str:
        """Node states, decoded values and loop latency, for a log every few seconds
        (one line per bus when there are several)."""
        runners: list[NodeRunner | None] = [*self._gateway_runners] or [None] * len(self.gateways)
        lines = [
            status_of(g) + ("" if r is None else behind_text(r.stats))
            for g, r in zip(self.gateways, runners, strict=True)
        ]
        if len(lines) == 1:
            return lines[0]
        return "\n".join(f"[{url}] {line}" for url, line in zip(self.bus_urls, lines, strict=True))


def behind_text(stats: RunnerStats) -> str:
    """What a gateway too slow for its bus has skipped so far ("" while it kept up): the
    PDOs its runner dropped for a newer one of their COB-ID, which the log only warns
    about every 10 s."""
    if not stats.superseded:
        return ""
    worst_cob_id, worst = stats.superseded_by_cob_id.most_common(1)[0]
    return (
        f" | behind the bus: {stats.superseded} PDOs superseded in {stats.catch_ups} "
        f"catch-ups (most 0x{worst_cob_id:03X}: {worst})"
    )


def status_of(gateway: Gateway) -> str:
    """One gateway's status line, from its latest snapshot."""
    snap = gateway.latest
    if snap is None:
        return "gateway starting"
    nodes = " ".join(
        f"{kind}:{n.phase}" + (f"/{n.pdos_dropped}drop" if n.pdos_dropped else "")
        for kind, n in snap.nodes.items()
    )
    skin, belt, hand, loop = snap.skin, snap.belt, snap.hand, snap.loop
    slip = "-" if not skin.slip else f"SLIP {slip_text(skin)}"
    force = skin.grip_force_n
    grip = hand.setpoint_n
    latency = loop.latency_p99_us
    parts = [
        f"up {snap.uptime_s:.1f} s",
        nodes,
        f"skin {force:.1f} N" if force is not None else "skin -",
        slip,
        f"belt {belt.belt}{'' if belt.level is None else belt.level}",
        f"grip {grip:.1f} N" if grip is not None else "grip -",
        f"reflex {hand.reflex}",
        f"loop p99 {latency:.0f} us" if latency is not None else "loop -",
    ]
    beat = snap.heartbeat
    if beat.late:
        parts.append(
            f"own heartbeat late {beat.late}x (max {beat.late_max_ms:.0f} ms, "
            f"{beat.over_consumer} over {beat.consumer_ms:.0f} ms)"
        )
    if snap.alarms:
        parts.append("ALARMS " + "; ".join(f"{k}: {v}" for k, v in snap.alarms.items()))
    return " | ".join(parts)


def slip_text(skin: SkinSnapshot) -> str:
    """A slip's speed for the status line: "40 mm/s +" (speed, direction), ">= 12 mm/s"
    (only a bound: its lower end), "(speed ?)"; the direction "+" towards the last ridge,
    "-" back, "?" not told."""
    speed, low = skin.slip_speed_mm_s, skin.slip_speed_low_mm_s
    direction = {1: "+", -1: "-"}.get(skin.slip_direction, "?")  # type: ignore[arg-type]
    if speed is not None:
        return f"{speed:.0f} mm/s {direction}"
    if low is not None:
        return f">= {low:.0f} mm/s {direction}"
    return "(speed ?)"

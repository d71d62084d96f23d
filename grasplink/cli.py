"""The `grasplink` command line.

Every error a user can cause prints one line naming the problem and exits
non-zero; tracebacks are for bugs only.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from contextlib import AbstractContextManager, ExitStack, nullcontext
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from grasplink.errors import ConfigError, GrasplinkError

if TYPE_CHECKING:
    from grasplink.gateway.config import GatewayConfig

EXIT_ERROR = 1
PROBE_S = 0.35  # longer than the default 100 ms heartbeat period, several times over


def node_id_arg(text: str) -> int:
    """Node-IDs in decimal or 0x-hex, 1..127."""
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"node-ID {text!r} is not a number") from None
    if not 1 <= value <= 127:
        raise argparse.ArgumentTypeError(f"node-ID {text} is outside 1..127")
    return value


def device_node_id_arg(text: str) -> int:
    """A device's node-ID: 1..127, or 0xFF for a node that waits for an LSS master."""
    if text.strip().lower() in ("0xff", "255"):
        return 0xFF
    return node_id_arg(text)


def serial_arg(text: str) -> int:
    try:
        value = int(text, 0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"serial number {text!r} is not a number") from None
    if not 0 <= value <= 0xFFFFFFFF:
        raise argparse.ArgumentTypeError(f"serial number {text} is outside 0..0xFFFFFFFF")
    return value


def positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(
            f"duration must be a positive number of seconds, got {text}"
        )
    return value


def positive_hz(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of Hz") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"sample rate must be a positive number of Hz, got {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    from grasplink.bus.reconnect import DEFAULT_RECONNECT_TIMEOUT_S
    from grasplink.bus.url import DEFAULT_BUS_URL, DEFAULT_HUB_PORT
    from grasplink.profiles.kinds import KINDS

    parser = argparse.ArgumentParser(prog="grasplink", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    node = sub.add_parser("node", help="run one device node as its own process")
    node.add_argument(
        "kind", choices=KINDS, nargs="?", help="which device (or --eds: any vendor's file)"
    )
    node.add_argument(
        "--eds",
        type=Path,
        default=None,
        metavar="FILE",
        help="a node built from any EDS or DCF: the protocol its file describes, no "
        "application (docs/devices.md, Nodes from any EDS)",
    )
    node.add_argument(
        "--value",
        action="append",
        default=[],
        metavar="OBJECT=VALUE",
        help="with --eds: an object's value, e.g. 6401sub1=512 (repeatable)",
    )
    node.add_argument(
        "--bus",
        default=DEFAULT_BUS_URL,
        help=f"bus URL (default {DEFAULT_BUS_URL}; see docs/buses.md)",
    )
    node.add_argument(
        "--node-id",
        type=device_node_id_arg,
        default=None,
        help="CANopen node-ID 1..127 (default: the profile's), or 0xFF: unconfigured, "
        "silent until an LSS master gives it one (docs/devices.md, LSS)",
    )
    node.add_argument(
        "--serial",
        type=serial_arg,
        default=None,
        help="serial number in 1018h:04 (default 0), the part of the LSS address that "
        "tells nodes of one kind apart",
    )
    node.add_argument(
        "--duration",
        type=positive_seconds,
        default=None,
        help="stop after this many seconds (default: run until Ctrl-C)",
    )
    node.add_argument(
        "--reconnect-timeout",
        type=reconnect_seconds,
        default=DEFAULT_RECONNECT_TIMEOUT_S,
        metavar="S",
        help="when the bus is lost, retry with back-off for this long, then exit 1 "
        f"(default {DEFAULT_RECONNECT_TIMEOUT_S:g}; 0: one attempt)",
    )

    gateway = sub.add_parser(
        "gateway", help="master the network, decode skin and EMG, close the feedback loop"
    )
    gateway.add_argument(
        "--bus",
        action="append",
        default=None,
        help=f"bus URL (default {DEFAULT_BUS_URL}; see docs/buses.md); repeat it to master "
        "several buses from one thread, a gateway per bus (telemetry: a topic tree and "
        "Sparkplug edge node per bus, see --mqtt-id; Modbus: a unit per bus)",
    )
    gateway.add_argument(
        "--config", type=Path, default=None, help="gateway TOML (default: built-in defaults)"
    )
    gateway.add_argument(
        "--with-nodes",
        action="store_true",
        help="also run the four device nodes in this process (a self-contained embedded bus)",
    )
    gateway.add_argument(
        "--duration",
        type=positive_seconds,
        default=None,
        help="stop this many seconds after the gateway is up (default: run until Ctrl-C)",
    )
    gateway.add_argument(
        "--ready-file",
        type=Path,
        default=None,
        metavar="PATH",
        help="write this file once the gateway is up (every surface bound, the bus open, "
        "its heartbeat running) and remove it on exit: for scripts to wait on",
    )
    gateway.add_argument(
        "--reconnect-timeout",
        type=reconnect_seconds,
        default=DEFAULT_RECONNECT_TIMEOUT_S,
        metavar="S",
        help="retry a lost bus for this long, then exit 1 "
        f"(default {DEFAULT_RECONNECT_TIMEOUT_S:g})",
    )
    gateway.add_argument(
        "--mqtt",
        default=None,
        metavar="URL",
        help="publish telemetry (JSON topic tree and Sparkplug B) to this broker: "
        "mqtt://[user[:password]@]host[:port] or mqtts://... (see docs/telemetry.md)",
    )
    gateway.add_argument(
        "--mqtt-id",
        action="append",
        default=None,
        metavar="ID",
        help="the gateway's telemetry ID: topics grasplink/ID/..., Sparkplug edge node ID "
        "(default gateway); with several --bus, one per bus in the same order, or one ID "
        "for all: ID-1, ID-2, ...",
    )
    gateway.add_argument(
        "--mqtt-ca",
        type=Path,
        default=None,
        metavar="FILE",
        help="CA certificate (PEM) to trust for an mqtts:// broker (default: the system's)",
    )
    gateway.add_argument(
        "--mqtt-rate-hz",
        type=positive_hz,
        default=None,
        metavar="HZ",
        help="publish telemetry values at most this often (default 20: every snapshot)",
    )
    gateway.add_argument(
        "--sparkplug-host-id",
        default=None,
        metavar="ID",
        help="Sparkplug primary host application: births wait until its STATE says online "
        "(default: [telemetry] sparkplug_host_id of the configuration, else none)",
    )
    gateway.add_argument(
        "--modbus",
        metavar="URL",
        default=None,
        help="also serve the register map over Modbus: tcp://127.0.0.1:1502 or "
        "rtu:///dev/ttyUSB0?baud=115200&parity=N&unit=1 (see docs/modbus.md)",
    )
    gateway.add_argument(
        "--check",
        action="store_true",
        help="read the configuration and every file it names, say what each node is, and "
        "exit (1 on the first error); no bus is opened",
    )
    gateway.add_argument(
        "--print-register-map",
        action="store_true",
        help="print the Modbus register map (docs/modbus.md; with --config, with that "
        "configuration's device objects) and exit",
    )

    bus = sub.add_parser("bus", help="bus tools")
    bus_sub = bus.add_subparsers(dest="bus_command", required=True, metavar="BUS_COMMAND")
    hub = bus_sub.add_parser("hub", help="run a loopback CAN hub for several processes")
    hub.add_argument("--host", default="127.0.0.1")
    hub.add_argument("--port", type=int, default=DEFAULT_HUB_PORT)

    demo = sub.add_parser("demo", help="boot all nodes with a master and report the bus")
    demo.add_argument("--duration", type=positive_seconds, default=3.0)
    demo.add_argument("--bus", default=None, help="bus URL (default: a private virtual bus)")

    run = sub.add_parser("run", help="run a scene and record what happened")
    run.add_argument("scene", type=Path, help="scene file (scenes/*.toml)")
    run.add_argument(
        "--out", type=Path, default=None, help="output folder (default out/<scene name>)"
    )
    run.add_argument(
        "--realtime",
        action="store_true",
        help="pace the scene to the wall clock",
    )
    run.add_argument(
        "--bus",
        default=None,
        metavar="URL",
        help="run the scene's nodes and physics in real time on this bus, which can.asc "
        "records whole (hardware in the loop; see docs/hil.md and docs/buses.md); with the "
        "scene's own controller unless --master external",
    )
    run.add_argument(
        "--master",
        choices=("scene", "external"),
        default="scene",
        help="with --bus: who masters the nodes: the scene's [controller] on the same bus "
        "(default), or whatever master is on it (external: the nodes boot and wait "
        "PRE-OPERATIONAL for its NMT start, take their commands from its RPDOs)",
    )

    plot = sub.add_parser("plot", help="draw PNGs of a recording made by `grasplink run`")
    plot.add_argument("recording", type=Path, help="folder written by grasplink run")

    decode = sub.add_parser(
        "decode",
        help="decode slip, speed (and its range), direction, position and grip force from a "
        "skin recording: JSON lines of the decoders' output contract (docs/decoding.md)",
    )
    decode.add_argument(
        "file",
        type=Path,
        help="CSV (header t_s,force_n or t_s,skin.force_n), NPZ (t_s, force_n), a CAN log "
        "of the skin node (.asc, .blf, .log, .trc) or a folder written by `grasplink run` "
        "(its skin.csv: the simulated force before the node's ADC; give FOLDER/can.asc "
        "to decode what a gateway received, with its grip commands)",
    )
    decode.add_argument(
        "--skin",
        default=None,
        metavar="LAYOUT",
        help="ridge layout: a name (alpha0.1, fibonacci, uniform4, ...), "
        "comma-separated spacings in mm, 0.5-200 mm each, at most 40 (the skin node's "
        "0x2140), or a layout file PATH.toml (`grasplink skin design`); default for a run "
        "folder: the layout in its summary.json",
    )
    decode.add_argument(
        "--fs",
        type=positive_hz,
        default=None,
        metavar="HZ",
        help="sample rate, 80-1000 Hz (the skin node's 0x2120) (default: from a run "
        "folder's summary.json or the median time step of a CSV/NPZ; the EDS default, "
        "400 Hz, for a CAN log)",
    )
    decode.add_argument(
        "--decoder",
        default=None,
        metavar="NAME",
        help="fft, ratio, mmse, dtw or tracker (default: the one the "
        "decoding benchmark recommends, registry.DEFAULT_DECODER)",
    )
    decode.add_argument(
        "--node-id", type=node_id_arg, default=0x10, help="skin node-ID in a CAN log (default 0x10)"
    )
    decode.add_argument(
        "--hand-node-id",
        type=node_id_arg,
        default=0x40,
        help="hand node-ID in a CAN log (default 0x40): its grip commands (RPDO, 0x2400) are "
        "fed to the decoder as the gateway fed them live (the efference copy)",
    )
    decode.add_argument(
        "--no-grip-commands",
        action="store_true",
        help="decode a CAN log's skin samples alone, without the hand's grip commands",
    )

    bench = sub.add_parser("bench", help="benchmarks that write their figures into docs/")
    bench_sub = bench.add_subparsers(dest="bench_command", required=True, metavar="BENCHMARK")
    bench_decode = bench_sub.add_parser(
        "decode",
        help="every skin decoder over simulated signals and over the slip scenes' CAN logs: "
        "accuracy against cost",
    )
    bench_decode.add_argument(
        "--quick", action="store_true", help="reduced synthetic grid (smoke test, < 2 min)"
    )
    bench_decode.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="folder for decoding.md/.json/_pareto.png (default: docs/benchmarks/ of the "
        "grasplink checkout the current folder is in)",
    )
    bench_decode.add_argument(
        "--scenes",
        type=Path,
        default=None,
        metavar="DIR",
        help="folder with the slip scenes for the CAN path (default: scenes/ of that "
        "checkout, else of the checkout grasplink is installed from in editable mode)",
    )
    bench_loop = bench_sub.add_parser(
        "loop",
        help="the closed loop in silico, trial by trial: slips stopped per feedback mode, "
        "with and without the reflex",
    )
    bench_loop.add_argument(
        "--quick", action="store_true", help="reduced grid: 3 speeds, 1 seed (< 2 min)"
    )
    bench_loop.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="DIR",
        help="folder for loop.md/.json/.png (default: docs/benchmarks/ of the grasplink "
        "checkout the current folder is in)",
    )
    bench_loop.add_argument(
        "--task",
        choices=("pulled", "least-force"),
        default="pulled",
        help="pulled (default): loop_headline's pull, every mode with and without the reflex "
        "(loop.md); least-force: the object pulled through a damper, whose slip speed is the "
        "grip missing, fragile, dry and getting wet, slip speed against occurrence (loop_task.md)",
    )
    add_worker_arguments(bench_loop, "trials")

    profiles = sub.add_parser("profiles", help="object dictionaries (EDS)")
    prof_sub = profiles.add_subparsers(
        dest="profiles_command", required=True, metavar="PROFILES_COMMAND"
    )
    doc = prof_sub.add_parser("doc", help="generate docs/profiles.md from the EDS files")
    doc.add_argument("--out", type=Path, default=Path("docs/profiles.md"))
    check = prof_sub.add_parser(
        "check",
        help="load EDS/DCF files as canopen and Lely do, printing each quirk repaired "
        "(docs/eds_files.md)",
    )
    check.add_argument("files", nargs="+", type=Path)
    check.add_argument(
        "--strict",
        action="store_true",
        help="grasplink's own rules for its EDS files: the first problem is an error",
    )
    dbc = prof_sub.add_parser(
        "dbc", help="every node's PDO map (and NMT, heartbeat, EMCY, SDO) as a DBC file"
    )
    dbc.add_argument("--out", type=Path, default=None, help="DBC file (default: stdout)")
    dbc.add_argument(
        "--node-id",
        dest="node_ids",
        type=kind_node_id_arg,
        action="append",
        default=[],
        metavar="KIND=ID",
        help=f"node-ID of a node kind ({', '.join(KINDS)}, gateway), e.g. skin=0x11; "
        "repeatable (default: the profiles' node-IDs and the gateway's 1)",
    )
    _add_log_commands(sub, DEFAULT_BUS_URL)
    _add_view_command(sub)
    _add_skin_commands(sub)
    return parser


def _add_skin_commands(sub: Subcommands) -> None:
    """`skin design`: search a ridge layout for a skin (docs/design.md)."""
    from grasplink.decoding.registry import DECODERS, DEFAULT_DECODER
    from grasplink.evaluation import design

    skin = sub.add_parser("skin", help="skin design tools")
    skin_sub = skin.add_subparsers(dest="skin_command", required=True, metavar="SKIN_COMMAND")
    d = skin_sub.add_parser(
        "design",
        help="search ridge layouts (NSGA-II) by a decoder's accuracy on simulated slips "
        "and the resolution; writes front.csv, layout.toml and report.md",
    )
    d.add_argument(
        "--length-mm",
        type=float,
        default=design.THESIS_LENGTH_MM,
        help=f"skin length in mm (default {design.THESIS_LENGTH_MM:g}, the thesis's palm)",
    )
    goal = d.add_mutually_exclusive_group()
    goal.add_argument(
        "--alpha",
        type=float,
        default=None,
        metavar="A",
        help="minimise table 5.1's F = A·(1 - accuracy) + (1 - A)·(1 - resolution)",
    )
    goal.add_argument(
        "--pareto",
        action="store_true",
        help="keep the front of speed error, position error and resolution (the default); "
        f"layout.toml gets its member best at α = {design.PARETO_ALPHA:g}",
    )
    d.add_argument(
        "--speeds",
        default=design.THESIS_SPEEDS,
        metavar="START:STOP:STEP",
        help=f"slip speeds in mm/s, or a comma list (default {design.THESIS_SPEEDS}, ch. 5.3.3)",
    )
    d.add_argument(
        "--decoder",
        default=DEFAULT_DECODER,
        metavar="NAME",
        help=f"the decoder judged ({', '.join(DECODERS)}; default {DEFAULT_DECODER})",
    )
    stop = d.add_mutually_exclusive_group()
    stop.add_argument(
        "--generations",
        type=int,
        default=None,
        metavar="G",
        help=f"a fixed amount of work: the same result on any workers "
        f"(default {design.GENERATIONS})",
    )
    stop.add_argument(
        "--budget-min",
        type=float,
        default=None,
        metavar="M",
        help="stop after the generation that ends past M minutes (machine-dependent result)",
    )
    d.add_argument(
        "--population",
        type=int,
        default=design.POPULATION,
        metavar="P",
        help=f"layouts per generation (default {design.POPULATION})",
    )
    d.add_argument(
        "--slips",
        type=int,
        default=design.SLIPS,
        metavar="K",
        help=f"simulated slips per fitness evaluation (default {design.SLIPS}; "
        "docs/benchmarks/layouts.md: fidelity against time)",
    )
    add_worker_arguments(d, "fitness evaluations")
    d.add_argument("--seed", type=int, default=1, help="the run's seed (default 1)")
    d.add_argument(
        "--out",
        type=Path,
        default=Path("skin_design"),
        metavar="DIR",
        help="folder for front.csv, layout.toml and report.md (default ./skin_design)",
    )


def add_worker_arguments(parser: argparse.ArgumentParser, what: str) -> None:
    """`--workers N | --dask ADDRESS`: where a study's independent tasks run."""
    where = parser.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help=f"{what} run in N local processes at once (default: all cores; 1: in this process)",
    )
    where.add_argument(
        "--dask",
        default=None,
        metavar="tcp://HOST:PORT",
        help=f"{what} run on the workers of this Dask scheduler instead (docs/design.md)",
    )


class Subcommands(Protocol):
    """What `ArgumentParser.add_subparsers` returns, as far as we use it (its class is
    argparse's private `_SubParsersAction`)."""

    def add_parser(self, name: str, *, help: str | None = ...) -> argparse.ArgumentParser: ...


def _add_log_commands(sub: Subcommands, default_bus: str) -> None:
    """`record` and `replay`: CAN logs in the formats analysers read (docs/can_tools.md)."""
    record = sub.add_parser("record", help="record a bus to a CAN log (.asc, .blf, .log, .trc)")
    record.add_argument(
        "out", type=Path, metavar="OUT", help="OUT.asc, OUT.blf, OUT.log or OUT.trc"
    )
    record.add_argument("--bus", default=default_bus, help=f"bus URL (default {default_bus})")
    record.add_argument(
        "--duration",
        type=positive_seconds,
        default=None,
        help="stop after this many seconds (default: until Ctrl-C or SIGTERM)",
    )
    record.add_argument("--force", action="store_true", help="overwrite OUT if it exists")
    replay = sub.add_parser("replay", help="replay a CAN log onto a bus at its timestamps")
    replay.add_argument("log", type=Path, metavar="LOG", help="a .asc, .blf, .log or .trc file")
    replay.add_argument("--bus", default=default_bus, help=f"bus URL (default {default_bus})")
    replay.add_argument(
        "--speed",
        type=speed_factor,
        default=1.0,
        metavar="X",
        help="time factor: 2 plays twice as fast (default 1; a gateway decodes a replay "
        "exactly as live only at 1)",
    )
    replay.add_argument("--loop", action="store_true", help="start again at the end, until Ctrl-C")
    replay.add_argument(
        "--nodes-only",
        action="store_true",
        help="send only what device nodes sent (TPDOs, EMCY, SDO responses, heartbeats), "
        "never NMT, SYNC, SDO requests or RPDOs that would command nodes on the bus",
    )
    replay.add_argument(
        "--master-id",
        type=node_id_arg,
        default=None,
        help="with --nodes-only: the master whose heartbeat and EMCY are left out "
        "(default: the gateway's, 1)",
    )


def _add_view_command(sub: Subcommands) -> None:
    """`view`: the live page over a broker's telemetry (docs/view.md)."""
    view = sub.add_parser(
        "view", help="serve a live web page of the gateways' telemetry, or of a recording"
    )
    view.add_argument(
        "folder",
        nargs="?",
        type=Path,
        default=None,
        metavar="DIR",
        help="play this folder `grasplink run --out` wrote (pause, seek; truth beside the "
        "decoded values) instead of following a broker",
    )
    view.add_argument(
        "--mqtt",
        default=None,
        metavar="URL",
        help="the broker the gateways publish to: mqtt://[user[:password]@]host[:port] "
        "or mqtts://... (read only unless --allow-commands)",
    )
    view.add_argument("--mqtt-ca", type=Path, default=None, metavar="FILE", help="CA for mqtts")
    view.add_argument(
        "--gateway-id", default=None, metavar="ID", help="show this gateway only (default: all)"
    )
    view.add_argument(
        "--http",
        default="127.0.0.1:8642",
        metavar="HOST:PORT",
        help="where to serve the page (default 127.0.0.1:8642; port 0: any free one)",
    )
    view.add_argument(
        "--duration", type=positive_seconds, default=None, help="stop after this many seconds"
    )
    view.add_argument(
        "--allow-commands",
        action="store_true",
        help="let the page send the gateway's tuning commands (feedback mode, reflex, EMG "
        "calibration), checked against its limits first; give --mqtt a user with write "
        "rights on grasplink/ID/cmd/# (docs/view.md)",
    )


def kind_node_id_arg(text: str) -> tuple[str, int]:
    """KIND=ID for `profiles dbc --node-id`."""
    kind, sep, value = text.partition("=")
    if not sep or not kind.strip():
        raise argparse.ArgumentTypeError(f"expected KIND=ID, e.g. skin=0x11, got {text!r}")
    return kind.strip(), node_id_arg(value.strip())


def speed_factor(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"speed {text!r} is not a number") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"speed must be a positive factor, got {text}")
    return value


def reconnect_seconds(text: str) -> float:
    """--reconnect-timeout: seconds >= 0 (0: a single attempt, then give up)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not 0 <= value < float("inf"):
        raise argparse.ArgumentTypeError(f"reconnect timeout must be >= 0 seconds, got {text}")
    return value


def _object_value(text: str) -> tuple[int, int, int | float]:
    """`6401sub1=512` -> (0x6401, 1, 512); ConfigError naming what is wrong."""
    from grasplink.profiles import object_key

    key, sep, value = text.partition("=")
    try:
        index, subindex = object_key(key)
    except ConfigError:
        sep = ""
    if not sep:
        raise ConfigError(f"--value {text!r}: expected OBJECT=VALUE, e.g. 6401sub1=512")
    try:
        number: int | float = int(value, 0)
    except ValueError:
        try:
            number = float(value)
        except ValueError:
            raise ConfigError(f"--value {text!r}: {value!r} is not a number") from None
    return index, subindex, number


def cmd_node(args: argparse.Namespace) -> int:
    from grasplink.bus import NodeRunner, open_bus
    from grasplink.core.frames import HEARTBEAT_BASE
    from grasplink.devices.factory import build_from_file, build_node
    from grasplink.errors import BusError

    if (args.kind is None) == (args.eds is None):
        raise ConfigError("name a node kind or --eds FILE, not both or neither")
    if args.eds is not None:
        if args.serial is not None:
            raise ConfigError("--serial is for our node kinds; a file's 1018h:04 is its own")
        values = [_object_value(text) for text in args.value]
        node, warnings = build_from_file(args.eds, args.node_id, values)
        for warning in warnings:
            print(f"warning: {warning}", file=sys.stderr)
        args.kind = args.eds.name
    elif args.value:
        raise ConfigError("--value sets objects of a node built from a file (--eds)")
    else:
        node = build_node(args.kind, args.node_id, serial=args.serial)
    bus = open_bus(args.bus)
    try:
        if node.configured:
            _refuse_if_node_id_taken(bus, node.node_id, args.bus)
        stop = threading.Event()
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, lambda *_: stop.set())
        # A lost bus is reopened from the same URL with back-off; the node keeps its
        # state meanwhile, like a CAN node whose bus comes back (docs/buses.md).
        with NodeRunner(
            bus,
            [node],
            name=f"{args.kind} node 0x{node.node_id:02X}",
            reopen=lambda: open_bus(args.bus),
            reconnect_timeout_s=args.reconnect_timeout,
        ) as runner:
            if node.configured:
                print(f"{args.kind} node 0x{node.node_id:02X} running on {args.bus}", flush=True)
            else:
                print(
                    f"{args.kind} node running unconfigured on {args.bus}: "
                    "waiting for an LSS master to give it a node-ID",
                    flush=True,
                )
            deadline = None if args.duration is None else time.monotonic() + args.duration
            warned = False
            node_id = node.node_id
            try:
                while not stop.wait(0.1):
                    if runner.failure is not None:
                        raise runner.failure
                    # Once running, a duplicate node-ID is an alarm (the node sends EMCY
                    # 8150h itself), never a reason to leave the bus: a guarding RTR or one
                    # stray frame must not take a node down.
                    colliding = node.collision_active
                    if node.node_id != node_id:  # LSS gave or changed it
                        node_id = node.node_id
                        state = f"0x{node_id:02X}" if node.configured else "none (unconfigured)"
                        print(f"node-ID now {state}", flush=True)
                    heartbeat_id = HEARTBEAT_BASE + node_id
                    if colliding and not warned:
                        print(
                            f"warning: another node transmits on 0x{heartbeat_id:03X} "
                            f"(node-ID 0x{node.node_id:02X}) on {args.bus}: duplicate "
                            f"node-ID? EMCY 8150h sent; still running",
                            file=sys.stderr,
                            flush=True,
                        )
                    warned = colliding
                    if deadline is not None and time.monotonic() >= deadline:
                        break
            except KeyboardInterrupt:
                pass
            down_s = runner.outage_s
            if down_s is not None:
                raise BusError(f"stopped while {args.bus} was down ({down_s:.1f} s)")
            stats = runner.stats
        foreign = node.duplicate_frames
        duplicates = f", {foreign} from another node on our heartbeat COB-ID" if foreign else ""
        print(
            f"stopped: {stats.frames_tx} frames sent, {stats.frames_rx} received{duplicates}",
            flush=True,
        )
    finally:
        bus.shutdown()
    return 0


def _refuse_if_node_id_taken(bus, node_id: int, url: str) -> None:
    """Listen before booting: a heartbeat, EMCY or TPDO with our node-ID means a clash.

    Only data frames count: a remote frame on 700h+ID is a master's node-guarding
    request for the node we are about to be, not another node.
    """
    from grasplink.bus.url import BusDisconnected, message_to_frame
    from grasplink.core.frames import node_cob_ids

    ours = set(node_cob_ids(node_id))
    deadline = time.monotonic() + PROBE_S
    while (left := deadline - time.monotonic()) > 0:
        try:
            msg = bus.recv(left)
        except BusDisconnected:
            return  # the hub went away meanwhile: the runner reconnects, and listens again
        frame = message_to_frame(msg) if msg is not None else None
        if frame is not None and not frame.rtr and frame.can_id in ours:
            raise ConfigError(
                f"node-ID 0x{node_id:02X} is already in use on {url} "
                f"(saw COB-ID 0x{frame.can_id:03X}); choose another with --node-id"
            )


def cmd_bus(args: argparse.Namespace) -> int:
    from grasplink.bus import run_hub

    run_hub(args.host, args.port)
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from grasplink.demo import run_demo

    figures = run_demo(args.duration, args.bus)
    silent = [kind for kind, state in figures["states"].items() if state != "OPERATIONAL"]
    if silent:
        print(f"grasplink: error: nodes not operational: {', '.join(silent)}", file=sys.stderr)
        return EXIT_ERROR
    return 0


def _speed_text(simulated_s: float, wall_s: float) -> str:
    """How fast a run went against the wall clock, in two significant digits at least:
    "38x real time", "2.5x real time", "0.42x real time (2.4x slower)"."""
    if simulated_s <= 0 or wall_s <= 0:
        return "no time simulated" if simulated_s <= 0 else "faster than the clock resolves"
    speed = simulated_s / wall_s
    text = f"{_figure(speed)}x real time"
    if speed < 0.95:
        text += f" ({_figure(1 / speed)}x slower)"
    return text


def _figure(x: float) -> str:
    """Two significant digits, never an exponent: 0.042, 2.5, 38, 1200."""
    return f"{x:.0f}" if x >= 10 else f"{x:.2g}"


def cmd_run(args: argparse.Namespace) -> int:
    from grasplink.controllers import build_controllers
    from grasplink.simulators.engine import Simulation
    from grasplink.simulators.recording import Recorder
    from grasplink.simulators.scene import load_scene
    from grasplink.terminal import ProgressBar, StopSignals

    if args.master == "external" and args.bus is None:
        raise ConfigError("--master external needs --bus URL: the bus the master is on")
    scene = load_scene(args.scene)
    controllers = build_controllers(scene)  # validates [controller] before any file is written
    if args.master == "external":
        controllers = []  # the loop is closed by the master on the bus
    out = args.out or Path("out") / args.scene.stem
    with ExitStack() as bus_open:
        live = None if args.bus is None else bus_open.enter_context(_scene_bus(args, scene))
        if live is not None:
            _refuse_taken_node_ids(live.bus, args.bus, scene, controllers)
        sim = Simulation(scene, Recorder(out), controllers=controllers, live=live)
        realtime = args.realtime or scene.clock == "realtime" or live is not None
        progress = ProgressBar(scene.name)
        with StopSignals() as stop:
            try:
                summary = sim.run(realtime=realtime, progress=progress, should_stop=stop)
            finally:
                progress.close()
    states = ", ".join(f"{k} {v['state'].lower()}" for k, v in summary["nodes"].items())
    simulated_s = summary["simulated_s"]
    if live is None:
        how = f"{_speed_text(simulated_s, sim.wall_s)}{', paced' if realtime else ''}"
    else:
        timing = summary["bus"]["realtime"]
        how = (
            f"real time on {args.bus}, master {args.master}; physics stepped at most "
            f"{timing['max_late_ms']:g} ms late, {timing['late_chunks']} chunk(s) over a chunk"
        )
    print(f"{scene.name}: {simulated_s:g} s simulated in {sim.wall_s:.2f} s ({how})")
    print(f"  nodes: {states or 'none'}; effects: {', '.join(summary['effects']) or 'none'}")
    print(f"  wrote {out}/ ({', '.join(sorted(p.name for p in out.iterdir()))})")
    if args.master == "external":
        _print_master_activity(out, summary)
    if not summary["complete"]:
        name = stop.received.name if stop.received else "a stop request"
        print(
            f"grasplink: stopped by {name} at {simulated_s:g} of {scene.duration_s:g} s; "
            f"{out}/ holds a partial recording (summary.json: complete = false)",
            file=sys.stderr,
        )
        return stop.exit_code or EXIT_ERROR
    return 0


def _scene_bus(args: argparse.Namespace, scene: Any) -> AbstractContextManager[Any]:
    """`run --bus`: the bus opened (a bad URL fails here, before any file is written), as a
    `LiveBus` that a lost bus is reopened from with back-off; shut down on leaving."""
    from contextlib import contextmanager

    from grasplink.bus import open_bus
    from grasplink.simulators.live import LiveBus

    @contextmanager
    def opened() -> Any:
        bus = open_bus(args.bus)
        try:
            yield LiveBus(bus, args.bus, reopen=lambda: open_bus(args.bus))
        finally:
            bus.shutdown()

    return opened()


def _refuse_taken_node_ids(bus: Any, url: str, scene: Any, controllers: Sequence[Any]) -> None:
    """Listen before booting: a heartbeat, EMCY, TPDO or SDO answer from one of the node-IDs
    we are about to bring (the scene's nodes, its controller) means a clash, such as a
    second master when the scene's own is run beside another (--master external)."""
    from grasplink.bus.url import BusDisconnected, message_to_frame
    from grasplink.core.frames import node_cob_ids

    ours = {n.node_id: f"the scene's {k} node" for k, n in scene.nodes.items()}
    ours |= {c.node_id: "the scene's controller" for c in controllers}
    taken = {can_id: (node_id, what) for node_id, what in ours.items()
             for can_id in node_cob_ids(node_id)}  # fmt: skip
    deadline = time.monotonic() + PROBE_S
    while (left := deadline - time.monotonic()) > 0:
        try:
            msg = bus.recv(left)
        except BusDisconnected:
            return  # the hub went away meanwhile: the runner reconnects
        frame = message_to_frame(msg) if msg is not None else None
        if frame is None or frame.rtr or frame.can_id not in taken:
            continue
        node_id, what = taken[frame.can_id]
        hint = "; is a master running there? then --master external" if controllers else ""
        raise ConfigError(
            f"node-ID 0x{node_id:02X} ({what}) is already in use on {url} "
            f"(saw COB-ID 0x{frame.can_id:03X}){hint}"
        )


def _print_master_activity(out: Path, summary: dict) -> None:
    """What the external master did, from the recording: who it started, what it sent,
    and, for a closed-loop scene, how the loop went."""
    from grasplink.evaluation.hil import master_activity
    from grasplink.evaluation.loop import LOOP_KINDS
    from grasplink.evaluation.loop_plot import describe_loop

    nodes = {kind: int(n["node_id"]) for kind, n in summary["nodes"].items()}
    activity = master_activity(out / "can.asc", nodes)
    print("  the master on the bus:")
    for line in activity.lines():
        print(f"    {line}")
    never = [kind for kind in nodes if kind not in activity.started_s]
    if never:
        print(
            f"grasplink: warning: no NMT start for {', '.join(never)}: they stayed "
            "PRE-OPERATIONAL (was the master running on the bus?)",
            file=sys.stderr,
        )
    elif set(LOOP_KINDS) <= set(nodes):
        print("  the loop:")
        for line in describe_loop(out):
            print(f"    {line}")


def cmd_plot(args: argparse.Namespace) -> int:
    from grasplink.simulators.plots import plot_recording, read_summary

    for path in plot_recording(args.recording):
        print(f"wrote {path}")
    summary = read_summary(args.recording / "summary.json")
    controller = summary.get("controller")
    # an external master's loop (run --bus --master external) is drawn alike
    if controller == "gateway" or (controller == "external" and "skin" in summary["nodes"]):
        from grasplink.evaluation.loop_plot import describe_loop, plot_loop

        print(f"wrote {plot_loop(args.recording)}")
        print("what happened on the bus:")
        for line in describe_loop(args.recording):
            print(f"  {line}")
    return 0


DECODE_CHUNK = 4096  # samples per feed(): streams like a gateway would, prints as it goes


def cmd_decode(args: argparse.Namespace) -> int:
    """Decode a recording; what the input lost goes to stderr, JSON lines to stdout.

    Exits 1 when less than base.MIN_USABLE_SHARE of the input was usable (skin
    frames of a CAN log, or samples the decoder's input guard accepted).
    """
    import json

    from grasplink.decoding import io, registry
    from grasplink.decoding.base import SkinGeometry, check_sample_rate
    from grasplink.evaluation.decoders import make_decoder
    from grasplink.profiles.layouts import parse_layout

    layout = None if args.skin is None else parse_layout(args.skin)
    if layout is not None:
        SkinGeometry(layout)  # a layout the skin node cannot hold fails before reading
    fs = None if args.fs is None else check_sample_rate(args.fs)
    name = args.decoder or registry.DEFAULT_DECODER
    registry.decoder_class(name)  # an unknown or missing decoder fails before reading
    source = str(args.file)
    grip = None  # a CAN log's grip commands
    if args.file.is_dir():
        run = io.read_run_folder(args.file)
        t, force, source = run.t_s, run.force_n, str(run.source)
        if layout is None:
            if run.layout is None:
                raise ConfigError(f"{args.file}: its summary names no skin layout; give --skin")
            layout = parse_layout(run.layout) if isinstance(run.layout, str) else run.layout
        if fs is None:
            fs = run.rate_hz if run.rate_hz is not None else io.infer_rate(t, source)
    elif layout is None:
        raise ConfigError("--skin LAYOUT is required unless FILE is a `grasplink run` folder")
    elif args.file.suffix.lower() in io.CAN_EXTENSIONS:
        t, force, stats = io.read_can_log(args.file, node_id=args.node_id, fs_hz=fs)
        print(f"grasplink: {stats.summary(source)}", file=sys.stderr, flush=True)
        stats.check_usable(source)
        fs = stats.rate_hz
        if not args.no_grip_commands:
            grip = io.read_grip_commands(args.file, node_id=args.hand_node_id)
            print(f"grasplink: {grip.summary(source)}", file=sys.stderr, flush=True)
    else:
        t, force = io.read_recording(args.file)
        fs = fs if fs is not None else io.infer_rate(t, source)
    fs = check_sample_rate(fs)
    # the evaluation layer supplies the reference slips mmse and dtw match against
    decoder = make_decoder(name, layout, fs)
    if grip is not None:
        grip.feed(decoder)
    out = sys.stdout
    try:
        for start in range(0, len(t), DECODE_CHUNK):
            for estimate in decoder.feed(
                t[start : start + DECODE_CHUNK], force[start : start + DECODE_CHUNK]
            ):
                out.write(json.dumps(estimate.as_dict()) + "\n")
            out.flush()
    except BrokenPipeError:  # the reader (e.g. `| head`) has all it wanted
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), out.fileno())
        return 0
    report = decoder.input_report()
    if report is not None:
        print(f"grasplink: {source}: {report}", file=sys.stderr, flush=True)
    decoder.check_usable(source)
    return 0


def cmd_profiles(args: argparse.Namespace) -> int:
    if args.profiles_command == "dbc":
        return cmd_profiles_dbc(args)
    if args.profiles_command == "doc":
        from grasplink.profiles.docgen import write_profiles_doc

        write_profiles_doc(args.out)
        print(f"wrote {args.out}")
        return 0
    if args.strict:
        from grasplink.profiles.eds import validate_eds

        for path in args.files:
            validate_eds(path)
            print(f"{path}: ok")
        return 0
    return _check_field_files(args.files)


def _check_field_files(paths: Sequence[Path]) -> int:
    """`profiles check` without --strict: every file, its warnings, exit 1 if one fails."""
    from grasplink.errors import EdsError
    from grasplink.profiles.field import load_object_dictionary

    failed = False
    for path in paths:
        try:
            od, warnings = load_object_dictionary(path)
        except EdsError as exc:
            print(f"grasplink: error: {exc}", file=sys.stderr)
            failed = True
            continue
        for warning in warnings:
            print(warning)
        print(f"{path}: ok ({len(od)} objects, {len(warnings)} warnings)")
    return EXIT_ERROR if failed else 0


def cmd_bench(args: argparse.Namespace) -> int:
    from grasplink.controllers import build_controllers
    from grasplink.evaluation.decoding_bench import run_benchmark

    if args.bench_command == "loop":
        return cmd_bench_loop(args)

    results, out = run_benchmark(
        quick=args.quick, out=args.out, scenes_dir=args.scenes, controllers_for=build_controllers
    )
    print(f"recommended default decoder: {results['recommended_default']}; wrote {out}/decoding.md")
    return 0


def cmd_bench_loop(args: argparse.Namespace) -> int:
    from grasplink.controllers import build_controllers
    from grasplink.evaluation.loop import console_table, report_to

    if args.task == "least-force":
        return cmd_bench_loop_task(args)
    results, out = report_to(
        quick=args.quick,
        out=args.out,
        controllers_for=build_controllers,
        workers=args.workers,
        dask=args.dask,
    )
    print(console_table(results))
    print(f"wrote {out}/loop.md, loop.json, loop.png")
    return 0


def cmd_bench_loop_task(args: argparse.Namespace) -> int:
    from grasplink.controllers import build_controllers
    from grasplink.evaluation import loop_task

    results, out = loop_task.report_to(
        quick=args.quick,
        out=args.out,
        controllers_for=build_controllers,
        workers=args.workers,
        dask=args.dask,
    )
    print(loop_task.headline(results))
    print(f"wrote {out}/loop_task.md, loop_task.json, loop_task.png")
    return 0


def config_check_lines(config: GatewayConfig) -> list[str]:
    """`gateway --check`: each node as the configuration describes it, and its file's
    warnings (what the field loader repaired)."""
    lines = []
    for node in config.nodes.values():
        source = node.eds.name if node.eds is not None else f"our {node.kind} EDS"
        extras = [f"bound: {type(node.binding).__name__}"] if node.binding is not None else []
        extras += ["mandatory"] if node.mandatory else []
        extras += [f"{len(node.sdo)} SDO writes"] if node.sdo else []
        extras += ["identity checked"] if node.identity is not None else []
        tail = f" ({', '.join(extras)})" if extras else ""
        lines.append(f"nodes.{node.name}: {node.role} 0x{node.node_id:02X} from {source}{tail}")
        lines += [f"  warning: {w}" for w in node.file_warnings]
    sync = f"SYNC every {config.sync_period_us / 1000:g} ms" if config.sync_period_us else "no SYNC"
    lines.append(f"configuration ok: {len(config.nodes)} nodes, {sync}")
    return lines


def cmd_gateway(args: argparse.Namespace) -> int:
    from grasplink.bus.url import DEFAULT_BUS_URL
    from grasplink.gateway.config import load_config
    from grasplink.gateway.live import LiveGateway
    from grasplink.terminal import StopSignals

    config = load_config(args.config)  # a bad file fails here, before the bus is touched
    if args.check:
        for line in config_check_lines(config):
            print(line)
        return 0
    if args.print_register_map:  # the map this configuration serves
        from grasplink.surfaces.modbus.docgen import render_modbus_markdown
        from grasplink.surfaces.modbus.registers import register_map_for

        sys.stdout.write(render_modbus_markdown(register_map_for(config)))
        return 0
    modbus_url = None
    if args.modbus is not None:
        from grasplink.surfaces.modbus.url import parse_modbus_url

        modbus_url = parse_modbus_url(args.modbus)  # a bad URL too
    buses = args.bus or [DEFAULT_BUS_URL]
    if modbus_url is not None:
        from grasplink.surfaces.modbus.url import unit_ids

        unit_ids(modbus_url, len(buses))  # a unit per bus: too many for the address space
    telemetry = telemetry_options(args)  # and bad --mqtt options
    telemetry_ids = mqtt_ids(args.mqtt_id, len(buses))
    ready_file = args.ready_file
    if ready_file is not None:
        _clear_ready_file(ready_file)  # a stale one must not say "up" for this run
    for node in config.nodes.values():  # what the field loader repaired in a vendor's file
        for warning in node.file_warnings:
            print(f"warning: nodes.{node.name}: {warning}", file=sys.stderr)
    if config.lss:  # unconfigured nodes get their node-IDs first (docs/gateway.md, LSS)
        from grasplink.gateway.lss import assign_at_start

        for url in buses:
            report = assign_at_start(url, config)
            print(f"{url}: {report.summary()}", file=sys.stdout if report.ok else sys.stderr)
    # Start-up order: every surface is bound or connected before the network is touched,
    # so a failure (port taken, broker unreachable) exits having sent no frame.
    with StopSignals() as stop, ExitStack() as running:
        live = LiveGateway(
            buses[0],
            config,
            with_nodes=args.with_nodes,
            reconnect_timeout_s=args.reconnect_timeout,
            more_buses=buses[1:],
        )
        running.callback(live.stop)
        live.open()  # the buses open and the decoder ready: no frame yet
        modbus = running.enter_context(_modbus_server(live.edges, modbus_url))
        if modbus is not None:
            print(modbus.describe(), flush=True)
        publishers = [
            running.enter_context(telemetry(edge, config, gateway_id))
            for edge, gateway_id in zip(live.edges, telemetry_ids, strict=True)
        ]
        live.go()  # the first frame: reset, provisioning, heartbeat
        up_at = time.monotonic()
        deadline = None if args.duration is None else up_at + args.duration
        kinds = ", ".join(f"{k} 0x{n.node_id:02X}" for k, n in config.nodes.items())
        reflex = config.reflex
        print(
            f"gateway 0x{config.node_id:02X} on {', '.join(buses)} ({config.source}): "
            f"{kinds}; feedback {config.feedback.mode.value}, "
            f"reflex {f'above {reflex.threshold_mm_s:g} mm/s' if reflex.enabled else 'off'}",
            flush=True,
        )
        _wait_for_heartbeat(live)
        print(
            f"up: heartbeat every {config.heartbeat_ms} ms ({live.heartbeat_priority}), "
            f"the nodes' consumer time {config.consumer_ms} ms; gateway thread at "
            f"{live.runner_priority}",
            flush=True,
        )
        if ready_file is not None:
            _write_ready_file(ready_file)
            running.callback(_clear_ready_file, ready_file)
        next_status = time.monotonic() + min(1.0, config.status_period_s)
        while not stop():
            if live.failure is not None:
                raise live.failure
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                break
            if now >= next_status:
                print(live.status_line(), flush=True)
                for publisher in publishers:
                    if publisher is not None:
                        print(publisher.status_line(), flush=True)
                next_status = now + config.status_period_s
            time.sleep(0.05)
        final = live.status_line()
    print(f"stopped: {final}", flush=True)
    return stop.exit_code if stop.received is not None and stop.exit_code != 130 else 0


def _wait_for_heartbeat(live: Any, timeout_s: float = 5.0) -> None:
    """Until the heartbeat thread runs (it says what priority it got), or the timeout."""
    deadline = time.monotonic() + timeout_s
    while live.heartbeat_priority is None and time.monotonic() < deadline:
        if live.failure is not None:
            raise live.failure
        time.sleep(0.005)


def _write_ready_file(path: Path) -> None:
    """The ready file, whole or not at all (written aside, then renamed into place)."""
    partial = path.with_name(path.name + ".partial")
    try:
        partial.write_text(f"up pid {os.getpid()}\n")
        partial.replace(path)
    except OSError as exc:
        raise ConfigError(f"--ready-file {path}: cannot write: {exc.strerror}") from None


def _clear_ready_file(path: Path) -> None:
    try:
        path.unlink(missing_ok=True)
    except OSError as exc:
        raise ConfigError(f"--ready-file {path}: cannot remove: {exc.strerror}") from None


def _modbus_server(gateways: list[Any], url: object) -> AbstractContextManager[Any]:
    """The gateways' Modbus server for `url` (a ModbusUrl; a unit per gateway), or a context
    of None without one."""
    if url is None:
        return nullcontext()
    from grasplink.surfaces.modbus.server import ModbusServer

    return ModbusServer(gateways, url)  # type: ignore[arg-type]


def mqtt_ids(given: list[str] | None, buses: int) -> list[str]:
    """Each bus's telemetry ID: as given, one per bus; one ID (or the default) for several
    buses becomes ID-1, ID-2, ... Checked before the bus or broker is touched."""
    from grasplink.surfaces.telemetry.url import check_id

    ids = list(given or ["gateway"])
    if len(ids) == 1 and buses > 1:
        ids = [f"{ids[0]}-{k}" for k in range(1, buses + 1)]
    if len(ids) != buses:
        raise ConfigError(
            f"--mqtt-id given {len(ids)} times for {buses} buses: give one per --bus, "
            "or one for all"
        )
    for gateway_id in ids:
        check_id(gateway_id, "--mqtt-id")
    if len(set(ids)) != len(ids):
        raise ConfigError(f"--mqtt-id: each bus needs its own ID, got {', '.join(ids)}")
    return ids


def telemetry_options(args: argparse.Namespace) -> Callable[..., AbstractContextManager[Any]]:
    """The --mqtt options, checked before the bus or broker is touched; returns what starts
    the publisher for a gateway (a context of None without --mqtt)."""
    if args.mqtt is None:
        options = ("mqtt_id", "mqtt_ca", "mqtt_rate_hz", "sparkplug_host_id")
        given = [f for f in options if getattr(args, f) is not None]
        if given:
            raise ConfigError(f"--{given[0].replace('_', '-')} needs --mqtt URL")
        return lambda gateway, config, gateway_id: nullcontext()
    from grasplink.surfaces.telemetry import (
        DEFAULT_RATE_HZ,
        TelemetryPublisher,
        check_id,
        parse_broker_url,
        tls_context,
    )

    url = parse_broker_url(args.mqtt)
    tls = tls_context(url, args.mqtt_ca)
    rate_hz = args.mqtt_rate_hz or DEFAULT_RATE_HZ
    if args.sparkplug_host_id is not None:
        check_id(args.sparkplug_host_id, "--sparkplug-host-id")

    def start(gateway: Any, config: Any, gateway_id: str) -> TelemetryPublisher:
        host_id = args.sparkplug_host_id or config.telemetry.sparkplug_host_id or None
        waits = f"; Sparkplug births wait for primary host {host_id}" if host_id else ""
        print(
            f"telemetry to {url.display}: grasplink/{gateway_id}/..., "
            f"spBv1.0/{url.group}/+/{gateway_id}, at most {rate_hz:g} Hz{waits}",
            flush=True,
        )
        return TelemetryPublisher(
            gateway,
            url,
            gateway_id,
            tls=tls,
            rate_hz=rate_hz,
            controls=TelemetryPublisher.controls_of(config),
            log=lambda line: print(line, flush=True),
            primary_host_id=host_id,
            state_dir=Path(config.telemetry.state_dir).expanduser(),
            first_snapshot_s=0.0,  # connected before the gateway runs: none is coming yet
        )

    return start


def cmd_view(args: argparse.Namespace) -> int:
    from grasplink.surfaces.telemetry import check_id, parse_broker_url, tls_context
    from grasplink.surfaces.view.server import parse_http_address, serve
    from grasplink.terminal import StopSignals

    if args.folder is not None:
        return _view_recording(args)
    if args.mqtt is None:
        raise ConfigError("view: give a broker (--mqtt URL) or a run folder (DIR)")
    broker = parse_broker_url(args.mqtt)
    tls = tls_context(broker, args.mqtt_ca)
    gateway_id = None if args.gateway_id is None else check_id(args.gateway_id, "--gateway-id")
    http = parse_http_address(args.http)
    with StopSignals() as stop:
        serve(
            broker,
            http,
            gateway_id=gateway_id,
            tls=tls,
            allow_commands=args.allow_commands,
            duration_s=args.duration,
            log=lambda line: print(line, flush=True),
            stop=stop,
        )
    return stop.exit_code


def _view_recording(args: argparse.Namespace) -> int:
    """`view DIR`: the page over a recording, replayed once before it is served."""
    from grasplink.surfaces.view.recording import load_recording
    from grasplink.surfaces.view.recording_server import serve_recording
    from grasplink.surfaces.view.server import parse_http_address
    from grasplink.terminal import StopSignals

    live_only = [
        option
        for option, given in (
            ("--mqtt", args.mqtt is not None),
            ("--mqtt-ca", args.mqtt_ca is not None),
            ("--gateway-id", args.gateway_id is not None),
            ("--allow-commands", args.allow_commands),
        )
        if given
    ]
    if live_only:
        raise ConfigError(
            f"view: give DIR (a recording) or --mqtt (a broker), not both: "
            f"{', '.join(live_only)} given with DIR"
        )
    http = parse_http_address(args.http)
    print(f"view: replaying {args.folder} (once, before the page is served)", flush=True)
    recording = load_recording(args.folder)
    with StopSignals() as stop:
        serve_recording(
            recording,
            http,
            duration_s=args.duration,
            log=lambda line: print(line, flush=True),
            stop=stop,
        )
    return stop.exit_code


def cmd_profiles_dbc(args: argparse.Namespace) -> int:
    from grasplink.profiles.dbc import dbc_text, write_dbc

    overrides = dict(args.node_ids)
    if args.out is None:
        sys.stdout.write(dbc_text(overrides))
        return 0
    write_dbc(args.out, overrides)
    print(f"wrote {args.out}")
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    from grasplink.bus import open_bus
    from grasplink.bus.logs import check_record_path, record_bus
    from grasplink.terminal import StopSignals

    name = check_record_path(args.out, force=args.force)  # before the bus is touched
    with StopSignals() as stop:
        bus = open_bus(args.bus)
        try:
            until = f"for {args.duration:g} s" if args.duration else "until Ctrl-C"
            print(f"recording {args.bus} to {args.out} ({name}) {until}", flush=True)
            stats = record_bus(
                bus,
                args.out,
                duration_s=args.duration,
                should_stop=stop,
                force=args.force,
                bus_name=args.bus,
            )
        finally:
            bus.shutdown()
    errors = f", {stats.error_frames} error frames" if stats.error_frames else ""
    if stats.left_out:  # a TRC log holds data frames only (python-can's TRCWriter)
        errors += f", {stats.left_out} error/remote frames left out ({name} holds data frames)"
    print(f"wrote {args.out}: {stats.frames} frames{errors} in {stats.wall_s:.1f} s", flush=True)
    return stop.exit_code if stop.received is not None and stop.exit_code != 130 else 0


def cmd_replay(args: argparse.Namespace) -> int:
    from grasplink.bus import open_bus
    from grasplink.bus.logs import (
        ReplaySchedule,
        from_nodes_only,
        read_log,
        replay_to_bus,
        scan_log,
    )
    from grasplink.profiles.objects import GATEWAY_NODE_ID
    from grasplink.terminal import StopSignals

    if args.master_id is not None and not args.nodes_only:
        raise ConfigError("--master-id only applies with --nodes-only")
    summary = scan_log(args.log)  # a malformed or empty log fails before the bus is touched
    master_id = GATEWAY_NODE_ID if args.master_id is None else args.master_id
    keep = from_nodes_only(master_id) if args.nodes_only else None
    schedule = ReplaySchedule(speed=args.speed, loop=args.loop, keep=keep)
    with StopSignals() as stop:
        bus = open_bus(args.bus)
        try:
            print(
                f"replaying {args.log} ({summary.frames} frames over {summary.span_s:.1f} s) "
                f"onto {args.bus} at speed {args.speed:g}{', looping' if args.loop else ''}",
                flush=True,
            )
            stats = replay_to_bus(
                bus, schedule.timeline(lambda: read_log(args.log)), should_stop=stop
            )
        finally:
            bus.shutdown()
    skipped = []
    if summary.error_frames:
        skipped.append(f"{summary.error_frames} error frames")
    if keep is not None:
        skipped.append("frames a master sent (--nodes-only)")
    print(
        f"sent {stats.frames_sent} frames in {stats.wall_s:.1f} s"
        + (f" ({stats.passes} passes)" if args.loop else "")
        + f"; latest frame {1000 * stats.max_late_s:.1f} ms behind its time"
        + (f"; left out {', '.join(skipped)}" if skipped else ""),
        flush=True,
    )
    return stop.exit_code if stop.received is not None and stop.exit_code != 130 else 0


def cmd_skin(args: argparse.Namespace) -> int:
    """`skin design`: every setting checked and the workers reached before the search."""
    from grasplink.evaluation import design
    from grasplink.evaluation.workers import open_workers

    settings = design.DesignSettings(
        length_mm=args.length_mm,
        alpha=args.alpha,
        speeds_mm_s=design.parse_speeds(args.speeds),
        decoder=args.decoder,
        generations=(
            args.generations
            if args.generations is not None or args.budget_min is not None
            else design.GENERATIONS
        ),
        budget_min=args.budget_min,
        population=args.population,
        slips=args.slips,
        seed=args.seed,
    ).check()
    if args.out.exists() and not args.out.is_dir():
        raise ConfigError(f"--out {args.out}: exists and is not a folder")
    with open_workers(args.workers, args.dask) as workers:
        result = design.search(settings, workers, log=lambda line: print(line, flush=True))
    paths = design.write_outputs(result, args.out)
    print(
        f"layout {','.join(f'{x:g}' for x in result.chosen)} mm; wrote {', '.join(map(str, paths))}"
    )
    return 0


COMMANDS = {
    "skin": cmd_skin,
    "record": cmd_record,
    "replay": cmd_replay,
    "gateway": cmd_gateway,
    "node": cmd_node,
    "bus": cmd_bus,
    "demo": cmd_demo,
    "run": cmd_run,
    "plot": cmd_plot,
    "decode": cmd_decode,
    "bench": cmd_bench,
    "profiles": cmd_profiles,
    "view": cmd_view,
}


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except GrasplinkError as exc:
        print(f"grasplink: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())

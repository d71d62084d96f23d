"""Scene files (`scenes/*.toml`): which nodes exist, the clock, the seed, and the effects asked for.

A scene is validated completely on load; every error names the file, the key
and what was expected. See docs/scenes.md for the format.
"""

from __future__ import annotations

import copy
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import grasplink.simulators.effects  # noqa: F401  (registers every effect)
from grasplink.core.params import Params, SceneError
from grasplink.errors import ConfigError
from grasplink.profiles import objects as obj
from grasplink.profiles.field import node_file
from grasplink.profiles.kinds import KINDS, node_kind, unknown_kind
from grasplink.profiles.layouts import LAYOUTS_MM, parse_layout
from grasplink.simulators.bindings import BINDINGS, DEFAULT_RATES_HZ, DriveWiring, InputWiring
from grasplink.simulators.core import REGISTRY, Context, Effect, Endpoint, build_graph

US_PER_S = 1_000_000
CLOCKS = ("virtual", "realtime")
DEFAULT_CONTROLLER = "scripted"  # the NMT master that starts the nodes (see grasplink.controllers)
NO_CONTROLLER = "none"
MAX_DURATION_S = 7 * 24 * 3600.0
DEFAULT_LAYOUT = "alpha0.1"  # the skin node's EDS default (thesis best skin)


@dataclass
class NodeSpec:
    kind: str
    node_id: int
    sample_rate_hz: int | None = None
    samples_per_pdo: int | None = None
    layout: str | None = None
    file: Path | None = None  # a vendor's EDS/DCF the node is built from; None: ours
    wiring: InputWiring | DriveWiring | None = None  # how a vendor's node meets the scene


@dataclass
class ControllerSpec:
    """The scene's `[controller]`: which sans-IO controller masters the network, and its options.

    The simulators do not know controllers; the caller (CLI) builds one by name through
    `grasplink.controllers` and validates `options` then, before anything runs.
    """

    name: str | None  # None: no controller (nodes stay PRE-OPERATIONAL)
    options: dict
    source: str
    key: str = "controller"

    def params(self) -> Params:
        return Params(dict(self.options), self.source, self.key)


@dataclass
class PowerLoss:
    node: str
    at_s: float
    restore_s: float | None


@dataclass
class BusFaults:
    latency_us: int = 0
    jitter_us: int = 0
    drop_probability: float = 0.0
    error_frames_per_s: float = 0.0
    power_loss: list[PowerLoss] = field(default_factory=list)


@dataclass
class Scene:
    path: str
    name: str
    description: str
    seed: int
    duration_s: float
    clock: str
    physics_rate_hz: int
    chunk_us: int
    layout_mm: tuple[float, ...] | None
    layout_name: str | None
    nodes: dict[str, NodeSpec]
    controller: ControllerSpec
    effects: list[Effect]  # as written in the scene
    bus: BusFaults | None
    context: Context
    endpoints: list[Endpoint]  # what the nodes read and write
    ordered: list[Effect]  # effects in the order they step
    domain_of: dict[str, str]  # signal -> domain
    data: dict | None = field(default=None, repr=False, compare=False)  # parsed from this
    claimed: bool = field(default=False, repr=False, compare=False)  # a Simulation ran it

    def fresh(self) -> Scene:
        """The scene parsed again from what it was parsed from: its effects carry a run's
        state (object, grip, filters, generators), so each run needs its own."""
        if self.data is None:
            raise ConfigError(f"{self.path}: this scene was not parsed from data; load it again")
        return parse_scene(self.data, self.path)

    @property
    def duration_us(self) -> int:
        return round(self.duration_s * US_PER_S)

    def rate_hz(self, domain: str) -> int:
        return self.context.rates_hz[domain]

    def node_settings(self) -> dict[str, dict]:
        """The nodes as plain settings (what a controller fills its own tables from); the
        skin's layout as text (name or spacings)."""
        layout = self.layout_name or ",".join(f"{s:g}" for s in self.layout_mm or ())
        nodes = {}
        for kind, spec in self.nodes.items():
            settings = {k: v for k, v in vars(spec).items() if v is not None and k != "kind"}
            if kind == "skin" and layout:
                settings["layout"] = layout
            nodes[kind] = settings
        return nodes


def load_scene(path: str | Path) -> Scene:
    source = str(path)
    try:
        with open(path, "rb") as handle:
            raw = handle.read()
    except FileNotFoundError:
        raise SceneError(source, "", "no such scene file") from None
    except OSError as exc:
        raise SceneError(source, "", f"cannot read: {exc.strerror}") from None
    try:
        # TOML is UTF-8; decoding here (not in tomllib.load) turns a binary file into a
        # SceneError naming the line, instead of tomllib's bare UnicodeDecodeError.
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise SceneError(
            source,
            "",
            f"not a TOML text file: byte 0x{raw[exc.start]:02X} on line {line} is not UTF-8",
        ) from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(source, "", f"not valid TOML: {exc}") from None
    return parse_scene(data, source)


def parse_scene(data: dict, source: str) -> Scene:
    kept = copy.deepcopy(data)  # for `Scene.fresh`: neither the caller nor an effect changes it
    top = Params(data, source)
    head = top.table_of("scene")
    name = head.string("name", Path(source).stem)
    description = head.string("description", "")
    seed = head.integer("seed", 0, low=0)
    duration_s = head.number("duration_s", low=0.0, low_open=True, high=MAX_DURATION_S)
    clock = head.string("clock", "virtual", choices=CLOCKS)
    physics_rate_hz = head.integer("physics_rate_hz", 1000, low=10, high=100_000)
    if US_PER_S % physics_rate_hz:
        raise head.error("physics_rate_hz", "must divide 1000000 (e.g. 500, 1000, 2000)")
    chunk_ms = head.number("chunk_ms", 10.0, low=0.0, low_open=True, high=1000.0)
    chunk_us = round(chunk_ms * 1000)
    period_us = US_PER_S // physics_rate_hz
    if chunk_us % period_us:
        raise head.error("chunk_ms", f"must be a multiple of the physics period ({period_us} us)")
    scene_layout = head.raw("layout", None)
    head.finish()

    nodes = _parse_nodes(top.table_of("nodes", {}))
    layout_text = nodes["skin"].layout if "skin" in nodes and nodes["skin"].layout else None
    layout_text = layout_text or scene_layout
    if layout_text is None and "skin" in nodes:
        layout_text = DEFAULT_LAYOUT  # a skin node always has a layout
    layout_mm, layout_name = _parse_layout(layout_text, source)
    controller = _parse_controller(top.table_of("controller", {}))
    rates = {
        "physics": physics_rate_hz,
        "skin": (nodes["skin"].sample_rate_hz if "skin" in nodes else None)
        or DEFAULT_RATES_HZ["skin"],
        "emg": (nodes["emg"].sample_rate_hz if "emg" in nodes else None) or DEFAULT_RATES_HZ["emg"],
    }
    context = Context(source, seed, rates, layout_mm, {k: vars(v) for k, v in nodes.items()})
    effects, bus = _parse_effects(top.raw("effects", []), source, context)
    top.finish()
    endpoints = node_endpoints(nodes)
    ordered, domain_of = build_graph(effects, endpoints, source)
    return Scene(
        source,
        name,
        description,
        seed,
        duration_s,
        clock,
        physics_rate_hz,
        chunk_us,
        layout_mm,
        layout_name,
        nodes,
        controller,
        effects,
        bus,
        context,
        endpoints,
        ordered,
        domain_of,
        kept,
    )


def node_endpoints(nodes: dict[str, NodeSpec]) -> list[Endpoint]:
    """Signals the nodes read (sensors, actual values) and write (actuator commands)."""
    return [BINDINGS[kind].endpoint() for kind in nodes]


def _parse_nodes(table: Params) -> dict[str, NodeSpec]:
    nodes: dict[str, NodeSpec] = {}
    used_ids: dict[int, str] = {}
    for kind in list(table.table):
        if kind not in KINDS:
            raise table.error(kind, unknown_kind(kind))
        p = table.table_of(kind)
        spec = NodeSpec(kind, p.integer("node_id", node_kind(kind).node_id, low=1, high=127))
        spec.file = node_file(p, Path(table.source).parent)
        if spec.node_id in used_ids or spec.node_id == obj.GATEWAY_NODE_ID:
            other = used_ids.get(spec.node_id, "gateway")
            raise p.error("node_id", f"0x{spec.node_id:02X} is already used by {other}")
        used_ids[spec.node_id] = kind
        BINDINGS[kind].parse_options(p, spec)
        p.finish()
        nodes[kind] = spec
    return nodes


def _parse_layout(text, source: str) -> tuple[tuple[float, ...] | None, str | None]:
    if text is None:
        return None, None
    if not isinstance(text, str):
        raise SceneError(
            source, "scene.layout", 'expected a layout name or spacings in mm such as "19,12,5"'
        )
    try:
        spacings = parse_layout(text)
    except ConfigError as exc:
        raise SceneError(source, "layout", str(exc)) from None
    return spacings, text if text in LAYOUTS_MM else None


def _parse_controller(p: Params) -> ControllerSpec:
    name = p.string("type", DEFAULT_CONTROLLER)
    options = {k: v for k, v in p.table.items() if k != "type"}
    return ControllerSpec(None if name == NO_CONTROLLER else name, options, p.source, p.prefix)


def _parse_effects(items, source: str, context: Context) -> tuple[list[Effect], BusFaults | None]:
    if not isinstance(items, list):
        raise SceneError(source, "effects", "expected an array of tables ([[effects]])")
    effects: list[Effect] = []
    bus: BusFaults | None = None
    for index, item in enumerate(items):
        p = Params(item, source, f"effects[{index}]")
        kind = p.string("type")
        if kind == "bus.faults":
            if bus is not None:
                raise p.error("type", "bus.faults is given twice")
            bus = _parse_bus(p, context)
            continue
        cls = REGISTRY.get(kind)
        if cls is None:
            known = ", ".join(sorted([*REGISTRY, "bus.faults"]))
            raise p.error("type", f"unknown effect {kind!r}; known effects: {known}")
        effects.append(cls(p, context))
        p.finish()
    return effects, bus


def _parse_bus(p: Params, context: Context) -> BusFaults:
    faults = BusFaults(
        latency_us=p.integer("latency_us", 0, low=0, high=1_000_000),
        jitter_us=p.integer("jitter_us", 0, low=0, high=1_000_000),
        drop_probability=p.number("drop_probability", 0.0, low=0.0, high=1.0),
        error_frames_per_s=p.number("error_frames_per_s", 0.0, low=0.0, high=10_000.0),
    )
    for i, item in enumerate(p.raw("power_loss", [])):
        q = Params(item, p.source, p.key(f"power_loss[{i}]"))
        node = q.string("node", choices=tuple(context.nodes))
        at_s = q.number("at_s", low=0.0)
        restore_s = q.number("restore_s", None, low=at_s, low_open=True)
        q.finish()
        faults.power_loss.append(PowerLoss(node, at_s, restore_s))
    p.finish()
    return faults

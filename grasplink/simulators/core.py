"""Effects, domains and the graph a scene builds from the effects it asks for.

An effect is a small unit that declares the signals it consumes and
produces and steps on one *domain*'s integer sample clock: `physics`
(object, hand, belt, wearer; the scene's physics rate), `skin` (the skin
node's sample rate) or `emg` (the EMG node's sample rate). A scene builds
the graph of the requested effects only, ordered so every input is produced
before it is read; a requested effect whose input nothing provides is an
error naming the missing signal and what could provide it.

Signals carry their unit in their name (`object.speed_mm_s`). An effect
that lists a signal as both input and output *modifies* it (e.g. ridge
speed dips, noise): it runs after the producer and before the consumers.
"""

from __future__ import annotations

import copy
import hashlib
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any, ClassVar

import numpy as np

from grasplink.core.params import Params, SceneError
from grasplink.simulators import signals as sig

PHYSICS, SKIN, EMG = "physics", "skin", "emg"
DOMAINS = (PHYSICS, SKIN, EMG)  # the order domains step in: physics feeds the sensors


@dataclass
class Context:
    """What an effect may know about its scene when it is built."""

    source: str
    seed: int
    rates_hz: dict[str, int]
    layout_mm: tuple[float, ...] | None = None
    nodes: dict[str, dict] = field(default_factory=dict)

    def rng(self, effect_key: str) -> np.random.Generator:
        """A generator per effect, independent of which other effects exist."""
        digest = hashlib.sha256(effect_key.encode()).digest()
        return np.random.default_rng([self.seed, int.from_bytes(digest[:8], "little")])

    def require_layout(self, params: Params, what: str) -> tuple[float, ...]:
        if self.layout_mm is None:
            raise params.error(
                "type", f"{what} needs a skin layout: set [nodes.skin] layout or [scene] layout"
            )
        return self.layout_mm


class Io:
    """One domain chunk's view of the signals: read inputs, write outputs."""

    def __init__(
        self,
        times_us: np.ndarray,
        read: Callable[[str, np.ndarray], np.ndarray],
        write: Callable[[str, np.ndarray], None],
    ):
        self.times_us = times_us
        self._read = read
        self._write = write

    @cached_property
    def t_s(self) -> np.ndarray:
        """The sample times in seconds, worked out only for an effect that asks."""
        return self.times_us / 1e6

    def __len__(self) -> int:
        return len(self.times_us)

    def get(self, name: str) -> np.ndarray:
        return self._read(name, self.times_us)

    def put(self, name: str, values: np.ndarray) -> None:
        values = np.asarray(values, dtype=np.float64)
        if values.shape != self.times_us.shape:
            raise ValueError(f"{name}: {values.shape} values for {len(self.times_us)} samples")
        self._write(name, values)


#: An input-free stream (noise) is made this many samples ahead of its use.
AHEAD_SAMPLES = 1024
#: A filter steps a chunk of this many samples or fewer in Python floats: the same
#: arithmetic in the same order as scipy's, without its call cost on a few samples.
SHORT_CHUNK_SAMPLES = 64


class AheadStream:
    """A signal that depends on no input (noise), made in blocks ahead of its use.

    `make(count)` returns the next `count` values (rows); an element's value must not
    depend on how the stream is cut, so taking it block by block equals taking it chunk by
    chunk, and a chunk of a few samples costs a slice instead of a generator and a filter.
    """

    def __init__(self, make: Callable[[int], np.ndarray], block: int = AHEAD_SAMPLES):
        self.make = make
        self.block = block
        self.buffer: np.ndarray | None = None
        self.at = 0

    def take(self, count: int) -> np.ndarray:
        buffer = self.buffer
        if buffer is None or self.at + count > len(buffer):
            fresh = self.make(max(count, self.block))
            buffer = fresh if buffer is None else np.concatenate([buffer[self.at :], fresh])
            self.buffer, self.at = buffer, 0
        out = buffer[self.at : self.at + count]
        self.at += count
        return out


class Effect:
    """Base of every effect; subclasses set the class variables and `step`."""

    kind: ClassVar[str]
    domain: ClassVar[str]
    inputs: ClassVar[tuple[str, ...]] = ()
    outputs: ClassVar[tuple[str, ...]] = ()
    summary: ClassVar[str] = ""

    def __init__(self, params: Params, ctx: Context):
        self.params = params
        self.ctx = ctx

    @property
    def modifies(self) -> tuple[str, ...]:
        return tuple(s for s in self.outputs if s in self.inputs)

    def step(self, io: Io) -> None:
        raise NotImplementedError

    def snapshot(self) -> Snapshot:
        """The effect's state now, to come back to (the engine's run-ahead rolls back)."""
        return Snapshot(self)


# What an effect is built from, never changed by stepping: not saved in a snapshot.
_BUILT_FROM = frozenset({"params", "ctx"})
_CONTAINERS = (list, dict, deque, set)


class Snapshot:
    """An object's state, restorable any number of times.

    State is what `step` changes: attributes that are numbers or arrays replaced (never
    written into), containers whose items are replaced (copied one level deep), random
    generators (their bit generator's state), and grasplink objects holding the same
    (saved alike, restored into the same object). An effect whose state is otherwise
    overrides `Effect.snapshot`.
    """

    def __init__(self, target: object):
        self.target = target
        self.saved = {k: _save(v) for k, v in vars(target).items() if k not in _BUILT_FROM}

    def restore(self) -> None:
        state = vars(self.target)
        for name in [k for k in state if k not in self.saved and k not in _BUILT_FROM]:
            del state[name]
        for name, value in self.saved.items():
            state[name] = _restored(value)


class _GeneratorState:
    def __init__(self, generator: np.random.Generator):
        self.generator = generator
        self.state = generator.bit_generator.state


def _save(value: Any) -> Any:
    if isinstance(value, np.random.Generator):
        return _GeneratorState(value)
    if isinstance(value, _CONTAINERS):
        return copy.copy(value)
    if type(value).__module__.startswith("grasplink.") and hasattr(value, "__dict__"):
        return Snapshot(value)
    return value


def _restored(value: Any) -> Any:
    if isinstance(value, _GeneratorState):
        value.generator.bit_generator.state = value.state
        return value.generator
    if isinstance(value, _CONTAINERS):
        return copy.copy(value)
    if isinstance(value, Snapshot):
        value.restore()
        return value.target
    return value


REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator: make an effect available to scenes by its `kind`."""
    if cls.domain not in DOMAINS:
        raise ValueError(f"{cls.__name__}: unknown domain {cls.domain!r}")
    REGISTRY[cls.kind] = cls
    return cls


@dataclass(frozen=True)
class Endpoint:
    """A node's side of the graph: signals it reads (sensor) or writes (actuator command)."""

    node: str
    reads: tuple[str, ...] = ()
    writes: tuple[str, ...] = ()
    domain: str = PHYSICS


def build_graph(
    effects: list[Effect], endpoints: list[Endpoint], source: str
) -> tuple[list[Effect], dict[str, str]]:
    """Order effects so inputs come first; return (ordered effects, signal -> domain).

    Raises SceneError when an input has no producer, two effects produce the
    same signal, or an effect reads a signal from a domain that steps later.
    """
    producers: dict[str, str] = {}
    domain_of: dict[str, str] = {}
    for endpoint in endpoints:
        for name in endpoint.writes:
            producers[name] = f"node {endpoint.node}"
            domain_of[name] = endpoint.domain
    for index, effect in enumerate(effects):
        for name in effect.outputs:
            if name in effect.inputs:
                continue
            if name in producers:
                raise SceneError(
                    source,
                    f"effects[{index}]",
                    f"{effect.kind} produces {name}, already produced by {producers[name]}",
                )
            producers[name] = effect.kind
            domain_of[name] = effect.domain
    for index, effect in enumerate(effects):
        for name in effect.inputs:
            if name not in producers:
                raise SceneError(
                    source,
                    f"effects[{index}]",
                    f"{effect.kind} needs {name}, which nothing in this scene "
                    f"provides; add {_providers_of(name)}",
                )
            if DOMAINS.index(domain_of[name]) > DOMAINS.index(effect.domain):
                raise SceneError(
                    source,
                    f"effects[{index}]",
                    f"{effect.kind} ({effect.domain}) cannot read {name} from "
                    f"the later {domain_of[name]} domain",
                )
    return _topological(effects, source), domain_of


def _providers_of(signal: str) -> str:
    kinds = [k for k, cls in REGISTRY.items() if signal in cls.outputs and signal not in cls.inputs]
    nodes = {"belt.command_mrad_s": "[nodes.belt]", sig.HAND_TARGET_N: "[nodes.hand]"}
    options = [f"an effect of type {k!r}" for k in sorted(kinds)]
    if signal in nodes:
        options.append(nodes[signal])
    return " or ".join(options) if options else "an effect that produces it"


def _topological(effects: list[Effect], source: str) -> list[Effect]:
    """Producers, then modifiers in scene order, then consumers; stable otherwise."""
    remaining = list(range(len(effects)))
    ordered: list[int] = []
    ready_signals: set[str] = set()
    external = {name for e in effects for name in e.inputs} - {
        name for e in effects for name in e.outputs
    }
    ready_signals |= external
    # A modified signal is ready for plain consumers only after all its modifiers ran.
    modifiers: dict[str, list[int]] = {}
    for i, effect in enumerate(effects):
        for name in effect.modifies:
            modifiers.setdefault(name, []).append(i)
    produced: set[str] = set(external)
    while remaining:
        progress = False
        for i in list(remaining):
            effect = effects[i]
            needs_ok = True
            for name in effect.inputs:
                if name in effect.modifies:
                    earlier = [m for m in modifiers[name] if m < i]
                    if name not in produced or any(m in remaining for m in earlier):
                        needs_ok = False
                elif name not in produced or any(m in remaining for m in modifiers.get(name, [])):
                    needs_ok = False
            if needs_ok:
                ordered.append(i)
                remaining.remove(i)
                produced.update(effect.outputs)
                progress = True
        if not progress:
            kinds = ", ".join(effects[i].kind for i in remaining)
            raise SceneError(source, "effects", f"effects depend on each other in a loop: {kinds}")
    return [effects[i] for i in ordered]


def independent_parts(
    effects: list[Effect], endpoints: list[Endpoint]
) -> list[tuple[list[Effect], list[Endpoint]]]:
    """Split the graph where no signal passes: each part's effects (in the given order) and
    the command endpoints writing into them, no signal shared between parts.

    A part's samples depend only on its own effects and commands, so the engine runs each
    ahead on its own and rolls one back only when a command of its own changed (a ramp of
    the hand's grip leaves the belt, the wearer and the EMG alone). Parts come in the order
    of their first effect (or endpoint), so a scene always splits the same way.
    """
    members: list[Effect | Endpoint] = [*effects, *(e for e in endpoints if e.writes)]
    parent = list(range(len(members)))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    holder: dict[str, int] = {}  # a signal -> a member that reads or writes it
    for i, member in enumerate(members):
        names = member.writes if isinstance(member, Endpoint) else member.inputs + member.outputs
        for name in names:
            if name in holder:
                parent[root(i)] = root(holder[name])
            else:
                holder[name] = i
    parts: dict[int, tuple[list[Effect], list[Endpoint]]] = {}
    for i, member in enumerate(members):
        part = parts.setdefault(root(i), ([], []))
        if isinstance(member, Endpoint):
            part[1].append(member)
        else:
            part[0].append(member)
    return list(parts.values())

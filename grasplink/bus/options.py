"""Bus URL options: which ``?key=value`` options each interface takes, and of what type.

A python-can bus silently swallows keyword arguments it does not know
(``**kwargs``), so a misspelt option would be ignored without a word. Every
option of a bus URL is therefore checked here before anything is opened:

* ``virtual``, ``remote`` and ``socketcan`` (the buses grasplink documents)
  have hand-written tables with ranges and hints;
* any other python-can interface: the names and types come from its bus
  class's ``__init__`` (signature and ``:param`` docstring lines), read from
  the source with `ast` rather than imported - importing a driver module
  fails or logs when its vendor library is missing, and a URL must be
  checkable anywhere. Parameters no URL can express (``can_filters``,
  ``timing`` objects, an SSL context) are not offered.

An interface whose source cannot be read (a third-party plugin installed
some other way) has its option names unchecked; its values are converted
by their look (integers, floats, true/false, text).
"""

from __future__ import annotations

import ast
import enum
import functools
import importlib.util
import re
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import can
from can.interfaces import BACKENDS

from grasplink.errors import BusError

_INT_RE = re.compile(r"[+-]?\d+")
_HEX_RE = re.compile(r"0[xX][0-9a-fA-F]+")
_FLOAT_RE = re.compile(r"[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?")
_PARAM_RE = re.compile(r":param\s+(?:([^:]*?)\s+)?(\w+)\s*:")

# Keys can.Bus itself consumes, or that are part of INTERFACE:CHANNEL.
RESERVED = ("interface", "bustype", "channel", "ignore_config", "config_context", "context")
# __init__ parameters a URL cannot carry (objects, not values).
_NOT_URL = frozenset({"self", "channel", "can_filters", "timing", "ssl_context", "protocol"})
_KINDS = {"bool": "bool", "int": "int", "float": "float", "str": "str"}
_STATE_NAMES = {"BusState", "can.BusState", "can.bus.BusState", "bus.BusState"}


@dataclass(frozen=True)
class OptionSpec:
    """One accepted option: its value kind and, for numbers, a lower bound."""

    name: str
    kind: str  # "bool", "int", "float", "str", "state" (can.BusState name) or "any"
    minimum: float | None = None
    above_minimum: bool = False  # True: the value must be > minimum, not >=

    def describe(self) -> str:
        what = {
            "bool": "true or false",
            "int": "an integer",
            "float": "a number",
            "str": "text",
            "state": " or ".join(s.name for s in can.BusState),
            "any": "a value",
        }[self.kind]
        if self.minimum is not None:
            what += f" {'>' if self.above_minimum else '>='} {self.minimum:g}"
        return what


_VIRTUAL = (
    OptionSpec("receive_own_messages", "bool"),
    OptionSpec("rx_queue_size", "int", 0),
    OptionSpec("preserve_timestamps", "bool"),
)
_HANDWRITTEN: dict[str, tuple[OptionSpec, ...]] = {
    "virtual": _VIRTUAL,
    # The hub's server side overrides interface and channel; only these mean something.
    "remote": (
        OptionSpec("connect_timeout", "float", 0, above_minimum=True),
        OptionSpec("receive_own_messages", "bool"),
    ),
    "socketcan": (
        OptionSpec("receive_own_messages", "bool"),
        OptionSpec("local_loopback", "bool"),
        OptionSpec("fd", "bool"),
        OptionSpec("ignore_rx_error_frames", "bool"),
    ),
}
_HINTS = {
    ("socketcan", "bitrate"): (
        "a SocketCAN interface's bitrate is set with `sudo ip link set CHANNEL type can "
        "bitrate N` while the link is down, not in the bus URL"
    ),
    ("socketcan", "data_bitrate"): (
        "a SocketCAN interface's data bitrate is set with `ip link ... dbitrate N`, "
        "not in the bus URL"
    ),
    ("remote", "bitrate"): "a hub is a virtual bus and has no bitrate",
    ("virtual", "bitrate"): "a virtual bus has no bitrate",
}


def accepted_options(interface: str) -> dict[str, OptionSpec] | None:
    """The options a URL of this interface may carry; None if they cannot be known."""
    if interface in _HANDWRITTEN:
        return {spec.name: spec for spec in _HANDWRITTEN[interface]}
    return _introspected(interface)


def convert_options(interface: str, url: str, pairs: Iterable[tuple[str, str]]) -> dict[str, Any]:
    """Check and convert ``(key, text)`` pairs; raises `BusError` naming the bad one."""
    pairs = list(pairs)
    seen: set[str] = set()
    for key, text in pairs:  # the URL's form first, then what the options mean
        if not key.isidentifier():
            raise BusError(f"bus URL {url!r}: option name {key!r} is not a valid name")
        if text == "":
            raise BusError(f"bus URL {url!r}: option {key!r} has no value")
        if key in seen:
            raise BusError(f"bus URL {url!r}: option {key!r} is given twice")
        if key in RESERVED:
            raise BusError(
                f"bus URL {url!r}: {key!r} cannot be an option; it is part of INTERFACE:CHANNEL"
            )
        seen.add(key)
    accepted = accepted_options(interface) if pairs else {}
    options: dict[str, Any] = {}
    for key, text in pairs:
        if accepted is None:
            options[key] = guess_value(text)
            continue
        spec = accepted.get(key)
        if spec is None:
            hint = _HINTS.get((interface, key))
            listed = ", ".join(sorted(accepted)) or "none"
            raise BusError(
                f"bus URL {url!r}: unknown option {key!r} for the {interface} interface"
                + (f" ({hint})" if hint else "")
                + f"; accepted options: {listed}"
            )
        options[key] = _convert(spec, text, url, accepted)
    return options


def guess_value(text: str) -> Any:
    """A value by its look: int (``0x`` is hex), float, true/false, else the text."""
    if _INT_RE.fullmatch(text):
        return int(text, 10)
    if _HEX_RE.fullmatch(text):
        return int(text, 16)
    if _FLOAT_RE.fullmatch(text):
        return float(text)
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    return text


def format_value(value: Any) -> str:
    """The URL text of an option value (inverse of the conversion)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, enum.Enum):
        return value.name
    return str(value)


def _convert(spec: OptionSpec, text: str, url: str, accepted: dict[str, OptionSpec]) -> Any:
    value: Any
    if spec.kind == "str":
        return text
    if spec.kind == "any":
        return guess_value(text)
    if spec.kind == "bool":
        value = text.lower() == "true" if text.lower() in ("true", "false") else None
    elif spec.kind == "state":
        value = can.BusState.__members__.get(text.upper())
    else:
        number = guess_value(text)
        wanted = int if spec.kind == "int" else int | float
        if isinstance(number, wanted) and not isinstance(number, bool):
            value = float(number) if spec.kind == "float" else number
        else:
            value = None
    if value is not None and spec.minimum is not None:
        too_small = value <= spec.minimum if spec.above_minimum else value < spec.minimum
        if too_small:
            value = None
    if value is None:
        raise BusError(
            f"bus URL {url!r}: option {spec.name!r} must be {spec.describe()}, got {text!r}; "
            f"accepted options: {', '.join(sorted(accepted))}"
        )
    return value


# -- reading a python-can bus class's parameters from its source ----------------------


@functools.cache
def _introspected(interface: str) -> dict[str, OptionSpec] | None:
    target = BACKENDS.get(interface)
    if target is None:
        return None
    module, class_name = target
    found = _find_class(module, class_name, hops=4)
    if found is None:
        return None
    init = next(
        (
            node
            for node in found.body
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and node.name == "__init__"
        ),
        None,
    )
    if init is None:
        return None
    specs: dict[str, OptionSpec] = {}
    excluded: set[str] = set(_NOT_URL)
    args = init.args
    positional = args.posonlyargs + args.args
    defaults: list[ast.expr | None] = [None] * (len(positional) - len(args.defaults))
    defaults += list(args.defaults)
    named = list(zip(positional, defaults, strict=True))
    named += list(zip(args.kwonlyargs, args.kw_defaults, strict=True))
    docs = "\n".join(filter(None, (ast.get_docstring(found), ast.get_docstring(init))))
    doc_types = {name: kind for kind, name in _PARAM_RE.findall(docs)}
    for arg, default in named:
        if arg.arg in excluded:
            continue
        kind = _kind_of_annotation(arg.annotation) if arg.annotation is not None else None
        if kind is None and arg.annotation is None:
            kind = _kind_of_doc_type(doc_types.get(arg.arg, "")) or _kind_of_default(default)
        if kind is None:  # an object no URL can express
            excluded.add(arg.arg)
            continue
        specs[arg.arg] = OptionSpec(arg.arg, kind)
    if args.kwarg is not None:  # documented keyword arguments taken through **kwargs
        for name, doc_type in doc_types.items():
            if name in specs or name in excluded or name == args.kwarg.arg:
                continue
            kind = _kind_of_doc_type(doc_type) if doc_type else "any"
            if kind is not None:
                specs[name] = OptionSpec(name, kind)
    return specs


def _kind_of_annotation(node: ast.expr) -> str | None:
    """Kind of a primitive annotation (Optional/union with None allowed); None otherwise."""
    members = [m for m in _union_members(node) if ast.unparse(m) != "None"]
    kinds = set()
    for member in members:
        text = ast.unparse(member).strip("'\"")
        if text in _KINDS:
            kinds.add(_KINDS[text])
        elif text in _STATE_NAMES:
            kinds.add("state")
        else:
            return None
    if not kinds:
        return None
    return kinds.pop() if len(kinds) == 1 else "any"


def _union_members(node: ast.expr) -> list[ast.expr]:
    if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
        return _union_members(node.left) + _union_members(node.right)
    if isinstance(node, ast.Subscript):
        head = ast.unparse(node.value)
        if head in ("Optional", "typing.Optional", "Union", "typing.Union"):
            inner = node.slice
            parts = inner.elts if isinstance(inner, ast.Tuple) else [inner]
            return [m for part in parts for m in _union_members(part)]
    return [node]


def _kind_of_doc_type(text: str) -> str | None:
    """Kind of a docstring type ("int", "bool or None", ...); None if not primitive."""
    words = [w for w in re.findall(r"[\w.]+", text) if w not in ("or", "None", "Optional")]
    if not words:
        return None
    kinds = set()
    for word in words:
        if word in _KINDS:
            kinds.add(_KINDS[word])
        elif word in _STATE_NAMES:
            kinds.add("state")
        else:
            return None
    return kinds.pop() if len(kinds) == 1 else "any"


def _kind_of_default(default: ast.expr | None) -> str | None:
    if default is None:
        return "any"
    if isinstance(default, ast.Constant):
        value = default.value
        if value is None:
            return "any"
        for kind, type_ in (("bool", bool), ("int", int), ("float", float), ("str", str)):
            if isinstance(value, type_):
                return kind
    if isinstance(default, ast.UnaryOp) and isinstance(default.operand, ast.Constant):
        return _kind_of_default(default.operand)
    return None


def _find_class(module: str, class_name: str, hops: int) -> ast.ClassDef | None:
    """The class's definition, following ``from X import Name`` / ``*`` re-exports."""
    path = _module_path(module)
    if path is None or hops < 0:
        return None
    try:
        tree = ast.parse(path.read_text(encoding="utf-8"))
    except (OSError, SyntaxError, UnicodeDecodeError):
        return None
    for node in tree.body:
        if isinstance(node, ast.ClassDef) and node.name == class_name:
            return node
    is_package = path.name == "__init__.py"
    for node in tree.body:
        if not isinstance(node, ast.ImportFrom):
            continue
        names = {alias.asname or alias.name for alias in node.names}
        if class_name not in names and "*" not in names:
            continue
        source = _absolute(module, is_package, node.level, node.module)
        if source is None:
            continue
        wanted = next(
            (a.name for a in node.names if (a.asname or a.name) == class_name), class_name
        )
        found = _find_class(source, wanted, hops - 1)
        if found is not None:
            return found
    return None


def _absolute(module: str, is_package: bool, level: int, name: str | None) -> str | None:
    if level == 0:
        return name
    parts = module.split(".")
    if not is_package:
        parts = parts[:-1]
    if level > 1:
        parts = parts[: -(level - 1)] if level - 1 <= len(parts) else []
    if not parts:
        return None
    return ".".join(parts + ([name] if name else []))


def _module_path(module: str) -> Path | None:
    """The source file of a module, found without importing it (only its top package)."""
    top, *rest = module.split(".")
    try:
        spec = importlib.util.find_spec(top)
    except (ImportError, ValueError):
        return None
    if spec is None or spec.origin is None:
        return None
    origin = Path(spec.origin)
    if not rest:
        return origin if origin.suffix == ".py" else None
    if not spec.submodule_search_locations:
        return None
    base = Path(next(iter(spec.submodule_search_locations))).joinpath(*rest)
    for candidate in (base.with_suffix(".py"), base / "__init__.py"):
        if candidate.is_file():
            return candidate
    return None

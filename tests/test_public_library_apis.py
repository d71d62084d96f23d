"""grasplink uses the public APIs of the libraries it drives; a library upgrade may still
change a public API, but then it says so in its changelog. Two rules:

- The surfaces (aiomqtt, paho-mqtt, pymodbus), strictest: no name starting with `_` is
  reached on any object but the code's own `self` or `cls`, none is imported, and none of
  pymodbus's connection internals (its request handler, the transaction manager, the
  framers) is imported to be overridden.
- The whole package: no private of a library object (python-can, canopen, can_remote,
  pymodbus, aiomqtt, paho, numpy, scipy, numba, serial, the standard library, ...) is
  reached, imported, reached by name, or redefined by a subclass. Our own objects'
  privates are not this rule. Whose an object is gets decided from the source: the
  module's imports, the annotations of parameters and attributes, the bases of classes
  (a library base's privates are read from its attributes and from its methods' source);
  where the source cannot tell, the private must be listed in `OWN_PRIVATES` for its file
  with why it is ours, so nothing unexplained passes. Documented APIs spelled with an
  underscore (`DOCUMENTED`: namedtuple's `_replace`, python-can's backend hooks) are public.
"""

from __future__ import annotations

import ast
import builtins
import functools
import importlib
import inspect
import textwrap
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SURFACES = ROOT / "grasplink" / "surfaces"
# the connection machinery of pymodbus: overriding it ties the server to one release
PYMODBUS_INTERNALS = ("pymodbus.server.requesthandler", "pymodbus.transaction", "pymodbus.framer")
GENERATED = {"sparkplug_b_pb2.py"}


def sources() -> list[Path]:
    return sorted(p for p in SURFACES.rglob("*.py") if p.name not in GENERATED)


def private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def violations(path: Path, root: Path = ROOT) -> Iterator[str]:
    tree = ast.parse(path.read_text(), str(path))
    where = path.relative_to(root)
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and private(node.attr):
            owner = node.value
            if not (isinstance(owner, ast.Name) and owner.id in ("self", "cls")):
                yield f"{where}:{node.lineno}: `{ast.unparse(node)}` reaches a private name"
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name):
            accessor = node.func.id in ("getattr", "setattr", "hasattr", "delattr")
            name = node.args[1] if accessor and len(node.args) > 1 else None
            if (
                isinstance(name, ast.Constant)
                and isinstance(name.value, str)
                and private(name.value)
            ):
                yield f"{where}:{node.lineno}: `{ast.unparse(node)}` by its name"
        elif isinstance(node, ast.ImportFrom):
            module = node.module or ""
            for alias in node.names:
                if private(alias.name) or any(private(part) for part in module.split(".")):
                    yield f"{where}:{node.lineno}: imports private `{module}.{alias.name}`"
            if module.startswith(PYMODBUS_INTERNALS):
                yield f"{where}:{node.lineno}: imports pymodbus's internals `{module}`"
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith(PYMODBUS_INTERNALS):
                    yield f"{where}:{node.lineno}: imports pymodbus's internals `{alias.name}`"


def test_the_surfaces_reach_no_private_name_of_another_object() -> None:
    found = [line for path in sources() for line in violations(path)]
    assert found == [], "\n".join(found)


@pytest.mark.parametrize(
    "code, says",
    [
        ("client._client.loop_read()", "`client._client` reaches a private name"),
        ("x = getattr(inner, '_sock', None)", "by its name"),
        ("from paho.mqtt.client import _socketpair_compat", "imports private"),
        ("from pymodbus.server.requesthandler import ServerRequestHandler", "internals"),
        ("import pymodbus.transaction", "internals"),
    ],
)
def test_the_check_finds_each_way_of_reaching_in(tmp_path: Path, code: str, says: str) -> None:
    module = tmp_path / "module.py"
    module.write_text(f"{code}\nself._own = cls._own_too = 1\n")
    found = list(violations(module, tmp_path))
    assert len(found) == 1 and says in found[0]


# -- the whole package: no private of a library object ---------------------------------------
#
# Everywhere in grasplink, a name starting with `_` is reached only on our own objects. What an
# owner is gets decided from the source, never guessed:
# - a module or class imported from outside grasplink, a builtin, `super()` or `self` of a
#   class with a library base that does not define the name itself, a value annotated with a
#   library type, the result of calling a library: a library object (flagged);
# - `self`/`cls`, a grasplink class or module, `super()` over grasplink bases, a parameter or
#   attribute annotated with a grasplink type: our own (a private our code defines itself);
# - anything else (a loop variable, an element, a local built by a call of ours) cannot be
#   told from the source: it passes only if `OWN_PRIVATES` lists that private for that file,
#   with why it is ours. A new, unlisted one fails, so a library private cannot slip in
#   through a variable.
# A class with a library base must not define (override or set) a private name the library's
# class defines: it is found in the base classes' attributes and in the `self._x = ...` of
# their source. Imports of a private module or name from a library are flagged, as is the
# name in a string given to `importlib.import_module`.

PACKAGE = ROOT / "grasplink"
OWN = "grasplink"

# Documented APIs spelled with an underscore: public, whatever object they are reached on.
DOCUMENTED = {
    # collections.namedtuple / typing.NamedTuple: "to prevent conflicts with field names,
    # the method and attribute names start with an underscore" (Python docs)
    "_replace",
    "_asdict",
    "_fields",
    "_field_defaults",
    "_make",
    # python-can's BusABC hooks a backend may override ("Extending the BusABC class")
    "_recv_internal",
    "_send_periodic_internal",
    "_apply_filters",
    "_detect_available_configs",
}

# Privates of our own objects reached where the source cannot tell whose the object is: per
# file, the name and whose it is. Each entry must still be used (an unused one fails).
OWN_PRIVATES: dict[str, dict[str, str]] = {
    "grasplink/bus/runner.py": {
        # MultiRunner steps its NodeRunners' cycle on its one thread (the same module)
        "_thread": "NodeRunner's (MultiRunner checks its runners have none)",
        "_start_pacer": "NodeRunner's",
        "_power_on": "NodeRunner's",
        "_progress_us": "NodeRunner's",
        "_clock": "NodeRunner's",
        "_wake_us": "NodeRunner's",
        "_step": "NodeRunner's",
    },
    "grasplink/decoding/tracker.py": {
        # a _Bank's two matrices, handed to the numba kernels as they are
        "_f": "_Bank's float columns",
        "_i": "_Bank's integer columns",
    },
}


@dataclass
class Module:
    name: str
    path: Path
    tree: ast.Module
    imports: dict[str, str] = field(default_factory=dict)  # local name -> dotted target
    functions: set[str] = field(default_factory=set)
    classes: dict[str, ast.ClassDef] = field(default_factory=dict)
    annotated: dict[str, ast.expr] = field(default_factory=dict)  # module-level `x: T = ...`
    parents: dict[ast.AST, ast.AST] = field(default_factory=dict)

    @classmethod
    def parse(cls, name: str, path: Path) -> Module:
        module = cls(name, path, ast.parse(path.read_text(), str(path)))
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        for node in ast.walk(module.tree):
            for child in ast.iter_child_nodes(node):
                module.parents[child] = node
            if isinstance(node, ast.Import):
                for alias in node.names:
                    local = alias.asname or alias.name.partition(".")[0]
                    module.imports[local] = alias.name if alias.asname else local
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    up = package.split(".")[: len(package.split(".")) - node.level + 1]
                    base = ".".join([*up, base] if base else up)
                for alias in node.names:
                    module.imports[alias.asname or alias.name] = f"{base}.{alias.name}"
        for node in module.tree.body:
            if isinstance(node, ast.ClassDef):
                module.classes[node.name] = node
            elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                module.functions.add(node.name)
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                module.annotated[node.target.id] = node.annotation
        return module


OwnClass = tuple[Module, ast.ClassDef]


@dataclass(frozen=True)
class Whose:
    """What an expression is: a "library" object (`library` names it where known), "own"
    (an instance of `classes` where known), "self" or "super" in one of `classes`, "none",
    or "unknown"."""

    kind: str
    classes: tuple[OwnClass, ...] = ()
    library: str = ""

    @classmethod
    def of_own_class(cls, module: Module, node: ast.ClassDef) -> Whose:
        return cls("own", ((module, node),))


OWN_OBJECT, UNKNOWN, NONE = Whose("own"), Whose("unknown"), Whose("none")


def module_name(path: Path, root: Path) -> str:
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


@functools.cache
def package_modules() -> dict[str, Module]:
    paths = (p for p in PACKAGE.rglob("*.py") if p.name not in GENERATED)
    return {m.name: m for m in (Module.parse(module_name(p, ROOT), p) for p in paths)}


def resolve(dotted: str, modules: dict[str, Module], depth: int = 0) -> Whose:
    """What a dotted name imported somewhere is (following our packages' re-exports)."""
    if dotted.partition(".")[0] != OWN and dotted not in modules:
        return Whose("library", library=dotted)
    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        module = modules.get(".".join(parts[:cut]))
        if module is None:
            continue
        rest = parts[cut:]
        if not rest:
            return OWN_OBJECT
        if rest[0] in module.classes:
            return Whose.of_own_class(module, module.classes[rest[0]])
        if rest[0] in module.imports and depth < 10:
            return resolve(".".join([module.imports[rest[0]], *rest[1:]]), modules, depth + 1)
        return OWN_OBJECT
    return UNKNOWN


def combine(alternatives: list[Whose]) -> Whose:
    """A union's parts: a library object if any part is, ours if every part is."""
    for whose in alternatives:
        if whose.kind == "library":
            return whose
    alternatives = [w for w in alternatives if w.kind != "none"]
    if alternatives and all(w.kind == "own" for w in alternatives):
        if all(w.classes for w in alternatives):
            return Whose("own", tuple(c for w in alternatives for c in w.classes))
        return OWN_OBJECT
    return UNKNOWN


class Checker:
    """The widened rule over one module (see the comment above `PACKAGE`)."""

    def __init__(self, module: Module, modules: dict[str, Module], root: Path) -> None:
        self.module, self.modules = module, modules
        self.where = module.path.relative_to(root).as_posix()
        self.allowed = OWN_PRIVATES.get(self.where, {}) if root == ROOT else {}
        self.used: set[str] = set()
        self.found: list[str] = []

    # -- what a name or expression is --------------------------------------------------------
    def at_module(self, name: str, module: Module | None = None) -> Whose:
        module = module or self.module
        if name in module.imports:
            return resolve(module.imports[name], self.modules)
        if name in module.classes:
            return Whose.of_own_class(module, module.classes[name])
        if name in module.functions:
            return OWN_OBJECT
        if name in module.annotated:
            return self.annotation(module.annotated[name], module)
        if name in assigned_at_module(module):
            return UNKNOWN  # a module-level variable: whatever it was given
        if hasattr(builtins, name):
            return Whose("library", library=f"builtins.{name}")
        return UNKNOWN

    def annotation(self, node: ast.expr | None, module: Module | None = None) -> Whose:
        """What a value annotated `node` is (a union: library if any part is)."""
        module = module or self.module
        if node is None:
            return UNKNOWN
        if isinstance(node, ast.Constant):
            if node.value is None:
                return NONE
            if isinstance(node.value, str):
                return self.annotation(ast.parse(node.value, mode="eval").body, module)
            return UNKNOWN
        if isinstance(node, ast.BinOp) and isinstance(node.op, ast.BitOr):
            return combine(
                [self.annotation(node.left, module), self.annotation(node.right, module)]
            )
        if isinstance(node, ast.Subscript):
            outer = self.annotation(node.value, module)
            if outer.library in ("typing.Optional", "typing.Union", "typing.Annotated"):
                args = node.slice.elts if isinstance(node.slice, ast.Tuple) else [node.slice]
                picked = args[:1] if outer.library == "typing.Annotated" else args
                return combine([self.annotation(a, module) for a in picked])
            return outer
        if isinstance(node, ast.Name):
            return self.at_module(node.id, module)
        if isinstance(node, ast.Attribute):
            owner = self.annotation(node.value, module)
            if owner.kind == "library":
                return Whose("library", library=f"{owner.library}.{node.attr}")
            return UNKNOWN
        return UNKNOWN

    def enclosing(self, node: ast.AST, *kinds: type) -> Iterator[ast.AST]:
        while node in self.module.parents:
            node = self.module.parents[node]
            if isinstance(node, kinds):
                yield node

    def method_class(self, function: ast.AST) -> ast.ClassDef | None:
        """The class whose method `function` is, unless a static one (no self, no cls)."""
        parent = self.module.parents.get(function)
        if not isinstance(parent, ast.ClassDef) or not isinstance(
            function, ast.FunctionDef | ast.AsyncFunctionDef
        ):
            return None
        static = any(ast.unparse(d) == "staticmethod" for d in function.decorator_list)
        return None if static else parent

    def name(self, name: str, node: ast.AST) -> Whose:
        functions = (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)
        for function in self.enclosing(node, *functions):
            assert isinstance(function, functions)
            args = function.args
            params = [*args.posonlyargs, *args.args, *args.kwonlyargs]
            params += [a for a in (args.vararg, args.kwarg) if a is not None]
            for param in params:
                if param.arg != name:
                    continue
                owner = self.method_class(function)
                first = (args.posonlyargs + args.args)[:1]
                if owner is not None and first and first[0] is param:
                    return Whose("self", ((self.module, owner),))
                return self.annotation(param.annotation)
            body = function.body if isinstance(function.body, list) else [function.body]
            for inner in (n for stmt in body for n in ast.walk(stmt)):
                if (
                    isinstance(inner, ast.AnnAssign)
                    and isinstance(inner.target, ast.Name)
                    and inner.target.id == name
                ):
                    return self.annotation(inner.annotation)
                stored = isinstance(inner, ast.Name) and not isinstance(inner.ctx, ast.Load)
                if stored and inner.id == name:
                    return UNKNOWN  # a local: whatever it was given
        return self.at_module(name)

    def expression(self, node: ast.expr) -> Whose:
        if isinstance(node, ast.Name):
            return self.name(node.id, node)
        if isinstance(node, ast.Call):
            if isinstance(node.func, ast.Name) and node.func.id == "super" and not node.args:
                owner = next(self.enclosing(node, ast.ClassDef), None)
                assert isinstance(owner, ast.ClassDef)
                return Whose("super", ((self.module, owner),))
            made_by = self.expression(node.func)
            if made_by.kind == "library":
                return made_by  # what a library makes is the library's
            if made_by.kind == "own" and made_by.classes:
                return made_by  # an instance of our class
            return UNKNOWN
        if isinstance(node, ast.Attribute):
            owner = self.expression(node.value)
            if owner.kind == "library":
                return Whose("library", library=f"{owner.library}.{node.attr}")
            if owner.kind in ("own", "self") and len(owner.classes) == 1:
                module, cls = owner.classes[0]
                hint = self.attribute_annotation(module, cls, node.attr)
                return UNKNOWN if hint is None else checker_of(module, self).annotation(hint)
            if owner.kind == "own" and not owner.classes:
                return OWN_OBJECT  # an attribute of one of our modules
            return UNKNOWN
        return UNKNOWN

    # -- what our classes define, and what their library bases do -----------------------------
    def attribute_annotation(
        self, module: Module, node: ast.ClassDef, attr: str
    ) -> ast.expr | None:
        for stmt in ast.walk(node):
            if isinstance(stmt, ast.AnnAssign):
                target = stmt.target
                if (isinstance(target, ast.Name) and target.id == attr and stmt in node.body) or (
                    isinstance(target, ast.Attribute)
                    and target.attr == attr
                    and isinstance(target.value, ast.Name)
                    and target.value.id in ("self", "cls")
                ):
                    return stmt.annotation
        return None

    def bases(
        self, module: Module, node: ast.ClassDef
    ) -> Iterator[tuple[Module, ast.ClassDef] | str]:
        """The class's bases: ours as (module, class), a library's by dotted name."""
        checker = checker_of(module, self)
        for base in node.bases:
            if isinstance(base, ast.Subscript):
                base = base.value  # Counter[str], Generic[T]
            whose = checker.annotation(base)
            if whose.kind == "library":
                yield whose.library
            elif whose.kind == "own":
                yield from whose.classes

    def own_names(self, module: Module, node: ast.ClassDef, depth: int = 0) -> set[str]:
        """The private names a class of ours and its own bases define."""
        if (module.name, node.name) in _OWN_NAMES:
            return _OWN_NAMES[module.name, node.name]
        names = defined_names(node)
        for base in self.bases(module, node):
            if not isinstance(base, str) and depth < 20:
                names |= self.own_names(*base, depth + 1)
        if package_modules().get(module.name) is module:
            _OWN_NAMES[module.name, node.name] = names
        return names

    def library_bases(self, module: Module, node: ast.ClassDef, depth: int = 0) -> list[str]:
        """The library classes a class of ours derives from, through its own bases too."""
        if (module.name, node.name) in _LIBRARY_BASES:
            return _LIBRARY_BASES[module.name, node.name]
        found: list[str] = []
        for base in self.bases(module, node):
            if isinstance(base, str):
                found.append(base)
            elif depth < 20:
                found += self.library_bases(*base, depth + 1)
        if package_modules().get(module.name) is module:
            _LIBRARY_BASES[module.name, node.name] = found
        return found

    # -- the checks ----------------------------------------------------------------------------
    def flag(self, node: ast.AST, what: str) -> None:
        self.found.append(f"{self.where}:{getattr(node, 'lineno', 0)}: {what}")

    def reach(self, node: ast.AST, owner: ast.expr, name: str, shown: str) -> None:
        if not private(name) or name in DOCUMENTED:
            return
        whose = self.expression(owner)
        if whose.kind == "library":
            self.flag(node, f"`{shown}` reaches a private of {whose.library or 'a library object'}")
        for module, cls in whose.classes:  # ours, unless a library base of theirs has it
            ours = self.own_names(module, cls)
            if whose.kind == "super":
                own_bases = [b for b in self.bases(module, cls) if not isinstance(b, str)]
                ours = set().union(*(self.own_names(*b) for b in own_bases))
            library = self.library_bases(module, cls)
            if name not in ours and library:
                self.flag(node, f"`{shown}` reaches a private of the library base {library[0]}")
                break
        if whose.kind == "unknown":
            if name in self.allowed:
                self.used.add(name)
            else:
                self.flag(
                    node,
                    f"`{shown}`: whose private is this? If ours, list it in OWN_PRIVATES "
                    "with why (or annotate the owner with our type)",
                )

    def imported(self, node: ast.AST, dotted: str) -> None:
        if dotted.partition(".")[0] != OWN and any(private(p) for p in dotted.split(".")):
            self.flag(node, f"imports the library private `{dotted}`")

    def overrides(self, node: ast.ClassDef) -> None:
        """A class with a library base defines no private name the library's class has."""
        for dotted in self.library_bases(self.module, node):
            theirs = library_names(dotted)
            for name in sorted(defined_names(node) & theirs - DOCUMENTED):
                self.flag(node, f"class {node.name} redefines {dotted}'s private `{name}`")

    def run(self) -> list[str]:
        for node in ast.walk(self.module.tree):
            if isinstance(node, ast.Attribute):
                self.reach(node, node.value, node.attr, ast.unparse(node))
            elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name | ast.Attribute):
                func = ast.unparse(node.func)
                text = node.args[1] if len(node.args) > 1 else None
                by_name = func in ("getattr", "setattr", "hasattr", "delattr")
                if by_name and isinstance(text, ast.Constant) and isinstance(text.value, str):
                    self.reach(node, node.args[0], text.value, ast.unparse(node))
                spec = node.args[0] if node.args else None
                if func in (
                    "importlib.import_module",
                    "import_module",
                    "__import__",
                ) and isinstance(spec, ast.Constant):
                    self.imported(node, str(spec.value))
            elif isinstance(node, ast.ImportFrom) and not node.level:
                for alias in node.names:
                    self.imported(node, f"{node.module}.{alias.name}")
            elif isinstance(node, ast.Import):
                for alias in node.names:
                    self.imported(node, alias.name)
            elif isinstance(node, ast.ClassDef):
                self.overrides(node)
            for text in string_annotations(node):
                for inner in ast.walk(ast.parse(text, mode="eval")):
                    if isinstance(inner, ast.Attribute):
                        inner.lineno = getattr(node, "lineno", 0)
                        self.reach(node, inner.value, inner.attr, ast.unparse(inner))
        return self.found


def assigned_at_module(module: Module) -> set[str]:
    """The names a module binds at its top level other than by import, def, class or annotation."""
    return {
        t.id
        for stmt in module.tree.body
        if isinstance(stmt, ast.Assign | ast.AugAssign | ast.For | ast.With | ast.Try | ast.If)
        for t in ast.walk(stmt)
        if isinstance(t, ast.Name) and not isinstance(t.ctx, ast.Load)
    }


_CHECKERS: dict[str, Checker] = {}
# per (module, class) of the package (a test's snippet is not cached)
_OWN_NAMES: dict[tuple[str, str], set[str]] = {}
_LIBRARY_BASES: dict[tuple[str, str], list[str]] = {}


def checker_of(module: Module, current: Checker) -> Checker:
    """A checker for another of our modules, to read its annotations in its own imports."""
    if module is current.module:
        return current
    if module.name not in _CHECKERS or _CHECKERS[module.name].module is not module:
        _CHECKERS[module.name] = Checker(module, current.modules, ROOT)
    return _CHECKERS[module.name]


def string_annotations(node: ast.AST) -> Iterator[str]:
    """The annotations written as strings on a def, an argument or an annotated assignment."""
    hints: list[ast.expr | None] = []
    if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
        args = node.args
        every = [*args.posonlyargs, *args.args, *args.kwonlyargs, args.vararg, args.kwarg]
        hints = [node.returns, *(a.annotation for a in every if a is not None)]
    elif isinstance(node, ast.AnnAssign):
        hints = [node.annotation]
    for hint in hints:
        for part in ast.walk(hint) if hint is not None else ():
            if isinstance(part, ast.Constant) and isinstance(part.value, str):
                yield part.value


def defined_names(node: ast.ClassDef) -> set[str]:
    """The private names a class's body defines, and its methods set on `self` or `cls`."""
    names: set[str] = set()
    for stmt in node.body:
        if isinstance(stmt, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.add(stmt.name)
        elif isinstance(stmt, ast.Assign | ast.AnnAssign | ast.AugAssign):
            targets = stmt.targets if isinstance(stmt, ast.Assign) else [stmt.target]
            names |= {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
    for part in ast.walk(node):
        if (
            isinstance(part, ast.Attribute)
            and not isinstance(part.ctx, ast.Load)
            and isinstance(part.value, ast.Name)
            and part.value.id in ("self", "cls")
        ):
            names.add(part.attr)
    return {n for n in names if private(n)}


@functools.cache
def library_names(dotted: str) -> frozenset[str]:
    """The private names a library class has: its (inherited) attributes, and what the
    methods of each class in its MRO set on `self` (read from their source where there is one)."""
    parts = dotted.split(".")
    target: object = None
    for cut in range(len(parts), 0, -1):
        try:
            target = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for part in parts[cut:]:
            target = getattr(target, part)
        break
    if not isinstance(target, type):
        return frozenset()
    names = {n for n in dir(target) if private(n)}
    for klass in target.__mro__:
        try:
            source = textwrap.dedent(inspect.getsource(klass))
        except (OSError, TypeError):
            continue
        tree = ast.parse(source)
        names |= {n for c in tree.body if isinstance(c, ast.ClassDef) for n in defined_names(c)}
    return frozenset(names)


def library_privates(path: Path, root: Path = ROOT) -> tuple[list[str], set[str]]:
    """What the widened rule finds in one file, and the `OWN_PRIVATES` entries it used."""
    modules = package_modules()
    module = modules.get(module_name(path, root)) if root == ROOT else None
    if module is None:
        module = Module.parse(module_name(path, root), path)
        modules = {**modules, module.name: module}
    checker = Checker(module, modules, root)
    return checker.run(), checker.used


def package_sources() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if p.name not in GENERATED)


def test_the_package_reaches_no_private_of_a_library_object() -> None:
    found = [line for path in package_sources() for line in library_privates(path)[0]]
    assert found == [], "\n".join(found)


def test_every_listed_own_private_is_still_reached() -> None:
    for where, names in OWN_PRIVATES.items():
        used = library_privates(ROOT / where)[1]
        assert set(names) - used == set(), f"{where}: no longer reached, unlist them"


@pytest.mark.parametrize(
    "code, says",
    [
        (
            "import argparse\ndef add(sub: argparse._SubParsersAction) -> None: ...",
            "`argparse._SubParsersAction` reaches a private of argparse",
        ),
        (
            "import argparse\nsub: 'argparse._SubParsersAction | None' = None",
            "reaches a private of argparse",
        ),
        (
            "from paho.mqtt.client import Client\ndef f(c: Client | None) -> None:\n"
            "    c._out_packet.clear()",
            "`c._out_packet` reaches a private of paho.mqtt.client.Client",
        ),
        ("import can\ncan.Bus(interface='virtual')._is_shutdown", "a private of can.Bus"),
        ("import numpy as np\nx = getattr(np, '_NoValue')", "a private of numpy"),
        (
            "import can\nclass Bus(can.BusABC):\n    def shutdown(self) -> None:\n"
            "        if not self._is_shutdown:\n            super().shutdown()",
            "reaches a private of the library base can.BusABC",
        ),
        (
            "from can import ASCWriter\nclass Writer(ASCWriter):\n"
            "    def _format_header_datetime(self, dt): return ''",
            "redefines can.ASCWriter's private `_format_header_datetime`",
        ),
        ("import numpy._core", "imports the library private `numpy._core`"),
        ("from paho.mqtt.client import _socketpair_compat", "imports the library private"),
        ("import importlib\nimportlib.import_module('numba._helperlib')", "library private"),
        ("def f(items):\n    for x in items:\n        x._secret = 1", "whose private is this?"),
    ],
)
def test_the_package_check_finds_a_private_of_a_library(
    tmp_path: Path, code: str, says: str
) -> None:
    module = tmp_path / "module.py"
    module.write_text(code + "\n")
    found = library_privates(module, tmp_path)[0]
    assert len(found) == 1 and says in found[0], found


@pytest.mark.parametrize(
    "code",
    [
        "from grasplink.gateway.sdo_client import Transfer\n"
        "def f(t: Transfer) -> None:\n    t._toggle ^= 1",
        "class Base:\n    def _step(self) -> None: ...\n"
        "class Child(Base):\n    def _step(self) -> None:\n        super()._step()",
        "from grasplink.profiles.eds import _types",
        "from typing import NamedTuple\nclass P(NamedTuple):\n    a: int\nP(1)._replace(a=2)",
        "import can\nclass Counting(can.Listener):\n    def __init__(self) -> None:\n"
        "        self._seen = 0\n    def on_message_received(self, msg: can.Message) -> None:\n"
        "        self._seen += 1",
        "import can\nclass Bus(can.BusABC):\n    def _recv_internal(self, timeout): ...",
    ],
)
def test_the_package_check_passes_our_own_privates(tmp_path: Path, code: str) -> None:
    module = tmp_path / "module.py"
    module.write_text(code + "\n")
    assert library_privates(module, tmp_path)[0] == []

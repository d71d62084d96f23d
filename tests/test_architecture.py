"""The layering of grasplink, checked from the source (docs/architecture.md, "Dependencies").

Every module under grasplink/ is parsed with `ast`; every import it makes — at
module level, inside functions, under ``if TYPE_CHECKING:``, relative or
absolute, ``from grasplink import x``, and the dynamic forms
``importlib.import_module("grasplink.x")`` and registry strings
``"grasplink.x.y:Class"`` — is mapped to the layer it reaches. A layer may
import its own package and lower ranks only: never a higher rank, never a
sibling of the same rank.
"""

from __future__ import annotations

import ast
import io
import re
import tokenize
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "grasplink"
TOP = "grasplink (top level)"

# Layer -> rank. Top-level modules (cli, demo, controllers, __init__) form one layer.
RANKS: dict[str, int] = {
    "errors": 0,
    "core": 0,
    "profiles": 1,
    "decoding": 2,
    "devices": 2,
    "bus": 3,
    "simulators": 4,
    "gateway": 5,
    "surfaces": 6,
    "evaluation": 7,
    TOP: 8,
}
# The one edge between layers of the same rank: core may raise user errors.
SAME_RANK_ALLOWED = {("core", "errors")}
# A module path the code names in a registry string ("grasplink.x.y:Class").
REGISTRY_STRING = re.compile(r"grasplink(?:\.\w+)+:\w+")


@dataclass(frozen=True)
class Import:
    line: int
    text: str  # the import as written, e.g. "from ..gateway import scripted"
    target: str  # absolute dotted module it reaches


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def layer_of(module: str) -> str:
    """The layer a dotted grasplink module belongs to."""
    parts = module.split(".")
    if len(parts) == 1:
        return TOP  # grasplink/__init__.py
    if parts[1] in RANKS or (PACKAGE / parts[1]).is_dir():
        return parts[1]
    return TOP


def _resolve_from(node: ast.ImportFrom, module: str, is_package: bool) -> list[str]:
    """The absolute modules a ``from X import a, b`` reaches (a, b may be submodules)."""
    if node.level:
        base = module.split(".")
        if not is_package:
            base.pop()
        if node.level > 1:
            base = base[: len(base) - (node.level - 1)]
        prefix = ".".join(base + ([node.module] if node.module else []))
    else:
        prefix = node.module or ""
    if prefix.split(".")[0] != "grasplink":
        return []
    targets = []
    for alias in node.names:
        # `from grasplink import devices` imports the package; `from grasplink import
        # __version__` a name of grasplink/__init__.py.
        sub = ROOT.joinpath(*f"{prefix}.{alias.name}".split("."))
        is_module = sub.is_dir() or sub.with_suffix(".py").is_file()
        targets.append(f"{prefix}.{alias.name}" if is_module else prefix)
    return targets


def _dynamic_target(node: ast.Call) -> str | None:
    """The module of ``importlib.import_module("grasplink...")`` or ``__import__(...)``."""
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
    if name not in {"import_module", "__import__"} or not node.args:
        return None
    arg = node.args[0]
    if isinstance(arg, ast.Constant) and str(arg.value).split(".")[0] == "grasplink":
        return arg.value
    return None


def imports_in(source: str, module: str, is_package: bool = False) -> list[Import]:
    """Every grasplink import in one module's source, wherever it sits."""
    tree = ast.parse(source)
    found: list[Import] = []

    def add(node: ast.AST, targets: list[str]) -> None:
        text = " ".join((ast.get_source_segment(source, node) or "").split())
        found.extend(Import(node.lineno, text, target) for target in targets)

    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            add(node, [a.name for a in node.names if a.name.split(".")[0] == "grasplink"])
        elif isinstance(node, ast.ImportFrom):
            add(node, _resolve_from(node, module, is_package))
        elif isinstance(node, ast.Call) and (target := _dynamic_target(node)):
            add(node, [target])
        elif (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and REGISTRY_STRING.fullmatch(node.value)
        ):
            add(node, [node.value.split(":")[0]])
    return sorted(found, key=lambda i: i.line)


def rule_broken(source_layer: str, target_layer: str) -> str | None:
    """Why `source_layer` may not import `target_layer`, or None if it may."""
    if source_layer == target_layer:
        return None
    for layer in (source_layer, target_layer):
        if layer not in RANKS:
            return (
                f"package {layer!r} has no rank: add it to RANKS in tests/test_architecture.py "
                "and to docs/architecture.md, 'Dependencies'"
            )
    mine, theirs = RANKS[source_layer], RANKS[target_layer]
    if theirs < mine or (source_layer, target_layer) in SAME_RANK_ALLOWED:
        return None
    if theirs == mine:
        return (
            f"{source_layer} (rank {mine}) must not import its sibling {target_layer} "
            f"(rank {theirs}): move what both need down a rank"
        )
    return (
        f"{source_layer} (rank {mine}) must not import {target_layer} (rank {theirs}): "
        "a layer imports lower ranks only"
    )


def module_violations(where: str, module: str, is_package: bool, source: str) -> list[str]:
    """One message per import of `module` that breaks the ranks: file:line, import, rule."""
    found: dict[str, None] = {}  # ordered set: `from x import a, b` breaks a rule once
    for imp in imports_in(source, module, is_package):
        problem = rule_broken(layer_of(module), layer_of(imp.target))
        if problem:
            found[f"{where}:{imp.line}: `{imp.text}` — {problem}"] = None
    return list(found)


def python_files() -> list[Path]:
    return sorted(PACKAGE.rglob("*.py"))


def test_every_import_follows_the_layer_ranks() -> None:
    problems = []
    for path in python_files():
        source = path.read_text(encoding="utf-8")
        where = str(path.relative_to(ROOT))
        problems += module_violations(where, module_name(path), path.name == "__init__.py", source)
    assert not problems, "layering broken (docs/architecture.md, Dependencies):\n" + "\n".join(
        problems
    )


def test_every_package_has_a_rank() -> None:
    packages = {p.parent.name for p in PACKAGE.glob("*/*.py")}
    assert packages - set(RANKS) == set(), "add the new package to RANKS and to the docs"


# -- the checker itself -----------------------------------------------------------------


@pytest.mark.parametrize(
    ("module", "code", "target"),
    [
        ("grasplink.devices.node", "from grasplink.bus import hub", "grasplink.bus.hub"),
        ("grasplink.devices.node", "import grasplink.bus.hub as h", "grasplink.bus.hub"),
        ("grasplink.devices.node", "from ..bus import hub", "grasplink.bus.hub"),
        ("grasplink.devices.node", "from ..bus.hub import CanHub", "grasplink.bus.hub"),
        ("grasplink.devices.node", "from . import store", "grasplink.devices.store"),
        ("grasplink.decoding.kernels.branch", "from ...bus import url", "grasplink.bus.url"),
        ("grasplink.devices.node", "from grasplink import bus", "grasplink.bus"),
        ("grasplink.devices.node", "from grasplink import __version__", "grasplink"),
        ("grasplink.devices.node", "import grasplink", "grasplink"),
        (
            "grasplink.devices.node",
            "def f():\n    from grasplink.gateway import master",
            "grasplink.gateway.master",
        ),
        (
            "grasplink.devices.node",
            "if TYPE_CHECKING:\n    from grasplink.bus import url",
            "grasplink.bus.url",
        ),
        (
            "grasplink.devices.node",
            "import importlib\nm = importlib.import_module('grasplink.bus.hub')",
            "grasplink.bus.hub",
        ),
        ("grasplink.devices.node", "R = {'x': 'grasplink.bus.hub:CanHub'}", "grasplink.bus.hub"),
    ],
)
def test_checker_resolves_every_import_form(module, code, target) -> None:
    assert [i.target for i in imports_in(code, module)] == [target]


def test_checker_resolves_relative_imports_in_a_package_init() -> None:
    found = imports_in("from ..bus import hub", "grasplink.devices", is_package=True)
    assert [i.target for i in found] == ["grasplink.bus.hub"]


def test_checker_ignores_other_packages_and_plain_strings() -> None:
    code = 'import can\nfrom numpy import array\nLOG = "grasplink.bus"\n"""grasplink.bus.hub"""\n'
    assert imports_in(code, "grasplink.devices.node") == []


@pytest.mark.parametrize(
    ("module", "layer"),
    [
        ("grasplink", TOP),
        ("grasplink.cli", TOP),
        ("grasplink.controllers", TOP),
        ("grasplink.errors", "errors"),
        ("grasplink.core.frames", "core"),
        ("grasplink.decoding.io", "decoding"),
        ("grasplink.surfaces.modbus.server", "surfaces"),
        ("grasplink.evaluation.anything", "evaluation"),
    ],
)
def test_modules_map_to_their_layer(module, layer) -> None:
    assert layer_of(module) == layer


@pytest.mark.parametrize(
    ("source", "target", "allowed"),
    [
        ("devices", "profiles", True),
        ("devices", "devices", True),
        ("core", "errors", True),
        ("errors", "core", False),
        ("core", "profiles", False),
        ("profiles", "devices", False),
        ("simulators", "gateway", False),
        ("gateway", "simulators", True),
        ("decoding", "devices", False),
        ("devices", "decoding", False),
        ("gateway", "decoding", True),
        ("decoding", "gateway", False),
        ("surfaces", "gateway", True),
        ("gateway", "surfaces", False),
        ("evaluation", "surfaces", True),
        ("evaluation", "simulators", True),
        ("evaluation", "gateway", True),
        ("gateway", "evaluation", False),
        (TOP, "evaluation", True),
        (TOP, TOP, True),
        ("bus", TOP, False),
        ("newpackage", "core", False),
    ],
)
def test_rule_allows_only_lower_ranks(source, target, allowed) -> None:
    assert (rule_broken(source, target) is None) is allowed


def test_violation_message_names_file_line_import_and_rule() -> None:
    source = '"""doc"""\n\ndef f():\n    from ..devices import skin\n'
    assert module_violations("grasplink/decoding/x.py", "grasplink.decoding.x", False, source) == [
        "grasplink/decoding/x.py:4: `from ..devices import skin` — decoding (rank 2) "
        "must not import its sibling devices (rank 2): move what both need down a rank"
    ]


def test_violation_message_names_an_upward_import() -> None:
    source = "from grasplink.surfaces.telemetry import json_tree\n"
    assert module_violations("grasplink/gateway/x.py", "grasplink.gateway.x", False, source) == [
        "grasplink/gateway/x.py:1: `from grasplink.surfaces.telemetry import json_tree` — "
        "gateway (rank 5) must not import surfaces (rank 6): a layer imports lower ranks only"
    ]


# -- CANopen COB-ID layout lives in grasplink.core ----------------------------------------

# Function codes of the predefined connection set (CiA 301 7.3.3): SYNC/EMCY, TPDOn, RPDOn,
# SDO tx/rx, heartbeat. Written as a 3-digit hex literal they are a CAN-ID.
COB_ID_BASES = frozenset(
    {0x080, 0x180, 0x200, 0x280, 0x300, 0x380, 0x400, 0x480, 0x500, 0x580, 0x600, 0x700}
)
CAN_ID_LITERAL = re.compile(r"0[xX]0?[0-7][0-9a-fA-F]{2}")
# Files allowed to spell COB-IDs: the layout itself, and the EDS text generator.
COB_ID_FILES_ALLOWED = ("grasplink/core/", "grasplink/profiles/edsgen.py")
# 0x200 added to a PDO communication-parameter index is the offset to its mapping
# parameter (1400h -> 1600h, 1800h -> 1A00h), an object-dictionary index, not a CAN-ID.
OD_OFFSET = re.compile(r"comm\w*\s*\+\s*0x200\b")


def hard_coded_cob_ids(where: str, source: str) -> list[str]:
    """`file:line: literal` for each COB-ID base written in code (not strings or comments)."""
    lines = source.splitlines()
    found = []
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type != tokenize.NUMBER or not CAN_ID_LITERAL.fullmatch(tok.string):
            continue
        row = tok.start[0]
        if int(tok.string, 16) in COB_ID_BASES and not OD_OFFSET.search(lines[row - 1]):
            found.append(f"{where}:{row}: {tok.string} in `{lines[row - 1].strip()}`")
    return found


def test_cob_id_bases_are_spelled_only_in_core() -> None:
    found = []
    for path in python_files():
        where = str(path.relative_to(ROOT))
        if not where.startswith(COB_ID_FILES_ALLOWED):
            found += hard_coded_cob_ids(where, path.read_text(encoding="utf-8"))
    assert not found, (
        "CANopen COB-ID bases belong in grasplink.core.frames (import TPDO_BASES, "
        "SDO_TX_BASE, HEARTBEAT_BASE, ...):\n" + "\n".join(found)
    )


def test_cob_id_check_sees_code_but_not_docs_or_od_offsets() -> None:
    source = (
        '"""Answers on 0x580 + node-ID."""\n'
        "SDO = 0x580 + node_id  # from 0x600\n"
        "text = '0x700'\n"
        "mapping = comm + 0x200\n"
        "TPDO1 = 0x180\n"
        "BYTE = 0x80\n"
        "INDEX = 0x1800\n"
        "NODE_10_TPDO1 = 0x190\n"
    )
    assert hard_coded_cob_ids("x.py", source) == [
        "x.py:2: 0x580 in `SDO = 0x580 + node_id  # from 0x600`",
        "x.py:5: 0x180 in `TPDO1 = 0x180`",
    ]


# -- one error hierarchy ------------------------------------------------------------------


def error_classes_outside_errors_py(where: str, source: str, user_errors: set[str]) -> list[str]:
    """`file:line: class X(Base)` for each class that derives from a user error."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.ClassDef):
            bases = {
                b.attr if isinstance(b, ast.Attribute) else getattr(b, "id", "") for b in node.bases
            }
            if bases & user_errors:
                found.append(
                    f"{where}:{node.lineno}: class {node.name}({', '.join(sorted(bases))})"
                )
    return found


def test_every_user_error_class_is_defined_in_errors_py() -> None:
    from grasplink import errors

    user_errors = {
        name
        for name, value in vars(errors).items()
        if isinstance(value, type) and issubclass(value, errors.GrasplinkError)
    }
    found = []
    for path in python_files():
        where = str(path.relative_to(ROOT))
        if where != "grasplink/errors.py":
            found += error_classes_outside_errors_py(where, path.read_text("utf-8"), user_errors)
    assert not found, "define user errors in grasplink/errors.py:\n" + "\n".join(found)


def test_error_class_check_sees_direct_and_qualified_bases() -> None:
    source = (
        "class A(GrasplinkError): pass\n"
        "class B(errors.ConfigError): pass\n"
        "class C(Exception): pass\n"
    )
    assert error_classes_outside_errors_py("x.py", source, {"GrasplinkError", "ConfigError"}) == [
        "x.py:1: class A(GrasplinkError)",
        "x.py:2: class B(ConfigError)",
    ]


def test_scene_mistakes_are_configuration_errors() -> None:
    from grasplink.errors import ConfigError, GrasplinkError, RecordingError, SceneError

    error = SceneError("scenes/slip.toml", "effects[2].speed_mm_s", "expected a number >= 0")
    assert isinstance(error, ConfigError)
    assert str(error) == "scenes/slip.toml: effects[2].speed_mm_s: expected a number >= 0"
    assert issubclass(RecordingError, GrasplinkError)


def test_docs_list_every_user_error() -> None:
    from grasplink import errors

    doc = (ROOT / "docs" / "architecture.md").read_text(encoding="utf-8")
    section = doc.split("## Errors", 1)[1].split("\n## ", 1)[0]
    missing = [
        name
        for name, value in vars(errors).items()
        if isinstance(value, type)
        and issubclass(value, errors.GrasplinkError)
        and not re.search(rf"\b{name}\b", section)
    ]
    assert not missing, f"docs/architecture.md, 'Errors' does not list {missing}"

"""The surfaces use the public APIs of the libraries they drive (aiomqtt, paho-mqtt, pymodbus):
no name starting with `_` is reached on any object but the code's own `self` or `cls`,
none is imported, and none of pymodbus's connection internals (its request handler, the
transaction manager, the framers) is imported to be overridden. A library upgrade may still
change a public API, but then it says so in its changelog."""

from __future__ import annotations

import ast
from collections.abc import Iterator
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

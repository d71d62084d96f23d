"""Classes registered by name as "module:Class", imported when first asked for.

Decoders, controllers and other pluggable parts are named in configuration
files; importing them lazily keeps the start-up cheap and makes a missing
or broken module fail only when it is asked for, with an error naming it.
"""

from __future__ import annotations

import importlib
from collections.abc import Iterable, Mapping

from grasplink.errors import ConfigError


def load_class(
    what: str, table: Mapping[str, str], name: str, *, also_valid: Iterable[str] = ()
) -> type:
    """The class `table[name]` names ("module:Class"); ConfigError if unknown or missing.

    `what` names the kind of thing in messages ("decoder", "controller"); `also_valid` lists
    names the caller handles itself (shown as valid, never looked up here).
    """
    if name not in table:
        known = ", ".join([*table, *also_valid])
        raise ConfigError(f"unknown {what} {name!r}; valid {what}s: {known}")
    module_name, _, class_name = table[name].partition(":")
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is not None and module_name.startswith(exc.name):
            raise ConfigError(
                f"{what} {name!r} is not available: module {module_name} is not installed"
            ) from None
        raise
    cls: type | None = getattr(module, class_name, None)
    if cls is None:
        raise ConfigError(f"{what} {name!r} is not available: {module_name} has no {class_name}")
    return cls

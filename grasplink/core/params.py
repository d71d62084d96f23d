"""Reading configuration tables (scene files, controller options) with errors naming file and key.

Every scene value passes through `Params`, which knows where it came from
(`scenes/slip.toml`, `effects[2].speed_mm_s`) so a mistake is reported as
`scenes/slip.toml: effects[2].speed_mm_s: expected a number >= 0, got -3`.
Unknown keys are errors too: a misspelt parameter must not silently fall
back to a default.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from typing import Any, overload

from grasplink.errors import SceneError as SceneError  # with every user error; re-exported here

_MISSING = object()


class Params:
    """A table of a scene file, consumed key by key."""

    def __init__(self, table: dict[str, Any], source: str, prefix: str = ""):
        if not isinstance(table, dict):
            raise SceneError(source, prefix, f"expected a table, got {_describe(table)}")
        self.table = table
        self.source = source
        self.prefix = prefix
        self._used: set[str] = set()

    def key(self, name: str) -> str:
        return f"{self.prefix}.{name}" if self.prefix else name

    def error(self, name: str, problem: str) -> SceneError:
        return SceneError(self.source, self.key(name), problem)

    def has(self, name: str) -> bool:
        return name in self.table

    def _get(self, name: str, default: Any) -> Any:
        self._used.add(name)
        if name in self.table:
            return self.table[name]
        if default is _MISSING:
            raise self.error(name, "is required")
        return default

    @overload
    def number(
        self,
        name: str,
        default: float = ...,
        *,
        low: float | None = None,
        high: float | None = None,
        low_open: bool = False,
    ) -> float: ...

    @overload
    def number(
        self,
        name: str,
        default: None,
        *,
        low: float | None = None,
        high: float | None = None,
        low_open: bool = False,
    ) -> float | None: ...

    def number(
        self,
        name: str,
        default: Any = _MISSING,
        *,
        low: float | None = None,
        high: float | None = None,
        low_open: bool = False,
    ) -> float | None:
        """A number within bounds; None only when absent and the default is None."""
        value = self._get(name, default)
        if value is None:
            return value
        return self._check_number(name, value, low, high, low_open)

    def integer(
        self, name: str, default: Any = _MISSING, *, low: int | None = None, high: int | None = None
    ) -> int:
        value = self._get(name, default)
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, f"expected an integer, got {_describe(value)}")
        return int(self._check_number(name, value, low, high, False))

    def boolean(self, name: str, default: Any = _MISSING) -> bool:
        value = self._get(name, default)
        if not isinstance(value, bool):
            raise self.error(name, f"expected true or false, got {_describe(value)}")
        return value

    @overload
    def string(
        self, name: str, default: str = ..., *, choices: Sequence[str] | None = None
    ) -> str: ...

    @overload
    def string(
        self, name: str, default: None, *, choices: Sequence[str] | None = None
    ) -> str | None: ...

    def string(
        self, name: str, default: Any = _MISSING, *, choices: Sequence[str] | None = None
    ) -> str | None:
        """A string (one of `choices`); None only when absent and the default is None."""
        value = self._get(name, default)
        if value is None and default is None:
            return None  # optional and absent
        if not isinstance(value, str):
            raise self.error(name, f"expected a string, got {_describe(value)}")
        if choices is not None and value not in choices:
            raise self.error(
                name, f"expected one of {', '.join(map(repr, choices))}, got {value!r}"
            )
        return value

    def numbers(
        self,
        name: str,
        default: Any = _MISSING,
        *,
        low: float | None = None,
        high: float | None = None,
        low_open: bool = False,
        min_len: int = 1,
    ) -> tuple[float, ...]:
        value = self._get(name, default)
        if not isinstance(value, list) or len(value) < min_len:
            raise self.error(
                name, f"expected a list of at least {min_len} numbers, got {_describe(value)}"
            )
        return tuple(
            self._check_number(f"{name}[{i}]", v, low, high, low_open) for i, v in enumerate(value)
        )

    def pairs(
        self,
        name: str,
        default: Any = _MISSING,
        *,
        low: float | None = None,
        high: float | None = None,
        integer: bool = False,
        what: str = "value",
    ) -> tuple[tuple[float, float], ...]:
        """A list of [time_s, value] pairs (a profile over time), values within bounds."""
        value = self._get(name, default)
        if not isinstance(value, list) or not value:
            raise self.error(
                name, f"expected a list of [time_s, value] pairs, got {_describe(value)}"
            )
        out = []
        for i, item in enumerate(value):
            if not isinstance(item, list) or len(item) != 2:
                raise self.error(
                    f"{name}[{i}]", f"expected a [time_s, value] pair, got {_describe(item)}"
                )
            value = self._check_number(f"{name}[{i}][1]", item[1], None, None, False)
            out_of_range = (low is not None and value < low) or (high is not None and value > high)
            if out_of_range or (integer and not float(value).is_integer()):
                span = f"{low:g}..{high:g}" if high is not None else f">= {low:g}"
                kind = "an integer " if integer else "a "
                raise self.error(f"{name}[{i}][1]", f"expected {kind}{what} {span}, got {value:g}")
            out.append((self._check_number(f"{name}[{i}][0]", item[0], 0.0, None, False), value))
        times = [t for t, _ in out]
        if any(b <= a for a, b in itertools.pairwise(times)):
            raise self.error(name, "times must increase strictly")
        return tuple(out)

    def table_of(self, name: str, default: Any = _MISSING) -> Params:
        value = self._get(name, default)
        return Params(value if value is not None else {}, self.source, self.key(name))

    def raw(self, name: str, default: Any = _MISSING) -> Any:
        return self._get(name, default)

    def finish(self) -> None:
        """Refuse keys nobody asked for (typos must not fall back to defaults)."""
        unknown = sorted(set(self.table) - self._used)
        if unknown:
            known = ", ".join(sorted(self._used)) or "none"
            raise self.error(unknown[0], f"unknown key (known here: {known})")

    def _check_number(
        self, name: str, value: Any, low: float | None, high: float | None, low_open: bool
    ) -> float:
        if not isinstance(value, int | float) or isinstance(value, bool):
            raise self.error(name, f"expected a number, got {_describe(value)}")
        if not math.isfinite(value):
            raise self.error(name, f"expected a finite number, got {value}")
        if low is not None and (value < low or (low_open and value == low)):
            bound = f"> {low:g}" if low_open else f">= {low:g}"
            raise self.error(name, f"expected a number {bound}, got {value:g}")
        if high is not None and value > high:
            raise self.error(name, f"expected a number <= {high:g}, got {value:g}")
        return value


def _describe(value: Any) -> str:
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, str):
        return f"the string {value!r}"
    return repr(value)

"""Markdown for the benchmark docs: tables from rows of cells, numbers with their units.

Every benchmark renders its doc from its figures JSON with these, so a table is a list
of rows in the code, never a hand-built `| a | b |` line, and the number formats (a
dash for what was not measured, spaces between thousands) are the same in every doc.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

ALIGN = {"l": "---", "r": "---:", "c": ":---:"}


def row(cells: Sequence[object]) -> str:
    """One table row; an empty cell is a single space, as `| a | |`."""
    return "|" + "|".join(f" {cell} " if str(cell) else " " for cell in cells) + "|"


def table(headers: Sequence[str], rows: Iterable[Sequence[object]], align: str = "") -> list[str]:
    """A table's lines: header, separator, rows.

    `align` has a letter per column, l (default), r or c; columns past its end are l.
    Cells are written with `str`, so numbers should be formatted before (`number`).
    """
    alignment = align.ljust(len(headers), "l")
    lines = [row(headers), "|" + "|".join(ALIGN[a] for a in alignment) + "|"]
    for cells in rows:
        if len(cells) != len(headers):
            raise ValueError(f"{len(cells)} cells for {len(headers)} columns: {cells!r}")
        lines.append(row(cells))
    return lines


def missing(value: float | None) -> bool:
    """Not measured: None or NaN."""
    return value is None or (isinstance(value, float) and math.isnan(value))


def number(value: float | None, digits: int = 0, unit: str = "") -> str:
    """`value` with `digits` decimals and spaces between thousands, then its unit; "-" if
    it was not measured."""
    if missing(value):
        return "-"
    assert value is not None
    text = f"{value:,.{digits}f}".replace(",", " ")
    return f"{text} {unit}" if unit else text


def signed(value: float | None, digits: int = 0, unit: str = "") -> str:
    """As `number`, always with its sign (a difference: "+12", "-3")."""
    if missing(value):
        return "-"
    assert value is not None
    text = f"{value:+,.{digits}f}".replace(",", " ")
    return f"{text} {unit}" if unit else text


def block(text: str) -> list[str]:
    """A prose block's lines: a triple-quoted string written flush left, without its
    first newline (so the source reads as the doc does)."""
    return text.removeprefix("\n").splitlines()

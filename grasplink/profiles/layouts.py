"""Named ridge layouts of the skin sensor (thesis ch. 5, table 5.1).

A layout is the list of spacings between successive ridges, in mm, along an
84 mm skin. The skin node stores the spacings in 0x2140 (in µm, at most
`MAX_NODE_SPACINGS`) and the preset number in 0x2141, so a layout given on
the command line or in a scene file has to be turned into those numbers; this
module is the one place that knows the names, the layout files (`PATH.toml`
with `spacings_mm = [...]`, as `grasplink skin design` writes them) and
checks user input.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

from grasplink.errors import ConfigError

#: Spacings in mm. The α layouts come from the thesis's genetic search
#: (fitness α·accuracy + (1 − α)·resolution); fibonacci is its reference
#: layout; uniform4 is the best uniform skin of ch. 4 (D = 4 mm).
LAYOUTS_MM: dict[str, tuple[float, ...]] = {
    "alpha0.1": (19.0, 12.0, 5.0, 8.0, 4.0, 3.0, 33.0),
    "alpha0.3": (4.0, 3.0, 48.0, 29.0),
    "alpha0.5": (5.0, 12.0, 67.0),
    "alpha0.7": (7.0, 64.0, 13.0),
    "alpha0.9": (6.0, 20.0, 58.0),
    "fibonacci": (5.0, 34.0, 21.0, 8.0, 3.0, 13.0),
    "uniform4": (4.0,) * 21,
}

#: Values of the skin node's 0x2141 "Ridge layout preset"; 0 means custom
#: (the spacings in 0x2140 are authoritative).
PRESET_CODES: dict[int, str] = {code: name for code, name in enumerate(LAYOUTS_MM, start=1)}
CUSTOM_PRESET = 0

#: Spacing sub-indices in 0x2140: room for every named layout (uniform4 has
#: 21) and for a 2.5 mm pitch over the 84 mm skin (34).
MAX_NODE_SPACINGS = 40


MIN_SPACING_MM = 0.1
MAX_SPACING_MM = 1000.0


LAYOUT_FILE_SUFFIX = ".toml"
LAYOUT_FILE_KEYS = ("spacings_mm", "design")  # the layout, and how it was found (not read)


def parse_layout(text: str) -> tuple[float, ...]:
    """Turn a layout name, "19,12,5" (mm) or a layout file PATH.toml into spacings in mm.

    Raises ConfigError naming the offending value (and file), so a typo in a
    command line reports what was wrong rather than a bare ValueError. More
    than `MAX_NODE_SPACINGS` spacings are accepted here (simulators can use
    them); only the node's object dictionary is limited. A relative PATH is
    taken from the current folder.
    """
    stripped = text.strip()
    if not stripped:
        raise ConfigError("ridge layout is empty; give a name or comma-separated spacings in mm")
    if stripped in LAYOUTS_MM:
        return LAYOUTS_MM[stripped]
    if stripped.lower().endswith(LAYOUT_FILE_SUFFIX):
        return read_layout_file(Path(stripped))
    if "," not in stripped and not _is_number(stripped):
        raise ConfigError(
            f"unknown ridge layout {stripped!r}; valid names: {', '.join(LAYOUTS_MM)} "
            "(or comma-separated spacings in mm)"
        )
    spacings: list[float] = []
    for position, item in enumerate(stripped.split(","), start=1):
        spacings.append(_parse_spacing(item.strip(), position))
    return tuple(spacings)


def read_layout_file(path: Path) -> tuple[float, ...]:
    """The spacings of a layout file: `spacings_mm = [19, 12, 5]` (a `[design]` table may
    say how they were found; any other key is an error, so a misspelt key is not ignored)."""
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"ridge layout file {path}: not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"ridge layout file {path}: cannot be read ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"ridge layout file {path}: not valid TOML ({exc})") from None
    unknown = [key for key in data if key not in LAYOUT_FILE_KEYS]
    if unknown:
        raise ConfigError(
            f"ridge layout file {path}: unknown key {unknown[0]!r}; expected spacings_mm = [...] "
            "(and an optional [design] table)"
        )
    values = data.get("spacings_mm")
    if not isinstance(values, list) or not values:
        raise ConfigError(
            f"ridge layout file {path}: spacings_mm must be a non-empty list of spacings in mm, "
            "e.g. spacings_mm = [19, 12, 5]"
        )
    spacings = []
    for position, value in enumerate(values, start=1):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(
                f"ridge layout file {path}: spacings_mm #{position} {value!r} is not a number (mm)"
            )
        try:
            spacings.append(_parse_spacing(repr(float(value)), position))
        except ConfigError as exc:
            raise ConfigError(f"ridge layout file {path}: {exc}") from None
    return tuple(spacings)


def spacings_um(spacings_mm: tuple[float, ...]) -> tuple[int, ...]:
    """Spacings rounded to whole µm, the unit of the node's 0x2140 entries."""
    return tuple(round(s * 1000) for s in spacings_mm)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _parse_spacing(item: str, position: int) -> float:
    if not item:
        raise ConfigError(f"ridge spacing #{position} is empty")
    try:
        value = float(item)
    except ValueError:
        raise ConfigError(f"ridge spacing #{position} {item!r} is not a number (mm)") from None
    if not math.isfinite(value):
        raise ConfigError(f"ridge spacing #{position} {item!r} is not a finite number")
    if not MIN_SPACING_MM <= value <= MAX_SPACING_MM:
        raise ConfigError(
            f"ridge spacing #{position} {item!r} must be {MIN_SPACING_MM:g}..{MAX_SPACING_MM:g} mm "
            "(a ridge is wider than 0.1 mm; a fingertip or palm skin is far shorter than 1 m)"
        )
    return value

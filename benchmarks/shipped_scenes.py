"""The shipped scenes by name, for the benchmark scripts: a name that names no scene file
is one clear error (the names, and where they were looked for) before any work starts."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def scene_paths(names: Iterable[str]) -> list[Path]:
    """scenes/NAME.toml for each name; SystemExit naming every one that is missing."""
    paths = [SCENES / f"{name}.toml" for name in names]
    missing = [p.stem for p in paths if not p.is_file()]
    if missing:
        raise SystemExit(f"no scene {', '.join(map(repr, missing))} in {SCENES}")
    return paths


def scene_path(name: str) -> Path:
    """scenes/NAME.toml; SystemExit naming it when there is no such file."""
    return scene_paths([name])[0]

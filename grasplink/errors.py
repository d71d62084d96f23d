"""User-facing errors.

Every error a user can cause (a bad file, a bad option, an unreachable hub)
is a `GrasplinkError` whose message names the problem; the CLI prints it and
exits non-zero without a traceback.
"""

from __future__ import annotations


class GrasplinkError(Exception):
    """An error caused by input or environment, reported without traceback."""


class EdsError(GrasplinkError):
    """A malformed or inconsistent EDS; names the file, section and key."""

    def __init__(self, path: str, section: str | None, key: str | None, problem: str):
        self.path, self.section, self.key, self.problem = path, section, key, problem
        where = path
        if section:
            where += f" [{section}]"
        if key:
            where += f" {key}"
        super().__init__(f"{where}: {problem}")


class ConfigError(GrasplinkError):
    """An invalid option or configuration value."""


class BusError(GrasplinkError):
    """A bus that cannot be opened or reached."""

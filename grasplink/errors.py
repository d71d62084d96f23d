"""User-facing errors: the one hierarchy every package raises from.

Every error a user can cause (a bad file, a bad option, an unreachable hub)
is a `GrasplinkError` whose message names the problem; the CLI prints it on
one line and exits 1 without a traceback. Keeping every class here lets any
layer raise or catch them without importing another layer::

    GrasplinkError
    ├── EdsError         a malformed or inconsistent EDS (file and line, section, key)
    ├── ConfigError      an invalid option or configuration value
    │   └── SceneError   a scene file value (file, key, what was expected)
    ├── RecordingError   a recording that cannot be read (file, line or key)
    ├── BusError         a bus that cannot be opened or reached
    ├── BrokerError      an MQTT broker that cannot be reached or refuses the connection
    └── PdoError         a PDO that does not fit its mapping (length, range, type)

Protocol-level and private control-flow exceptions are not user errors and
stay beside their code (see docs/architecture.md, "Errors").
"""

from __future__ import annotations


class GrasplinkError(Exception):
    """An error caused by input or environment, reported without traceback."""


class EdsError(GrasplinkError):
    """A malformed or inconsistent EDS; names the file (and line), section and key."""

    def __init__(
        self,
        path: str,
        section: str | None,
        key: str | None,
        problem: str,
        line: int | None = None,
    ):
        self.path, self.section, self.key, self.problem = path, section, key, problem
        self.line = line
        where = path if line is None else f"{path}:{line}"
        if section:
            where += f" [{section}]"
        if key:
            where += f" {key}"
        super().__init__(f"{where}: {problem}")


class ConfigError(GrasplinkError):
    """An invalid option or configuration value."""


class SceneError(ConfigError):
    """An invalid scene-file value; names the file, the key and what was expected.

    A ConfigError because a scene is configuration: code that refuses bad
    configuration in general catches scene mistakes too.
    """

    def __init__(self, source: str, key: str, problem: str):
        self.source, self.key, self.problem = source, key, problem
        super().__init__(f"{source}: {key}: {problem}" if key else f"{source}: {problem}")


class RecordingError(GrasplinkError):
    """A recording file that cannot be read; the message names file and line, key or value."""


class BusError(GrasplinkError):
    """A bus that cannot be opened or reached."""


class BrokerError(GrasplinkError):
    """An MQTT broker (telemetry) that cannot be reached, or refuses us (credentials, TLS)."""


class PdoError(GrasplinkError):
    """A PDO that cannot be packed or unpacked through its mapping (length, range, type)."""

"""The device-specific half of a node: what the skin, EMG, belt or hand *does*.

`DeviceNode` handles the protocol; a `DeviceApp` reads its configuration
from the store, produces process data (setting mapped objects and asking
for TPDOs), and reacts to RPDO writes and NMT changes. It is sans-IO too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from grasplink.core.frames import Frame
from grasplink.core.nmt import NmtState

if TYPE_CHECKING:
    from grasplink.devices.node import DeviceNode


class DeviceApp:
    """Base application: does nothing (a bare communication-only device)."""

    node: DeviceNode

    def attach(self, node: DeviceNode) -> None:
        self.node = node
        self.store = node.store

    def on_reset(self, t_us: int) -> None:
        """Reset application: the store holds defaults (and stored parameters) again."""

    def on_state(self, state: NmtState, t_us: int) -> None:
        """NMT state changed."""

    def on_rpdo(self, number: int, t_us: int) -> None:
        """An RPDO wrote its mapped objects into the store."""

    def enter_safe_state(self, t_us: int, reason: str) -> None:
        """Communication with the master is lost: go to the safe state."""

    def advance(self, t_us: int) -> list[Frame]:
        """Run behaviour up to t_us; return TPDO frames it triggered."""
        return []

    def next_deadline_us(self) -> int | None:
        return None

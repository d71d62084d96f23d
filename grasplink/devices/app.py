"""The device-specific half of a node: what the skin, EMG, belt or hand *does*.

`DeviceNode` handles the protocol; a `DeviceApp` reads its configuration
from the store, produces process data (setting mapped objects and asking
for TPDOs), and reacts to RPDO writes and NMT changes. It is sans-IO too.
An application sees its node only through `AppServices`: the store, the
NMT state, the clock, TPDO requests and EMCY — the few things firmware
gives an application task, so an app cannot reach into the protocol engines.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

from grasplink.core.frames import Frame
from grasplink.core.nmt import NmtState
from grasplink.devices.store import Key, ObjectStore, Value


class AppServices(Protocol):
    """What a node offers its application."""

    store: ObjectStore

    @property
    def nmt_state(self) -> NmtState:
        """The node's NMT state (process data flows only in OPERATIONAL)."""
        ...

    def now_us(self) -> int:
        """The time of the call the node is handling (a frame, a tick, a store change)."""
        ...

    def transmit_tpdo(self, number: int, t_us: int) -> list[Frame]:
        """Send TPDO `number` now, its inhibit time permitting."""
        ...

    def tpdo_enabled(self, number: int) -> bool:
        """Whether TPDO `number` exists and its COB-ID is valid."""
        ...

    def raise_error(self, code: int, register_bit: int, t_us: int, data: bytes = b"") -> None:
        """Signal an error through EMCY and the error register (1001h)."""
        ...

    def clear_error(self, code: int, t_us: int) -> None:
        """The error `code` went away (EMCY error reset once none is left)."""
        ...

    def error_active(self, code: int) -> bool: ...

    def direct_tpdo(
        self, number: int, given: tuple[Key, ...], unmapped: tuple[Key, ...] = ()
    ) -> Callable[..., Frame] | None:
        """TPDO `number`'s frame as a function of the objects `given`, when a trigger
        right after writing them sends it at once and changes nothing else (a stream told
        ahead packs its packets without the store; `PdoEngine.direct_tpdo`), else None."""
        ...

    def sent_directly(self, number: int, t_us: int) -> None:
        """Frames `direct_tpdo` made went out, the last at `t_us`."""
        ...


@dataclass(slots=True)
class StreamSpan:
    """An application's ticks told ahead: what `advance` returns at each, and the objects
    it writes with their values after each (what its node's timers send in between, say
    an event-timer TPDO of the newest sample count, is packed from these)."""

    times_us: list[int]
    frames: list[list[Frame]]
    keys: tuple[Key, ...]
    values: list[tuple[Value, ...]]
    next_us: int  # its first tick not told: the span holds before it only


class DeviceApp:
    """Base application: does nothing (a bare communication-only device)."""

    services: AppServices
    store: ObjectStore
    # TPDOs that stream samples: never re-sent on entering OPERATIONAL (stale samples).
    streamed_tpdos: tuple[int, ...] = ()
    # TPDOs whose every trigger is a new packet of a stream: made synchronous while the
    # manufacturer switch `packets_on_sync` (index, subindex) is 1, they carry every packet
    # since the last due SYNC on it, not only the newest (devices/pdo.py).
    packet_tpdos: tuple[int, ...] = ()
    packets_on_sync: tuple[int, int] | None = None

    def attach(self, services: AppServices) -> None:
        self.services = services
        self.store = services.store

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

    def stream_until_us(self, t_us: int) -> int | None:
        """How far `stream_ahead(t_us, until_us)` must reach to tell anything (None: it
        tells nothing now); see `core.protocol.StreamingDevice.stream_until_us`."""
        return None

    def stream_ahead(self, t_us: int, until_us: int) -> StreamSpan | None:
        """Its ticks from its deadline (not before `t_us`) up to `until_us` told ahead, when
        nothing else reaches it meanwhile (`core.protocol.StreamingDevice`): what `advance`
        would return at each, changing nothing yet. None: ticked one by one."""
        return None

    def commit_stream(self, ticks: int) -> None:
        """The first `ticks` ticks of the last `stream_ahead` happened (0: none did): the
        application is as after `advance` at each."""

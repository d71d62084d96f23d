"""Give unconfigured nodes their node-IDs over LSS (CiA 305), as a CiA 302 master does at boot.

python-canopen's `LssMaster` speaks the protocol; this module decides what to
say. Fastscan finds every node without a node-ID; each one found stays in the
LSS configuration state, so the next scan finds the next. Then, back in the
waiting state, each node whose identity the caller names is selected by its
full LSS address (switch state selective), given its node-ID, told to store
it, and switched back to waiting, where it boots with it. A node nobody named
is reported, never left unconfigured in silence.

Blocking, on python-canopen's notifier thread: call it before the gateway's
loop starts, with a `canopen.Network` connected to the bus. Each exchange
waits at most `network.lss.RESPONSE_TIMEOUT` (0.5 s by default); fastscan
costs one such wait per identity bit that is 1, so a scan takes a few seconds
and its length, not the deadline, bounds an exchange already under way.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import NamedTuple, Protocol

import canopen
from canopen.lss import LssError

from grasplink.errors import ConfigError
from grasplink.gateway.config import GatewayConfig

log = logging.getLogger(__name__)

DEFAULT_DEADLINE_S = 120.0
MAX_NODES = 127  # more unconfigured nodes than node-IDs cannot all be assigned
# A fastscan that finds nobody is tried again once: a reply lost to a loaded bus or
# host looks exactly like no node (python-canopen returns False for both).
SCAN_ATTEMPTS = 2


class LssMasterApi(Protocol):
    """The part of python-canopen's `LssMaster` (public, untyped) used here, typed."""

    WAITING_STATE: int

    def send_switch_state_global(self, mode: int, /) -> None: ...
    def send_switch_state_selective(
        self, vendor_id: int, product_code: int, revision: int, serial: int, /
    ) -> bool: ...
    def fast_scan(self) -> tuple[bool, list[int] | None]: ...
    def configure_node_id(self, node_id: int, /) -> None: ...
    def store_configuration(self) -> None: ...


class LssAddress(NamedTuple):
    """A node's LSS address: its identity object 1018h, sub-indices 1 to 4."""

    vendor_id: int
    product_code: int
    revision: int
    serial: int

    def __str__(self) -> str:
        return (
            f"vendor 0x{self.vendor_id:08X} product 0x{self.product_code:08X} "
            f"revision 0x{self.revision:08X} serial 0x{self.serial:08X}"
        )


@dataclass
class LssReport:
    """What one `assign_node_ids` run did, node by node."""

    assigned: dict[LssAddress, int] = field(default_factory=dict)  # stored and booting
    unknown: list[LssAddress] = field(default_factory=list)  # found, named by nobody
    missing: list[LssAddress] = field(default_factory=list)  # named, not found unconfigured
    failed: dict[LssAddress, str] = field(default_factory=dict)  # named, found, refused
    not_stored: list[LssAddress] = field(default_factory=list)  # assigned, lost at power-off
    # False when the deadline or MAX_NODES ended the scan: more nodes may be waiting
    complete: bool = False

    @property
    def ok(self) -> bool:
        """Every unconfigured node had a wanted node-ID and took it for good."""
        return self.complete and not (self.unknown or self.failed or self.not_stored)

    def summary(self) -> str:
        parts = [f"LSS: {len(self.assigned)} node-ID(s) assigned"]
        parts += [f"0x{node_id:02X} to {a}" for a, node_id in self.assigned.items()]
        parts += [f"unknown unconfigured node: {a}" for a in self.unknown]
        parts += [f"{a} refused: {why}" for a, why in self.failed.items()]
        parts += [f"{a} did not store its node-ID" for a in self.not_stored]
        parts += [f"not found unconfigured: {a}" for a in self.missing]
        if not self.complete:
            parts.append("scan stopped before the last node (time or node limit)")
        return "; ".join(parts)


def check_assignments(wanted: Mapping[LssAddress, int]) -> None:
    """Node-IDs in 1..127, each given once: refused before the bus is touched."""
    seen: dict[int, LssAddress] = {}
    for address, node_id in wanted.items():
        if isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127:
            raise ConfigError(f"LSS: node-ID {node_id!r} for {address} is outside 1..127")
        if node_id in seen:
            raise ConfigError(
                f"LSS: node-ID 0x{node_id:02X} wanted for both {seen[node_id]} and {address}"
            )
        seen[node_id] = address


def assign_node_ids(
    network: canopen.Network,
    wanted: Mapping[LssAddress, int],
    *,
    deadline_s: float = DEFAULT_DEADLINE_S,
    max_nodes: int = MAX_NODES,
    clock: Callable[[], float] = time.monotonic,
) -> LssReport:
    """Fastscan every unconfigured node, give the `wanted` ones their node-IDs; see module."""
    check_assignments(wanted)
    lss: LssMasterApi = network.lss
    end = clock() + deadline_s
    report = LssReport()
    # Start from a known state: every node waiting (a node some earlier master left
    # in configuration with a pending node-ID boots with it now, as CiA 305 says).
    lss.send_switch_state_global(lss.WAITING_STATE)
    found = _scan(lss, max_nodes, end, clock, report)
    lss.send_switch_state_global(lss.WAITING_STATE)  # the found nodes wait again, unconfigured
    for address in found:
        node_id = wanted.get(address)
        if node_id is None:
            report.unknown.append(address)
        elif clock() >= end:
            report.failed[address] = f"no time left (deadline {deadline_s:g} s)"
        else:
            _assign(lss, address, node_id, report)
    report.missing = [a for a in wanted if a not in found]
    log.info("%s", report.summary())
    return report


def _scan(
    lss: LssMasterApi,
    max_nodes: int,
    end: float,
    clock: Callable[[], float],
    report: LssReport,
) -> list[LssAddress]:
    found: list[LssAddress] = []
    misses = 0
    while len(found) < max_nodes and clock() < end:
        hit, identity = lss.fast_scan()
        if hit and identity is not None:
            found.append(LssAddress(*identity))
            misses = 0
            continue
        misses += 1
        if misses >= SCAN_ATTEMPTS:
            report.complete = True
            break
    return found


def _assign(lss: LssMasterApi, address: LssAddress, node_id: int, report: LssReport) -> None:
    try:
        if not lss.send_switch_state_selective(*address):
            report.failed[address] = "answered switch state selective with another frame"
            return
        lss.configure_node_id(node_id)
        try:
            lss.store_configuration()
        except LssError as exc:
            log.warning(
                "LSS: %s took node-ID 0x%02X but did not store it: %s", address, node_id, exc
            )
            report.not_stored.append(address)
        report.assigned[address] = node_id
    except LssError as exc:
        report.failed[address] = str(exc)
    finally:
        lss.send_switch_state_global(lss.WAITING_STATE)  # boots with its node-ID


def wanted_from(config: GatewayConfig) -> dict[LssAddress, int]:
    """The description's nodes that LSS can address: those whose identity names all of
    vendor, product, revision and serial (an LSS address), with their node-IDs."""
    wanted = {}
    for node in config.nodes.values():
        expected = dict(node.identity.expected) if node.identity is not None else {}
        if len(expected) == len(LssAddress._fields):
            wanted[LssAddress(*(expected[sub] for sub in (1, 2, 3, 4)))] = node.node_id
    return wanted


def assign_at_start(bus_url: str, config: GatewayConfig) -> LssReport:
    """`[gateway] lss = true`: before the gateway's loop, give every unconfigured node the
    description names its node-ID, on a bus handle of its own (python-canopen's)."""
    from grasplink.bus.url import open_bus

    network = canopen.Network(open_bus(bus_url))
    network.connect()
    try:
        return assign_node_ids(network, wanted_from(config))
    finally:
        network.disconnect()

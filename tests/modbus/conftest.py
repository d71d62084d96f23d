"""Fixtures for the Modbus tests: a live gateway with its nodes, served on a free port.

Servers bind 127.0.0.1 port 0 (any free port), so parallel workers never collide; each
virtual CAN channel is named uniquely within its process.
"""

from __future__ import annotations

import subprocess
import uuid
from collections.abc import Iterator

import pytest

from grasplink.gateway.config import parse_config
from grasplink.gateway.live import LiveGateway
from grasplink.surfaces.modbus.registers import register_map
from grasplink.surfaces.modbus.server import ModbusServer
from tests.live import operational, wait_until

RMAP = register_map()
ALL_NODES = 0b1111


def node_of(live: LiveGateway, kind: str):
    """The device node of `kind` running beside the gateway (--with-nodes)."""
    node_id = live.config.nodes[kind].node_id
    return next(d for r in live._runners for d in r.devices if getattr(d, "node_id", 0) == node_id)


@pytest.fixture(scope="module")
def live_modbus() -> Iterator[tuple[LiveGateway, ModbusServer]]:
    """The live gateway with its four nodes on the embedded bus and its Modbus server."""
    channel = f"virtual:modbus-{uuid.uuid4().hex[:12]}"
    with (
        LiveGateway(channel, parse_config({}, "<test>"), with_nodes=True) as live,
        ModbusServer(live.edge, "tcp://127.0.0.1:0") as server,
    ):
        wait_until(lambda: operational(live.gateway), what="every node operational")
        yield live, server


def mbpoll(*args: str, timeout: float = 20.0) -> subprocess.CompletedProcess[str]:
    """mbpoll once (-1) with PDU addressing (-0), output captured."""
    return subprocess.run(
        ["mbpoll", "-0", "-1", *args], capture_output=True, text=True, timeout=timeout
    )


def mbpoll_values(stdout: str) -> dict[int, int]:
    """{address: value} from mbpoll's "[12]: \t345" lines (signed readings in brackets dropped)."""
    values = {}
    for line in stdout.splitlines():
        if line.startswith("[") and "]:" in line:
            address, _, rest = line.partition("]:")
            values[int(address[1:])] = int(rest.split()[0])
    return values

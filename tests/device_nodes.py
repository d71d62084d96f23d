"""A gateway with a `device` node (a vendor's file, not one of the loop's kinds) for the
surface tests: the file, the configuration and the generic node built from it."""

from __future__ import annotations

import shutil
import tomllib
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.devices.app import DeviceApp
from grasplink.devices.node import DeviceNode
from grasplink.gateway.config import GatewayConfig, parse_config
from grasplink.gateway.service import Gateway
from grasplink.profiles import eds_path, load_profile
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import KINDS

FSR = 0x30
GRIP = obj.HAND_ACTUAL_GRIP_MN  # 2401h: made REAL32 [N] in the vendor's file
STATUSWORD = obj.STATUSWORD  # 6041h: UNSIGNED16
GRIP_KEY, STATUS_KEY = f"{GRIP:04X}sub0", f"{STATUSWORD:04X}sub0"


def vendor_eds(folder: Path) -> Path:
    """Our hand's EDS as a vendor's file would differ: its TPDO maps the statusword
    (UNSIGNED16) and a force as REAL32 with a Unit, as CiA 306 lets a file say."""
    path = folder / "vendor" / "fsr.eds"
    path.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(eds_path("hand"), path)
    text = path.read_text()
    section = (
        f"[{GRIP:04X}]\nParameterName=Actual grip force [mN]\nObjectType=0x7\nDataType=0x0007\n"
    )
    assert section in text
    text = text.replace(
        section,
        f"[{GRIP:04X}]\nParameterName=Measured force\nObjectType=0x7\nDataType=0x0008\nUnit=N\n",
    )
    path.write_text(text)
    return path


def device_config(folder: Path, extra: str = "", *, loop: bool = False) -> GatewayConfig:
    """A configuration file with the device `fsr` (and the loop's nodes when `loop`)."""
    vendor_eds(folder)
    off = "" if loop else "".join(f"[nodes.{kind}]\nenabled = false\n" for kind in KINDS)
    text = off + f'[nodes.fsr]\nnode_id = {FSR}\neds = "vendor/fsr.eds"\n' + extra
    path = folder / "gw.toml"
    path.write_text(text)
    return parse_config(tomllib.loads(text), str(path))


class Reading(DeviceApp):
    """An application that only holds fixed readings: set on every reset, on the node's
    own thread (a live runner's), so a test never writes a running node's store."""

    def __init__(self, values: dict[tuple[int, int], int | float]):
        self.values = values

    def on_reset(self, t_us: int) -> None:
        for (index, subindex), value in self.values.items():
            self.store.set(index, subindex, value)


def fsr_node(
    folder: Path, node_id: int = FSR, values: dict[tuple[int, int], int | float] | None = None
) -> DeviceNode:
    """The generic device built from the vendor's file: protocol only, no application
    (or one holding fixed `values`)."""
    app = DeviceApp() if values is None else Reading(values)
    return DeviceNode(load_profile(folder / "vendor" / "fsr.eds", node_id), node_id, app)


def running(folder: Path, seconds: float = 1.0) -> tuple[Gateway, DeviceNode, LockstepNetwork]:
    """The gateway and the device in virtual time, the device started and mastered."""
    gateway = Gateway(device_config(folder))
    device = fsr_node(folder)
    network = LockstepNetwork([gateway, device])
    network.start()
    network.run_until(round(seconds * 1e6))
    return gateway, device, network


@contextmanager
def served_device(config: GatewayConfig, device: DeviceNode, name: str = "fsr") -> Iterator:
    """The live gateway and `device` on one virtual bus, the Modbus server on a free port,
    once the device is operational: yields (live gateway, Modbus server)."""
    from grasplink.bus.runner import NodeRunner
    from grasplink.bus.url import open_bus
    from grasplink.gateway.live import LiveGateway
    from grasplink.gateway.snapshot import NodePhase
    from grasplink.surfaces.modbus.server import ModbusServer
    from tests.live import wait_until

    channel = f"virtual:device-{uuid.uuid4().hex[:12]}"
    bus = open_bus(channel)
    runner = NodeRunner(bus, [device], name=f"test {name}")
    try:
        with (
            LiveGateway(channel, config) as live,
            ModbusServer(live.edge, "tcp://127.0.0.1:0") as server,
        ):
            runner.start()
            wait_until(
                lambda: (
                    live.gateway.latest is not None
                    and live.gateway.latest.nodes[name].phase is NodePhase.OPERATIONAL
                ),
                timeout_s=30,
                what="the device operational",
            )
            yield live, server
    finally:
        runner.stop()
        bus.shutdown()

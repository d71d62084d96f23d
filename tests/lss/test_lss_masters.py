"""LSS masters against our unconfigured nodes on a python-can virtual bus, in real time:
python-canopen's LssMaster used directly, and the gateway's `assign_node_ids` on top of it."""

from __future__ import annotations

import queue
import uuid
from collections.abc import Callable, Iterator

import can
import canopen
import pytest

from grasplink.bus.runner import NodeRunner
from grasplink.devices.factory import build_node
from grasplink.devices.node import DeviceNode
from grasplink.errors import ConfigError
from grasplink.gateway.lss import LssAddress, assign_node_ids, check_assignments
from grasplink.profiles import eds_path
from grasplink.profiles import objects as obj
from grasplink.profiles.edsgen import REVISION, VENDOR_ID
from tests.live import first_from

UNCONFIGURED = 0xFF
SKIN_PRODUCT, HAND_PRODUCT = 1, 4
BOOT_WAIT_S = 5.0  # a bound, not a delay: the boot-up normally comes within milliseconds


class VirtualBus:
    """Nodes in a NodeRunner on one handle of a fresh virtual channel, a canopen master
    on another."""

    def __init__(self, nodes: list[DeviceNode]):
        channel = f"lss-{uuid.uuid4().hex}"
        self.nodes = nodes
        self.device_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        master_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
        self.network = canopen.Network(master_bus)
        self.network.NOTIFIER_CYCLE = 0.01  # quick teardown
        self.network.connect()
        self.runner = self._runner()

    def _runner(self) -> NodeRunner:
        return NodeRunner(self.device_bus, self.nodes, max_wait_s=0.01, name="lss-nodes").start()

    def boot_ups(self, node_id: int) -> queue.Queue[bytes]:
        """Every frame on 700h + node_id from now on."""
        frames: queue.Queue[bytes] = queue.Queue()
        self.network.subscribe(0x700 + node_id, lambda can_id, data, t: frames.put(bytes(data)))
        return frames

    def power_cycle(self) -> None:
        self.runner.stop()
        for node in self.nodes:
            node.power_off()
        self.runner = self._runner()

    def close(self) -> None:
        self.runner.stop()
        self.network.disconnect()
        self.device_bus.shutdown()


@pytest.fixture
def virtual_bus() -> Iterator[Callable[[list[DeviceNode]], VirtualBus]]:
    opened: list[VirtualBus] = []

    def make(nodes: list[DeviceNode]) -> VirtualBus:
        bus = VirtualBus(nodes)
        opened.append(bus)
        return bus

    yield make
    for bus in opened:
        bus.close()


def first_frame(frames: queue.Queue[bytes]) -> bytes:
    return frames.get(timeout=BOOT_WAIT_S)


def boot_up_after_power_cycle(frames: queue.Queue[bytes]) -> bytes:
    """The boot-up of the cycled node, past the heartbeats the node sent before it was cut
    off: subscribing before the cycle races with the last of them (seen at load 15)."""
    if first_from(frames, BOOT_WAIT_S, lambda data: data == b"\x00"):
        return b"\x00"
    raise AssertionError(f"no boot-up within {BOOT_WAIT_S} s of the power cycle")


@pytest.mark.slow
def test_python_canopen_assigns_a_node_id_the_node_boots_and_keeps_it(virtual_bus):
    node = build_node("skin", UNCONFIGURED, serial=5)
    bus = virtual_bus([node])
    lss = bus.network.lss
    found, identity = lss.fast_scan()
    assert found and identity == [VENDOR_ID, SKIN_PRODUCT, REVISION, 5]
    assert lss.inquire_node_id() == UNCONFIGURED  # fastscan left it in configuration
    lss.configure_node_id(0x21)
    lss.store_configuration()
    boot_ups = bus.boot_ups(0x21)
    lss.send_switch_state_global(lss.WAITING_STATE)
    assert first_frame(boot_ups) == b"\x00"
    remote = bus.network.add_node(0x21, str(eds_path("skin")))
    remote.sdo.RESPONSE_TIMEOUT = 3.0
    assert remote.sdo.upload(obj.IDENTITY, 4) == (5).to_bytes(4, "little")

    boot_ups = bus.boot_ups(0x21)
    bus.power_cycle()
    boot_up_after_power_cycle(boot_ups)  # at the stored node-ID: an FFh node sends none
    assert node.node_id == 0x21


@pytest.mark.slow
def test_python_canopen_switch_state_selective_reaches_one_node_by_its_address(virtual_bus):
    nodes = [build_node("skin", UNCONFIGURED, serial=s) for s in (1, 2)]
    bus = virtual_bus(nodes)
    lss = bus.network.lss
    assert lss.send_switch_state_selective(VENDOR_ID, SKIN_PRODUCT, REVISION, 2)
    assert lss.inquire_lss_address(0x5D) == 2  # inquire serial: only that node answers
    lss.configure_node_id(0x12)
    boot_ups = bus.boot_ups(0x12)
    lss.send_switch_state_global(lss.WAITING_STATE)
    assert first_frame(boot_ups) == b"\x00"
    assert [n.node_id for n in nodes] == [UNCONFIGURED, 0x12]


@pytest.mark.slow
def test_the_gateway_assigns_known_nodes_and_reports_the_unknown_one(virtual_bus):
    skin = build_node("skin", UNCONFIGURED, serial=1)
    hand = build_node("hand", UNCONFIGURED, serial=2)
    stranger = build_node("skin", UNCONFIGURED, serial=4)
    configured = build_node("belt")  # has its node-ID: fastscan never sees it
    bus = virtual_bus([skin, hand, stranger, configured])
    skin_address = LssAddress(VENDOR_ID, SKIN_PRODUCT, REVISION, 1)
    hand_address = LssAddress(VENDOR_ID, HAND_PRODUCT, REVISION, 2)
    absent = LssAddress(VENDOR_ID, SKIN_PRODUCT, REVISION, 99)
    boot_ups = {node_id: bus.boot_ups(node_id) for node_id in (0x11, 0x41)}

    report = assign_node_ids(bus.network, {skin_address: 0x11, hand_address: 0x41, absent: 0x12})

    assert report.assigned == {skin_address: 0x11, hand_address: 0x41}
    assert report.unknown == [LssAddress(VENDOR_ID, SKIN_PRODUCT, REVISION, 4)]
    assert report.missing == [absent]
    assert report.complete and not report.failed and not report.not_stored
    assert not report.ok  # an unknown node is waiting
    assert "unknown unconfigured node" in report.summary()
    for frames in boot_ups.values():
        assert first_frame(frames) == b"\x00"
    assert (skin.node_id, hand.node_id, stranger.node_id) == (0x11, 0x41, UNCONFIGURED)
    assert stranger.lss.state == 0  # left waiting, not in configuration

    boot_ups = {node_id: bus.boot_ups(node_id) for node_id in (0x11, 0x41)}
    bus.power_cycle()
    for frames in boot_ups.values():
        boot_up_after_power_cycle(frames)


@pytest.mark.parametrize(
    "wanted, message",
    [
        ({LssAddress(1, 2, 3, 4): 0}, "outside 1..127"),
        ({LssAddress(1, 2, 3, 4): 0x80}, "outside 1..127"),
        ({LssAddress(1, 2, 3, 4): 5, LssAddress(1, 2, 3, 5): 5}, "wanted for both"),
    ],
)
def test_assignments_with_bad_node_ids_are_refused_before_the_bus(wanted, message):
    with pytest.raises(ConfigError, match=message):
        check_assignments(wanted)


@pytest.mark.slow
def test_the_gateway_assigns_the_descriptions_identities_at_start():
    """`[gateway] lss = true`: the node whose description names its whole LSS address is
    given its node-ID before the gateway's loop starts, on a bus handle of its own."""
    from grasplink.gateway.config import parse_config
    from grasplink.gateway.lss import assign_at_start, wanted_from

    identity = {
        "vendor_id": VENDOR_ID,
        "product_code": SKIN_PRODUCT,
        "revision": REVISION,
        "serial": 9,
    }
    data = {
        "gateway": {"lss": True},
        "nodes": {"skin": {"node_id": 0x12, "identity": identity}},
    }
    config = parse_config(data, "gw.toml")
    assert wanted_from(config) == {LssAddress(VENDOR_ID, SKIN_PRODUCT, REVISION, 9): 0x12}
    channel = f"lss-{uuid.uuid4().hex}"
    node = build_node("skin", UNCONFIGURED, serial=9)
    device_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    runner = NodeRunner(device_bus, [node], max_wait_s=0.01, name="lss-nodes").start()
    try:
        report = assign_at_start(f"virtual:{channel}", config)
    finally:
        runner.stop()
        device_bus.shutdown()
    assert report.assigned == {LssAddress(VENDOR_ID, SKIN_PRODUCT, REVISION, 9): 0x12}
    assert node.node_id == 0x12


def test_lss_at_start_needs_a_whole_lss_address_in_the_description():
    from grasplink.gateway.config import parse_config

    data = {"gateway": {"lss": True}, "nodes": {"skin": {"identity": {"vendor_id": 1}}}}
    with pytest.raises(ConfigError, match=r"gateway\.lss: no node.s identity names vendor_id"):
        parse_config(data, "gw.toml")

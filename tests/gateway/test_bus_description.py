"""The bus description: devices mastered from their EDS/DCF, identity checked, configured from
the DCF and the `[sdo]` table, held for mandatory nodes (CiA 302-2), in virtual time."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import SDO_RX_BASE
from grasplink.core.nmt import NmtState
from grasplink.devices.app import DeviceApp
from grasplink.devices.node import DeviceNode
from grasplink.errors import ConfigError
from grasplink.gateway.config import DEVICE_ROLE, parse_config
from grasplink.gateway.service import NETWORK_HELD, Gateway
from grasplink.gateway.snapshot import NodePhase
from grasplink.profiles import eds_path, load_profile
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import KINDS

GRIPPER = 0x30
VENDOR, PRODUCT = 0xABC, 0x4  # what the hand's EDS (copied as a vendor's file) says in 1018h
CRUSH = f"{obj.HAND_CRUSH_LIMIT_MN:04X}sub0"
RATE = f"{obj.HAND_GRIP_RATE_MN_S:04X}sub0"


@pytest.fixture
def vendor_eds(tmp_path: Path) -> Path:
    """A device's EDS as an integrator gets it: a file beside the configuration."""
    path = tmp_path / "vendor" / "gripper.eds"
    path.parent.mkdir()
    shutil.copy(eds_path("hand"), path)
    return path


def config(tmp_path: Path, device: str, *, kinds_off: bool = True) -> dict:
    """A configuration file's text: the loop's nodes off (unless kept), one device table."""
    off = "".join(f"[nodes.{kind}]\nenabled = false\n" for kind in KINDS) if kinds_off else ""
    text = off + device
    (tmp_path / "gw.toml").write_text(text)
    import tomllib

    return tomllib.loads(text)


def gateway_for(tmp_path: Path, device: str, **kw) -> Gateway:
    data = config(tmp_path, device, **kw)
    return Gateway(parse_config(data, str(tmp_path / "gw.toml")))


def gripper(path: Path, node_id: int = GRIPPER) -> DeviceNode:
    """A generic device built from the vendor's file: protocol only, no application."""
    return DeviceNode(load_profile(path, node_id), node_id, DeviceApp())


def run(devices: list, seconds: float = 1.0) -> LockstepNetwork:
    network = LockstepNetwork(devices)
    network.start()
    network.run_until(round(seconds * 1e6))
    return network


# -- reading the description -------------------------------------------------------------------
def test_a_device_table_names_its_file_relative_to_the_configuration(tmp_path, vendor_eds):
    gw = gateway_for(
        tmp_path,
        f'[nodes.gripper]\nnode_id = {GRIPPER}\neds = "vendor/gripper.eds"\n'
        f"identity = {{ vendor_id = {VENDOR}, product_code = {PRODUCT} }}\n"
        f'[nodes.gripper.sdo]\n"{CRUSH}" = 30000\n',
    )
    node = gw.config.nodes["gripper"]
    assert (node.kind, node.role, node.name, node.node_id) == (
        DEVICE_ROLE,
        DEVICE_ROLE,
        "gripper",
        GRIPPER,
    )
    assert node.eds == vendor_eds
    assert node.identity is not None and node.identity.expected == ((1, VENDOR), (2, PRODUCT))
    assert [(w.index, w.subindex) for w in node.sdo] == [(obj.HAND_CRUSH_LIMIT_MN, 0)]
    assert "gripper" not in gw.by_kind  # not in the loop


@pytest.mark.parametrize(
    ("table", "needle"),
    [
        ("node_id = 0x30\n", "nodes.gripper.eds: unknown node kind 'gripper'"),
        ('node_id = 0x30\neds = "vendor/none.eds"\n', "nodes.gripper.eds: no such file"),
        (
            'node_id = 0x30\neds = "vendor/gripper.eds"\ndcf = "vendor/gripper.eds"\n',
            "nodes.gripper.dcf: give eds or dcf, not both",
        ),
        ('eds = "vendor/gripper.eds"\n', "nodes.gripper.node_id: is required"),
        (
            'node_id = 0x30\neds = "vendor/gripper.eds"\nrole = "hand"\n',
            "the hand role's node is [nodes.hand]",
        ),
        (
            'node_id = 0x30\neds = "vendor/gripper.eds"\nidentity = {}\n',
            "nodes.gripper.identity: name at least one of vendor_id",
        ),
        (
            'node_id = 0x30\neds = "vendor/gripper.eds"\n[nodes.gripper.sdo]\n"6060x" = 3\n',
            "nodes.gripper.sdo.6060x: '6060x' is not an object",
        ),
        (
            'node_id = 0x30\neds = "vendor/gripper.eds"\n[nodes.gripper.sdo]\n"5FFFsub0" = 3\n',
            "nodes.gripper.sdo.5FFFsub0: the node's dictionary has no object 0x5FFF",
        ),
        (
            'node_id = 0x30\neds = "vendor/gripper.eds"\n[nodes.gripper.sdo]\n"6060sub0" = 3\n',
            "nodes.gripper.sdo.6060sub0: Modes of operation = 3 is outside -1..-1",
        ),
        (
            'node_id = 0x30\neds = "vendor/gripper.eds"\n[nodes.gripper.sdo]\n"1018sub1" = 3\n',
            "nodes.gripper.sdo.1018sub1: Vendor-ID (0x1018sub1) is ro",
        ),
        (
            f'node_id = 0x30\neds = "vendor/gripper.eds"\n[nodes.gripper.sdo]\n"{CRUSH}" = -1\n',
            f"nodes.gripper.sdo.{CRUSH}:",
        ),
        (
            f'node_id = 0x30\neds = "vendor/gripper.eds"\n[nodes.gripper.sdo]\n"{CRUSH}" = 1.5\n',
            "takes an integer, got 1.5",
        ),
    ],
)
def test_a_bad_description_names_file_node_and_key_before_the_bus(
    tmp_path, vendor_eds, table, needle
):
    with pytest.raises(ConfigError) as info:
        gateway_for(tmp_path, "[nodes.gripper]\n" + table)
    assert needle in str(info.value)
    assert "gw.toml" in str(info.value)


def test_a_loop_node_is_grasplinks_own_and_keeps_its_table_name(tmp_path):
    with pytest.raises(ConfigError, match=r"nodes\.hand\.eds: the hand role's node is grasplink"):
        gateway_for(tmp_path, '[nodes.hand]\neds = "x.eds"\n', kinds_off=False)
    with pytest.raises(ConfigError, match=r"nodes.belt.role: \[nodes.belt\] is the belt role"):
        gateway_for(tmp_path, '[nodes.belt]\nrole = "hand"\n', kinds_off=False)
    with pytest.raises(ConfigError, match=r"nodes\.Grip: a node's name is a-z"):
        gateway_for(tmp_path, '[nodes.Grip]\nnode_id = 0x30\neds = "x.eds"\n')


# -- mastering it ------------------------------------------------------------------------------
def test_a_device_is_identified_configured_and_started(tmp_path, vendor_eds):
    gw = gateway_for(
        tmp_path,
        f'[nodes.gripper]\nnode_id = {GRIPPER}\neds = "vendor/gripper.eds"\n'
        f"identity = {{ vendor_id = {VENDOR}, product_code = {PRODUCT} }}\n"
        f'[nodes.gripper.sdo]\n"{CRUSH}" = 30000\n"{RATE}" = 20000\n',
    )
    device = gripper(vendor_eds)
    run([gw, device])
    assert device.state is NmtState.OPERATIONAL
    assert device.store.get(obj.HAND_CRUSH_LIMIT_MN) == 30000
    assert device.store.get(obj.HAND_GRIP_RATE_MN_S) == 20000
    assert device.store.get(obj.HEARTBEAT_PRODUCER_MS) == 100
    snap = gw.snapshot()
    assert snap.nodes["gripper"].phase is NodePhase.OPERATIONAL
    assert not snap.alarms


def test_a_wrong_identity_is_an_alarm_and_the_node_is_not_started(tmp_path, vendor_eds):
    gw = gateway_for(
        tmp_path,
        f'[nodes.gripper]\nnode_id = {GRIPPER}\neds = "vendor/gripper.eds"\n'
        f'identity = {{ vendor_id = 0x360 }}\n[nodes.gripper.sdo]\n"{CRUSH}" = 30000\n',
    )
    device = gripper(vendor_eds)
    run([gw, device], seconds=5.0)  # beyond a provisioning retry: a wrong identity stays wrong
    assert device.state is NmtState.PRE_OPERATIONAL
    assert device.store.get(obj.HAND_CRUSH_LIMIT_MN) != 30000  # nothing written
    snap = gw.snapshot()
    assert snap.nodes["gripper"].phase is NodePhase.FAILED
    assert snap.alarms["gripper.identity"] == (
        "wrong identity: vendor_id 0xABC, expected 0x360; not started"
    )


def test_a_mandatory_node_holds_the_network_start_until_it_is_ready(tmp_path, vendor_eds):
    other = vendor_eds.with_name("other.eds")
    shutil.copy(vendor_eds, other)
    gw = gateway_for(
        tmp_path,
        f'[nodes.gripper]\nnode_id = {GRIPPER}\neds = "vendor/gripper.eds"\nmandatory = true\n'
        f'[nodes.wrist]\nnode_id = 0x31\neds = "vendor/other.eds"\n',
    )
    wrist = gripper(other, 0x31)
    network = run([gw, wrist])
    assert wrist.state is NmtState.PRE_OPERATIONAL  # configured, held
    snap = gw.snapshot()
    assert snap.nodes["wrist"].phase is NodePhase.READY
    assert snap.alarms[NETWORK_HELD] == "waiting for mandatory node gripper (0x30)"
    device = gripper(vendor_eds)
    network.add(device)
    network.start_device(device)
    network.run_for(1_000_000)
    assert device.state is wrist.state is NmtState.OPERATIONAL
    assert NETWORK_HELD not in gw.snapshot().alarms


def test_a_device_that_reboots_is_configured_again(tmp_path, vendor_eds):
    gw = gateway_for(
        tmp_path,
        f'[nodes.gripper]\nnode_id = {GRIPPER}\neds = "vendor/gripper.eds"\n'
        f'[nodes.gripper.sdo]\n"{CRUSH}" = 30000\n',
    )
    device = gripper(vendor_eds)
    network = LockstepNetwork([gw, device])
    writes: list[int] = []  # times of the crush-limit writes the gateway sent

    def tap(t_us: int, frame, sender) -> None:
        index = int.from_bytes(frame.data[1:3], "little") if len(frame.data) == 8 else None
        if frame.can_id == SDO_RX_BASE + GRIPPER and index == obj.HAND_CRUSH_LIMIT_MN:
            writes.append(t_us)

    network.taps.append(tap)
    network.start()
    network.run_until(1_000_000)
    boots = gw.snapshot().nodes["gripper"].boots
    device.power_off()
    network.run_for(100_000)
    network.start_device(device)  # power back: defaults again, then the gateway's values
    network.run_for(1_000_000)
    assert device.state is NmtState.OPERATIONAL
    assert device.store.get(obj.HAND_CRUSH_LIMIT_MN) == 30000
    assert len(writes) == 2 and writes[1] >= 1_100_000
    assert gw.snapshot().nodes["gripper"].boots == boots + 1


def test_a_dcf_writes_its_values_then_the_table_has_the_last_word(tmp_path, vendor_eds):
    """A DCF's ParameterValues are written (CiA 302 concise DCF), in index order, then the
    `[sdo]` table's values, which win where both name an object."""
    text = vendor_eds.read_text()
    for index, value in ((obj.HAND_CRUSH_LIMIT_MN, 25000), (obj.HAND_GRIP_RATE_MN_S, 15000)):
        section = f"[{index:04X}]\n"
        assert section in text
        text = text.replace(section, f"{section}ParameterValue={value}\n")
    dcf = vendor_eds.with_suffix(".dcf")
    dcf.write_text(text)
    gw = gateway_for(
        tmp_path,
        f'[nodes.gripper]\nnode_id = {GRIPPER}\ndcf = "vendor/gripper.dcf"\n'
        f'[nodes.gripper.sdo]\n"{RATE}" = 20000\n',
    )
    whats = [w.what for w in gw.links[GRIPPER].writes]
    assert any("(DCF)" in what for what in whats)
    device = gripper(vendor_eds)
    run([gw, device])
    assert device.state is NmtState.OPERATIONAL
    assert device.store.get(obj.HAND_CRUSH_LIMIT_MN) == 25000  # the DCF's
    assert device.store.get(obj.HAND_GRIP_RATE_MN_S) == 20000  # the table's, written last

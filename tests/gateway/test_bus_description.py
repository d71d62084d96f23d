"""The bus description: devices mastered from their EDS/DCF, identity checked, configured from
the DCF and the `[sdo]` table, held for mandatory nodes (CiA 302-2), in virtual time."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.controllers import simulation
from grasplink.core.frames import SDO_RX_BASE
from grasplink.core.nmt import NmtState
from grasplink.decoding.io import skin_tpdo
from grasplink.devices.app import DeviceApp
from grasplink.devices.node import DeviceNode
from grasplink.errors import ConfigError
from grasplink.gateway.config import DEVICE_ROLE, parse_config
from grasplink.gateway.service import NETWORK_HELD, Gateway
from grasplink.gateway.snapshot import NodePhase
from grasplink.profiles import eds_path, load_profile
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import KINDS
from tests.gateway.test_service import HAND_RPDO, belt_velocities, scene
from tests.gateway.test_service import run as run_scene

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


def test_a_loop_node_keeps_its_table_name_and_a_vendors_binds_its_objects(tmp_path, vendor_eds):
    with pytest.raises(ConfigError, match=r"nodes\.hand\.drive: a vendor's node in the hand"):
        gateway_for(tmp_path, '[nodes.hand]\neds = "vendor/gripper.eds"\n', kinds_off=False)
    with pytest.raises(ConfigError, match=r"nodes\.hand\.drive: binds a vendor's node"):
        gateway_for(tmp_path, '[nodes.hand.drive]\ntarget = "2400sub0"\n', kinds_off=False)
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
    assert snap.alarms[NETWORK_HELD] == "waiting for mandatory node gripper (0x30): not booted"
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


# -- roles: a vendor's node in the loop --------------------------------------------------------
def hand_rpdos(frames) -> list[tuple[int, bytes]]:
    return [(t, bytes(f.data)) for t, f in frames if f.can_id == HAND_RPDO]


def test_a_vendor_hand_bound_to_our_objects_is_commanded_bit_for_bit_as_ours(vendor_eds):
    """The hand role bound through the description (the hand's own EDS as a vendor's file,
    its grip objects named, 1000 units per N) drives the loop exactly as our own hand."""
    _, _, ours = run_scene(scene(duration=2.0))
    bound = (
        f'[controller.nodes.hand]\neds = "{vendor_eds}"\n[controller.nodes.hand.drive]\n'
        f'target = "{obj.HAND_TARGET_GRIP_MN:04X}sub0"\nunits_per_n = 1000.0\n'
        f'actual = "{obj.HAND_ACTUAL_GRIP_MN:04X}sub0"\n'
    )
    _, gateway, theirs = run_scene(scene(duration=2.0, controller=bound))
    assert gateway.config.nodes["hand"].binding is not None
    assert len(hand_rpdos(ours)) > 10
    assert hand_rpdos(theirs) == hand_rpdos(ours)


def test_a_vendor_drive_binding_is_checked_against_its_file(tmp_path, vendor_eds):
    def refused(drive: str) -> str:
        with pytest.raises(ConfigError) as info:
            gateway_for(
                tmp_path,
                f'[nodes.hand]\neds = "vendor/gripper.eds"\n[nodes.hand.drive]\n{drive}',
                kinds_off=False,
            )
        return str(info.value)

    target = f'target = "{obj.HAND_TARGET_GRIP_MN:04X}sub0"\n'
    assert "nodes.hand.drive.units_per_n: is required" in refused(target)
    assert "is in no RPDO of the file" in refused('target = "2401sub0"\nunits_per_n = 1.0\n')
    assert "nodes.hand.drive.actual: 0x2400sub0 is in no TPDO" in refused(
        target + 'units_per_n = 1.0\nactual = "2400sub0"\n'
    )
    assert "expected a number > 0" in refused(target + "units_per_n = 0\n")


def test_a_vendor_skin_bound_to_analogue_values_is_timed_by_arrival(tmp_path):
    """The skin role bound to three sample objects without a packet number (as an analogue
    module sends them): samples are timed by arrival, the slip is decoded all the same."""
    vendor = tmp_path / "skin.eds"
    shutil.copy(eds_path("skin"), vendor)
    step = skin_tpdo().calibration.n_per_count
    slots = ", ".join(f'"{obj.SKIN_SAMPLE_SLOTS:04X}sub{sub}"' for sub in (1, 2, 3))
    bound = (
        f'[controller.nodes.skin]\neds = "{vendor}"\n[controller.nodes.skin.samples]\n'
        f"objects = [{slots}]\nnewtons_per_unit = {step!r}\n"
    )
    _, ours, _ = run_scene(scene(duration=2.5))
    _, theirs, _ = run_scene(scene(duration=2.5, controller=bound))
    binding = theirs.config.nodes["skin"].binding
    assert binding is not None and binding.objects.sequence is None
    assert theirs.skin_frames.stats.packets == ours.skin_frames.stats.packets > 100
    assert theirs.last_estimate is not None and theirs.last_estimate.slip
    assert theirs.last_estimate.speed_mm_s == pytest.approx(ours.last_estimate.speed_mm_s, rel=0.05)


# -- devices from other projects' files -------------------------------------------------------
FIELD = Path(__file__).resolve().parents[1] / "profiles" / "field"


@pytest.mark.parametrize(
    "name",
    [
        "canopendemo_demoDevice.eds",
        "python-canopen_e35.eds",
        "canopennode_DS301_profile.eds",
        "lely_co-nmt-slave.dcf",
        "lely_coapp-fiber-slave.dcf",
        "python-canopen_sample.eds",
    ],
)
def test_a_node_from_another_projects_file_boots_and_is_mastered(tmp_path, name):
    """Files written by other CANopen stacks (tests/profiles/field/README.md): a node built
    from each boots, and the gateway masters it from a description naming the file."""
    from grasplink.profiles.field import load_object_dictionary

    key = "dcf" if name.endswith(".dcf") else "eds"
    gw = gateway_for(tmp_path, f'[nodes.vendor]\nnode_id = 0x35\n{key} = "{FIELD / name}"\n')
    device = DeviceNode(load_object_dictionary(FIELD / name, 0x35)[0], 0x35, DeviceApp())
    run([gw, device], seconds=2.0)
    assert device.state is NmtState.OPERATIONAL
    snap = gw.snapshot()
    assert snap.nodes["vendor"].phase is NodePhase.OPERATIONAL, snap.alarms


def test_a_gateway_start_parses_each_nodes_file_once(tmp_path, monkeypatch):
    """Config check, role binding, codecs and provisioning share the dictionary the
    description read: one parse per file (there were 3 of a vendor's, up to 9 of ours)."""
    import grasplink.profiles
    import grasplink.profiles.field as field
    from grasplink.profiles import object_limits, shipped_profile

    parses: list[str] = []
    load_field, load_shipped = field.load_object_dictionary, grasplink.profiles.load_profile

    def counted_field(path, *args, **kwargs):
        parses.append(Path(path).name)
        return load_field(path, *args, **kwargs)

    def counted_shipped(kind, *args, **kwargs):
        parses.append(str(kind))
        return load_shipped(kind, *args, **kwargs)

    monkeypatch.setattr(field, "load_object_dictionary", counted_field)
    monkeypatch.setattr(grasplink.profiles, "load_profile", counted_shipped)
    shipped_profile.cache_clear()  # a cold process: nothing parsed yet
    object_limits.cache_clear()
    e35 = FIELD / "python-canopen_e35.eds"
    device = f'[nodes.vendor]\nnode_id = 0x35\neds = "{e35}"\n'
    gw = gateway_for(tmp_path, device, kinds_off=False)
    assert sorted(parses) == sorted([*KINDS, e35.name])
    parses.clear()
    gateway_for(tmp_path, device, kinds_off=False)  # ours stay parsed; the vendor file is reread
    assert parses == [e35.name]
    link = gw.links[0x35]
    od = gw.config.nodes["vendor"].dictionary()
    assert link.codec.od_entry(0x1017) is od[0x1017]  # the codec reads the description's


# -- a foreign node that refuses its configuration or does not answer ------------------------
class MuteSdo:
    """A node that boots and sends its heartbeat but never answers SDO (its SDO server
    hears nothing): what the gateway meets in a device with a broken SDO channel."""

    def __init__(self, node: DeviceNode):
        self.node, self.node_id = node, node.node_id

    def start(self, t_us: int) -> list:
        return self.node.start(t_us)

    def receive(self, frame, t_us: int) -> list:
        return [] if frame.can_id == SDO_RX_BASE + self.node_id else self.node.receive(frame, t_us)

    def advance(self, t_us: int) -> list:
        return self.node.advance(t_us)

    def next_deadline_us(self) -> int | None:
        return self.node.next_deadline_us()


def refusing(vendor_eds: Path, change: str) -> Path:
    """The device's own file, where the crush limit (2402h) is not what the integrator's
    copy says: read-only, or a narrower range. The gateway is configured from the copy."""
    text = vendor_eds.read_text()
    section = f"[{obj.HAND_CRUSH_LIMIT_MN:04X}]\n"
    start = text.index(section)
    end = text.index("\n[", start)
    body = text[start:end]
    if change == "read-only":
        body = body.replace("AccessType=rw", "AccessType=ro")
    else:
        body = (
            "\n".join(line for line in body.splitlines() if not line.startswith("HighLimit="))
            + "\nHighLimit=20000"
        )
    path = vendor_eds.with_name(f"firmware_{change}.eds")
    path.write_text(text[:start] + body + text[end:])
    return path


@pytest.mark.parametrize(
    ("change", "abort"),
    [("read-only", "0x06010002 (READ_ONLY)"), ("range", "0x06090031 (VALUE_TOO_HIGH)")],
)
def test_a_device_refusing_its_configuration_is_an_alarm_and_not_started(
    tmp_path, vendor_eds, change, abort
):
    """CiA 302-2 boot error J (configuration download failed): not started, retried, and
    the loop and the other nodes go on as without it."""
    firmware = refusing(vendor_eds, change)
    device = f'[controller.nodes.gripper]\nnode_id = {GRIPPER}\neds = "{vendor_eds}"\n'
    device += f'[controller.nodes.gripper.sdo]\n"{CRUSH}" = 30000\n'
    other = f'[controller.nodes.wrist]\nnode_id = 0x31\neds = "{vendor_eds}"\n'
    _, _, alone = run_scene(scene(duration=5.0))
    sim = simulation(scene(duration=5.0, controller=device + other))
    gripper_node, wrist = gripper(firmware), gripper(vendor_eds, 0x31)
    sim.network.add(gripper_node)
    sim.network.add(wrist)
    frames: list = []
    sim.network.taps.append(lambda t_us, frame, sender: frames.append((t_us, frame)))
    sim.run()
    gw = sim.controllers[0]
    snap = gw.snapshot()
    assert gripper_node.state is NmtState.PRE_OPERATIONAL
    assert snap.nodes["gripper"].phase is NodePhase.FAILED
    assert snap.alarms["gripper.provisioning"] == (
        f"Crush limit [mN] = 30000: write 0x{obj.HAND_CRUSH_LIMIT_MN:04X}:00 aborted {abort}"
    )
    crush = obj.HAND_CRUSH_LIMIT_MN.to_bytes(2, "little")
    refused = [t for t, f in frames if f.can_id == SDO_RX_BASE + GRIPPER and f.data[1:3] == crush]
    assert len(refused) >= 2  # retried (every 2 s), never a hang
    assert wrist.state is NmtState.OPERATIONAL
    assert {n: s.phase for n, s in snap.nodes.items() if n != "gripper"} == dict.fromkeys(
        ("skin", "belt", "hand", "wrist"), NodePhase.OPERATIONAL
    )
    # the loop's commands: the same, at the same times (a node coming up repeats the last)
    assert set(hand_rpdos(frames)) == set(hand_rpdos(alone)) and len(hand_rpdos(alone)) > 10
    assert set(belt_velocities(frames)) == set(belt_velocities(alone))
    assert set(snap.alarms) == {"gripper.provisioning"}


@pytest.mark.parametrize("identity", [False, True])
def test_a_device_that_boots_but_never_answers_sdo_is_an_alarm_not_a_hang(
    tmp_path, vendor_eds, identity
):
    """Its heartbeat comes, its SDO answers never do: each transfer gives up after the SDO
    timeout, the alarm says which object had no answer, the node is retried and not
    started, and the rest of the network starts and runs."""
    ident = f"identity = {{ vendor_id = {VENDOR} }}\n" if identity else ""
    gw = gateway_for(
        tmp_path,
        f'[nodes.gripper]\nnode_id = {GRIPPER}\neds = "vendor/gripper.eds"\n{ident}'
        f'[nodes.wrist]\nnode_id = 0x31\neds = "vendor/gripper.eds"\n',
    )
    mute, wrist = MuteSdo(gripper(vendor_eds)), gripper(vendor_eds, 0x31)
    requests: list[int] = []
    network = LockstepNetwork([gw, mute, wrist])
    network.taps.append(
        lambda t_us, frame, sender: (
            requests.append(t_us)
            if frame.can_id == SDO_RX_BASE + GRIPPER and frame.data[0] >> 5 != 4  # not an abort
            else None
        )
    )
    network.start()
    network.run_until(4_000_000)  # gave up at 0.5 s, retried at 2.5 s, gave up at 3 s
    snap = gw.snapshot()
    assert len(requests) == 2 and 2_500_000 <= requests[1] < 3_000_000
    assert mute.node.state is NmtState.PRE_OPERATIONAL
    assert snap.nodes["gripper"].phase is NodePhase.FAILED
    what = "identity: read 0x1018:01" if identity else "heartbeat time: write 0x1017:00"
    assert snap.alarms["gripper.provisioning"] == (
        f"{what} aborted 0x05040000 (TIMEOUT): no answer after 500 ms"
    )
    assert wrist.state is NmtState.OPERATIONAL
    assert snap.nodes["wrist"].phase is NodePhase.OPERATIONAL
    assert set(snap.alarms) == {"gripper.provisioning"}


@pytest.mark.parametrize("failure", ["refuses", "mute"])
def test_a_mandatory_node_that_fails_its_boot_holds_the_start_saying_why(
    tmp_path, vendor_eds, failure
):
    gw = gateway_for(
        tmp_path,
        f'[nodes.gripper]\nnode_id = {GRIPPER}\neds = "vendor/gripper.eds"\nmandatory = true\n'
        f'[nodes.gripper.sdo]\n"{CRUSH}" = 30000\n'
        f'[nodes.wrist]\nnode_id = 0x31\neds = "vendor/gripper.eds"\n',
    )
    if failure == "refuses":
        device = gripper(refusing(vendor_eds, "read-only"))
        why = f"Crush limit [mN] = 30000: write 0x{CRUSH[:4]}:00 aborted 0x06010002 (READ_ONLY)"
    else:
        device = MuteSdo(gripper(vendor_eds))
        why = "heartbeat time: write 0x1017:00 aborted 0x05040000 (TIMEOUT): "
        why += "no answer after 500 ms"
    wrist = gripper(vendor_eds, 0x31)
    run([gw, device, wrist], seconds=5.0)
    snap = gw.snapshot()
    assert wrist.state is NmtState.PRE_OPERATIONAL  # configured, held
    assert snap.nodes["wrist"].phase is NodePhase.READY
    assert snap.alarms["gripper.provisioning"] == why
    assert snap.alarms[NETWORK_HELD] == f"waiting for mandatory node gripper (0x30): {why}"


def test_restart_node_resets_a_device_by_its_name_and_it_is_configured_again(tmp_path, vendor_eds):
    """Any node of the description, by its table name (posted as a surface does): NMT
    reset node, then its boot-up is a reboot: configured again and started."""
    from grasplink.gateway.commands import Command
    from grasplink.gateway.edge import GatewayEdge

    gw = gateway_for(
        tmp_path,
        f'[nodes.gripper]\nnode_id = 0x35\neds = "vendor/gripper.eds"\n'
        f'[nodes.gripper.sdo]\n"{CRUSH}" = 30000\n',
        kinds_off=False,
    )
    edge, device = GatewayEdge(gw), gripper(vendor_eds, 0x35)
    network = run([edge, device])
    assert device.state is NmtState.OPERATIONAL
    device.store.set(obj.HAND_CRUSH_LIMIT_MN, 0, 12345)  # changed behind the gateway's back
    boots = gw.snapshot().nodes["gripper"].boots
    future = edge.post(Command("restart_node", "gripper"))
    network.run_for(1_000_000)
    result = future.result(timeout=0)
    assert result.accepted and result.detail == "reset node gripper"
    assert device.state is NmtState.OPERATIONAL
    assert device.store.get(obj.HAND_CRUSH_LIMIT_MN) == 30000  # configured again
    assert gw.snapshot().nodes["gripper"].boots == boots + 1
    assert "gateway.second_master" not in gw.snapshot().alarms

    result, frames = gw.execute(Command("restart_node", "arm"), network.t_us)
    assert not result.accepted and frames == []
    assert result.detail == "restart_node: no node 'arm'; nodes: skin, emg, belt, hand, gripper"
    result, _ = gw.execute(Command("restart_node", 4), network.t_us)
    assert not result.accepted and "restart_node: expected a node's name" in result.detail

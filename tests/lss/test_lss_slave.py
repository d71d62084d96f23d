"""LSS (CiA 305) on the device side, in virtual time: every service, its error codes,
the unconfigured node, pending/active/stored node-IDs, and fastscan over several nodes."""

from __future__ import annotations

import struct

import pytest

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import LSS_MASTER_COB_ID, LSS_SLAVE_COB_ID, Frame
from grasplink.core.nmt import NmtState
from grasplink.devices.factory import build_node
from grasplink.devices.lss import LssState
from grasplink.devices.node import DeviceNode
from grasplink.errors import ConfigError
from grasplink.profiles import objects as obj
from grasplink.profiles.edsgen import REVISION, VENDOR_ID
from tests.rawcan import Recorder, nmt, read_uint, write_uint

MS = 1000
UNCONFIGURED = 0xFF
SKIN_PRODUCT = 1
WAITING, CONFIGURATION = 0x00, 0x01
# command specifiers
SWITCH_GLOBAL, CONFIGURE_NODE_ID, CONFIGURE_BIT_TIMING = 0x04, 0x11, 0x13
ACTIVATE_BIT_TIMING, STORE = 0x15, 0x17
SELECT_VENDOR, SELECT_PRODUCT, SELECT_REVISION, SELECT_SERIAL = 0x40, 0x41, 0x42, 0x43
SELECTED = 0x44
IDENTIFY_VENDOR, IDENTIFY_NON_CONFIGURED = 0x46, 0x4C
IDENTIFY_SLAVE, NON_CONFIGURED_SLAVE, FASTSCAN = 0x4F, 0x50, 0x51
INQUIRE_VENDOR, INQUIRE_PRODUCT, INQUIRE_REVISION, INQUIRE_SERIAL = 0x5A, 0x5B, 0x5C, 0x5D
INQUIRE_NODE_ID = 0x5E


def lss_frame(cs: int, *payload: int) -> Frame:
    return Frame(LSS_MASTER_COB_ID, bytes([cs, *payload]).ljust(8, b"\0"))


def lss_u32(cs: int, value: int) -> Frame:
    return Frame(LSS_MASTER_COB_ID, struct.pack("<BI3x", cs, value))


def replies(net: LockstepNetwork, frame: Frame) -> list[bytes]:
    """The LSS answers `frame` caused (one per node that answered)."""
    return [f.data for f in net.inject(frame) if f.can_id == LSS_SLAVE_COB_ID]


def one_reply(net: LockstepNetwork, frame: Frame) -> bytes:
    answers = replies(net, frame)
    assert len(answers) == 1, answers
    assert len(answers[0]) == 8
    return answers[0]


def network(*nodes: DeviceNode) -> tuple[LockstepNetwork, Recorder]:
    net = LockstepNetwork(nodes)
    rec = Recorder(net)
    net.start()
    return net, rec


def unconfigured(kind: str = "skin", serial: int = 0x1234) -> DeviceNode:
    return build_node(kind, UNCONFIGURED, serial=serial)


def configure(net: LockstepNetwork, node_id: int) -> bytes:
    return one_reply(net, lss_frame(CONFIGURE_NODE_ID, node_id))


def fastscan(net: LockstepNetwork) -> tuple[int, ...] | None:
    """CiA 305 fastscan as python-canopen's LssMaster runs it: the lowest unconfigured
    identity, now in the configuration state; None when no node answers."""

    def acknowledged(id_number: int, bit: int, sub: int, following: int) -> bool:
        frame = Frame(
            LSS_MASTER_COB_ID, struct.pack("<BIBBB", FASTSCAN, id_number, bit, sub, following)
        )
        return any(data[0] == IDENTIFY_SLAVE for data in replies(net, frame))

    if not acknowledged(0, 0x80, 0, 0):
        return None
    identity = [0, 0, 0, 0]
    for sub in range(4):
        for bit in range(31, -1, -1):
            if not acknowledged(identity[sub], bit, sub, sub):
                identity[sub] |= 1 << bit
        if not acknowledged(identity[sub], 0, sub, (sub + 1) % 4):
            return None
    return tuple(identity)


# -- the unconfigured node ---------------------------------------------------------------------
def test_an_unconfigured_node_sends_no_bootup_no_heartbeat_and_answers_no_sdo_or_nmt():
    node = unconfigured()
    net, rec = network(node)
    net.run_until(2000 * MS)
    assert rec.frames == []
    assert node.next_deadline_us() is None
    assert net.inject(Frame(0x000, bytes([0x01, 0]))) == []  # NMT start all
    assert net.inject(Frame(0x000, bytes([0x82, 0]))) == []  # NMT reset communication
    assert net.inject(Frame(0x67F, bytes([0x40, 0x18, 0x10, 4, 0, 0, 0, 0]))) == []
    assert node.state == NmtState.INITIALISING and not node.configured


def test_an_unconfigured_node_answers_identify_non_configured_remote_slave():
    net, _ = network(unconfigured())
    assert one_reply(net, lss_frame(IDENTIFY_NON_CONFIGURED)) == bytes(
        [NON_CONFIGURED_SLAVE, *[0] * 7]
    )


def test_a_configured_node_is_not_non_configured():
    net, _ = network(build_node("skin"))
    assert replies(net, lss_frame(IDENTIFY_NON_CONFIGURED)) == []


def test_switched_back_to_waiting_with_a_node_id_the_node_boots_with_it():
    node = unconfigured(serial=0xCAFE)
    net, rec = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    assert configure(net, 0x22) == bytes([CONFIGURE_NODE_ID, 0, 0, 0, 0, 0, 0, 0])
    assert rec.of(0x722) == [] and not node.configured  # pending until the switch
    caused = net.inject(lss_frame(SWITCH_GLOBAL, WAITING))
    assert Frame(0x722, b"\x00") in caused
    assert node.node_id == 0x22 and node.state == NmtState.PRE_OPERATIONAL
    net.run_until(net.t_us + 1000 * MS)
    assert len(rec.of(0x722)) == 11  # boot-up, then 100 ms heartbeats
    assert read_uint(net, 0x22, obj.IDENTITY, 4) == 0xCAFE  # SDO on 622h/5A2h
    # COB-IDs given as $NODEID+... in the EDS follow the new node-ID
    assert read_uint(net, 0x22, obj.COB_ID_EMCY) == 0x80 + 0x22
    assert read_uint(net, 0x22, obj.TPDO_COMM, 1) & 0x7FF == 0x180 + 0x22
    nmt(net, 0x01, 0x22)
    net.run_until(net.t_us + 100 * MS)
    assert rec.of(0x1A2)  # skin samples on TPDO1 of node 22h


def test_switching_to_waiting_without_a_node_id_leaves_the_node_unconfigured():
    node = unconfigured()
    net, rec = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    assert net.inject(lss_frame(SWITCH_GLOBAL, WAITING)) == []
    assert not node.configured
    assert {f.can_id for _, f in rec.frames} == {LSS_MASTER_COB_ID}  # the node sent nothing


# -- configure node-ID -------------------------------------------------------------------------
@pytest.mark.parametrize("node_id", [0, 0x80, 0xFE])
def test_configure_node_id_out_of_range_answers_error_1_and_changes_nothing(node_id):
    node = unconfigured()
    net, _ = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    assert configure(net, node_id)[:3] == bytes([CONFIGURE_NODE_ID, 1, 0])
    assert node.lss.pending_node_id == UNCONFIGURED


@pytest.mark.parametrize("node_id", [1, 0x7F, UNCONFIGURED])
def test_configure_node_id_accepts_1_to_127_and_ff(node_id):
    node = build_node("skin")
    net, _ = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    assert configure(net, node_id)[:2] == bytes([CONFIGURE_NODE_ID, 0])
    assert node.lss.pending_node_id == node_id


def test_configuration_services_are_ignored_in_the_waiting_state():
    net, _ = network(unconfigured())
    for frame in (
        lss_frame(CONFIGURE_NODE_ID, 5),
        lss_frame(CONFIGURE_BIT_TIMING, 0, 2),
        lss_frame(STORE),
        lss_frame(INQUIRE_NODE_ID),
        lss_frame(INQUIRE_VENDOR),
    ):
        assert replies(net, frame) == []


def test_a_configured_node_takes_a_new_node_id_at_the_next_reset_communication():
    node = build_node("belt")  # 20h
    net, _ = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    configure(net, 0x35)
    assert net.inject(lss_frame(SWITCH_GLOBAL, WAITING)) == []  # configured: no reboot
    assert node.node_id == 0x20
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    assert one_reply(net, lss_frame(INQUIRE_NODE_ID))[:2] == bytes([INQUIRE_NODE_ID, 0x20])
    caused = nmt(net, 0x82, 0x20)
    assert Frame(0x735, b"\x00") in caused and node.node_id == 0x35
    assert read_uint(net, 0x35, obj.RPDO_COMM, 1) & 0x7FF == 0x200 + 0x35


def test_reset_node_also_activates_the_pending_node_id():
    node = build_node("hand")  # 40h
    net, _ = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    configure(net, 0x41)
    assert Frame(0x741, b"\x00") in nmt(net, 0x81, 0x40)


def test_configuring_ff_unconfigures_a_node_at_its_next_reset():
    node = build_node("emg")  # 30h
    net, _ = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    configure(net, UNCONFIGURED)
    net.inject(lss_frame(SWITCH_GLOBAL, WAITING))
    assert nmt(net, 0x82, 0x30) == []  # no boot-up: the node now waits for LSS
    assert not node.configured and node.next_deadline_us() is None
    assert one_reply(net, lss_frame(IDENTIFY_NON_CONFIGURED))[0] == NON_CONFIGURED_SLAVE


# -- store configuration -----------------------------------------------------------------------
def test_a_stored_node_id_survives_a_power_cycle():
    node = unconfigured()
    net, rec = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    configure(net, 0x23)
    assert one_reply(net, lss_frame(STORE))[:3] == bytes([STORE, 0, 0])
    net.inject(lss_frame(SWITCH_GLOBAL, WAITING))
    node.power_off()
    rec.clear()
    net.start_device(node)
    assert [f for _, f in rec.frames] == [Frame(0x723, b"\x00")]


def test_an_unstored_node_id_is_lost_at_power_off():
    node = unconfigured()
    net, rec = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    configure(net, 0x23)
    net.inject(lss_frame(SWITCH_GLOBAL, WAITING))
    assert node.node_id == 0x23
    node.power_off()
    rec.clear()
    net.start_device(node)
    assert rec.frames == [] and not node.configured


def test_a_changed_node_id_stored_moves_a_configured_node_after_power_on():
    node = build_node("skin")  # 10h
    net, rec = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    configure(net, 0x11)
    one_reply(net, lss_frame(STORE))
    node.power_off()
    rec.clear()
    net.start_device(node)
    assert [f for _, f in rec.frames] == [Frame(0x711, b"\x00")]


def test_store_configuration_on_a_node_without_storage_answers_error_1():
    node = unconfigured()
    node.lss.can_store = False
    net, _ = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    configure(net, 0x23)
    assert one_reply(net, lss_frame(STORE))[:2] == bytes([STORE, 1])
    assert node.lss.stored_node_id is None


def test_a_stored_default_cob_id_follows_the_node_id_and_a_changed_one_stays():
    node = build_node("belt")  # 20h
    net, _ = network(node)
    # TPDO2 moved to 2A5h; every other COB-ID is the EDS default
    write_uint(net, 0x20, obj.TPDO_COMM + 1, 1, 0xC0000000 | 0x2A5, 4)
    write_uint(net, 0x20, obj.STORE_PARAMETERS, 1, obj.STORE_SIGNATURE, 4)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    configure(net, 0x26)
    nmt(net, 0x82, 0x20)
    assert read_uint(net, 0x26, obj.TPDO_COMM, 1) & 0x7FF == 0x180 + 0x26
    assert read_uint(net, 0x26, obj.TPDO_COMM + 1, 1) & 0x7FF == 0x2A5


# -- bit timing --------------------------------------------------------------------------------
def test_configure_bit_timing_accepts_the_standard_table():
    node = unconfigured()
    net, _ = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    assert one_reply(net, lss_frame(CONFIGURE_BIT_TIMING, 0, 3))[:3] == bytes([0x13, 0, 0])
    assert node.lss.pending_bit_timing == 3 and node.lss.active_bit_timing is None
    assert net.inject(lss_frame(ACTIVATE_BIT_TIMING, 0x64, 0x00)) == []  # no answer
    assert node.lss.active_bit_timing == 3 and node.lss.switch_delay_ms == 100


@pytest.mark.parametrize(
    "selector, index",
    [(0, 5), (0, 9), (0, 10), (1, 0)],
    ids=["reserved", "auto", "beyond-table", "other-table"],
)
def test_configure_bit_timing_outside_the_table_answers_error_1(selector, index):
    node = unconfigured()
    net, _ = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    assert one_reply(net, lss_frame(CONFIGURE_BIT_TIMING, selector, index))[:2] == bytes([0x13, 1])
    assert node.lss.pending_bit_timing is None


def test_a_stored_bit_timing_is_active_after_a_power_cycle():
    node = build_node("skin")
    net, _ = network(node)
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    one_reply(net, lss_frame(CONFIGURE_BIT_TIMING, 0, 2))
    one_reply(net, lss_frame(STORE))
    node.power_off()
    net.start_device(node)
    assert node.lss.active_bit_timing == 2


# -- inquire -----------------------------------------------------------------------------------
def test_inquire_identity_answers_1018h_and_inquire_node_id_the_active_one():
    net, _ = network(unconfigured(serial=0xDEADBEEF))
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    expected = {
        INQUIRE_VENDOR: VENDOR_ID,
        INQUIRE_PRODUCT: SKIN_PRODUCT,
        INQUIRE_REVISION: REVISION,
        INQUIRE_SERIAL: 0xDEADBEEF,
    }
    for cs, value in expected.items():
        assert one_reply(net, lss_frame(cs)) == struct.pack("<BI3x", cs, value)
    assert one_reply(net, lss_frame(INQUIRE_NODE_ID)) == bytes([INQUIRE_NODE_ID, 0xFF, *[0] * 6])
    configure(net, 0x12)  # pending: inquire still names the active one
    assert one_reply(net, lss_frame(INQUIRE_NODE_ID))[1] == 0xFF


# -- switch state selective --------------------------------------------------------------------
def select(net: LockstepNetwork, vendor: int, product: int, revision: int, serial: int):
    out: list[bytes] = []
    for cs, value in zip(
        (SELECT_VENDOR, SELECT_PRODUCT, SELECT_REVISION, SELECT_SERIAL),
        (vendor, product, revision, serial),
        strict=True,
    ):
        out += replies(net, lss_u32(cs, value))
    return out


def test_switch_state_selective_puts_only_the_addressed_node_in_configuration():
    first, second = unconfigured(serial=1), unconfigured(serial=2)
    net, _ = network(first, second)
    assert select(net, VENDOR_ID, SKIN_PRODUCT, REVISION, 2) == [bytes([SELECTED, *[0] * 7])]
    assert second.lss.state == LssState.CONFIGURATION and first.lss.state == LssState.WAITING
    configure(net, 0x50)
    assert second.lss.pending_node_id == 0x50 and first.lss.pending_node_id == UNCONFIGURED


def test_switch_state_selective_with_another_identity_gets_no_answer():
    node = unconfigured(serial=1)
    net, _ = network(node)
    assert select(net, VENDOR_ID, SKIN_PRODUCT, REVISION, 3) == []
    assert select(net, VENDOR_ID, 2, REVISION, 1) == []
    assert node.lss.state == LssState.WAITING


def test_switch_state_selective_out_of_order_starts_over():
    node = unconfigured(serial=1)
    net, _ = network(node)
    replies(net, lss_u32(SELECT_VENDOR, VENDOR_ID))
    replies(net, lss_u32(SELECT_REVISION, REVISION))  # product skipped
    replies(net, lss_u32(SELECT_SERIAL, 1))
    assert node.lss.state == LssState.WAITING
    assert select(net, VENDOR_ID, SKIN_PRODUCT, REVISION, 1) == [bytes([SELECTED, *[0] * 7])]


# -- identify remote slave ---------------------------------------------------------------------
def identify(net: LockstepNetwork, *bounds: int) -> list[bytes]:
    out: list[bytes] = []
    for offset, value in enumerate(bounds):
        out += replies(net, lss_u32(IDENTIFY_VENDOR + offset, value))
    return out


def test_identify_remote_slave_answers_nodes_in_the_revision_and_serial_ranges():
    nodes = [unconfigured(serial=s) for s in (10, 20, 30)]
    net, _ = network(*nodes)
    found = identify(net, VENDOR_ID, SKIN_PRODUCT, 0, REVISION, 15, 30)
    assert found == [bytes([IDENTIFY_SLAVE, *[0] * 7])] * 2
    assert identify(net, VENDOR_ID, SKIN_PRODUCT, REVISION + 1, 0xFFFFFFFF, 0, 100) == []
    assert identify(net, VENDOR_ID, 2, 0, 0xFFFFFFFF, 0, 100) == []


def test_identify_remote_slave_works_for_configured_nodes_too():
    net, _ = network(build_node("skin", serial=4))
    assert len(identify(net, VENDOR_ID, SKIN_PRODUCT, 0, 0xFFFFFFFF, 0, 0xFFFFFFFF)) == 1


# -- fastscan ----------------------------------------------------------------------------------
def test_fastscan_finds_three_unconfigured_nodes_one_after_the_other():
    serials = (0x00C0FFEE, 7, 0x0100)
    nodes = [unconfigured("skin", s) for s in serials] + [build_node("belt")]
    net, _ = network(*nodes)
    found = []
    for node_id in (0x61, 0x62, 0x63):
        identity = fastscan(net)
        assert identity is not None
        found.append(identity)
        configure(net, node_id)
        one_reply(net, lss_frame(STORE))
        assert Frame(0x700 + node_id, b"\x00") in net.inject(lss_frame(SWITCH_GLOBAL, WAITING))
    assert fastscan(net) is None  # every node has a node-ID now
    assert found == [(VENDOR_ID, SKIN_PRODUCT, REVISION, s) for s in sorted(serials)]
    by_serial = {node.lss.identity()[3]: node.node_id for node in nodes[:3]}
    assert by_serial == {7: 0x61, 0x0100: 0x62, 0x00C0FFEE: 0x63}


def test_fastscan_is_ignored_by_configured_nodes_and_in_the_configuration_state():
    node = unconfigured()
    net, _ = network(node, build_node("skin"))
    net.inject(lss_frame(SWITCH_GLOBAL, CONFIGURATION))
    assert fastscan(net) is None
    net.inject(lss_frame(SWITCH_GLOBAL, WAITING))
    assert fastscan(net) == (VENDOR_ID, SKIN_PRODUCT, REVISION, 0x1234)


def test_fastscan_with_an_invalid_field_gets_no_answer():
    net, _ = network(unconfigured())
    replies(net, Frame(LSS_MASTER_COB_ID, struct.pack("<BIBBB", FASTSCAN, 0, 0x80, 0, 0)))
    for bit, sub, following in ((32, 0, 0), (31, 4, 0), (31, 0, 4)):
        frame = Frame(LSS_MASTER_COB_ID, struct.pack("<BIBBB", FASTSCAN, 0, bit, sub, following))
        assert replies(net, frame) == []


def test_lss_frames_shorter_than_8_bytes_or_remote_are_ignored():
    net, _ = network(unconfigured())
    assert net.inject(Frame(LSS_MASTER_COB_ID, bytes([IDENTIFY_NON_CONFIGURED]))) == []
    assert net.inject(Frame(LSS_MASTER_COB_ID, rtr=True, dlc=8)) == []


# -- building nodes ----------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["skin", "emg", "belt", "hand"])
def test_every_kind_can_be_built_unconfigured_and_assigned(kind):
    node = build_node(kind, UNCONFIGURED, serial=9)
    net, _ = network(node)
    assert select(net, *node.lss.identity()) == [bytes([SELECTED, *[0] * 7])]
    configure(net, 0x70)
    assert Frame(0x770, b"\x00") in net.inject(lss_frame(SWITCH_GLOBAL, WAITING))


def test_a_serial_number_outside_32_bits_is_refused():
    with pytest.raises(ConfigError, match="serial number"):
        build_node("skin", serial=1 << 32)


def test_an_unconfigured_device_node_needs_the_node_id_of_its_dictionary():
    from grasplink.profiles import load_profile

    with pytest.raises(ConfigError, match="unconfigured"):
        DeviceNode(load_profile("skin", 0x10), UNCONFIGURED)

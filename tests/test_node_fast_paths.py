"""The shortcuts a node and the lock-step bus take for speed behave as the long way did.

A node caches its deadline until its store's change count moves, a PDO engine is told
only of the changes it acts on (`interest`), a TPDO packs the store's entries directly,
and the bus leaves a node out of frames its acceptance filter drops. Each test here
pins what the shortcut must still see: a change made from outside any call, a TPDO made
event-driven (255) on the skin's samples, a PDO moved to another CAN-ID by SDO.
"""

from __future__ import annotations

import numpy as np

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import LSS_MASTER_COB_ID, NMT_COB_ID, Frame
from grasplink.core.protocol import FilteringDevice
from grasplink.devices.factory import build_node
from grasplink.devices.node import DeviceNode
from grasplink.devices.sources import FunctionSource
from grasplink.devices.store import ObjectStore
from grasplink.profiles import objects as obj
from tests.rawcan import FilteringListener

SKIN = 0x10
SDO_RX, SDO_TX = 0x600 + SKIN, 0x580 + SKIN
TPDO1, TPDO2 = 0x180 + SKIN, 0x280 + SKIN


def skin(source: FunctionSource | None = None) -> DeviceNode:
    return build_node("skin", SKIN, source or FunctionSource(lambda t: 3 + np.sin(7 * t)))


def sdo_write(net: LockstepNetwork, index: int, sub: int, value: int, size: int) -> None:
    """An expedited SDO download, as a master's tool sends it; asserts it is confirmed."""
    command = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
    data = bytes([command, index & 0xFF, index >> 8, sub]) + value.to_bytes(4, "little")
    replies = net.inject(Frame(SDO_RX, data))
    assert [f.data[0] for f in replies if f.can_id == SDO_TX] == [0x60], replies


def operational(node: DeviceNode) -> LockstepNetwork:
    net = LockstepNetwork([node])
    net.start()
    net.inject(Frame(NMT_COB_ID, bytes([0x01, 0])))
    return net


def test_the_bus_leaves_a_filtering_device_out_of_frames_it_drops_but_taps_see_all() -> None:
    recorder = FilteringListener(0x42, frozenset({TPDO2}))
    node = skin()
    assert isinstance(recorder, FilteringDevice) and isinstance(node, FilteringDevice)
    net = operational(node)
    net.add(recorder)
    tapped: list[int] = []
    net.taps.append(lambda t_us, frame, sender: tapped.append(frame.can_id))
    net.run_until(200_000)
    assert TPDO1 in tapped and TPDO2 in tapped
    assert recorder.heard and set(recorder.heard) == {TPDO2}


def test_a_node_accepts_nothing_off_lss_alone_unconfigured_and_its_services_running() -> None:
    node = skin()
    assert node.accepted_can_ids() == frozenset()
    net = operational(node)
    accepted = node.accepted_can_ids()
    assert {NMT_COB_ID, SDO_RX, LSS_MASTER_COB_ID, 0x080, 0x701} <= accepted  # 701h: 1016h
    assert 0x700 + SKIN in accepted  # its own heartbeat COB-ID: another node with its ID
    assert 0x181 not in accepted  # another node's process data concerns none of its services
    assert 0x77F not in accepted  # nor a heartbeat its consumer (1016h) does not watch
    unconfigured = build_node("skin", 0xFF)
    LockstepNetwork([unconfigured]).start()
    assert unconfigured.accepted_can_ids() == frozenset({LSS_MASTER_COB_ID})
    assert net.frames_delivered


def test_the_heartbeats_accepted_follow_what_1016h_watches() -> None:
    node = skin()
    net = operational(node)
    net.inject(Frame(0x725, bytes([5])))  # not watched: filtered out, nothing follows
    net.run_until(net.t_us + 2_000_000)
    assert 0x725 not in node.accepted_can_ids() and not node.consumer.any_timed_out()
    sdo_write(net, obj.HEARTBEAT_CONSUMER, 1, 0x25_01F4, 4)  # watch node 25h, 500 ms
    assert 0x725 in node.accepted_can_ids() and 0x701 not in node.accepted_can_ids()
    net.inject(Frame(0x725, bytes([5])))  # its first beat arms the monitor
    net.run_until(net.t_us + 600_000)
    assert node.consumer.any_timed_out()  # the beat reached the consumer, then stopped


def test_a_pdo_moved_to_another_can_id_by_sdo_is_accepted_there() -> None:
    node = skin()
    net = operational(node)
    net.inject(Frame(NMT_COB_ID, bytes([0x80, 0])))  # PRE-OPERATIONAL: PDOs configurable
    sdo_write(net, obj.TPDO_COMM, 1, 0xC0000000 | TPDO1, 4)  # invalid first (CiA 301)
    sdo_write(net, obj.TPDO_COMM, 1, 0x1F0, 4)  # bit 30 clear: RTR allowed
    accepted = node.accepted_can_ids()
    assert 0x1F0 in accepted  # RTR of the moved TPDO reaches it
    net.inject(Frame(NMT_COB_ID, bytes([0x01, 0])))
    net.run_until(net.t_us + 20_000)
    replies = net.inject(Frame(0x1F0, b"", rtr=True))
    assert [f.can_id for f in replies] == [0x1F0]


def test_a_store_change_from_outside_any_call_moves_the_cached_deadline() -> None:
    node = skin()
    net = operational(node)
    net.inject(Frame(NMT_COB_ID, bytes([0x80, 0])))
    sdo_write(net, obj.TPDO_COMM + 1, 1, 0xC0000000 | TPDO2, 4)
    sdo_write(net, obj.TPDO_COMM + 1, 2, 255, 1)  # TPDO2 sent on any change of its data
    sdo_write(net, obj.TPDO_COMM + 1, 5, 0, 2)  # no event timer
    sdo_write(net, obj.TPDO_COMM + 1, 1, 0x40000000 | TPDO2, 4)
    net.inject(Frame(NMT_COB_ID, bytes([0x01, 0])))
    net.run_until(net.t_us + 50_000)
    before = node.next_deadline_us()
    assert before is not None and before > net.t_us
    node.store.set(obj.SKIN_STATIC_FORCE_MN, 0, 123_456)  # a simulator writing, between calls
    after = node.next_deadline_us()  # the pending TPDO2 is due at once (no inhibit time)
    assert after is not None and after <= net.t_us
    sent: list[Frame] = []
    net.taps.append(lambda t_us, frame, sender: sent.append(frame))
    net.run_until(net.t_us + 1)
    assert [f.can_id for f in sent] == [TPDO2]
    assert int.from_bytes(sent[0].data[:4], "little", signed=True) == 123_456


def test_an_event_driven_tpdo_on_the_samples_sends_each_packet_once() -> None:
    """TPDO1 made type 255 reacts to its own mapped samples changing: the engine must be
    told of those writes (its interest grows with the mapping's type), and each packet
    goes out once, as when every change was notified."""
    node = skin()
    net = operational(node)
    net.inject(Frame(NMT_COB_ID, bytes([0x80, 0])))
    assert obj.SKIN_SAMPLE_SLOTS not in node.pdo._interest
    sdo_write(net, obj.TPDO_COMM, 1, 0xC0000000 | TPDO1, 4)
    sdo_write(net, obj.TPDO_COMM, 2, 255, 1)
    sdo_write(net, obj.TPDO_COMM, 1, 0x40000000 | TPDO1, 4)
    assert obj.SKIN_SAMPLE_SLOTS in node.pdo._interest
    net.inject(Frame(NMT_COB_ID, bytes([0x01, 0])))
    sent: list[Frame] = []
    net.taps.append(lambda t_us, frame, sender: sent.append(frame) if frame.can_id == TPDO1 else 0)
    net.run_until(net.t_us + 100_000)
    sequences = [f.data[6] for f in sent]
    assert len(sequences) >= 12
    assert sequences == [(sequences[0] + k) & 0xFF for k in range(len(sequences))]
    slots = node.store
    assert sent[-1].data[:6] == b"".join(
        int(slots.get(obj.SKIN_SAMPLE_SLOTS, s)).to_bytes(2, "little") for s in (1, 2, 3)
    )


def test_a_listener_with_an_interest_hears_only_those_indices_as_the_set_changes() -> None:
    node = skin()
    store: ObjectStore = node.store
    heard: list[int] = []
    interest: set[int] = {obj.SKIN_STATIC_FORCE_MN}
    store.add_listener(lambda index, sub, value: heard.append(index), interest=interest)
    changes = store.changes
    store.set(obj.SKIN_PACKET_SEQUENCE, 0, 7)
    store.set(obj.SKIN_STATIC_FORCE_MN, 0, 5)
    interest.add(obj.SKIN_PACKET_SEQUENCE)
    store.set(obj.SKIN_PACKET_SEQUENCE, 0, 8)
    store.set(obj.SKIN_PACKET_SEQUENCE, 0, 8)  # no change: no call, not counted
    assert heard == [obj.SKIN_STATIC_FORCE_MN, obj.SKIN_PACKET_SEQUENCE]
    assert store.changes == changes + 3

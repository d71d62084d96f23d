"""The NMT master starts nodes and gets them back after a reboot, even if a boot-up is lost."""

from __future__ import annotations

import struct
import uuid

import can

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.bus.runner import NodeRunner
from grasplink.bus.url import frame_to_message
from grasplink.core.frames import Frame
from grasplink.core.nmt import NmtCommand, NmtState
from grasplink.devices.factory import build_node
from grasplink.gateway.master import CONSUMER_ALLOWANCE_MS, NmtMaster
from grasplink.gateway.scripted import ScriptedMaster
from grasplink.profiles import objects as obj

MS = 1000


def test_master_starts_every_node_on_its_boot_up():
    nodes = [build_node(k) for k in ("skin", "belt", "emg", "hand")]
    master = NmtMaster()
    net = LockstepNetwork([master, *nodes])
    net.start()
    net.run_for(300 * MS)
    assert {n.node_id: n.state for n in nodes} == dict.fromkeys(
        (0x10, 0x20, 0x30, 0x40), NmtState.OPERATIONAL
    )
    assert all(master.nodes[n.node_id].state == NmtState.OPERATIONAL for n in nodes)


def test_node_seen_pre_operational_is_started_again_without_its_boot_up():
    belt = build_node("belt")
    master = NmtMaster()
    net = LockstepNetwork([master, belt])
    net.start()
    net.run_for(300 * MS)
    net.inject(Frame(0x000, bytes([0x80, belt.node_id])))  # someone sends it to pre-op
    assert belt.state == NmtState.PRE_OPERATIONAL
    net.run_for(300 * MS)  # its next heartbeat says 7Fh: the master starts it
    assert belt.state == NmtState.OPERATIONAL


def test_scripted_master_walks_the_enable_sequence_again_after_a_reboot():
    belt = build_node("belt")
    master = ScriptedMaster(belt_id=belt.node_id, belt_mrad_s=[(0.0, 5000.0)])
    net = LockstepNetwork([master, belt])
    net.start()
    net.run_for(1000 * MS)
    assert belt.app.velocity_mrad_s == 5000
    belt.power_off()
    net.run_for(500 * MS)
    net.start_device(belt)
    net.run_for(1500 * MS)
    assert belt.state == NmtState.OPERATIONAL
    assert belt.app.velocity_mrad_s == 5000
    status = struct.unpack("<H", belt.store.encode(0x6041))[0]
    assert status & 0x6F == 0x27  # OPERATION ENABLED again


# -- safe state held while the fault lasts ---------------------------------------------------
SKIN_WATCH_MS = 300
EMCY_BASE = 0x080
RPDO1_BASE = 0x200


def _belt_watching_the_skin(belt_nvm: dict[tuple[int, int], int] | None = None):
    """Master commanding the belt at 5 rad/s; the belt's 1016h:02 watches the skin."""
    skin, belt = build_node("skin"), build_node("belt")
    belt.store.nvm[(obj.HEARTBEAT_CONSUMER, 2)] = (skin.node_id << 16) | SKIN_WATCH_MS
    for (index, sub), value in (belt_nvm or {}).items():
        belt.store.nvm[(index, sub)] = value
    master = ScriptedMaster(belt_id=belt.node_id, belt_mrad_s=[(0.0, 5000.0)])
    net = LockstepNetwork([master, skin, belt])
    return net, master, skin, belt


def _run_sampling(net: LockstepNetwork, belt, until_us: int, step_us: int = MS) -> list[tuple]:
    """(t_us, velocity) of the belt every step until `until_us`."""
    samples = []
    while net.t_us < until_us:
        net.run_for(step_us)
        samples.append((net.t_us, belt.app.velocity_mrad_s))
    return samples


def _rpdo_times(log: list[tuple[int, Frame]], node_id: int) -> list[int]:
    return [t for t, f in log if f.can_id == RPDO1_BASE + node_id]


def test_belt_in_consumer_fault_stays_stopped_until_the_watched_skin_returns():
    net, master, skin, belt = _belt_watching_the_skin()
    net.start()
    net.run_for(1000 * MS)
    assert belt.app.velocity_mrad_s == 5000
    skin.power_off()
    off_us = net.t_us
    while_dead = _run_sampling(net, belt, off_us + 3000 * MS)
    # It stopped (quick stop, EMCY 8130h, PRE-OPERATIONAL) and stays stopped while the skin is dead.
    stopped_us = next(t for t, v in while_dead if v == 0)
    assert stopped_us < off_us + 500 * MS
    assert all(v == 0 for t, v in while_dead if t > stopped_us)
    assert belt.state == NmtState.PRE_OPERATIONAL
    assert master.nodes[belt.node_id].in_consumer_fault
    assert master.nodes[skin.node_id].lost
    net.start_device(skin)
    back_us = net.t_us
    after = _run_sampling(net, belt, back_us + 1000 * MS)
    turning_us = next(t for t, v in after if v != 0)
    # Error reset EMCY at the skin's boot-up -> NMT start -> enable sequence (3 command periods).
    assert back_us < turning_us <= back_us + 250 * MS
    assert belt.state == NmtState.OPERATIONAL and belt.app.velocity_mrad_s == 5000
    assert not master.nodes[belt.node_id].in_consumer_fault


def test_drive_kept_operational_by_1029h_gets_no_commands_while_in_consumer_fault():
    # 1029h:01 = 1: no NMT state change on a communication error
    net, _master, skin, belt = _belt_watching_the_skin({(obj.ERROR_BEHAVIOUR, 1): 1})
    log: list[tuple[int, Frame]] = []
    net.taps.append(lambda t, f, _sender: log.append((t, f)))
    net.start()
    net.run_for(1000 * MS)
    skin.power_off()
    off_us = net.t_us
    _run_sampling(net, belt, off_us + 2000 * MS)
    assert belt.state == NmtState.OPERATIONAL and belt.app.velocity_mrad_s == 0
    fault_us = next(t for t, f in log if f.can_id == EMCY_BASE + belt.node_id)
    assert not [t for t in _rpdo_times(log, belt.node_id) if t > fault_us]
    net.start_device(skin)
    back_us = net.t_us
    _run_sampling(net, belt, back_us + 1000 * MS)
    assert belt.app.velocity_mrad_s == 5000  # enable sequence walked afresh after the fault
    assert min(t for t in _rpdo_times(log, belt.node_id) if t > fault_us) > back_us


def _emcy(node_id: int, code: int, register: int, info: bytes = b"") -> Frame:
    return Frame(EMCY_BASE + node_id, struct.pack("<HB", code, register) + info.ljust(5, b"\0"))


def test_master_tracks_active_emcys_from_code_register_and_manufacturer_bytes():
    master = NmtMaster()
    master.start(0)
    master.receive(Frame(0x720, bytes([NmtState.OPERATIONAL])), 1000)
    master.receive(_emcy(0x20, 0x8130, 0x11, b"\x10"), 2000)
    status = master.nodes[0x20]
    assert status.in_consumer_fault
    assert status.active_emcy[0x8130].manufacturer == b"\x10\0\0\0\0"
    master.receive(_emcy(0x20, 0xFF01, 0x91), 3000)
    assert set(status.active_emcy) == {0x8130, 0xFF01} and status.error_register == 0x91
    # Error reset with errors remaining: the communication bit is gone, so is 8130h.
    master.receive(_emcy(0x20, 0x0000, 0x81), 4000)
    assert set(status.active_emcy) == {0xFF01} and not status.in_consumer_fault
    master.receive(_emcy(0x20, 0x0000, 0x00), 5000)
    assert status.active_emcy == {} and status.error_register == 0
    master.receive(Frame(EMCY_BASE + 0x20, b"\x30\x81\x11"), 6000)  # not an 8-byte EMCY
    assert status.active_emcy == {}


def test_node_in_consumer_fault_is_not_started_on_its_pre_operational_heartbeat():
    master = NmtMaster()
    master.start(0)
    master.receive(_emcy(0x20, 0x8130, 0x11), 1000)
    assert master.receive(Frame(0x720, bytes([NmtState.PRE_OPERATIONAL])), 2000) == []
    assert master.receive(_emcy(0x20, 0x0000, 0x00), 3000) == [
        NmtMaster.command(NmtCommand.START, 0x20)
    ]


# -- lost nodes -------------------------------------------------------------------------------
def test_powered_off_belt_gets_no_rpdos_until_it_boots_again():
    belt = build_node("belt")
    master = ScriptedMaster(belt_id=belt.node_id, belt_mrad_s=[(0.0, 5000.0)])
    log: list[tuple[int, Frame]] = []
    net = LockstepNetwork([master, belt])
    net.taps.append(lambda t, f, _sender: log.append((t, f)))
    net.start()
    net.run_for(1000 * MS)
    belt.power_off()
    off_us = net.t_us
    net.run_for(1000 * MS)
    assert master.nodes[belt.node_id].lost
    last_beat_us = max(t for t, f in log if f.can_id == 0x720 and t <= off_us)
    lost_us = last_beat_us + 3 * 100 * MS + CONSUMER_ALLOWANCE_MS * MS
    assert not [t for t in _rpdo_times(log, belt.node_id) if t > lost_us]
    net.start_device(belt)
    boot_us = net.t_us
    net.run_for(500 * MS)
    assert not master.nodes[belt.node_id].lost
    assert [t for t in _rpdo_times(log, belt.node_id) if t > boot_us]
    assert belt.app.velocity_mrad_s == 5000


def _sdo_write_u16(node_id: int, index: int, subindex: int, value: int) -> Frame:
    return Frame(0x600 + node_id, struct.pack("<BHBH2x", 0x2B, index, subindex, value))


def test_lost_node_that_reappears_without_boot_up_is_reset_before_it_gets_commands():
    belt = build_node("belt")
    master = ScriptedMaster(belt_id=belt.node_id, belt_mrad_s=[(0.0, 5000.0)])
    log: list[tuple[int, Frame]] = []
    net = LockstepNetwork([master, belt])
    net.taps.append(lambda t, f, _sender: log.append((t, f)))
    net.start()
    net.run_for(1000 * MS)
    net.inject(_sdo_write_u16(belt.node_id, obj.HEARTBEAT_PRODUCER_MS, 0, 0))  # falls silent
    net.run_for(700 * MS)
    assert master.nodes[belt.node_id].lost
    silent_rpdos = len(_rpdo_times(log, belt.node_id))
    net.inject(_sdo_write_u16(belt.node_id, obj.HEARTBEAT_PRODUCER_MS, 0, 100))
    back_us = net.t_us
    net.run_for(1000 * MS)
    reset = NmtMaster.command(NmtCommand.RESET_COMMUNICATION, belt.node_id)
    reset_us = next(t for t, f in log if f == reset and t > back_us)
    boot_us = next(t for t, f in log if f.can_id == 0x720 and f.data == b"\0" and t >= reset_us)
    rpdos = _rpdo_times(log, belt.node_id)
    assert len([t for t in rpdos if t <= boot_us]) == silent_rpdos
    assert [t for t in rpdos if t > boot_us]
    assert not master.nodes[belt.node_id].lost
    assert master.nodes[belt.node_id].boots == 2


def test_node_that_boots_but_never_sends_a_heartbeat_is_lost():
    belt = build_node("belt")
    belt.store.nvm[(obj.HEARTBEAT_PRODUCER_MS, 0)] = 0  # as with a missing 1017h default
    master = ScriptedMaster(belt_id=belt.node_id, belt_mrad_s=[(0.0, 5000.0)])
    net = LockstepNetwork([master, belt])
    net.start()
    net.run_for(1000 * MS)
    assert master.nodes[belt.node_id].lost


def _heartbeat(node_id: int, state: NmtState) -> Frame:
    return Frame(0x700 + node_id, bytes([state]))


def test_a_node_heard_late_within_the_scheduling_allowance_is_not_lost():
    """The master's consumer of a node's heartbeat allows 3 periods plus the same scheduling
    allowance the nodes' consumers of ours get (a loaded host reads frames late)."""
    master = NmtMaster()
    master.start(0)
    master.receive(_heartbeat(0x20, NmtState.INITIALISING), 1000)
    master.receive(_heartbeat(0x20, NmtState.OPERATIONAL), 100 * MS)
    silent_until_us = 100 * MS + 3 * 100 * MS + CONSUMER_ALLOWANCE_MS * MS
    assert master.next_deadline_us() is not None
    master.advance(silent_until_us)
    assert not master.nodes[0x20].lost
    master.advance(silent_until_us + 1)
    assert master.nodes[0x20].lost


def test_a_master_without_allowance_loses_a_node_after_three_periods():
    master = NmtMaster(loss_allowance_ms=0)
    master.start(0)
    master.receive(_heartbeat(0x20, NmtState.INITIALISING), 1000)
    master.receive(_heartbeat(0x20, NmtState.OPERATIONAL), 100 * MS)
    master.advance(400 * MS)
    assert not master.nodes[0x20].lost
    master.advance(400 * MS + 1)
    assert master.nodes[0x20].lost


def test_reset_of_a_returning_lost_node_is_repeated_until_it_takes():
    master = NmtMaster()
    master.start(0)
    reset = NmtMaster.command(NmtCommand.RESET_COMMUNICATION, 0x20)
    start = NmtMaster.command(NmtCommand.START, 0x20)
    assert master.receive(_heartbeat(0x20, NmtState.INITIALISING), 1000) == [start]
    master.receive(_heartbeat(0x20, NmtState.OPERATIONAL), 100 * MS)
    master.advance(700 * MS)
    assert master.nodes[0x20].lost
    assert master.receive(_heartbeat(0x20, NmtState.OPERATIONAL), 800 * MS) == [reset]
    # The reset was lost: the node still says OPERATIONAL, so it is sent again.
    assert master.receive(_heartbeat(0x20, NmtState.OPERATIONAL), 900 * MS) == [reset]
    assert not master.commandable(0x20)
    # It reset, but its boot-up was lost: PRE-OPERATIONAL after the reset counts as booted.
    assert master.receive(_heartbeat(0x20, NmtState.PRE_OPERATIONAL), 1000 * MS) == [start]
    assert not master.nodes[0x20].lost and master.nodes[0x20].boots == 2


def test_lost_node_in_consumer_fault_is_reset_only_once_the_fault_clears():
    master = NmtMaster()
    master.start(0)
    master.receive(_heartbeat(0x20, NmtState.INITIALISING), 1000)
    master.receive(_emcy(0x20, 0x8130, 0x11), 2000)
    master.receive(_heartbeat(0x20, NmtState.PRE_OPERATIONAL), 100 * MS)
    master.advance(700 * MS)
    assert master.nodes[0x20].lost
    # A reset would wipe the fault (and the node's unarmed consumer would let it run).
    assert master.receive(_heartbeat(0x20, NmtState.PRE_OPERATIONAL), 800 * MS) == []
    assert master.receive(_emcy(0x20, 0x0000, 0x00), 850 * MS) == [
        NmtMaster.command(NmtCommand.RESET_COMMUNICATION, 0x20)
    ]


# -- a stalled runner hears the heartbeats queued meanwhile before it judges loss --------------
def _stalled_master(max_batch: int, supersede: bool = True) -> NmtMaster:
    """A master on a runner whose thread stalls 1 s (> 300 ms consumer time) while a node
    keeps talking: 20 TPDOs and then its heartbeat wait in the bus when the runner wakes.

    Driven step by step on a frozen clock (no thread, no sleeps): the python-can virtual
    bus queues a frame in the other handle the moment it is sent.
    """
    channel = f"master-stall-{uuid.uuid4().hex}"
    runner_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    node_bus = can.Bus(interface="virtual", channel=channel, receive_own_messages=False)
    now = [0]
    master = NmtMaster(heartbeat_ms=100, node_heartbeat_ms=100, autostart=False)
    runner = NodeRunner(
        runner_bus, [master], clock_us=lambda: now[0], max_batch=max_batch, supersede=supersede
    )
    try:
        runner.power_on()
        node_bus.send(frame_to_message(Frame(0x700 + 5, bytes([NmtState.OPERATIONAL]))))
        runner.step()
        assert master.nodes[5].last_seen_us == 0
        now[0] = 1_000_000  # the stall: the loss deadline (300 ms) is long past
        for i in range(20):
            node_bus.send(frame_to_message(Frame(0x185, bytes([i]))))
        node_bus.send(frame_to_message(Frame(0x705, bytes([NmtState.OPERATIONAL]))))
        runner.step()
        return master
    finally:
        runner_bus.shutdown()
        node_bus.shutdown()


def test_runner_after_a_stall_delivers_queued_heartbeats_before_the_loss_check():
    master = _stalled_master(max_batch=128)
    assert not master.nodes[5].lost
    assert master.nodes[5].last_seen_us == 1_000_000


def test_runner_delivering_one_frame_per_step_would_lose_the_node_after_a_stall():
    # What a batch of one (the runner before batching) does without reading the backlog
    # at once: the loss check runs while the heartbeat still waits behind the TPDOs.
    assert _stalled_master(max_batch=1, supersede=False).nodes[5].lost


def test_runner_behind_by_more_than_a_batch_hears_the_heartbeat_behind_the_pdos():
    # a batch of one, then the backlog read at once: the 19 TPDOs but the newest dropped
    assert not _stalled_master(max_batch=1).nodes[5].lost

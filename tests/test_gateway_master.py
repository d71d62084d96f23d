"""The NMT master starts nodes and gets them back after a reboot, even if a boot-up is lost."""

from __future__ import annotations

import struct

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import Frame
from grasplink.core.nmt import NmtState
from grasplink.devices.factory import build_node
from grasplink.gateway.master import NmtMaster
from grasplink.gateway.scripted import ScriptedMaster

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

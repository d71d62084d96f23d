"""A running node meets frames on its own heartbeat COB-ID: guarding RTRs, a duplicate node.

Node guarding is not supported (no 100Ch/100Dh in any EDS): a guarding RTR is ignored and
the node stays up. A heartbeat or boot-up at our node-ID that we did not send is a
duplicate node-ID: EMCY 8150h (CiA 301 "CAN-ID collision"), the node keeps running.
"""

from __future__ import annotations

import struct
import time

import can
import pytest

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import Frame
from grasplink.core.nmt import NmtState
from grasplink.devices import emcy as em
from grasplink.devices.factory import build_node
from grasplink.profiles import objects as obj
from tests.rawcan import Recorder, nmt, read_uint
from tests.test_cli import _end, _spawn, hub  # noqa: F401  (hub: the fixture)

EMG = 0x30
HEARTBEAT, EMCY = 0x700 + EMG, 0x080 + EMG
MS = 1000


def _running_emg() -> tuple[LockstepNetwork, Recorder]:
    net = LockstepNetwork([build_node("emg")])
    rec = Recorder(net)
    net.start()
    nmt(net, 1, EMG)  # start: OPERATIONAL
    net.run_until(200 * MS)
    return net, rec


def _emcy_codes(rec: Recorder) -> list[int]:
    return [struct.unpack_from("<H", f.data)[0] for _, f in rec.of(EMCY)]


@pytest.mark.parametrize("state", ["PRE_OPERATIONAL", "OPERATIONAL", "STOPPED"])
def test_guarding_rtr_is_ignored_and_the_node_stays_up(state):
    net = LockstepNetwork([build_node("emg")])
    rec = Recorder(net)
    net.start()
    command = {"OPERATIONAL": 1, "STOPPED": 2, "PRE_OPERATIONAL": 0x80}[state]
    nmt(net, command, EMG)
    for i in range(1, 51):  # an RTR every 10 ms for 0.5 s, as a guarding master sends
        net.run_until(i * 10 * MS)
        assert net.inject(Frame(HEARTBEAT, rtr=True, dlc=1)) == []
    node = net.devices[0]
    assert node.state == NmtState[state] and node.duplicate_frames == 0
    beats = [f for _, f in rec.of(HEARTBEAT)[1:] if not f.rtr]
    assert len(beats) == 5 and {f.data for f in beats} == {bytes([NmtState[state]])}
    assert _emcy_codes(rec) == []


def test_foreign_heartbeat_raises_can_id_collision_emcy_and_the_node_keeps_running():
    net, rec = _running_emg()
    node = net.devices[0]
    own: list[int] = []  # the node's own heartbeats
    net.taps.append(
        lambda t, f, sender: own.append(t) if sender is node and f.can_id == HEARTBEAT else None
    )
    for _ in range(5):  # the duplicate beats every 100 ms
        net.run_until(net.t_us + 100 * MS)
        net.inject(Frame(HEARTBEAT, bytes([NmtState.OPERATIONAL])))
    assert node.state == NmtState.OPERATIONAL and node.duplicate_frames == 5
    assert node.collision_active
    frames = [f for _, f in rec.of(EMCY)]
    assert len(frames) == 1, "one EMCY per episode, not one per foreign frame"
    code, register = struct.unpack_from("<HB", frames[0].data)
    assert code == em.CAN_ID_COLLISION == 0x8150
    assert register & em.REG_COMMUNICATION and register & em.REG_GENERIC
    assert frames[0].data[3:5] == HEARTBEAT.to_bytes(2, "little")  # the colliding CAN-ID
    assert read_uint(net, EMG, obj.ERROR_HISTORY, 1) & 0xFFFF == 0x8150
    assert len(own) == 5, "the node went on beating meanwhile"
    # quiet for the clear time: the error resets (0000h)
    net.run_until(net.t_us + 1_100 * MS)
    assert _emcy_codes(rec) == [0x8150, 0x0000] and not node.collision_active
    assert node.state == NmtState.OPERATIONAL


def test_foreign_bootup_is_a_collision_too():
    net, rec = _running_emg()
    net.inject(Frame(HEARTBEAT, b"\x00"))
    assert _emcy_codes(rec) == [0x8150]
    assert net.devices[0].state == NmtState.OPERATIONAL


def test_start_up_probe_ignores_a_guarding_rtr_on_its_heartbeat_id():
    from grasplink.cli import _refuse_if_node_id_taken

    class _OneFrameBus:
        def __init__(self, msg: can.Message) -> None:
            self.msgs = [msg]

        def recv(self, timeout: float | None = None) -> can.Message | None:
            if self.msgs:
                return self.msgs.pop()
            time.sleep(timeout or 0)  # nothing more on this bus until the probe ends
            return None

    rtr = can.Message(arbitration_id=HEARTBEAT, is_remote_frame=True, dlc=1, is_extended_id=False)
    _refuse_if_node_id_taken(_OneFrameBus(rtr), EMG, "virtual")  # no exception


@pytest.mark.slow
def test_node_process_survives_guarding_rtrs_and_a_duplicate_and_warns(hub):  # noqa: F811
    from grasplink.bus import open_bus

    node, out, err = _spawn("node", "emg", "--bus", hub.url, "--duration", "4")
    bus = open_bus(hub.url)
    try:
        out.wait_for("running on")
        for _ in range(5):
            bus.send(
                can.Message(
                    arbitration_id=HEARTBEAT, is_remote_frame=True, dlc=1, is_extended_id=False
                )
            )
        bus.send(can.Message(arbitration_id=HEARTBEAT, data=b"\x05", is_extended_id=False))
        err.wait_for(r"warning: another node transmits on 0x730 .*still running")
        out.wait_for(r"stopped: .* 1 from another node on our heartbeat COB-ID", timeout_s=20)
        assert node.wait(10) == 0
    finally:
        bus.shutdown()
        _end(node)

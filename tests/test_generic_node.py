"""`grasplink node --eds FILE`: a node built from another project's EDS, on a bus, with the
values a script gives it (issue 24, item 2)."""

from __future__ import annotations

import queue
import time
import uuid
from pathlib import Path

import can
import canopen
import pytest

from grasplink.bus.runner import NodeRunner
from grasplink.cli import main
from grasplink.devices.factory import build_from_file
from grasplink.errors import ConfigError

DEMO = Path(__file__).resolve().parent / "profiles" / "field" / "canopendemo_demoDevice.eds"
ANALOGUE_IN_1 = (0x6401, 1)  # CiA 401: analogue input 16-bit, channel 1
BOOT_WAIT_S = 10.0  # a bound, not a delay: the boot-up comes within milliseconds


def wait_for_boot_up(frames: queue.Queue[bytes]) -> None:
    """The next boot-up among the node's 700h frames (heartbeats are skipped)."""
    deadline = time.monotonic() + BOOT_WAIT_S
    while frames.get(timeout=max(0.0, deadline - time.monotonic())) != b"\x00":
        pass


def test_a_node_from_a_cia_401_file_reports_the_value_a_script_gives_it_over_sdo():
    channel = f"generic-{uuid.uuid4().hex}"
    node, _ = build_from_file(DEMO, 0x35, [(0x6401, 1, 1234)])
    device_bus = can.Bus(interface="virtual", channel=channel)
    network = canopen.Network(can.Bus(interface="virtual", channel=channel))
    network.connect()
    boot_ups: queue.Queue[bytes] = queue.Queue()  # listening before the node can boot
    network.subscribe(0x700 + 0x35, lambda can_id, data, t: boot_ups.put(bytes(data)))
    remote = network.add_node(0x35, str(DEMO))
    remote.sdo.RESPONSE_TIMEOUT = 5.0  # a bound for a loaded machine, not a delay
    runner = NodeRunner(device_bus, [node], max_wait_s=0.01, name="generic").start()
    try:
        wait_for_boot_up(boot_ups)
        value = int.from_bytes(remote.sdo.upload(*ANALOGUE_IN_1), "little", signed=True)
        assert value == 1234
        vendor = int.from_bytes(remote.sdo.upload(0x1018, 1), "little")
        assert vendor == remote.object_dictionary[0x1018][1].default
        remote.nmt.send_command(0x81)  # reset node: the script's value is its default
        wait_for_boot_up(boot_ups)
        assert int.from_bytes(remote.sdo.upload(*ANALOGUE_IN_1), "little", signed=True) == 1234
    finally:
        runner.stop()
        network.disconnect()
        device_bus.shutdown()


def test_grasplink_node_eds_runs_a_vendors_file_on_a_bus(capsys):
    argv = ["node", "--eds", str(DEMO), "--node-id", "0x35", "--value", "6401sub1=7"]
    assert main([*argv, "--bus", f"virtual:{uuid.uuid4().hex}", "--duration", "0.3"]) == 0
    assert "canopendemo_demoDevice.eds node 0x35 running on virtual:" in capsys.readouterr().out


def test_values_are_checked_against_the_file():
    node, _ = build_from_file(DEMO, 0x35, [(0x6401, 1, -5)])
    assert node.store.get(*ANALOGUE_IN_1) == -5
    with pytest.raises(ConfigError, match="no object 0x5FFF"):
        build_from_file(DEMO, 0x35, [(0x5FFF, 0, 1)])
    with pytest.raises(ConfigError, match="does not fit"):
        build_from_file(DEMO, 0x35, [(0x6401, 1, 1 << 20)])
    with pytest.raises(ConfigError, match="give a node-ID"):
        build_from_file(DEMO)


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["node"], "name a node kind or --eds FILE"),
        (["node", "skin", "--eds", str(DEMO)], "not both or neither"),
        (["node", "skin", "--value", "6401sub1=3"], "--value sets objects of a node built"),
        (["node", "--eds", str(DEMO), "--value", "6401=x"], "'x' is not a number"),
        (["node", "--eds", str(DEMO), "--value", "64x1sub1=3"], "expected OBJECT=VALUE"),
    ],
)
def test_a_bad_node_command_is_one_line_naming_the_problem(argv, needle, capsys):
    assert main([*argv, "--bus", "virtual:nothing", "--duration", "0.1"]) != 0
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1


E35 = DEMO.with_name("python-canopen_e35.eds")  # a CiA 402 drive: RPDO1 60FFh + 6040h


def test_a_vendors_cia_402_drive_is_brought_up_and_follows_the_belt_command(tmp_path):
    """python-canopen's e35.eds as the belt (its velocity bound in the description): its
    PDOs are synchronous (transmission type 1), so the gateway produces SYNC; the CiA 402
    handshake enables it and its actual velocity follows the command."""
    import tomllib

    from grasplink.bus.lockstep import LockstepNetwork
    from grasplink.core.nmt import NmtState
    from grasplink.devices.cia402 import DriveState
    from grasplink.gateway.config import parse_config
    from grasplink.gateway.service import Gateway
    from grasplink.profiles.kinds import KINDS

    off = "".join(f"[nodes.{kind}]\nenabled = false\n" for kind in KINDS if kind != "belt")
    text = (
        "[gateway]\nsync_period_ms = 10\n"
        + off
        + f'[nodes.belt]\nnode_id = 0x20\neds = "{E35}"\n[nodes.belt.drive]\n'
        'target = "60FFsub0"\nunits_per_rad_s = 1000.0\n'
    )
    gateway = Gateway(parse_config(tomllib.loads(text), str(tmp_path / "gw.toml")))
    drive, _ = build_from_file(E35, 0x20)
    network = LockstepNetwork([gateway, drive])
    network.start()
    network.run_until(1_000_000)
    assert drive.state is NmtState.OPERATIONAL
    assert drive.app.drive.state is DriveState.OPERATION_ENABLED
    assert gateway.snapshot().nodes["belt"].pdos_dropped == 0  # its TPDOs decode as mapped


def test_a_vendors_drive_enabled_moves_its_actual_value_towards_its_target():
    from grasplink.bus.lockstep import LockstepNetwork
    from grasplink.core.frames import Frame
    from grasplink.core.nmt import NmtCommand

    drive, _ = build_from_file(E35, 0x20)
    network = LockstepNetwork([drive])
    network.start()
    drive.receive(Frame(0, bytes([NmtCommand.START, 0x20])), 0)
    for controlword in (0x06, 0x07, 0x0F):  # shutdown, switch on, enable operation
        drive.store.set(0x6040, 0, controlword)
    drive.store.set(0x60FF, 0, 3000)
    network.run_for(25_000)  # half a time constant: on its way
    assert 0 < drive.store.get(0x606C) < 3000
    network.run_for(500_000)  # ten time constants: there
    assert drive.store.get(0x606C) == 3000
    assert drive.store.get(0x6041) & 0x6F == 0x27  # operation enabled

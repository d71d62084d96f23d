"""The sans-IO SDO client configures real device nodes over the lock-step bus."""

from __future__ import annotations

import struct

import pytest

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import Frame
from grasplink.devices.factory import build_node
from grasplink.devices.sdo_abort import AbortCode
from grasplink.gateway.sdo_client import SdoClient
from grasplink.profiles import objects as obj

SKIN = 0x10


class ClientDevice:
    """The client as a bus participant (what the gateway does around it)."""

    node_id = 0x01

    def __init__(self, client: SdoClient):
        self.client = client

    def start(self, t_us: int) -> list[Frame]:
        return []

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        return self.client.receive(frame, t_us)

    def advance(self, t_us: int) -> list[Frame]:
        return self.client.advance(t_us)

    def next_deadline_us(self) -> int | None:
        return self.client.next_deadline_us()


def network(*devices):
    net = LockstepNetwork(list(devices))
    net.start()
    return net


def run(net: LockstepNetwork, ms: int = 50) -> None:
    net.run_until(net.t_us + ms * 1000)


def test_expedited_write_then_read_back():
    skin, client = build_node("skin", SKIN), SdoClient(SKIN)
    net = network(ClientDevice(client), skin)
    write = client.download(obj.HEARTBEAT_PRODUCER_MS, 0, struct.pack("<H", 250))
    read = client.upload(obj.HEARTBEAT_PRODUCER_MS, 0)
    run(net)
    assert write.ok and read.ok
    assert struct.unpack("<H", read.data)[0] == 250
    assert skin.store.get(obj.HEARTBEAT_PRODUCER_MS) == 250
    assert client.idle


def test_segmented_upload_reads_a_string():
    skin, client = build_node("skin", SKIN), SdoClient(SKIN)
    net = network(ClientDevice(client), skin)
    name = client.upload(0x1008, 0)
    run(net)
    assert name.ok and len(name.data) > 4
    assert name.data.decode() == skin.store.get(0x1008)


def test_segmented_download_is_assembled_by_the_server():
    skin, client = build_node("skin", SKIN), SdoClient(SKIN)
    net = network(ClientDevice(client), skin)
    transfer = client.download(0x1017, 0, struct.pack("<H", 100) + bytes(4))  # 6 bytes: too long
    run(net)
    assert not transfer.ok
    assert transfer.abort_code in (AbortCode.LENGTH_TOO_HIGH, AbortCode.LENGTH_MISMATCH)


def test_refused_write_carries_the_servers_abort_code():
    skin, client = build_node("skin", SKIN), SdoClient(SKIN)
    net = network(ClientDevice(client), skin)
    transfer = client.download(0x1000, 0, struct.pack("<I", 1))
    after = client.upload(obj.HEARTBEAT_PRODUCER_MS, 0)
    run(net)
    assert transfer.done and not transfer.ok
    assert transfer.abort_code == AbortCode.READ_ONLY
    assert "READ_ONLY" in transfer.describe()
    assert after.ok, "a refused transfer does not block the ones queued behind it"


def test_silent_server_times_out_and_the_client_aborts():
    client = SdoClient(0x22, timeout_us=100_000)
    sent: list[Frame] = []
    net = network(ClientDevice(client))
    net.taps.append(lambda t, frame, sender: sent.append(frame))
    transfer = client.upload(0x1000, 0)
    run(net, 300)
    assert transfer.abort_code == AbortCode.TIMEOUT
    assert sent[-1].data[0] == 0x80 and struct.unpack_from("<I", sent[-1].data, 4)[0] == 0x05040000


def test_wrong_toggle_bit_aborts_the_transfer():
    client = SdoClient(0x22)
    transfer = client.upload(0x1008, 0)
    (request,) = client.advance(0)
    initiate = bytes([0x41]) + request.data[1:4] + struct.pack("<I", 20)
    client.receive(Frame(0x5A2, initiate), 10)
    (abort,) = client.receive(Frame(0x5A2, bytes([0x10]) + b"abcdefg"), 20)
    assert transfer.abort_code == AbortCode.TOGGLE_BIT
    assert abort.data[0] == 0x80


@pytest.mark.parametrize("payload", [b"", bytes(3), bytes(9)[:8].replace(b"\0", b"\xff")])
def test_garbage_response_never_completes_a_transfer_as_ok(payload):
    client = SdoClient(0x22)
    transfer = client.upload(0x1000, 0)
    client.advance(0)
    client.receive(Frame(0x5A2, payload), 10)
    assert not transfer.ok

"""Raw CANopen frames for tests that act as an external tool on a LockstepNetwork."""

from __future__ import annotations

import struct

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import Frame


class SdoAbortReply(Exception):
    def __init__(self, code: int):
        self.code = code
        super().__init__(f"abort 0x{code:08X}")


def _reply(net: LockstepNetwork, node_id: int, request: bytes) -> bytes:
    caused = net.inject(Frame(0x600 + node_id, request))
    replies = [f.data for f in caused if f.can_id == 0x580 + node_id]
    assert replies, "no SDO reply"
    data = replies[0]
    if data[0] == 0x80:
        raise SdoAbortReply(struct.unpack_from("<I", data, 4)[0])
    return data


def sdo_read(net: LockstepNetwork, node_id: int, index: int, sub: int = 0) -> bytes:
    data = _reply(net, node_id, struct.pack("<BHB4x", 0x40, index, sub))
    if data[0] & 0x02:  # expedited
        size = 4 - ((data[0] >> 2) & 3) if data[0] & 0x01 else 4
        return bytes(data[4 : 4 + size])
    size = struct.unpack_from("<I", data, 4)[0]
    out, toggle = b"", 0
    while True:
        seg = _reply(net, node_id, bytes([0x60 | toggle << 4]) + bytes(7))
        unused = (seg[0] >> 1) & 7
        out += bytes(seg[1 : 8 - unused])
        toggle ^= 1
        if seg[0] & 1:
            assert len(out) == size
            return out


def sdo_write(net: LockstepNetwork, node_id: int, index: int, sub: int, data: bytes) -> None:
    assert len(data) <= 4
    command = 0x23 | ((4 - len(data)) << 2)
    reply = _reply(net, node_id, struct.pack("<BHB", command, index, sub) + data.ljust(4, b"\0"))
    assert reply[0] == 0x60, reply


def read_uint(net, node_id, index, sub=0) -> int:
    return int.from_bytes(sdo_read(net, node_id, index, sub), "little")


def read_int(net, node_id, index, sub=0) -> int:
    return int.from_bytes(sdo_read(net, node_id, index, sub), "little", signed=True)


def write_uint(net, node_id, index, sub, value: int, size: int) -> None:
    sdo_write(net, node_id, index, sub, value.to_bytes(size, "little"))


def write_int(net, node_id, index, sub, value: int, size: int) -> None:
    sdo_write(net, node_id, index, sub, value.to_bytes(size, "little", signed=True))


def abort_of(fn, *args) -> int:
    try:
        fn(*args)
    except SdoAbortReply as exc:
        return exc.code
    raise AssertionError("expected an SDO abort")


def nmt(net: LockstepNetwork, command: int, node_id: int = 0) -> list[Frame]:
    return net.inject(Frame(0x000, bytes([command, node_id])))


class Listener:
    """A device on the network that keeps the CAN-ID of every frame it hears."""

    def __init__(self, node_id: int) -> None:
        self.node_id = node_id
        self.heard: list[int] = []

    def start(self, t_us: int) -> list[Frame]:
        return []

    def receive(self, frame: Frame, t_us: int) -> list[Frame]:
        self.heard.append(frame.can_id)
        return []

    def advance(self, t_us: int) -> list[Frame]:
        return []

    def next_deadline_us(self) -> int | None:
        return None


class FilteringListener(Listener):
    """A Listener with an acceptance filter (a `FilteringDevice`)."""

    def __init__(self, node_id: int, accepted: frozenset[int]) -> None:
        super().__init__(node_id)
        self.accepted = accepted

    def accepted_can_ids(self) -> frozenset[int]:
        return self.accepted


class Recorder:
    """A tap keeping (t_us, frame) of every frame on the network."""

    def __init__(self, net: LockstepNetwork):
        self.frames: list[tuple[int, Frame]] = []
        net.taps.append(lambda t, f, sender: self.frames.append((t, f)))

    def of(self, can_id: int, since_us: int = 0) -> list[tuple[int, Frame]]:
        return [(t, f) for t, f in self.frames if f.can_id == can_id and t >= since_us]

    def clear(self) -> None:
        self.frames.clear()

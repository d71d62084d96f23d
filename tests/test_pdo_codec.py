"""PDOs are packed and unpacked through the EDS mapping, and refuse what does not fit."""

from __future__ import annotations

import math

import pytest

from grasplink.bus.lockstep import LockstepNetwork
from grasplink.core.frames import Frame
from grasplink.devices.factory import build_node
from grasplink.errors import PdoError
from grasplink.profiles import objects as obj
from grasplink.profiles.pdo_codec import PdoCodec
from tests.rawcan import nmt

CONTROLWORD = (obj.CONTROLWORD, 0)
BELT_TARGET = (obj.BELT_TARGET_VELOCITY_MRAD_S, 0)
HAND_TARGET = (obj.HAND_TARGET_GRIP_MN, 0)


def test_encoded_rpdo_is_what_the_node_stores():
    hand = build_node("hand", 0x40)
    net = LockstepNetwork([hand])
    net.start()
    nmt(net, 0x01, 0x40)
    can_id, data = PdoCodec("hand", 0x40).encode(1, {CONTROLWORD: 0x06, HAND_TARGET: 12_345})
    net.inject(Frame(can_id, data))
    net.run_until(net.t_us + 1000)
    assert hand.store.get(obj.HAND_TARGET_GRIP_MN) == 12_345
    assert hand.store.get(obj.CONTROLWORD) == 0x06


def test_decoded_tpdo_gives_the_mapped_objects():
    codec = PdoCodec("hand", 0x40)
    (can_id,) = codec.tpdo_can_ids()
    values = codec.decode(can_id, bytes([0x37, 0x02, 0x10, 0x27, 0, 0]))
    assert values == {(obj.STATUSWORD, 0): 0x0237, (obj.HAND_ACTUAL_GRIP_MN, 0): 10_000}


@pytest.mark.parametrize("velocity", [1e30, -1e300, 8001, -7401, math.nan, math.inf, 0.5])
def test_value_the_node_would_refuse_is_never_packed(velocity):
    codec = PdoCodec("belt", 0x20)
    with pytest.raises(PdoError, match="Target velocity"):
        codec.encode(1, {CONTROLWORD: 0x0F, BELT_TARGET: velocity})


def test_missing_or_unmapped_values_are_refused():
    codec = PdoCodec("belt", 0x20)
    with pytest.raises(PdoError, match="no value for Target velocity"):
        codec.encode(1, {CONTROLWORD: 0x0F})
    with pytest.raises(PdoError, match="maps no 0x6040:1"):
        codec.encode(1, {CONTROLWORD: 0x0F, BELT_TARGET: 0, (0x6040, 1): 3})
    with pytest.raises(PdoError, match="no RPDO9"):
        codec.encode(9, {})


def test_frame_of_the_wrong_length_or_id_is_refused():
    codec = PdoCodec("skin", 0x10)
    can_id = min(codec.tpdo_can_ids())
    with pytest.raises(PdoError, match="needs 7"):
        codec.decode(can_id, bytes(8))
    with pytest.raises(PdoError, match="no TPDO"):
        codec.decode(0x7FF, bytes(2))


@pytest.mark.parametrize("kind", ["skin", "emg", "belt", "hand"])
def test_whole_byte_mappings_decode_in_one_struct_as_canopen_decodes_them(kind):
    """Every TPDO of the shipped profiles maps whole bytes: the codec unpacks it with one
    struct made from the mapping, giving what canopen's per-object decoding gives."""
    import random

    codec = PdoCodec(kind, 0x20)
    rng = random.Random(kind)
    assert {c for c, (_, _, unpack) in codec._tpdo_layouts.items() if unpack} == (
        codec.tpdo_can_ids()
    )
    for can_id, pdo in codec._tpdo_by_can_id.items():
        for _ in range(200):
            data = bytes(rng.randrange(256) for _ in range((pdo.length + 7) // 8))
            assert codec.decode(can_id, data) == codec._decode_by_map(pdo, data)


def test_a_mapping_with_bit_fields_is_left_to_canopen():
    """A mapping that is not whole bytes (a 4-bit object) gets no struct: canopen decodes it."""
    from grasplink.profiles.pdo_codec import _byte_layout

    codec = PdoCodec("hand", 0x40)
    pdo = next(iter(codec._tpdo_by_can_id.values()))
    assert _byte_layout(pdo) is not None
    pdo.map[0].length = 4  # the statusword's low nibble only
    assert _byte_layout(pdo) is None


def test_an_odd_sized_integer_is_left_to_canopen():
    """INTEGER24 unpacks through canopen's own subclass of struct (3 bytes, sign-extended):
    no one-struct layout is made of it."""
    from types import SimpleNamespace

    from canopen import objectdictionary as od

    from grasplink.profiles.pdo_codec import _byte_layout

    entry = od.ODVariable("odd", 0x2000, 0)
    entry.data_type = od.INTEGER24
    mapping = SimpleNamespace(map=[SimpleNamespace(od=entry, offset=0, length=24)], length=24)
    assert _byte_layout(mapping) is None  # type: ignore[arg-type]
    entry.data_type = od.INTEGER32
    mapping.map[0].length = mapping.length = 32
    assert _byte_layout(mapping) is not None  # type: ignore[arg-type]

"""Pack and unpack a node's PDOs through its object dictionary's PDO mapping.

Process data is never laid out by hand: the EDS says which objects a PDO
maps, in which order and with which data type, and python-canopen's PDO
maps (read from the dictionary, on a detached `canopen.Network` that never
touches a bus) do the bit packing. A frame whose length does not match its
mapping, or a value outside the mapped object's limits, is refused with an
error naming the PDO and the object, so a caller can drop and count it.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import canopen
from canopen.objectdictionary import ODVariable
from canopen.pdo.base import PdoMap

from grasplink.errors import PdoError
from grasplink.profiles import load_profile

# canopen logs a warning before it refuses an out-of-range value; we raise our own error.
logging.getLogger("canopen.objectdictionary").setLevel(logging.ERROR)
logging.getLogger("canopen.variable").setLevel(logging.ERROR)

INTEGER_TYPES = frozenset(canopen.objectdictionary.INTEGER_TYPES)
Key = tuple[int, int]  # (index, subindex) of a mapped object


@dataclass(frozen=True)
class MappedObject:
    index: int
    subindex: int
    name: str
    low: int | float | None
    high: int | float | None

    @property
    def key(self) -> Key:
        return (self.index, self.subindex)


class PdoCodec:
    """All PDOs of one node (`kind` or an EDS path at `node_id`), by CAN-ID and by number."""

    def __init__(self, kind_or_path: str | Path, node_id: int):
        self._build(load_profile(kind_or_path, node_id), node_id)

    @classmethod
    def from_od(cls, od: canopen.ObjectDictionary, node_id: int) -> PdoCodec:
        """The codec of a dictionary already loaded (a gateway's node keeps one, and every
        pass at start shares it instead of parsing the file again). Only read: the maps are
        the codec's own, so several codecs may share one dictionary."""
        codec: PdoCodec = cls.__new__(cls)
        codec._build(od, node_id)
        return codec

    def _build(self, od: canopen.ObjectDictionary, node_id: int) -> None:
        self.node_id = node_id
        network = canopen.Network()  # never connected: only holds the PDO maps' subscriptions
        self._node = canopen.RemoteNode(node_id, od)
        network.add_node(self._node)
        self.unreadable: list[str] = []  # PDOs whose file entries canopen cannot read
        for pdos in (self._node.tpdo, self._node.rpdo):
            for pdo in pdos.map.values() if pdos.map is not None else ():
                try:
                    pdo.read(from_od=True)
                except (KeyError, ValueError) as exc:  # e.g. a map without its entries
                    self.unreadable.append(f"{pdo.name}: {exc}")
                    pdo.enabled = False
        tpdos = self._node.tpdo.map.values() if self._node.tpdo.map is not None else ()
        self._tpdo_by_can_id = {
            m.cob_id: m for m in tpdos if m.cob_id is not None and m.enabled and len(m.map)
        }
        # per CAN-ID: (payload bytes, keys in map order, their struct's unpack or None)
        self._tpdo_layouts = {
            can_id: ((pdo.length + 7) // 8, *(_byte_layout(pdo) or ((), None)))
            for can_id, pdo in self._tpdo_by_can_id.items()
        }

    def od_entry(self, index: int, subindex: int = 0) -> ODVariable:
        """An object of the node's dictionary (its type encodes SDO values)."""
        entry = self._node.object_dictionary[index]
        return entry if isinstance(entry, ODVariable) else entry[subindex]

    # -- receive (TPDOs the node sends) ---------------------------------------------------
    def tpdo_can_ids(self) -> frozenset[int]:
        return frozenset(self._tpdo_by_can_id)

    def tpdo_keys(self, can_id: int) -> tuple[Key, ...]:
        """The objects TPDO `can_id` maps, in map order."""
        return tuple((v.od.index, v.od.subindex) for v in self._tpdo(can_id).map)

    def tpdo_objects(self) -> tuple[ODVariable, ...]:
        """Every object the node's TPDOs map, each once: TPDO by TPDO, in map order."""
        seen: dict[Key, ODVariable] = {}
        for pdo in self._tpdo_by_can_id.values():
            for var in pdo.map:
                seen.setdefault((var.od.index, var.od.subindex), var.od)
        return tuple(seen.values())

    def tpdo_length(self, can_id: int) -> int:
        """The data bytes a frame of TPDO `can_id` carries."""
        return (self._tpdo(can_id).length + 7) // 8

    def _tpdo(self, can_id: int) -> PdoMap:
        pdo = self._tpdo_by_can_id.get(can_id)
        if pdo is None:
            raise self._no_tpdo(can_id)
        return pdo

    def _no_tpdo(self, can_id: int) -> PdoError:
        return PdoError(f"0x{can_id:03X} is no TPDO of node 0x{self.node_id:02X}")

    def decode(self, can_id: int, data: bytes) -> dict[Key, int | float]:
        """The mapped values of a TPDO frame; PdoError for a frame that does not fit its map."""
        layout = self._tpdo_layouts.get(can_id)  # (one look-up: on every TPDO the gateway takes)
        if layout is None:
            raise self._no_tpdo(can_id)
        expected, keys, unpack = layout
        if len(data) != expected:
            pdo = self._tpdo(can_id)
            raise PdoError(f"{pdo.name}: {len(data)} bytes, its mapping needs {expected}")
        if unpack is not None:  # (every TPDO of the shipped profiles)
            return dict(zip(keys, unpack(data), strict=True))
        return self._decode_by_map(self._tpdo(can_id), data)

    @staticmethod
    def _decode_by_map(pdo: PdoMap, data: bytes) -> dict[Key, int | float]:
        """canopen's decoding of a mapped frame: any layout (bit fields too)."""
        pdo.data = bytearray(data)
        # What `v.raw` returns, without the debug text canopen formats at every read
        # (two thirds of a decode; this runs for every TPDO on the gateway's frame path).
        return {
            (v.od.index, v.od.subindex): cast(int | float, v.od.decode_raw(v.get_data()))
            for v in pdo.map
        }

    # -- transmit (RPDOs the node receives) -----------------------------------------------
    def rpdo_numbers(self) -> tuple[int, ...]:
        """The RPDOs the node's file enables and maps, by number."""
        maps = self._node.rpdo.map
        if maps is None:
            return ()
        return tuple(n for n, pdo in sorted(maps.items()) if pdo.enabled and len(pdo.map))

    def rpdo(self, number: int) -> PdoMap:
        try:
            pdo = self._node.rpdo[number]
        except KeyError:
            raise PdoError(f"node 0x{self.node_id:02X} has no RPDO{number}") from None
        if not pdo.enabled or not len(pdo.map):
            raise PdoError(f"RPDO{number} of node 0x{self.node_id:02X} is not mapped")
        return pdo

    def rpdo_objects(self, number: int) -> list[MappedObject]:
        return [
            MappedObject(v.od.index, v.od.subindex, v.od.name, v.od.min, v.od.max)
            for v in self.rpdo(number).map
        ]

    def decode_rpdo(self, number: int, data: bytes) -> dict[Key, int | float]:
        """The mapped values of an RPDO frame the node received (a CAN log read offline);
        PdoError for a frame that does not fit its map."""
        pdo = self.rpdo(number)
        expected = (pdo.length + 7) // 8  # (canopen gives the mapping's length in bits)
        if len(data) != expected:
            raise PdoError(f"{pdo.name}: {len(data)} bytes, its mapping needs {expected}")
        return self._decode_by_map(pdo, data)

    def encode(self, number: int, values: Mapping[Key, int | float]) -> tuple[int, bytes]:
        """(CAN-ID, payload) of RPDO `number` carrying `values`; every mapped object is required.

        A value outside the object's EDS limits or its data type is a PdoError: a command the
        node would refuse (or that would wrap) is never put on the bus.
        """
        pdo = self.rpdo(number)
        given = dict(values)
        for var in pdo.map:
            key = (var.od.index, var.od.subindex)
            if key not in given:
                raise PdoError(f"{pdo.name}: no value for {var.od.name} (0x{key[0]:04X}:{key[1]})")
            value = given.pop(key)
            if isinstance(value, float) and var.od.data_type in INTEGER_TYPES:
                if not value.is_integer():
                    raise PdoError(f"{pdo.name}: {var.od.name} = {value!r} is not an integer")
                value = int(value)
            low, high = var.od.min, var.od.max
            if (low is not None and value < low) or (high is not None and value > high):
                raise PdoError(f"{pdo.name}: {var.od.name} = {value} is outside {low}..{high}")
            try:
                var.raw = value
            except (ValueError, OverflowError, TypeError) as exc:
                raise PdoError(f"{pdo.name}: {var.od.name} = {value!r}: {exc}") from None
        if given:
            extra = ", ".join(f"0x{i:04X}:{s}" for i, s in given)
            raise PdoError(f"{pdo.name} maps no {extra}")
        if pdo.cob_id is None:
            raise PdoError(f"{pdo.name} has no COB-ID")
        return pdo.cob_id, bytes(pdo.data[: (pdo.length + 7) // 8])


def _byte_layout(pdo: PdoMap) -> tuple[list[Key], Callable[[bytes], tuple[Any, ...]]] | None:
    """A PDO mapping of whole bytes, as one struct: (keys in map order, its unpack); None
    for any other mapping (bit fields, strings, odd sizes: canopen decodes those).

    Made from the map canopen read from the EDS, at start-up: offsets, lengths and data
    types are the mapping's, and each object unpacks with canopen's own struct for its
    type, so the values are canopen's (`decode_raw` of `get_data`) in one call."""
    keys: list[Key] = []
    fields = ["<"]
    at = 0
    for var in pdo.map:
        od, length = var.od, var.length
        offset: int | None = var.offset  # (set when the map is read; canopen starts it None)
        kind = od.STRUCT_TYPES.get(od.data_type) if od.data_type is not None else None
        # (a plain struct: canopen's 24-, 40-, 48-, 56-bit types subclass it to unpack odd sizes)
        if kind is None or type(kind) is not struct.Struct:
            return None
        if offset is None or offset % 8 or length % 8:
            return None
        if kind.size * 8 != length or len(od) != length or offset < at * 8:
            return None
        fields.append("x" * (offset // 8 - at) + kind.format.lstrip("<>=!@"))
        at = offset // 8 + kind.size
        keys.append((od.index, od.subindex))
    fields.append("x" * ((pdo.length + 7) // 8 - at))
    return keys, struct.Struct("".join(fields)).unpack

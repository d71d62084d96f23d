"""Build a grasplink device node by kind: its EDS plus its application."""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import canopen
from canopen.objectdictionary import ODVariable

from grasplink.core.frames import UNCONFIGURED_NODE_ID
from grasplink.devices import emcy as em
from grasplink.devices.app import DeviceApp
from grasplink.devices.belt import BeltApp
from grasplink.devices.emg import EmgApp
from grasplink.devices.generic import GenericDriveApp, is_drive
from grasplink.devices.hand import HandApp
from grasplink.devices.node import DeviceNode
from grasplink.devices.skin import SkinApp
from grasplink.devices.sources import SampleSource
from grasplink.errors import ConfigError
from grasplink.profiles import find_variable, load_profile, od_variable
from grasplink.profiles import objects as obj
from grasplink.profiles.kinds import node_kind, per_kind


@dataclass(frozen=True, slots=True)
class KindDevice:
    """The devices layer's piece of a node kind (kinds.py)."""

    # the kind's default application; a sensor's samples `source`
    app: Callable[[SampleSource | None], DeviceApp]
    # the EMCY codes it can send (docs/devices.md): RPDO errors only where there are RPDOs
    emcy_codes: frozenset[int]


DEVICES = per_kind(
    "devices/factory.py DEVICES",
    {
        "skin": KindDevice(SkinApp, em.EVERY_NODE_CODES | {em.SENSOR_SATURATED}),
        "emg": KindDevice(EmgApp, em.EVERY_NODE_CODES),
        "belt": KindDevice(lambda _: BeltApp(), em.EVERY_NODE_CODES | em.RPDO_CODES),
        "hand": KindDevice(lambda _: HandApp(), em.EVERY_NODE_CODES | em.RPDO_CODES),
    },
)
#: kind -> the EMCY codes its node can send
CODES_BY_KIND = {kind: device.emcy_codes for kind, device in DEVICES.items()}


def make_app(kind: str, source: SampleSource | None = None) -> DeviceApp:
    return DEVICES[node_kind(kind).name].app(source)


SERIAL_MAX = 0xFFFFFFFF


def build_node(
    kind: str,
    node_id: int | None = None,
    source: SampleSource | None = None,
    app: DeviceApp | None = None,
    *,
    serial: int | None = None,
) -> DeviceNode:
    """A ready-to-start node of `kind` at `node_id` (default: the kind's, kinds.py).

    `node_id` 0xFF builds an unconfigured node that waits for an LSS master.
    `serial` is its serial number (1018h:04, default 0): nodes of one kind that an
    LSS master must tell apart need different ones.
    `app` replaces the default application of `kind` (e.g. a drive with an external motor).
    """
    default_id = node_kind(kind).node_id
    app = app or make_app(kind, source)
    node_id = default_id if node_id is None else node_id
    # The dictionary of an unconfigured node is built for the kind's node-ID; its
    # $NODEID defaults move to the one LSS gives it.
    od_node_id = default_id if node_id == UNCONFIGURED_NODE_ID else node_id
    od = load_profile(kind, od_node_id)
    if serial is not None:
        if not 0 <= serial <= SERIAL_MAX:
            raise ConfigError(f"serial number {serial} is outside 0..0x{SERIAL_MAX:X}")
        od_variable(od, obj.IDENTITY, 4).default = serial
    return DeviceNode(od, node_id, app, od_node_id=od_node_id)


def build_from_file(
    path: str | Path,
    node_id: int | None = None,
    values: Sequence[tuple[int, int, int | float]] = (),
    app: Callable[[canopen.ObjectDictionary], DeviceApp] | None = None,
) -> tuple[DeviceNode, list[str]]:
    """A node built from any EDS or DCF (the field loader), and the loader's warnings.

    It speaks the protocol its file describes (NMT, SDO, heartbeat, EMCY, its PDOs as
    mapped); a CiA 402 file gets the drive state machine and a plain drive
    (generic.py), any other no application: `values` (index, sub-index, value) become the
    defaults of those objects, so a script sets what the node reports and a reset
    keeps it. `node_id` defaults to the DCF's [DeviceComissioning] NodeID. `app` builds
    another application from the dictionary (a scene's sensor input, a measured drive).
    """
    from grasplink.profiles.field import load_object_dictionary

    od, warnings = load_object_dictionary(path, node_id)
    chosen = node_id if node_id is not None else od.node_id
    if chosen is None:
        raise ConfigError(f"{path}: give a node-ID (its file names none)")
    # A node built from a file comes up configured as its file says: a ParameterValue
    # (a DCF's, or an EDS that carries one) is what it holds, as python-canopen's
    # LocalNode serves it and as the master that decodes its PDOs reads it.
    for var in _variables(od):
        if var.value is not None:
            var.default = var.value
    for index, subindex, value in values:
        try:
            var = find_variable(od, index, subindex)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from None
        try:
            var.encode_raw(value)
        except (ValueError, TypeError, OverflowError, struct.error) as exc:
            raise ConfigError(f"{path}: {var.name} = {value!r} does not fit: {exc}") from None
        var.default = value  # type: ignore[assignment]  # (typed int; a REAL holds a float)
    built = app(od) if app is not None else GenericDriveApp(od) if is_drive(od) else DeviceApp()
    return DeviceNode(od, chosen, built), [str(w) for w in warnings]


def _variables(od: canopen.ObjectDictionary) -> list[ODVariable]:
    out: list[ODVariable] = []
    for index in od.indices:
        entry = od[index]
        out += [entry] if isinstance(entry, ODVariable) else list(entry.values())
    return out

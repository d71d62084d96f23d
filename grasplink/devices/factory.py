"""Build a grasplink device node by kind: its EDS plus its application."""

from __future__ import annotations

from grasplink.devices.app import DeviceApp
from grasplink.devices.belt import BeltApp
from grasplink.devices.emg import EmgApp
from grasplink.devices.hand import HandApp
from grasplink.devices.node import DeviceNode
from grasplink.devices.skin import SkinApp
from grasplink.devices.sources import SampleSource
from grasplink.errors import ConfigError
from grasplink.profiles import DEVICE_KINDS, load_profile
from grasplink.profiles import objects as obj


def make_app(kind: str, source: SampleSource | None = None) -> DeviceApp:
    if kind == "skin":
        return SkinApp(source)
    if kind == "emg":
        return EmgApp(source)
    if kind == "belt":
        return BeltApp()
    if kind == "hand":
        return HandApp()
    raise ConfigError(f"unknown node type {kind!r}; choose one of {', '.join(DEVICE_KINDS)}")


def build_node(
    kind: str,
    node_id: int | None = None,
    source: SampleSource | None = None,
    app: DeviceApp | None = None,
) -> DeviceNode:
    """A ready-to-start node of `kind` at `node_id` (default from objects.DEFAULT_NODE_IDS).

    `app` replaces the default application of `kind` (e.g. a drive with an external motor).
    """
    app = app or make_app(kind, source)
    node_id = obj.DEFAULT_NODE_IDS[kind] if node_id is None else node_id
    return DeviceNode(load_profile(kind, node_id), node_id, app)

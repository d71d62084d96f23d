"""CAN bus access: bus URLs, the loopback hub, the real-time node runner, bus load."""

from grasplink.bus.hub import CanHub, run_hub
from grasplink.bus.load import BusLoadMeter, frame_bits_worst_case
from grasplink.bus.runner import MultiRunner, NodeRunner, RunnerStats
from grasplink.bus.url import (
    DEFAULT_BUS_URL,
    DEFAULT_HUB_PORT,
    BusDisconnected,
    BusSpec,
    frame_to_message,
    message_to_frame,
    open_bus,
    parse_bus_url,
    socketcan_available,
)

__all__ = [
    "DEFAULT_BUS_URL",
    "DEFAULT_HUB_PORT",
    "BusDisconnected",
    "BusLoadMeter",
    "BusSpec",
    "CanHub",
    "MultiRunner",
    "NodeRunner",
    "RunnerStats",
    "frame_bits_worst_case",
    "frame_to_message",
    "message_to_frame",
    "open_bus",
    "parse_bus_url",
    "run_hub",
    "socketcan_available",
]

"""Sample streams rebuilt from PDOs: the gateway's name for the skin front end.

The front end (packets -> samples at their times on the node's clock, from the
packet sequence) is `grasplink.decoding.packets`, shared with offline
decoding (`decoding.io.read_can_log`), so a CAN log decodes as the live gateway
decodes the same frames. See that module for what it does with late, lost,
repeated and reordered packets, node restarts and clock drift.
"""

from __future__ import annotations

from grasplink.decoding.packets import (
    LIVE_SETTLE_US,
    SEQUENCE_MODULO,
    SampleStream,
    StreamStats,
)

__all__ = ["LIVE_SETTLE_US", "SEQUENCE_MODULO", "SampleStream", "StreamStats"]

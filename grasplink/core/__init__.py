"""Neutral vocabulary every layer shares: the CAN frame, the sans-IO device protocol,
NMT states and commands, and CANopen's predefined COB-ID layout.

It imports nothing else from grasplink, so devices, buses, simulators and the
gateway can all speak it without depending on one another.
"""

"""Surfaces: what carries the gateway's results out (MQTT telemetry, Modbus TCP/RTU).

They see the gateway through its snapshot and command API only, and the gateway
never imports them: a deployment may run none, one or both.
"""

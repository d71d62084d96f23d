"""Telemetry: the gateway's results over MQTT (a JSON topic tree and Sparkplug B 3.0)."""

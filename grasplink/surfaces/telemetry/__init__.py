"""Telemetry: the gateway's results over MQTT, as a JSON topic tree and as Sparkplug B 3.0.

- `json_tree.JsonTree` and `sparkplug.SparkplugSession`: sans-IO protocol objects
  (snapshots in, messages out; commands in, replies out), tested without a broker;
- `buffer`: the bounded snapshot queue and the store-and-forward `Outbox`;
- `transport.TelemetryPublisher`: the MQTT edge (aiomqtt in its own thread);
- `url`: broker URLs, identifiers and TLS contexts.

See docs/telemetry.md for the topics, metrics and commands.
"""

from grasplink.surfaces.telemetry.transport import DEFAULT_RATE_HZ, TelemetryPublisher
from grasplink.surfaces.telemetry.url import BrokerUrl, check_id, parse_broker_url, tls_context

__all__ = [
    "DEFAULT_RATE_HZ",
    "BrokerUrl",
    "TelemetryPublisher",
    "check_id",
    "parse_broker_url",
    "tls_context",
]

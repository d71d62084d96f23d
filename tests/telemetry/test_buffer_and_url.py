"""Bounded queues (drop-oldest, counted) and broker URLs, identifiers and TLS options."""

from __future__ import annotations

from pathlib import Path

import pytest

from grasplink.errors import ConfigError
from grasplink.surfaces.telemetry.buffer import (
    MESSAGE_OVERHEAD_BYTES,
    Message,
    Outbox,
    Sample,
    SnapshotQueue,
)
from grasplink.surfaces.telemetry.transport import SnapshotClock
from grasplink.surfaces.telemetry.url import check_id, parse_broker_url, tls_context


def message(k: int, size: int = 100) -> Message:
    return Message(f"t/{k:04d}", bytes(size - 6))


def test_outbox_keeps_order_and_drops_the_oldest_over_its_byte_bound() -> None:
    each = message(0).size_bytes
    assert each == 100 + MESSAGE_OVERHEAD_BYTES
    box = Outbox(max_bytes=10 * each)
    for k in range(25):
        box.push(message(k))
    assert len(box) == 10 and box.bytes == 10 * each and box.peak_bytes == 10 * each
    assert (box.dropped_messages, box.dropped_bytes) == (15, 15 * each)
    assert box.drops_since_report() == (15, 15 * each) and box.drops_since_report() == (0, 0)
    taken = box.take(4)
    assert [m.topic for m in taken] == [f"t/{k:04d}" for k in range(15, 19)]
    box.requeue(taken[2:])  # not acknowledged: back in front, in order
    assert [m.topic for m in box.take(3)] == ["t/0017", "t/0018", "t/0019"]


def test_outbox_drops_a_message_larger_than_its_bound() -> None:
    box = Outbox(max_bytes=500)
    box.push(message(0, size=1000))
    assert len(box) == 0 and box.dropped_messages == 1


def test_snapshot_queue_never_blocks_and_counts_what_it_drops() -> None:
    queue = SnapshotQueue(size=3)
    for k in range(5):
        queue.put(Sample(k, {}))
    assert queue.dropped == 2 and [s.ts_ms for s in queue.drain()] == [2, 3, 4]
    assert len(queue) == 0


def test_snapshot_clock_takes_the_quickest_poll_as_the_gateways_start() -> None:
    clock = SnapshotClock()
    wall = 1000.0  # wall - monotonic
    assert clock.stamp_ms(1.0, 11.003, wall) == 1_011_003  # seen 3 ms late
    assert clock.stamp_ms(1.05, 11.0505, wall) == 1_011_050  # quicker poll: origin moves back
    assert clock.stamp_ms(1.10, 11.105, wall) == 1_011_100
    assert clock.stamp_ms(0.05, 20.05, wall) == 1_020_050  # a new gateway: uptime restarted


def test_broker_urls_default_ports_credentials_and_options() -> None:
    url = parse_broker_url("mqtt://user:p%40ss@127.0.0.1")
    assert (url.host, url.port, url.username, url.password, url.tls) == (
        "127.0.0.1",
        1883,
        "user",
        "p@ss",
        False,
    )
    assert url.display == "mqtt://user@127.0.0.1:1883" and "p@ss" not in repr(url)
    secure = parse_broker_url("mqtts://h:9000?group=plant_1&buffer_kib=64&keepalive_s=5")
    assert (secure.port, secure.tls, secure.group, secure.buffer_bytes, secure.keepalive_s) == (
        9000,
        True,
        "plant_1",
        64 * 1024,
        5,
    )
    assert parse_broker_url("mqtts://h").port == 8883


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("tcp://h:1883", "expected mqtt://"),
        ("mqtt://:1883", "no host"),
        ("mqtt://h:99999", "out of range"),
        ("mqtt://h/topic", "no path"),
        ("mqtt://h?qos=2", "unknown option 'qos'"),
        ("mqtt://h?buffer_kib=0", "buffer_kib='0'"),
        ("mqtt://h?group=a/b", "group"),
        ("mqtt://u:secret@h:1/x", "no path"),
    ],
)
def test_bad_broker_urls_are_one_line_config_errors(text: str, why: str) -> None:
    with pytest.raises(ConfigError, match=why) as caught:
        parse_broker_url(text)
    assert "\n" not in str(caught.value) and "secret" not in str(caught.value)


def test_ids_are_one_topic_level() -> None:
    assert check_id("gw-1.a") == "gw-1.a"
    for bad in ("", "a/b", "a+b", "a#", "a b", "x" * 65):
        with pytest.raises(ConfigError, match="--mqtt-id"):
            check_id(bad)


def test_tls_options_are_checked_before_any_connection(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="needs an mqtts://"):
        tls_context(parse_broker_url("mqtt://h"), tmp_path / "ca.pem")
    with pytest.raises(ConfigError, match="no such file"):
        tls_context(parse_broker_url("mqtts://h"), tmp_path / "missing.pem")
    junk = tmp_path / "junk.pem"
    junk.write_text("not a certificate")
    with pytest.raises(ConfigError, match="not a PEM CA certificate"):
        tls_context(parse_broker_url("mqtts://h"), junk)
    assert tls_context(parse_broker_url("mqtt://h"), None) is None
    assert tls_context(parse_broker_url("mqtts://h"), None) is not None  # the system's CAs


def test_a_primary_host_id_is_one_topic_level_and_needs_a_broker(capsys) -> None:
    from grasplink import cli
    from grasplink.gateway.config import parse_config

    settings = parse_config({"telemetry": {"sparkplug_host_id": "scada-1"}}, "gw.toml").telemetry
    assert settings.sparkplug_host_id == "scada-1" and settings.state_dir.startswith("~")
    with pytest.raises(ConfigError, match=r"telemetry\.sparkplug_host_id"):
        parse_config({"telemetry": {"sparkplug_host_id": "a/b"}}, "gw.toml")
    with pytest.raises(ConfigError, match=r"telemetry\.state_dir"):
        parse_config({"telemetry": {"state_dir": " "}}, "gw.toml")
    assert cli.main(["gateway", "--sparkplug-host-id", "scada"]) == 1
    assert "--sparkplug-host-id needs --mqtt URL" in capsys.readouterr().err
    command = ["gateway", "--mqtt", "mqtt://127.0.0.1:1", "--sparkplug-host-id", "a#b"]
    assert cli.main(command) == 1
    assert "--sparkplug-host-id 'a#b'" in capsys.readouterr().err

"""Issue 21, item 9: smaller defects a new user meets (config keys, URLs, the hub, `run`, docs).

Each test names what a user sees; each failed on the code before its fix.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from grasplink.errors import ConfigError
from grasplink.gateway.config import load_config
from grasplink.gateway.decoding import registry

ROOT = Path(__file__).resolve().parents[1]


# -- 1. a gateway configuration's decoder ---------------------------------------------------


@pytest.mark.parametrize("name", ["nope", "mmse", "dtw"])
def test_a_decoder_the_gateway_cannot_run_names_file_key_and_valid_decoders(
    tmp_path: Path, name: str
) -> None:
    """`[nodes.skin] decoder = "nope"` failed at start-up without file or key; mmse and dtw
    (which need reference slips) passed the file and failed when the gateway started."""
    path = tmp_path / "gw.toml"
    path.write_text(f'[nodes.skin]\ndecoder = "{name}"\n')
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    message = str(caught.value)
    assert message.startswith(f"{path}: nodes.skin.decoder: ")
    assert repr(name) in message and "fft, ratio, tracker" in message
    assert "\n" not in message


def test_a_decoder_in_a_scenes_gateway_controller_names_the_controller_key() -> None:
    from grasplink.gateway.config import parse_config

    with pytest.raises(ConfigError, match=r"^s\.toml: controller\.nodes\.skin\.decoder: unknown"):
        parse_config({"nodes": {"skin": {"decoder": "nope"}}}, "s.toml", "controller")


def test_every_live_decoder_is_accepted_and_the_default_is_one() -> None:
    from grasplink.gateway.config import SkinConfig, parse_config

    assert registry.DEFAULT_DECODER in registry.live_decoders()
    for name in registry.live_decoders():
        skin = parse_config({"nodes": {"skin": {"decoder": name}}}, "gw.toml").nodes["skin"]
        assert isinstance(skin, SkinConfig) and skin.decoder == name


def test_the_reference_decoders_named_in_the_registry_are_those_whose_class_says_so() -> None:
    """The registry names them so a configuration is checked without importing every decoder."""
    for name in registry.DECODERS:
        needs = bool(getattr(registry.decoder_class(name), "needs_references", False))
        assert needs == (name in registry.NEEDS_REFERENCES), name


# -- 2, 3. Modbus, MQTT and hub URLs: the port and the host ------------------------------------


@pytest.mark.parametrize("text", ["tcp://", "tcp://127.0.0.1", "tcp://0.0.0.0"])
def test_a_modbus_tcp_url_without_a_port_is_refused_not_bound_to_502(text: str) -> None:
    """`--modbus tcp://` bound the privileged port 502 silently (as root) before."""
    from grasplink.gateway.modbus.url import parse_modbus_url

    with pytest.raises(ConfigError) as caught:
        parse_modbus_url(text)
    message = str(caught.value)
    assert "give a port, e.g. tcp://" in message and ":1502" in message and "\n" not in message


def test_modbus_port_502_is_taken_when_named() -> None:
    from grasplink.gateway.modbus.url import parse_modbus_url

    assert parse_modbus_url("tcp://127.0.0.1:502").port == 502


BAD_HOSTS = [
    ("256.1.1.1", "'256.1.1.1' is not an IPv4 address"),
    ("1.2.3.4.5", "'1.2.3.4.5' is not an IPv4 address"),
    ("bad_-.host..x", "'bad_-.host..x' is not a host name"),
]


@pytest.mark.parametrize(("host", "says"), BAD_HOSTS)
def test_a_malformed_modbus_host_is_named_not_unknown_error_2(host: str, says: str) -> None:
    """`tcp://256.1.1.1:1502` said "cannot listen on ...: Unknown error -2" at bind time."""
    from grasplink.gateway.modbus.url import parse_modbus_url

    with pytest.raises(ConfigError, match=f"^modbus URL 'tcp://{host}:1502': {says}"):
        parse_modbus_url(f"tcp://{host}:1502")


def test_a_modbus_host_that_does_not_resolve_is_named() -> None:
    from grasplink.gateway.modbus.url import parse_modbus_url

    # .invalid never resolves (RFC 2606); the resolver answers from its own rules.
    with pytest.raises(ConfigError, match=r"cannot resolve host 'nohost\.invalid' \("):
        parse_modbus_url("tcp://nohost.invalid:1502")


@pytest.mark.parametrize(
    "text", ["tcp://127.0.0.1:1502", "tcp://localhost:1502", "tcp://[::1]:1502", "tcp://:0"]
)
def test_modbus_hosts_that_are_addresses_or_local_names_are_accepted(text: str) -> None:
    from grasplink.gateway.modbus.url import parse_modbus_url

    assert parse_modbus_url(text).scheme == "tcp"


@pytest.mark.parametrize(("host", "says"), BAD_HOSTS)
def test_a_malformed_broker_host_is_named_before_connecting(host: str, says: str) -> None:
    """`mqtt://256.1.1.1` got as far as connecting: "Name or service not known"."""
    from grasplink.gateway.telemetry.url import parse_broker_url

    with pytest.raises(ConfigError, match=f"^--mqtt 'mqtt://{host}:1883': {says}"):
        parse_broker_url(f"mqtt://{host}:1883")


@pytest.mark.parametrize(("host", "says"), BAD_HOSTS)
def test_a_malformed_hub_host_is_named_not_no_hub_there(host: str, says: str) -> None:
    """`remote:ws://256.1.1.1:54701/` said "no CAN hub at ... start one with ..."."""
    from grasplink.bus.url import parse_bus_url
    from grasplink.errors import BusError

    with pytest.raises(BusError, match=f"bad hub host: {says}"):
        parse_bus_url(f"remote:ws://{host}:54701/")


def test_a_hub_host_that_does_not_resolve_is_named_not_no_hub_there() -> None:
    from grasplink.bus.url import open_bus
    from grasplink.errors import BusError

    with pytest.raises(BusError) as caught:
        open_bus("remote:ws://nohost.invalid:54701/?connect_timeout=2")
    message = str(caught.value)
    assert "cannot resolve hub host 'nohost.invalid'" in message
    assert "start one" not in message

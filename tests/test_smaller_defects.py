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

"""Skin decoders by name: `make_decoder("ratio", layout_mm, fs_hz, **settings)`.

Decoder modules are imported on first use, so a decoder whose module is
missing (or broken) fails only when it is asked for, with an error naming it.
The window matchers (mmse, dtw) also need `references=` (reference slips
the caller records or simulates; `needs_references(name)` tells which).
"""

from __future__ import annotations

from collections.abc import Sequence

from grasplink.core.registry import load_class
from grasplink.decoding.base import Decoder
from grasplink.errors import ConfigError

#: name -> "module:Class"
DECODERS: dict[str, str] = {
    "fft": "grasplink.decoding.fft:FftDecoder",
    "ratio": "grasplink.decoding.ratio:RatioDecoder",
    "mmse": "grasplink.decoding.mmse:MmseDecoder",
    "dtw": "grasplink.decoding.dtw:DtwDecoder",
    "tracker": "grasplink.decoding.tracker:TrackerDecoder",
}

#: The decoder `grasplink decode` uses unless told otherwise (set from the benchmark).
DEFAULT_DECODER = "tracker"

#: Decoders that match against reference slips (their class sets `needs_references`), named
#: here so a configuration is checked without importing every decoder; a test keeps the two
#: in step. A gateway decodes live and has no references to give them.
NEEDS_REFERENCES = frozenset({"mmse", "dtw"})


def live_decoders() -> list[str]:
    """The decoders that need only the layout and the sample rate: those a gateway runs."""
    return [name for name in DECODERS if name not in NEEDS_REFERENCES]


def check_live_decoder(name: str) -> str:
    """`name` if a gateway can run it, else ConfigError saying why and listing those it can."""
    valid = ", ".join(live_decoders())
    if name not in DECODERS:
        raise ConfigError(f"unknown decoder {name!r}; valid decoders: {valid}")
    if name in NEEDS_REFERENCES:
        raise ConfigError(
            f"decoder {name!r} matches against reference slips, which a live gateway does not "
            f"have (grasplink decode and the decoding benchmark simulate them); valid decoders "
            f"here: {valid}"
        )
    return name


def decoder_class(name: str) -> type[Decoder]:
    """The class registered under `name` (imported now); ConfigError if unknown or missing."""
    return load_class("decoder", DECODERS, name)


def available(name: str) -> bool:
    """Whether the decoder's module can be imported (without raising)."""
    try:
        decoder_class(name)
    except ConfigError:
        return False
    return True


def needs_references(name: str) -> bool:
    """Whether the decoder matches against reference slips the caller must supply."""
    return bool(getattr(decoder_class(name), "needs_references", False))


def make_decoder(name: str, layout_mm: Sequence[float], fs_hz: float, **settings) -> Decoder:
    """Build a decoder; unknown names or settings raise ConfigError naming them."""
    cls = decoder_class(name)
    try:
        return cls(layout_mm, fs_hz, **settings)
    except TypeError as exc:
        raise ConfigError(f"decoder {name!r}: bad settings {sorted(settings)}: {exc}") from None

"""Any registered decoder, ready to run: the window matchers get their reference slips here.

The gateway's mmse and dtw decoders match the live window against a slip
recorded at a known speed (`ReferenceSlip`); the gateway makes none. This
module simulates the thesis-like pair - a noise-free slip at 20 mm/s over
the whole skin, one per direction, at the decoder's sample rate and a fixed
seed (the same reference every time) - with the simulators' synthesiser,
and caches it per (layout, rate).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

from grasplink.decoding import registry
from grasplink.decoding.base import Decoder, SkinGeometry, check_sample_rate
from grasplink.decoding.mmse import ReferenceSlip
from grasplink.simulators import synth

REFERENCE_SPEED_MM_S = 20.0  # the thesis' reference: a slow slip resolves every ridge
REFERENCE_SEED = 20240  # fixed: the reference is the same every time
REFERENCE_CACHE = 32  # (layout, rate) pairs kept


def reference_slips(
    layout_mm: Sequence[float],
    fs_hz: float,
    *,
    speed_mm_s: float = REFERENCE_SPEED_MM_S,
    seed: int = REFERENCE_SEED,
) -> tuple[ReferenceSlip, ReferenceSlip]:
    """(forward, reverse) noise-free simulated slips over the whole skin at `speed_mm_s`."""
    return _reference_slips(
        tuple(float(s) for s in layout_mm), max(1, round(fs_hz)), float(speed_mm_s), int(seed)
    )


@lru_cache(maxsize=REFERENCE_CACHE)
def _reference_slips(
    layout_mm: tuple[float, ...], fs_hz: int, speed_mm_s: float, seed: int
) -> tuple[ReferenceSlip, ReferenceSlip]:
    slips = []
    for reverse in (False, True):
        rec = synth.slip_recording(
            layout_mm, speed_mm_s, fs_hz=fs_hz, reverse=reverse, noise_scale=0.0, seed=seed
        )
        moving = rec.speed_mm_s != 0
        slips.append(
            ReferenceSlip(
                speed_mm_s=-speed_mm_s if reverse else speed_mm_s,
                position_mm=rec.position_mm[moving],
                force_n=rec.force_n[moving],
                rest_force_n=float(rec.force_n[0]),
            )
        )
    return slips[0], slips[1]


def make_decoder(name: str, layout_mm: Sequence[float], fs_hz: float, **settings) -> Decoder:
    """`registry.make_decoder`, adding the reference slips a window matcher needs.

    References given in `settings` are used as they are.
    """
    if registry.needs_references(name) and "references" not in settings:
        SkinGeometry(layout_mm)  # a bad layout or rate fails as the decoder would say it
        check_sample_rate(fs_hz)
        settings["references"] = reference_slips(layout_mm, fs_hz)
    return registry.make_decoder(name, layout_mm, fs_hz, **settings)

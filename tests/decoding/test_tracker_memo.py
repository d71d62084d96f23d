"""The tracker's replay memo (`TrackerDecoder._step`): a step told and then revised to a
pulse replays contacts the tracker took before; their branches are reused, never changing
an estimate."""

from __future__ import annotations

import numpy as np

from grasplink.decoding.base import SlipEstimate
from grasplink.decoding.contacts import ContactEvent
from grasplink.decoding.tracker import TrackerDecoder, _Bank
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth


class CountingTracker(TrackerDecoder):
    """Counts the contacts branched anew (not found in the memo)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.branched = 0

    def _branch(self, ev: ContactEvent) -> _Bank:
        self.branched += 1
        return super()._branch(ev)


def slip_cycles(cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """The gateway benchmark's skin: a 60 mm/s slip over alpha0.1, then 0.8 s released."""
    rec = synth.slip_recording(LAYOUTS_MM["alpha0.1"], 60.0, fs_hz=400, seed=1)
    rest = np.random.default_rng(1).normal(float(rec.force_n[0]), 0.02, 320)
    x = np.tile(np.concatenate([rec.force_n, rest]), cycles)
    return np.arange(len(x)) / 400.0, x


def decode(decoder: TrackerDecoder, t: np.ndarray, x: np.ndarray) -> list[SlipEstimate]:
    out: list[SlipEstimate] = []
    for start in range(0, len(t), 3):  # a skin TPDO's 3 samples at a time
        out += decoder.feed(t[start : start + 3], x[start : start + 3])
    return out


def test_revised_steps_reuse_branches_and_change_no_estimate():
    t, x = slip_cycles(3)
    memo = CountingTracker(LAYOUTS_MM["alpha0.1"], 400)
    plain = CountingTracker(LAYOUTS_MM["alpha0.1"], 400)
    plain.MEMO = 0  # nothing kept: every contact of every replay branched again
    assert decode(memo, t, x) == decode(plain, t, x)
    assert memo.branched < plain.branched
    assert len(memo._memo) <= memo.MEMO and len(memo._pruned) <= memo.MEMO

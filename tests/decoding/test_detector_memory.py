"""The contact detector's buffers (written in place, not concatenated) stay bounded on an
endless stream, and what it tells does not depend on how the samples are chunked."""

from __future__ import annotations

import numpy as np
import pytest

from grasplink.decoding.contacts import ContactDetector
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

FS_HZ = 400.0


def _cycle() -> np.ndarray:
    """A slip over the ridges, then rest: contacts, pulse verdicts and quiet blocks."""
    layout = LAYOUTS_MM["alpha0.1"]
    slip = synth.slip_recording(layout, 60.0, seed=1).force_n
    rest = np.full(320, slip[0]) + np.random.default_rng(0).normal(0, 0.02, 320)
    return np.concatenate([slip, rest])


def _held(detector: ContactDetector) -> dict[str, int]:
    """Storage (entries allocated) of every buffer the detector extends per block."""
    sizes = {
        "samples": detector.samples.series.data.shape[-1],
        "level": detector.watcher._levels.data.shape[-1],
        "raw": len(detector.noise._raw),
    }
    for i, ch in enumerate(detector.channels):
        sizes[f"z{i}"] = ch.rows.data.shape[-1]
        sizes[f"abs{i}"] = len(ch.block_abs)
    for i, sc in enumerate(detector.steps.scales):
        sizes[f"step{i}"] = sc.store.data.shape[-1]
    return sizes


def _feed(detector: ContactDetector, x: np.ndarray, start: int, chunk: int) -> list[tuple]:
    """Contacts and verdicts told, by the sample that decided them (a chunk tells what its
    samples decided together: the order within one chunk is the detector's own)."""
    told: list[tuple] = []
    t = (start + np.arange(len(x))) / FS_HZ
    for i in range(0, len(x), chunk):
        events, checks = detector.feed(t[i : i + chunk], x[i : i + chunk])
        told += [(e.emit_index, 0, e.id, tuple(e)) for e in events]
        told += [(c.emit_index, 1, c.id, tuple(c)) for c in checks]
    return sorted(told)


def test_the_detector_buffers_stay_bounded_over_a_long_stream():
    cycle = _cycle()
    detector = ContactDetector(FS_HZ)
    held, told = [], 0
    for k in range(12):
        told += len(_feed(detector, cycle, k * len(cycle), 3))
        held.append(_held(detector))
    assert told > 0  # it did see contacts
    assert held[-1] == held[2]  # after the first cycles, no buffer grows any more
    keep = detector._keep
    level = detector.watcher._level
    # (the samples also hold a tail kink's look back, `tail_kinks.slow_look_s`: `_keep_x`)
    assert len(detector.samples.t) <= 2 * detector._keep_x
    assert len(level) <= 2 * keep + detector.watcher.watch
    for ch in detector.channels:
        assert ch.rows.size <= 2 * keep
    for sc in detector.steps.scales:
        assert sc.store.size <= 2 * keep


def test_the_detector_tells_the_same_in_any_chunking():
    x = np.concatenate([_cycle()] * 2)
    told = {chunk: _feed(ContactDetector(FS_HZ), x, 0, chunk) for chunk in (1, 3, 7, 50, 256)}
    assert told[3]  # contacts and verdicts to compare
    for chunk in (1, 7, 50, 256):
        assert told[chunk] == told[3]


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_a_non_finite_sample_is_refused_by_name_and_nothing_of_its_chunk_is_kept(
    bad: float,
) -> None:
    x = _cycle()
    t = np.arange(len(x)) / FS_HZ
    half = len(x) // 2
    clean, refused = ContactDetector(FS_HZ), ContactDetector(FS_HZ)
    told_clean = [clean.feed(t[:half], x[:half]), clean.feed(t[half:], x[half:])]
    told = [refused.feed(t[:half], x[:half])]
    broken = x[half : half + 3].copy()
    broken[1] = bad
    with pytest.raises(ValueError, match="finite"):
        refused.feed(t[half : half + 3], broken)
    told.append(refused.feed(t[half:], x[half:]))
    assert told == told_clean


class _AlwaysTrims(ContactDetector):
    """Asks every part's trim on every feed (as before `_trim_at`)."""

    def _trim(self) -> None:
        self._trim_at = 0
        super()._trim()


def _cuts(detector: ContactDetector) -> tuple[int, ...]:
    """Where each buffer the trims cut now starts."""
    return (
        detector.samples.start,
        detector.watcher._level_start,
        *(ch.z_start for ch in detector.channels),
        *(sc.start for sc in detector.steps.scales),
    )


@pytest.mark.parametrize("chunk", [1, 3, 7, 50])
def test_the_trims_not_asked_would_have_cut_nothing(chunk):
    """`_trim` skips the parts' trims until one could cut: every buffer is cut at the same
    sample as when they are asked on every feed, through a rail start (centres waiting
    for a noise), contacts and rest."""
    x = np.concatenate([np.zeros(150), *[_cycle()] * 3])
    t = np.arange(len(x)) / FS_HZ
    skipping, asking = ContactDetector(FS_HZ), _AlwaysTrims(FS_HZ)
    cuts, told = set(), 0
    for i in range(0, len(x), chunk):
        got = skipping.feed(t[i : i + chunk], x[i : i + chunk])
        assert got == asking.feed(t[i : i + chunk], x[i : i + chunk])
        told += len(got[0])
        assert _cuts(skipping) == _cuts(asking), i
        cuts.add(_cuts(skipping))
    assert told and len(cuts) > 10  # contacts told, and buffers cut many times

"""A verdict told before its contact is read when the contact comes (`EARLY_CHECKS`).

The pulse watcher can judge a contact before the kink bank has decided it: at 400 Hz the
bank's 80 ms scale decides 0.16 s after the onset, the watcher told constant 51140's
third ridge (10 mm/s on alpha0.3, ridge contacts 0.91, 1.31, 1.61, 6.41, 9.31 s) a step
0.1 s after its onset. Read only when the verdict came, the step's shape went untold
(no contact to measure from), so neither shape prior applied and the posterior took
the step for a stop: speed gone for the 4.8 s to the next ridge while the object slid.
Read when the contact comes, the shape is a ridge's and the speed stays.

Its cost on the tuned seeds: rates-drops 134010 (21 -> 98 mm/s on alpha0.9 sampled at
100 Hz), whose second ridge is told a step early and shaped like a stop's (at 100 Hz a
ridge's rise fits in the 2.5 samples `step_shape` calls fast), so its slip's track
loses to a stop there."""

from __future__ import annotations

import pytest

from grasplink.decoding.detector import step_shape
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import slip_reporting as sr
from tests.decoding.plan_cases import decode_case, score_case

ON, OFF = {"EARLY_CHECKS": 1.0}, {"EARLY_CHECKS": 0.0}


def _shape_at(decoder, t_s: float) -> int | None:
    (contact,) = [c for c in decoder._contacts if abs(c.t_s - t_s) < 0.03]
    return decoder._shapes.get(contact.id)


def test_a_step_told_before_its_contact_gets_its_shape():
    _, on, _ = decode_case("constant", 51140, ON, "10 mm/s")
    assert _shape_at(on, 1.61) == step_shape.RIDGE_LIKE
    _, off, _ = decode_case("constant", 51140, OFF, "10 mm/s")
    assert _shape_at(off, 1.61) == step_shape.UNTOLD


def test_with_its_shape_the_slide_is_not_read_as_a_stop():
    on = score_case("constant", 51140, ON, "10 mm/s")
    assert on.moving_from3 > 700
    assert on.missing_from3 == 0
    assert on.dropped_from2 == 0
    off = score_case("constant", 51140, OFF, "10 mm/s")
    assert off.missing_from3 >= 400


@pytest.mark.parametrize("chunk", [1, 7, 64])
def test_the_shape_read_does_not_depend_on_the_chunking(chunk, monkeypatch):
    monkeypatch.setattr(sr, "CHUNK", chunk)
    _, decoder, _ = decode_case("constant", 51140, ON, "10 mm/s")
    assert _shape_at(decoder, 1.61) == step_shape.RIDGE_LIKE


def test_its_cost_a_stop_like_early_step_at_100_hz_loses_the_track():
    on = score_case("rates-drops", 134010, ON, "100 Hz, 21->98 mm/s")
    off = score_case("rates-drops", 134010, OFF, "100 Hz, 21->98 mm/s")
    assert off.missing_from3 <= 10
    assert on.missing_from3 >= 60


def test_early_verdicts_are_read_by_default():
    assert TrackerDecoder.EARLY_CHECKS == 1

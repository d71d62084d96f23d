"""Issue 22's "Done when" on the shipped headline loop (`scenes/loop_headline.toml`): the
default decoder, fed the run's CAN log 3 samples at a time as `grasplink decode` does,
reports the slip speed from the third ridge contact after onset (the second where the
layout makes it unique) to within one contact interval of the stop, and never while the
object is at rest after the stop became observable (`slip_reporting.headline_figures`)."""

from __future__ import annotations

from functools import cache
from pathlib import Path

from grasplink.controllers import build_controllers
from grasplink.evaluation.slip_reporting import headline_check

SCENE = Path(__file__).resolve().parents[2] / "scenes" / "loop_headline.toml"


@cache
def figures() -> dict:
    return headline_check(SCENE, build_controllers)


def test_the_headline_slip_gets_a_speed_before_the_object_stops_where_one_is_owed():
    """A speed is owed once the contact the layout needs came before the stop; the reflex
    stops the object after two on alpha0.1 (not unique from the 2nd), so none is owed."""
    f = figures()
    assert f["stop_s"] is not None, f
    if f["first_speed_s"] is None:
        assert f["contact_needed_s"] is None, f
        return
    assert f["onset_s"] <= f["first_speed_s"] <= f["stop_s"], f
    if f["first_ok"] is not None:  # the contact the layout needs came before the stop
        assert f["first_ok"], f


def test_the_headline_slip_speed_ends_with_the_slip_and_never_shows_at_rest():
    """The reflex stops the object after two ridge contacts (1.77 s at 22 mm); the stop
    becomes observable at 1.99 s (ridge 31 due) and its report is due 0.15 s later. The
    last speed: 3.77 s on 1521ca0, 2.79 s with the due-time cap, 2.13 s now that a braking
    hypothesis whose own motion has come to rest is reported stopped (`BRAKE_Z`)."""
    f = figures()
    assert f["last_ok"] is not False and f["rest_ok"], f  # (None: no speed shown nor owed)


def test_the_headline_speed_at_rest_ends_within_a_second_of_the_stop_showing():
    """A braking hypothesis waits for its next contact at most 1.5 predicted intervals
    (`SPAN_MAX_REL`), not the seconds an unsure acceleration spreads it over. Offline the
    speed at rest ended 1.78 s after the stop became observable on 1521ca0; 0.80 s with
    the cap alone, 0.14 s now."""
    f = figures()
    assert f["observable_s"] is not None, f
    if f["last_speed_s"] is not None:
        assert f["last_speed_s"] - f["observable_s"] <= 1.0, f


def _first_speed_told_right(f: dict) -> bool:
    """The first speed shown while the object slides lies within 10 % of the truth then;
    none shown before the stop passes (alpha0.1 is not unique from the 2nd contact, and the
    reflex stops the object after two: the truth cannot be told from the contacts)."""
    first, stop = f["first_speed_s"], f["stop_s"]
    if first is None or stop is None or first >= stop:
        return True
    return abs(f["first_speed"] - f["first_speed_truth"]) <= 0.1 * f["first_speed_truth"]


def test_the_headline_first_speed_is_the_slips_or_none_before_it_can_be_told():
    """On 866822a: 65 mm/s at 1.70 s against 33.4, a bend at 1.496 s (hysteresis letting go
    onto the coverage ramp) taken for ridge 1 (`told_rise`). Now: the slip flagged, a range
    of 39.7-69 mm/s from 1.70 s (the reflex acts on its floor as before), no speed, the
    stop told at 1.95 s (observable at 1.99 s)."""
    f = figures()
    assert _first_speed_told_right(f), f
    assert f["speed_at_rest_updates"] == 0, f

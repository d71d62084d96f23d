"""No speed from a track whose last contact was told a step the level lay flat after.

Why (issue 22, *speed after a stop's report was due*): a stop's friction step is a
contact like a ridge's (the level rises as the object sticks), and a track may take it
for the ridge it expected - or, from a false contact and the step, build an alias whose
next ridge lies far on (stick-slip 81200: alpha0.3 at 118 mm/s, the 3 and 4 mm ridges'
pulses merged, a 35 mm/s alias on a contact no ridge made and the stop's step at 0.559 s,
its next ridge 48 mm on, due 2.3 s; the stop observable at 0.827 s). The pulse check
tells that contact a step whose rising trend ended (`PulseCheck.trend_on` False: the
object no longer covers more of the sensor) 0.1 s later, long before the silence can.
The posterior weighs it (`STOP_STEP_PER_S`, `GRIP_FLAT_STEP`) but keeps the slip while
that alias's silence is young; the speed the report shows is a measurement that ended
at a stop-like step, so the report withholds it - the flag and the range of speeds stay
the posterior's (a slip with no speed), and a later contact brings the speed back.

Pure: the tracker (`TrackerDecoder._report_evident`) asks per update of its chosen track.
"""

from __future__ import annotations


def withheld(last_id: int, steps: dict[int, bool | None]) -> bool:
    """Is the speed of a track whose last contact is `last_id` withheld: that contact told a
    step (`steps`: the step verdicts kept, id -> trend_on) after which the level lay flat
    (trend_on False; None, no trend to tell, and True, still rising, do not)?"""
    return steps.get(last_id) is False


def lone_pulse(pulses_told: int) -> bool:
    """At level 2 (`TrackerDecoder.FLAT_STEP_SPEED`), is a flat step's speed withheld: its
    track's recent contacts told `pulses_told` pulses, fewer than two? A ridge train that
    ends at a flat step has told its ridges' pulses before it (the 40 mm/s rail start over
    ADC counts: five, the sliding object's last gap then read at 37 mm/s); an alias built
    on a contact no ridge made has at most its first (stick-slip 81200: the 0.360 s ridge
    told a pulse, 0.468 s not told for a second, the stop's step at 0.559 s)."""
    return pulses_told < 2

"""A track whose last contact came from the detector's probes waits the probes' latency.

On the loop scenes' physics (slip_reporting's `loop` kind) the FSR's hysteresis holds the
ridge pulses' fall, the kink bank misses many ridges and the step and pulse probes find them
~0.2 s after their onset (`ContactDetector.probe_lag`), later than the 0.17 s the tracker
allows the kink bank. Waiting only that long, the tracker took each such ridge's silence
for a stop and dropped the slip flag until the late contact came.
"""

from __future__ import annotations

from grasplink.decoding.contacts import ContactDetector
from grasplink.decoding.tracker import TrackerDecoder
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation import slip_reporting as sr

# uniform4 at 30 mm/s, forward: ridges from 1.27 s every ~0.145 s; from 2.33 s on the probes
# find them (pulses told steps), each ~0.18 s late
CASE = sr.Case("loop", "30 mm/s", (30,), "uniform4", False, 166200)


def flags(tuning: dict) -> list[tuple[float, bool]]:
    rec = CASE.make()
    decoder = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz, tuning=tuning)
    estimates, _ = ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    return [(e.t_s, e.slip) for e in estimates if 2.52 <= e.t_s <= 2.80]


def test_the_probes_latency_is_known_to_the_tracker():
    detector = ContactDetector(400)
    assert detector.probe_lag > detector.lag  # told later than the kink bank tells any
    assert detector.probe_lag / 400 >= 0.18


def test_the_slip_flag_waits_for_a_ridge_the_probes_will_tell():
    assert all(slip for _, slip in flags({}))
    dropped = [t for t, slip in flags({"PROBE_WAIT": 0.0}) if not slip]
    assert dropped  # without the wait: dropped before each late contact

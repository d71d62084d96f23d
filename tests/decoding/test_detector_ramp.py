"""Ridge contacts on the entry ramp: the object sliding onto the skin (issue 22).

While the object slides onto the skin the share of it over the sensor grows and the level
ramps up (about 0.047 N/s per mm/s on the thesis object, 5 N grip). On the alpha0.3 skin
(spacings 4, 3, 48, 29 mm) the first three ridges lie in the first 7 mm: the second
ridge's pulse (1 - e^-0.4 of a full one) starts on the first one's falling tail and the
ramp holds its fall up, so the level rises, stays level a while and rises on. The watch's
fall test saw a level that kept rising and told nothing for a second ("unclear"): the
tracker got no second contact, and constant-speed slips on that skin gave no speed for
seconds. Judged against the level's trend after it (`ContactDetector._fell_on_ramp`) the
pulse rises and falls back to the ramp; a grip step stays up from it.
"""

from __future__ import annotations

from grasplink.gateway.decoding.contacts import ContactDetector
from grasplink.profiles.layouts import LAYOUTS_MM
from grasplink.simulators import synth

SPEEDS_MM_S = (35.0, 57.0, 95.0)
SEEDS = (3, 5, 7, 8)  # seeds whose second contact the kink bank finds (at every speed)
PROMPT_S = 0.3  # a first verdict later than this after the contact is no help
PROMPT_PULSES = 7  # of the 12: measured 8; 1 before the fix (the rest unclear after 1 s)


def first_verdicts(speed_mm_s: float, seed: int) -> list[tuple[float, bool | None, float]]:
    """(contact time, first verdict, verdict time) of each contact, fed 3 samples a time."""
    rec = synth.slip_recording(LAYOUTS_MM["alpha0.3"], speed_mm_s, seed=seed)
    detector = ContactDetector(rec.fs_hz)
    contacts, first = [], {}
    for i in range(0, len(rec.t_s), 3):
        events, checks = detector.feed(rec.t_s[i : i + 3], rec.force_n[i : i + 3])
        contacts += events
        for check in checks:
            first.setdefault(check.id, check)
    second = float(rec.contact_times_s[1])
    out = []
    for event in contacts:
        if abs(event.t_s - second) <= 0.02 and event.id in first:
            verdict = first[event.id]
            out.append((event.t_s, verdict.pulse, verdict.emit_index / rec.fs_hz))
    return out


def test_the_second_ridge_on_the_entry_ramp_is_a_pulse_at_its_first_verdict():
    """alpha0.3 forward at 35-95 mm/s: the contact 4 mm after the first, on the ramp."""
    prompt = found = 0
    for speed in SPEEDS_MM_S:
        for seed in SEEDS:
            told = first_verdicts(speed, seed)
            found += bool(told)
            prompt += any(p is True and at - t <= PROMPT_S for t, p, at in told)
    assert found >= 10, found
    assert prompt >= PROMPT_PULSES, (prompt, found)

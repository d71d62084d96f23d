"""Four ridge contacts a track fits are a slip when none was told a step or a noise
pulse, whatever else their verdicts (unclear: the loop's hysteresis).

Under the FSR's hysteresis (the loop scenes) a ridge pulse's fall is held: 41 % of the
found ridge contacts are told steps (8 % on the constant-speed set) and more are unclear.
A track needed a pulse among its contacts, or four contacts and no step, to be a slip:
a staircase of ridge steps never was, and the slip flag stayed down while the object
slid. ae49871 made three contacts a slip whatever their verdicts: an hour of a held
object was then flagged (a chain of unclear noise contacts), and with four, grip ramps
3-8-3 N every second were a staircase of steps a slow track fits (held-grip, alpha0.7,
seed 143120: 73 updates flagged). So `TrackerDecoder.EVIDENT_CONTACTS` (4) counts only
with no step and no pulse as low as noise (`WEAK_PULSE_SNR`) among them; two contacts
still need a pulse."""

from __future__ import annotations

import numpy as np

from grasplink.decoding.contacts import PulseCheck
from grasplink.decoding.kernels import posterior as posterior_kernels
from grasplink.decoding.tracker import TrackerDecoder

NONE = np.zeros(1)  # no speed, none before a restart: `_evidence`'s restart agreement idle


def evident(dec: TrackerDecoder, ids: list[int]) -> bool:
    row = np.array([[-1] * (6 - len(ids)) + ids], np.int64)
    n = np.array([len(ids)])
    flags, _ = posterior_kernels._evidence(
        row, n, n, dec._ring, dec._ring_id, *dec._evidence_tables, NONE, NONE, 0.0
    )
    return bool(flags[0])


def test_four_unclear_contacts_are_a_slip_a_staircase_of_grip_steps_is_not():
    dec = TrackerDecoder([4.0] * 10, 400.0)
    for contact_id, pulse in ((1, None), (2, None), (3, None), (4, None), (5, False)):
        dec._add_check(PulseCheck(contact_id, 0, pulse))
    assert evident(dec, [1, 2, 3, 4])  # four unclear (a hysteretic skin's ridges)
    assert not evident(dec, [1, 2, 3])  # three: a noise chain as likely
    assert not evident(dec, [2, 3, 4, 5])  # ... a step among them: grip ramps


def test_a_noise_pulse_breaks_the_count_and_gives_no_pulse_evidence():
    dec = TrackerDecoder([4.0] * 10, 400.0)
    for contact_id, pulse, height in ((1, None, None), (2, True, 2.2), (3, None, None)):
        dec._add_check(PulseCheck(contact_id, 0, pulse, height_snr=height))
    dec._add_check(PulseCheck(4, 0, None))
    dec._add_check(PulseCheck(5, 0, True, height_snr=30.0))
    assert not evident(dec, [1, 2, 3, 4])  # unclear, noise pulse, unclear, unclear
    assert not evident(dec, [1, 2])  # a noise pulse is no pulse
    assert evident(dec, [4, 5])  # a ridge pulse stands far higher

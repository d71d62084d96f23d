"""Four ridge contacts are a slip whatever their pulse verdicts (the loop's staircase) -
unless one of them is a noise pulse.

Under the FSR's hysteresis (the loop scenes) a ridge pulse's fall is held: 41 % of the
found ridge contacts are told steps (8 % on the constant-speed set) and more are unclear.
A track needed a pulse among its contacts, or four contacts and no step, to be a slip:
a staircase of ridge steps never was, and the slip flag stayed down while the object
slid. `TrackerDecoder.EVIDENT_CONTACTS`: four contacts a track's timing fits are a slip
(three flagged an hour of a held object: a chain of unclear noise contacts), none of them
a pulse no higher than noise (`WEAK_PULSE_SNR`); two still need a pulse (two grip steps
are not)."""

from __future__ import annotations

import numpy as np

from grasplink.gateway.decoding.contacts import PulseCheck
from grasplink.gateway.decoding.kernels import posterior as posterior_kernels
from grasplink.gateway.decoding.tracker import TrackerDecoder


def evident(dec: TrackerDecoder, ids: list[int]) -> bool:
    row = np.array([[-1] * (6 - len(ids)) + ids], np.int64)
    n = np.array([len(ids)])
    flags, _ = posterior_kernels._evidence(
        row, n, n, dec._ring, dec._ring_id, *dec._evidence_tables
    )
    return bool(flags[0])


def test_a_staircase_of_four_steps_is_a_slip_two_steps_are_not():
    dec = TrackerDecoder([4.0] * 10, 400.0)
    for contact_id, pulse in ((1, False), (2, None), (3, False), (4, False), (5, False)):
        dec._add_check(PulseCheck(contact_id, 0, pulse))
    assert evident(dec, [1, 2, 3, 4])  # step, unclear, step, step
    assert evident(dec, [1, 3, 4, 5])  # four steps
    assert not evident(dec, [1, 3])  # two steps: a grip change twice, as likely


def test_a_noise_pulse_breaks_the_count_and_gives_no_pulse_evidence():
    dec = TrackerDecoder([4.0] * 10, 400.0)
    for contact_id, pulse, height in ((1, None, None), (2, True, 2.2), (3, None, None)):
        dec._add_check(PulseCheck(contact_id, 0, pulse, height_snr=height))
    dec._add_check(PulseCheck(4, 0, None))
    dec._add_check(PulseCheck(5, 0, True, height_snr=30.0))
    assert not evident(dec, [1, 2, 3, 4])  # unclear, noise pulse, unclear, unclear
    assert not evident(dec, [1, 2])  # a noise pulse is no pulse
    assert evident(dec, [4, 5])  # a ridge pulse stands far higher

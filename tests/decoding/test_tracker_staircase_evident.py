"""Three ridge contacts are a slip whatever their pulse verdicts (the loop's staircase).

Under the FSR's hysteresis (the loop scenes) a ridge pulse's fall is held: 41 % of the
found ridge contacts are told steps (8 % on the constant-speed set) and more are unclear.
A track needed a pulse among its contacts, or four contacts and no step, to be a slip:
a staircase of ridge steps never was, and the slip flag stayed down while the object
slid. `TrackerDecoder.EVIDENT_CONTACTS`: three contacts a track's timing fits are a slip;
two still need a pulse (two grip steps are not)."""

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


def test_a_staircase_of_three_steps_is_a_slip_two_steps_are_not():
    dec = TrackerDecoder([4.0] * 10, 400.0)
    for contact_id, pulse in ((1, False), (2, None), (3, False), (4, False)):
        dec._add_check(PulseCheck(contact_id, 0, pulse))
    assert evident(dec, [1, 2, 3])  # step, unclear, step
    assert evident(dec, [1, 3, 4])  # three steps
    assert not evident(dec, [1, 3])  # two steps: a grip change twice, as likely

"""A probe's pulse verdict does not overwrite a kink-bank contact's (the ring of verdicts).

The tracker keeps each contact's pulse verdict in a ring indexed by the contact's id. The
step probe numbers its contacts from `STEP_IDS` (a multiple of the ring's length), so
probe j and kink contact j shared a slot: on the loop's physics (a fifth of the ridges
found by the probes) a probe's step verdict erased a recent ridge pulse, and a slip whose
only pulse that was stopped being one (its flag dropped)."""

from __future__ import annotations

import math

import numpy as np

from grasplink.decoding.contacts import STEP_IDS, PulseCheck
from grasplink.decoding.kernels import posterior as posterior_kernels
from grasplink.decoding.tracker import TrackerDecoder

NONE = np.zeros(1)  # no speed, none before a restart: `_evidence`'s restart agreement idle


def test_a_probe_verdict_leaves_the_kink_contact_with_the_same_number_its_own():
    dec = TrackerDecoder([10.0, 12.0, 14.0], 400.0)
    dec._add_check(PulseCheck(5, 0, True))  # kink contact 5: a pulse
    dec._add_check(PulseCheck(STEP_IDS + 5, 0, False))  # probe 5: a step
    ids = np.array([[-1, -1, -1, -1, 5, STEP_IDS + 5]], np.int64)
    evident, bonus = posterior_kernels._evidence(
        ids,
        np.array([2]),
        np.array([2]),
        dec._ring,
        dec._ring_id,
        *dec._evidence_tables,
        NONE,
        NONE,
        0.0,
    )
    assert bool(evident[0])  # two contacts, one a pulse: a slip
    assert math.isclose(float(bonus[0]), dec.LOG_PULSE - dec.LOG_STEP)

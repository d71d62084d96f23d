"""The slip flag raised again by a ridge pulse soon after it was up (`decoding.reflag`)."""

from __future__ import annotations

from typing import NamedTuple

import pytest

from grasplink.decoding import reflag


class _C(NamedTuple):
    id: int
    t_s: float


CONTACTS = [_C(1, 0.5), _C(2, 1.0), _C(3, 1.4), _C(4, 1.6)]


def test_the_latest_pulse_after_the_flag_within_the_window():
    pulses = {2, 3}.__contains__
    latch = reflag.Reflag()
    assert latch.candidate(CONTACTS, pulses, 0.8, 1.0) == (3, 1.4)  # 4 is no pulse
    assert latch.candidate(CONTACTS, pulses, 0.8, 0.5) == (2, 1.0)  # 3 came too late
    assert latch.candidate(CONTACTS, pulses, 1.5, 1.0) is None  # none since the flag
    assert latch.candidate(CONTACTS, pulses, 0.2, 0.1) is None  # none within 0.1 s


def test_an_expired_contact_stays_expired_until_another():
    pulses = {2, 3, 4}.__contains__
    latch = reflag.Reflag()
    assert latch.candidate(CONTACTS[:3], pulses, 0.8, 1.0) == (3, 1.4)
    latch.expire()  # its next ridge overdue
    assert latch.candidate(CONTACTS[:3], pulses, 0.8, 1.0) is None
    assert latch.candidate(CONTACTS, pulses, 0.8, 1.0) == (4, 1.6)  # a new pulse


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="within_s must be >= 0"):
        reflag.Reflag().candidate(CONTACTS, bool, 0.0, -1.0)

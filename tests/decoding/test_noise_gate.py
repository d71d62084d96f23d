"""The heavy-noise gate read from the white noise (`decoding.noise_gate`).

At 10 dB SNR the white noise under a ridge pulse is 0.1-0.3 N; thesis-like noise is
0.02 N. A rule meant for heavy noise opens above a level set between them, never while
the noise is not measured yet, never when the gate is off; a level that is not a number
is a clear error. The report's overdue rules rest where it reads heavy.
"""

from __future__ import annotations

import math

import pytest

from grasplink.decoding import noise_gate
from tests.decoding.plan_cases import decode_case


def test_the_gate_opens_in_10_db_noise_and_stays_shut_at_thesis_noise():
    assert noise_gate.heavy(0.25, 0.05)
    assert noise_gate.heavy(0.10, 0.05)
    assert not noise_gate.heavy(0.02, 0.05)


def test_the_gate_stays_shut_before_the_noise_is_measured():
    assert not noise_gate.heavy(None, 0.05)


def test_a_level_of_zero_turns_the_gate_off_so_no_noise_counts_as_heavy():
    assert not noise_gate.heavy(None, 0.0)
    assert not noise_gate.heavy(0.3, 0.0)


def test_a_level_that_is_not_a_number_is_an_error():
    with pytest.raises(ValueError, match="not a number"):
        noise_gate.heavy(0.1, math.nan)


def test_the_reports_overdue_rules_rest_where_the_white_noise_reads_heavy():
    """snr10, uniform4 (full plan, seed 116001): early in a 10 dB slip the rise evidence
    does not yet read the silence soft, so the report's overdue rules withheld speeds no
    stop had refuted (72 speed updates with them resting, 48 without); only speeds
    differ, every update's flag is the same."""
    runs = {
        resting: decode_case("snr10", 116_001, {"OVERDUE_NOISY_WHITE": resting})[2]
        for resting in (0.0, 1.0)
    }
    speeds = {k: sum(1 for e in v if e.speed_mm_s) for k, v in runs.items()}
    assert speeds[0.0] > speeds[1.0]
    assert [e.slip for e in runs[0.0]] == [e.slip for e in runs[1.0]]

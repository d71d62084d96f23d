"""The detection chance measured from the told pulses' rise (`decoding.detect_chance`).

At 10 dB SNR the told pulses' rise stands about 5 noise units at its median and the
detector tells about half the crossings; on a clean signal (20+ units) it tells all but
the shortest spacings'. A missed ridge's least score follows: small in heavy noise, the
DETECT_P table's on a clean signal (never lowered below it); bad input is a clear error.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from grasplink.decoding import detect_chance as dc
from grasplink.decoding import rise_evidence as rev
from grasplink.decoding.tracker import TrackerDecoder

LOG_MISS = math.log(1.0 - 0.99)  # the table's miss after 5+ mm
H_LOW = rev.H_LOW


def test_chance_grows_with_the_told_rise_and_matches_both_ends():
    medians = [2.0, 3.0, 5.0, 8.0, 20.0, 40.0]
    p = [dc.chance(m, H_LOW, rev.TOLD_Z) for m in medians]
    assert all(a < b for a, b in itertools.pairwise(p))
    # 10 dB: the detector tells 46 % of the snr10 crossings (docs/decoding.md)
    assert 0.35 < dc.chance(5.0, H_LOW, rev.TOLD_Z) < 0.55
    # clean: as sure as the table past 5 mm
    assert dc.chance(40.0, H_LOW, rev.TOLD_Z) > 0.99
    # a stricter threshold tells fewer
    assert dc.chance(5.0, H_LOW, 5.5) < dc.chance(5.0, H_LOW, rev.TOLD_Z)


def test_floor_is_lenient_in_heavy_noise_and_the_table_on_a_clean_signal():
    table = np.array([LOG_MISS, math.log(1.0 - 0.46), -math.inf])  # 5 mm, 3 mm, coast end
    kw = {"h_low": H_LOW, "threshold_z": rev.TOLD_Z}
    noisy = dc.floor(table, 5.0, weight=1.0, **kw)
    assert noisy[0] == pytest.approx(math.log(1.0 - dc.chance(5.0, H_LOW, rev.TOLD_Z)))
    assert noisy[0] > math.log(0.5)  # a skip costs under a nat, not 4.6
    assert noisy[1] >= table[1]  # never below the table (P capped by it)
    assert noisy[2] == -math.inf  # past the coast end the slip has stopped
    clean = dc.floor(table, 40.0, weight=1.0, **kw)
    assert clean[0] == pytest.approx(LOG_MISS, abs=0.5)
    assert clean[1] == table[1]  # the short spacing's own chance is lower still
    half = dc.floor(table, 5.0, weight=0.5, **kw)
    assert half[0] == pytest.approx(0.5 * (LOG_MISS + noisy[0]))
    assert np.array_equal(dc.floor(table, 5.0, weight=0.0, **kw), table)
    # one median per ridge
    each = dc.floor(table[:2], np.array([5.0, 40.0]), weight=1.0, **kw)
    assert each[0] == noisy[0] and each[1] == table[1]


def test_bad_input_is_a_clear_error():
    kw = {"h_low": H_LOW, "threshold_z": rev.TOLD_Z}
    with pytest.raises(ValueError, match="weight"):
        dc.floor(np.array([LOG_MISS]), 5.0, weight=1.5, **kw)
    with pytest.raises(ValueError, match="median"):
        dc.floor(np.array([LOG_MISS]), -1.0, weight=1.0, **kw)
    with pytest.raises(ValueError, match="threshold"):
        dc.chance(5.0, H_LOW, math.nan)


def test_tracker_count_constants_tune_as_counts():
    decoder = TrackerDecoder([5.0] * 8, 400.0, tuning={"MAX_SKIP": 3.0})
    assert decoder.MAX_SKIP == 3 and decoder._skip_prior.shape[2] == 4
    assert TrackerDecoder._tuning_value("DETECT_MEASURED_SILENCE", 0.5) == 0.5


def test_unread_ridges_take_the_measured_miss_and_read_ones_keep_their_evidence():
    z = np.array([math.nan, 6.0, 0.0, 2.5])  # not read, another contact's, flat, a rise
    table = np.full(4, LOG_MISS)
    unread = dc.floor(table, 5.0, h_low=H_LOW, threshold_z=rev.TOLD_Z, weight=1.0)
    plain = rev.skip_score(z, 5.0, table, H_LOW)
    got = rev.skip_score(z, 5.0, table, H_LOW, unread)
    assert got[0] == unread[0] and got[1] == unread[1]  # the miss alone, measured
    assert plain[0] == LOG_MISS and plain[1] == LOG_MISS  # (the table's without it)
    assert np.array_equal(got[2:], plain[2:])  # a z read is the evidence either way
    assert got[2] < unread[2]  # flat signal where a ridge was due: against going on


def test_speed_agreement_share_is_lower_only_while_the_told_pulses_are_weak():
    decoder = TrackerDecoder([5.0] * 8, 400.0, tuning={"SPEED_AGREE_SHARE_NOISY": 0.7})
    assert decoder._agree_share() == decoder.SPEED_AGREE_SHARE  # none told
    for k, height in enumerate((30.0, 40.0, 35.0)):  # a clean slip's pulses
        decoder._rise.note_height(k, height)
    assert decoder._agree_share() == decoder.SPEED_AGREE_SHARE
    for k, height in enumerate((4.0, 5.0, 6.0, 3.0, 4.5), start=3):  # 10 dB's
        decoder._rise.note_height(k, height)
    assert decoder._agree_share() == 0.7 < decoder.SPEED_AGREE_SHARE
    shipped = TrackerDecoder([5.0] * 8, 400.0)  # off: the one share whatever the noise
    for k, height in enumerate((4.0, 5.0, 6.0), start=3):
        shipped._rise.note_height(k, height)
    assert shipped._agree_share() == shipped.SPEED_AGREE_SHARE

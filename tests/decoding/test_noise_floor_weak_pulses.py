"""The widest hinge scale at 10 dB SNR (issue 22, item 3): weak ridge pulses are not its noise.

Each hinge scale is judged against the larger of the white noise (times the scale's gain)
and its own median |h| over the last 10 s (coloured noise). Blocks a told pulse touched do
not count - but only pulses 10 white-noise units high marked them, and never in the widest
scale (80 ms), whose noise keeps a clear pulse's slow bends. At 10 dB SNR every ridge pulse
is 3-7 units high: the widest scale counted them as noise and read 1.6 times the white
noise's at its median while a slip went on, and the weak kinks it finds fell under the
threshold. A told pulse of 3 units or more (`noise_floor.BUSY_SNR`; noise that falls back
like a pulse stands 1.8-3.0) now marks its blocks, in the widest scale too while under
10 units (`CLEAR_SNR`).
"""

from __future__ import annotations

import numpy as np

from grasplink.decoding.contacts import ContactDetector
from grasplink.decoding.detector.noise_floor import hinge_gain
from grasplink.evaluation import nonstationary as ns

# every snr10 signal forward (4 layouts, 4 speed variants, 2 seeds)
SIGNALS = [s for s in ns.signals(False) if s.category == "snr10" and not s.reverse]
# the widest scale's noise over white x gain, median over the blocks while the object
# slides: measured 1.33; 1.60 before (weak pulses marked no block)
WIDEST_RATIO_MAX = 1.45


def test_at_10_db_snr_the_widest_scale_does_not_count_ridge_pulses_as_noise():
    ratios = []
    for signal in SIGNALS:
        rec = signal.make()
        detector = ContactDetector(rec.fs_hz)
        detector.feed(rec.t_s, rec.force_n)
        noise = detector.noise
        widest = len(noise.widths) - 1
        gain = hinge_gain(noise.widths[widest])
        for block, value in noise.by_block[widest].items():
            white = noise.white(block)
            t_s = block * noise.block / rec.fs_hz
            sliding = abs(np.interp(t_s, rec.truth.t_s, rec.truth.speed_mm_s)) >= 1.0
            if white is not None and sliding:
                ratios.append(value / (white[0] * gain))
    assert len(SIGNALS) == 32
    assert float(np.median(ratios)) <= WIDEST_RATIO_MAX, float(np.median(ratios))

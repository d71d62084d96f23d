"""Warming a decoder up leaves nothing for the live loop to compile."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import numpy as np

from grasplink.decoding import tracker
from grasplink.profiles.layouts import LAYOUTS_MM

# In a fresh interpreter: warm up, count every kernel's compiled signatures, decode slips
# of every kind (speeding up, stopping, reversing, on the rail) on another layout, count
# again.
CHILD = textwrap.dedent(
    """
    import json, pkgutil, importlib
    import numpy as np
    import grasplink.decoding.kernels as kernels
    from grasplink.evaluation import nonstationary
    from grasplink.decoding.tracker import TrackerDecoder
    from grasplink.profiles.layouts import LAYOUTS_MM
    from tests.decoding.test_numerical_edges import railed_slip

    def counts():
        out = {}
        for info in pkgutil.iter_modules(kernels.__path__):
            module = importlib.import_module(f"{kernels.__name__}.{info.name}")
            for name, value in vars(module).items():
                if hasattr(value, "signatures"):
                    out[f"{info.name}.{name}"] = len(value.signatures)
        return out

    TrackerDecoder(LAYOUTS_MM["alpha0.1"], 400).warm_up()
    warm = counts()
    recordings = [s.make() for s in nonstationary.signals(True)[:6]]
    for rec in recordings:
        dec = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz)
        t, x = np.asarray(rec.t_s), np.asarray(rec.force_n)
        for i in range(0, len(t), 3):
            dec.feed(t[i : i + 3], x[i : i + 3])
    rec = railed_slip(60.0, True)
    TrackerDecoder(rec.layout_mm, rec.fs_hz).feed(rec.t_s, rec.force_n)
    # a gap in the stream: the decoder resets to its state before the first sample (a deep
    # copy), then takes the slip after the gap
    rec = recordings[0]
    dec = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz)
    t, x = np.asarray(rec.t_s), np.asarray(rec.force_n)
    for i in range(0, len(t), 3):
        dec.feed(t[i : i + 3], x[i : i + 3])
    for i in range(0, len(t), 3):
        dec.feed(t[i : i + 3] + t[-1] + 1.0, x[i : i + 3])
    assert dec.stats.gaps == 1
    print(json.dumps({"warm": warm, "after": counts()}))
    """
)


def test_after_warm_up_decoding_any_slip_compiles_nothing():
    """Nor after a gap, where the decoder's reset restores a copy of its first state: a
    copy that turned a read-only table writable made a kernel signature of its own, which
    the gateway's loop compiled live at the first contact after the gap (seconds)."""
    done = subprocess.run(
        [sys.executable, "-c", CHILD], capture_output=True, text=True, check=True, timeout=600
    )
    counts = json.loads(done.stdout.strip().splitlines()[-1])
    assert counts["after"] == counts["warm"]
    assert counts["warm"]["posterior.posterior"] >= 1 and counts["warm"]["prune.prune_choice"] >= 1


def test_the_warm_up_signal_is_a_slip_the_tracker_decodes():
    ridges_mm = np.concatenate([[0.0], np.cumsum(LAYOUTS_MM["alpha0.5"])])
    t, x = tracker.warm_up_signal(ridges_mm, 400.0)
    estimates = tracker.TrackerDecoder(LAYOUTS_MM["alpha0.5"], 400.0).feed(t, x)
    speeds = [e.speed_mm_s for e in estimates if e.slip and e.speed_mm_s]
    assert speeds and abs(np.median(speeds) - 40.0) < 4.0

"""Record the tracker's posterior, call by call, as the golden file of the compiled kernel's
test.

Run against the numpy `_posterior` it replaced (commit 0858d90):
    git worktree add /tmp/old 0858d90
    PYTHONPATH=/tmp/old python tests/decoding/data/make_posterior_golden.py
Feeds the decoder slip signals (steady, speeding up, stopping, reversing; and slips squeezed
onto the sensor's rail, whose silence there is no evidence) three samples at a time, as the
gateway does, and keeps every posterior it computed: the time, how long it holds, P(slip),
the agreement, the direction log odds, and the chosen track (stopped, the ridge it has not
reached, its travel and speed), NaN where none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from grasplink.evaluation import nonstationary
from grasplink.gateway.decoding.tracker import TrackerDecoder
from tests.decoding.test_numerical_edges import railed_slip

OUT = Path(__file__).with_name("posterior_golden.npz")
COLUMNS = ("g", "until", "p_slip", "agree", "odds", "stopped", "limit", "s", "v", "blind")


def record(t: np.ndarray, x: np.ndarray, layout_mm, fs_hz: float) -> np.ndarray:
    dec = TrackerDecoder(layout_mm, fs_hz)
    rows: list[list[float]] = []
    posterior = dec._posterior

    def recording(g: float):
        out = posterior(g)
        until, chosen, p_slip, agree, odds = out
        stopped = limit = s = v = np.nan
        if chosen is not None:
            one, stopped, limit = chosen
            s, v = one.s, one.v
        blind = dec._blind(dec._tracks.t, g) is not None
        rows.append([g, until, p_slip, agree, odds, stopped, limit, s, v, blind])
        return out

    dec._posterior = recording
    for i in range(0, len(t), 3):
        dec.process(t[i : i + 3], x[i : i + 3])
    return np.array(rows, float).reshape(-1, len(COLUMNS))


def main() -> None:
    runs: dict[str, np.ndarray] = {}
    for k, sig in enumerate(nonstationary.signals(True)[:10]):
        rec = sig.make()
        runs[f"signal{k}"] = record(
            np.asarray(rec.t_s), np.asarray(rec.force_n), rec.truth.layout_mm, rec.fs_hz
        )
    for reverse in (False, True):
        rec = railed_slip(60.0, reverse)
        runs[f"railed{int(reverse)}"] = record(rec.t_s, rec.force_n, rec.layout_mm, rec.fs_hz)
    np.savez_compressed(OUT, columns=np.array(COLUMNS), **runs)
    calls = sum(len(r) for r in runs.values())
    blind = sum(int(r[:, -1].sum()) for r in runs.values())
    print(f"{calls} posteriors ({blind} with time on the rail) in {len(runs)} runs to {OUT}")


if __name__ == "__main__":
    main()

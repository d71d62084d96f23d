"""Record the tracker's pruning decisions as the golden file of the compiled kernel's test.

Run against the numpy `_prune` it replaced (commit 0858d90):
    git worktree add /tmp/old 0858d90
    PYTHONPATH=/tmp/old python tests/decoding/data/make_prune_golden.py
Feeds the decoder slip signals (steady, speeding up, stopping, reversing) three samples at
a time, as the gateway does, and keeps every 6th pool it pruned: its scores, stop times and
int columns, the recent and held contact ids, and the rows kept, best first.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from grasplink.evaluation import nonstationary
from grasplink.gateway.decoding.tracker import TrackerDecoder

OUT = Path(__file__).with_name("prune_golden.npz")
EVERY = 6


def main() -> None:
    pools: dict[str, np.ndarray] = {}
    count = 0
    for sig in nonstationary.signals(True)[:8]:
        rec = sig.make()
        dec = TrackerDecoder(rec.truth.layout_mm, rec.fs_hz)
        prune = dec._prune

        def recording(B, recent, held, prune=prune, dec=dec):
            nonlocal count
            out = prune(B, recent, held)
            if len(B) and count % EVERY == 0:
                chosen = dec._pruned[id(B)][1]
                k = len(pools) // 6
                pools.update({
                    f"score{k}": np.array(B.score), f"stop{k}": np.array(B.stop),
                    f"ints{k}": np.array(B._i), f"recent{k}": np.asarray(recent, np.int64),
                    f"held{k}": np.asarray(held, np.int64), f"chosen{k}": np.asarray(chosen),
                })  # fmt: skip
            count += 1
            return out

        dec._prune = recording
        t, x = np.asarray(rec.t_s), np.asarray(rec.force_n)
        for i in range(0, len(t), 3):
            dec.process(t[i : i + 3], x[i : i + 3])
    np.savez_compressed(OUT, **pools)
    print(f"{len(pools) // 6} pools of {count} to {OUT}")


if __name__ == "__main__":
    main()

"""Record the contact detector's golden outputs (detector_golden.npz) from a tree's code.

usage: python tests/decoding/data/make_detector_golden.py [TREE]

Why: the detector's per-block numeric path (slope FIRs, hinges, normalising, local
maxima, the step probes' differences, the level) was compiled into kernels; its tests
compare the compiled code against what the numpy code it replaced told on the same
inputs. Run against that code (TREE: a checkout whose grasplink is imported, by default
this one) - it was recorded from main at 0858d90, before the kernels.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
FS_HZ = 400.0
CHUNK = 3  # what a CAN frame brings (the state is recorded after this chunking)
CHUNKS = (1, 3, 7, 50, 256)  # the events after each (the railed start depends on it)


def signals() -> dict[str, np.ndarray]:
    """Inputs that take every path: a slip and rest, quantised with rails, grip steps."""
    from grasplink.profiles.layouts import LAYOUTS_MM
    from grasplink.simulators import synth

    layout = LAYOUTS_MM["alpha0.1"]
    slip = synth.slip_recording(layout, 60.0, seed=1).force_n
    rest = np.full(320, slip[0]) + np.random.default_rng(0).normal(0, 0.02, 320)
    fast = synth.slip_recording(layout, 200.0, seed=2, noise_scale=2.0).force_n
    # on the lower rail first (blocks wait for a noise), ADC steps, clipped at the top
    lsb = 0.0244
    railed = np.concatenate([np.zeros(150), fast, np.full(80, fast[-1])])
    railed = np.minimum(np.round(railed / lsb) * lsb, 0.85 * float(np.max(fast)))
    steps = synth.static_recording(
        layout, [[0.0, 2.0], [1.5, 5.0], [3.0, 3.0], [4.5, 6.0]], duration_s=6.0, seed=3
    ).force_n
    slow = synth.slip_recording(layout, 25.0, seed=4, reverse=True, dips=True).force_n
    return {
        "slip": np.concatenate([slip, rest]),
        "slow": slow,
        "railed": railed,
        "steps": steps,
        "short": slip[:40],
    }


def _code(value: bool | None) -> float:
    return -1.0 if value is None else float(value)


def told(detector, x: np.ndarray, chunk: int) -> tuple[np.ndarray, np.ndarray]:
    """Contacts (all fields) and verdicts (id, emit, pulse, trend_on; None as -1), in the
    order of the sample that decided them."""
    t = np.arange(len(x)) / FS_HZ
    events, checks = [], []
    for i in range(0, len(x), chunk):
        ev, ck = detector.feed(t[i : i + chunk], x[i : i + chunk])
        events += [tuple(float(v) for v in e) for e in ev]
        checks += [
            (float(c.id), float(c.emit_index), _code(c.pulse), _code(c.trend_on)) for c in ck
        ]
    events.sort(key=lambda e: (e[3], e[0]))
    checks.sort(key=lambda c: (c[1], c[0]))
    return np.array(events).reshape(-1, 8), np.array(checks).reshape(-1, 4)


def state(detector) -> dict[str, np.ndarray]:
    """What the numeric path holds after the last sample: z rows, level, step differences."""
    out: dict[str, np.ndarray] = {}
    for i, ch in enumerate(detector.channels):
        out[f"rows{i}"] = ch.rows.view().copy()
        out[f"rows{i}_at"] = np.array([ch.z_start, ch.next_n, ch.next_test])
    out["level"] = detector._level.copy()
    out["level_at"] = np.array([detector._level_start])
    for i, sc in enumerate(detector._scales):
        out[f"step{i}"] = sc.d.copy()
        out[f"step{i}_at"] = np.array([sc.start, sc.next])
    return out


def main() -> None:
    tree = sys.argv[1] if len(sys.argv) > 1 else str(HERE.parents[2])
    sys.path.insert(0, tree)
    from grasplink.gateway.decoding.contacts import ContactDetector

    arrays: dict[str, np.ndarray] = {}
    for name, x in signals().items():
        for chunk in CHUNKS:
            detector = ContactDetector(FS_HZ)
            events, checks = told(detector, x, chunk)
            arrays[f"{name}/events{chunk}"], arrays[f"{name}/checks{chunk}"] = events, checks
            if chunk == CHUNK:
                arrays |= {f"{name}/{k}": v for k, v in state(detector).items()}
    np.savez_compressed(HERE / "detector_golden.npz", **arrays)
    counts = {k: len(v) for k, v in arrays.items() if k.endswith(("events3", "checks3"))}
    print(counts)


if __name__ == "__main__":
    main()

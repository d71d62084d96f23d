"""How equal two trees' skin decoders are: every estimate on a fixed input set, compared.

    .venv/bin/python benchmarks/compare_trees.py TREE_A TREE_B [--quick] [--decoders LIST]

TREE_A and TREE_B are checkouts (e.g. `git worktree add /tmp/base REV`). Each runs in its
own interpreter (the same module names) over 600 non-stationary signals (26 with --quick)
in 3- and 256-sample chunks, the decoding benchmark's target cases (3-sample chunks) and its
static recordings. --decoders: comma-separated registry names, or "all" (default: the
tracker); decoders other than the tracker take the 26 quick non-stationary signals.
Prints the share of estimates bit-equal and within 1e-9 relative, and every signal whose
estimates differ beyond tolerance (a slip flag, speed > 0.5 mm/s, position > 0.5 mm,
confidence > 0.02). docs/decoding.md ("Compiled kernels") quotes it. --cost ROUNDS:
instead the default decoder's CPU per sample in each tree (the target cases in 3-sample
chunks, the trees alternating, the least of ROUNDS runs each) and their ratio.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

TOLERANCE = {"speed_mm_s": 0.5, "position_mm": 0.5, "confidence": 0.02}

# Run inside each tree's interpreter: decode every input, save one array per run. The
# tracker's runs are named as before the other decoders were added (`(kind, index, chunk)`),
# so its digest reads as in earlier commits; the others' names lead with the decoder.
COLLECT = """
import sys
from concurrent.futures import ProcessPoolExecutor
import numpy as np
from grasplink.evaluation import decoding_bench as db
from grasplink.evaluation import nonstationary as ns
from grasplink.evaluation.decoders import make_decoder
from grasplink.decoding.tracker import TrackerDecoder

QUICK, OUT, DECODERS = sys.argv[1] == "1", sys.argv[2], sys.argv[3].split(",")
if DECODERS == ["all"]:  # every decoder the tree registers, the tracker first
    from grasplink.decoding.registry import DECODERS as REGISTERED
    DECODERS = sorted(REGISTERED, key=lambda name: name != "tracker")


def decode(name, t, x, layout, fs, chunk):
    if name == "tracker":
        dec = TrackerDecoder(layout, fs)
    else:
        dec = make_decoder(name, layout, fs)
    rows = []
    for i in range(0, len(t), chunk):
        for e in dec.process(t[i : i + chunk], x[i : i + chunk]):
            rows.append((e.t_s, float(bool(e.slip)), np.nan if e.speed_mm_s is None else
                         e.speed_mm_s, np.nan if e.position_mm is None else e.position_mm,
                         e.force_n, e.confidence))
    return np.array(rows, float).reshape(-1, 6)


def job(key):
    name, kind, idx, chunk = key
    if kind == "ns":
        r = ns.signals(QUICK or name != "tracker")[idx].make()
        return decode(name, np.asarray(r.t_s), np.asarray(r.force_n), r.truth.layout_mm,
                      r.fs_hz, chunk)
    if kind == "case":
        rec = [c for c in db.cases(QUICK) if "target" in c.tags][idx].recording(1)
    else:
        rec = db.static_cases(QUICK)[idx]
    return decode(name, rec.t_s, rec.force_n, rec.layout_mm, rec.fs_hz, chunk)


def keys(name):
    # the tracker on every non-stationary signal; the others (several times its cost) on
    # the quick set's 26
    signals = len(ns.signals(QUICK or name != "tracker"))
    out = [(name, "ns", i, c) for i in range(signals) for c in (3, 256)]
    targets = [c for c in db.cases(QUICK) if "target" in c.tags]
    out += [(name, "case", i, 3) for i in range(len(targets))]
    out += [(name, "static", i, 3) for i in range(len(db.static_cases(QUICK)))]
    return out


def label(key):
    return str(key[1:]) if key[0] == "tracker" else f"{key[0]} {key[1:]}"


if __name__ == "__main__":
    todo = [k for name in DECODERS for k in keys(name)]
    with ProcessPoolExecutor(2) as pool:
        runs = list(pool.map(job, todo, chunksize=4))
    np.savez(OUT, *runs, names=np.array([label(k) for k in todo]),
             decoders=np.array([k[0] for k in todo]))
"""


def collect(tree: Path, quick: bool, out: Path, decoders: tuple[str, ...] = ("tracker",)) -> None:
    """Every estimate of `decoders` on the input set, decoded by `tree`, saved to `out`
    (npz: arr_0 .., `names` and `decoders` per run)."""
    env_path = f"import sys; sys.path.insert(0, {str(tree)!r}); "
    script = out.with_suffix(".py")
    script.write_text(COLLECT)
    subprocess.run(
        [sys.executable, "-c", env_path + f"exec(open({str(script)!r}).read())",
         "1" if quick else "0", str(out), ",".join(decoders)],
        check=True, cwd=tempfile.gettempdir(),
    )  # fmt: skip


# Run inside each tree's interpreter: the default decoder's CPU per sample on the target
# cases, fed 3 samples at a time (a skin TPDO), after a warm-up (kernels loaded).
COST = """
import sys, time
import numpy as np
from grasplink.evaluation import decoding_bench as db
from grasplink.evaluation.decoders import make_decoder
from grasplink.decoding.registry import DEFAULT_DECODER

recs = [c.recording(1) for c in db.cases(True) if "target" in c.tags]
make_decoder(DEFAULT_DECODER, recs[0].layout_mm, recs[0].fs_hz).warm_up()
samples, cpu = 0, 0.0
for rec in recs:
    dec = make_decoder(DEFAULT_DECODER, rec.layout_mm, rec.fs_hz)
    start = time.process_time()
    for i in range(0, len(rec.t_s), 3):
        dec.process(rec.t_s[i : i + 3], rec.force_n[i : i + 3])
    cpu += time.process_time() - start
    samples += len(rec.t_s)
print(1e6 * cpu / samples)
"""


def cost_us(tree: Path) -> float:
    """The default decoder's CPU per sample (us) in `tree`, one run in its own interpreter."""
    env_path = f"import sys; sys.path.insert(0, {str(tree)!r}); "
    done = subprocess.run(
        [sys.executable, "-c", env_path + COST],
        check=True, cwd=tempfile.gettempdir(), capture_output=True, text=True,
    )  # fmt: skip
    return float(done.stdout.split()[-1])


def cost_ratio(tree_a: Path, tree_b: Path, rounds: int) -> tuple[float, float]:
    """The least CPU per sample of each tree over `rounds` runs, the trees alternating (a
    machine's load drifts: both see it alike)."""
    best = [float("inf"), float("inf")]
    for _ in range(rounds):
        for k, tree in enumerate((tree_a, tree_b)):
            best[k] = min(best[k], cost_us(tree))
    return best[0], best[1]


def compare(a: np.lib.npyio.NpzFile, b: np.lib.npyio.NpzFile) -> tuple[int, int, int, list]:
    total = equal = close = 0
    beyond = []
    for k, name in enumerate(a["names"]):
        x, y = a[f"arr_{k}"], b[f"arr_{k}"]
        if x.shape != y.shape:
            beyond.append((name, f"{len(x)} estimates against {len(y)}"))
            continue
        total += len(x)
        same = (x == y) | (np.isnan(x) & np.isnan(y))
        equal += int(same.all(axis=1).sum())
        near = same | (np.abs(x - y) <= 1e-9 * np.maximum(np.abs(x), 1.0))
        close += int(near.all(axis=1).sum())
        flags = int((x[:, 1] != y[:, 1]).sum())
        known = int((np.isnan(x[:, 2:4]) != np.isnan(y[:, 2:4])).sum())
        worst = {
            field: float(np.nanmax(np.abs(x[:, col] - y[:, col]), initial=0.0))
            for field, col in (("speed_mm_s", 2), ("position_mm", 3), ("confidence", 5))
        }
        if flags or known or any(worst[f] > TOLERANCE[f] for f in TOLERANCE):
            beyond.append((name, f"slip flags {flags}, known/unknown {known}, worst {worst}"))
    return total, equal, close, beyond


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tree_a", type=Path)
    parser.add_argument("tree_b", type=Path)
    parser.add_argument("--quick", action="store_true", help="26 non-stationary signals")
    parser.add_argument("--decoders", default="tracker", help='names, or "all" (the registry\'s)')
    parser.add_argument(
        "--cost", type=int, default=0, metavar="ROUNDS",
        help="instead: the default decoder's CPU per sample, B over A (least of ROUNDS runs)",
    )  # fmt: skip
    args = parser.parse_args()
    if args.cost:
        a, b = cost_ratio(args.tree_a.resolve(), args.tree_b.resolve(), args.cost)
        print(f"default decoder CPU: A {a:.2f} us/sample, B {b:.2f} us/sample, B/A {b / a:.3f}")
        return 0
    decoders = tuple(args.decoders.split(","))
    with tempfile.TemporaryDirectory() as tmp:
        paths = [Path(tmp) / "a.npz", Path(tmp) / "b.npz"]
        for tree, path in zip((args.tree_a, args.tree_b), paths, strict=True):
            collect(tree.resolve(), args.quick, path, decoders)
        total, equal, close, beyond = compare(np.load(paths[0]), np.load(paths[1]))
    print(
        f"estimates {total}: bit-equal {equal} ({100 * equal / max(total, 1):.2f} %), "
        f"within 1e-9 relative {close} ({100 * close / max(total, 1):.2f} %)"
    )
    print(f"signals differing beyond tolerance: {len(beyond)}")
    for name, why in beyond:
        print(f"  {name}: {why}")
    return 1 if beyond else 0


if __name__ == "__main__":
    raise SystemExit(main())

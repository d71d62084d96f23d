"""Is a ridge the detector did not tell still visible where a track predicts it? (issue 22)

Track-before-detect, measured before it is built: at the time a hypothesis predicts a
ridge crossing, the signal's local rise statistic z - the pulse probe's mean-after minus
mean-before over w, half the same difference 2 w either side taken out (a ramp is no
rise), in white-noise units (`detector.pulse_probe`) - is an observation whether or not
the detector told a contact there. This script samples z on slip_reporting's cases at
(a) true crossings the detector missed (no contact within `contact_truth.MATCH_S`), (b)
true crossings it found, and at the times an alias would predict a ridge where there is
none: (c) random times while the object slides, 2 rise times and 20 ms or more from any
crossing, and (d) random times at rest. Each at the crossing (the onset) plus a share of
the pulse's rise time (`ridge_pulses.RISE_MM` over the true speed: a track knows its
speed), on the probe's window nearest that rise time, exactly and with the predicted time
off by a normal 5 or 10 ms (a track's timing). The white noise is the median absolute
difference of the samples before the slip.

Printed per set: the quartiles of z, the share of (a) above (c)'s median and the area
under the curve (a) against (c), and the mean log likelihood ratio per ridge "a pulse
here" against "none" with the pulse's size h unknown: log-uniform from `H_LOW` to `H_HIGH`
times the median z of the found crossings (b) - the told pulses' median, as the decoder
would know it -, z ~ N(h, 1) against N(0, 1), clipped to +-`CLIP` nats. With (a)'s mean
log LR above (c)'s by a nat or more per ridge, three ridges of a hypothesis tell the true
track from an alias; near 0, the sub-threshold ridges carry no evidence.

Run: `.venv/bin/python benchmarks/snr10_soft_evidence.py [--seeds N] [--kinds snr10,constant]
[--layouts alpha0.3]`.
"""

from __future__ import annotations

import argparse
import math
from collections import defaultdict
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

import numpy as np

from grasplink.decoding.detector.pulse_probe import PULSE_RAMP, PULSE_SCALES_S
from grasplink.decoding.ridge_pulses import RISE_MM
from grasplink.evaluation import contact_truth as ct
from grasplink.evaluation import slip_reporting as sr

OFFSETS = (0.0, 0.5, 1.0)  # the centre after the onset, in rise times
H_LOW, H_HIGH = 0.1, 2.0  # the pulse size's prior, x the found crossings' median z
CLIP = 3.0  # nats each way per ridge
JITTERS_S = (0.0, 0.005, 0.01)  # a track's timing error (1 sigma)
NULL_PER_S = 20.0  # null samples drawn per s of slide / rest


def rise_z(x: np.ndarray, w: int, sigma: float) -> np.ndarray:
    """z at every centre c (NaN where the windows leave the signal): the pulse probe's
    rise statistic (module doc) in white-noise units."""
    n = len(x)
    c0 = np.concatenate([[0.0], np.cumsum(x)])
    d = np.full(n, np.nan)
    c = np.arange(w, n - w + 1)
    d[c] = (c0[c + w] - 2.0 * c0[c] + c0[c - w]) / w  # mean after - mean before
    adj = np.full(n, np.nan)
    inner = np.arange(2 * w, n - 2 * w)
    adj[inner] = d[inner] - PULSE_RAMP * (d[inner - 2 * w] + d[inner + 2 * w])
    return adj / (sigma * math.sqrt(2.0 / w * (1.0 + 2.0 * PULSE_RAMP**2)))


def job(case: sr.Case) -> dict:
    """One case's z samples by set and offset (lists), the crossing's ridge index kept."""
    rec = case.make()
    truth = rec.truth
    fs = float(rec.fs_hz)
    t, x = np.asarray(rec.t_s, float), np.asarray(rec.force_n, float)
    t_truth = np.asarray(truth.t_s)
    speed = np.abs(np.asarray(truth.speed_mm_s, float))
    sliding = np.asarray(truth.slipping) > 0
    if not sliding.any():
        return {}
    slip_from = float(t_truth[np.flatnonzero(sliding)[0]])
    slip_to = float(t_truth[np.flatnonzero(sliding)[-1]])
    before = x[t < slip_from - 0.05]
    sigma = float(np.median(np.abs(np.diff(before)))) / 0.6745 / math.sqrt(2.0)
    widths = {
        w: rise_z(x, w, sigma) for w in sorted({max(2, round(s * fs)) for s in PULSE_SCALES_S})
    }
    told = ct.detect(t, x, rec.fs_hz)
    times = np.array([e.t_s for e in told.contacts])
    crossings = np.asarray(truth.contact_times_s, float)
    rng = np.random.default_rng(case.seed * 7 + 1)
    out: dict = defaultdict(list)
    v_slide = float(np.median(speed[sliding]))

    def sample(name: str, at_s: float, v: float, extra: dict | None = None) -> None:
        rise_s = RISE_MM / max(v, 1.0)
        w = min(widths, key=lambda k: abs(math.log(k / (rise_s * fs))))
        for off in OFFSETS:
            for jit in JITTERS_S:
                centre = at_s + off * rise_s + (rng.normal(0.0, jit) if jit else 0.0)
                i = int(np.searchsorted(t, centre))
                z = widths[w][i] if 0 <= i < len(x) else np.nan
                if np.isfinite(z):
                    out[(name, off, jit)].append(float(z))
        if extra is not None:
            out[(name, "ridge")].append(extra)

    for k, c in enumerate(crossings):
        v = float(np.interp(c, t_truth, speed))
        found = len(times) and np.min(np.abs(times - c)) <= ct.MATCH_S
        sample("found" if found else "missed", c, v)
        out["ridge_" + ("found" if found else "missed")].append(k)
    near = 2.0 * RISE_MM / max(v_slide, 1.0) + ct.MATCH_S
    for _ in range(int(NULL_PER_S * (slip_to - slip_from))):
        at = float(rng.uniform(slip_from, slip_to))
        if not len(crossings) or np.min(np.abs(crossings - at)) > near:
            sample("slide", at, v_slide)
    rest_from, rest_to = slip_to + 0.3, float(t[-1]) - 0.2
    for _ in range(int(NULL_PER_S * max(0.0, rest_to - rest_from))):
        sample("rest", float(rng.uniform(rest_from, rest_to)), v_slide)
    out["kind"] = case.kind
    out["layout"] = case.layout
    out["reverse"] = case.reverse
    return dict(out)


def log_lr(z: np.ndarray, median_h: float) -> np.ndarray:
    """log p(z | a pulse, size log-uniform H_LOW..H_HIGH x median_h) / p(z | none), clipped."""
    h = np.exp(np.linspace(math.log(H_LOW * median_h), math.log(H_HIGH * median_h), 64))
    terms = z[:, None] * h[None, :] - 0.5 * h[None, :] ** 2
    top = terms.max(axis=1, keepdims=True)
    lr = top[:, 0] + np.log(np.mean(np.exp(terms - top), axis=1))
    return np.clip(lr, -CLIP, CLIP)


def auc(a: np.ndarray, b: np.ndarray) -> float:
    """P(a sample of a > one of b) (ties half)."""
    if not len(a) or not len(b):
        return math.nan
    both = np.concatenate([a, b])
    ranks = np.argsort(np.argsort(both, kind="stable"), kind="stable") + 1.0
    return float((ranks[: len(a)].sum() - len(a) * (len(a) + 1) / 2) / (len(a) * len(b)))


def report(title: str, rows: list[dict]) -> None:
    pooled: dict = defaultdict(list)
    for r in rows:
        for key, values in r.items():
            if isinstance(key, tuple):
                pooled[key] += values
    found0 = np.array(pooled[("found", 0.5, False)])
    median_h = float(np.median(found0)) if len(found0) else 5.0
    print(f"\n### {title}: {len(rows)} cases; found crossings' median z {median_h:.2f}")
    print(
        "| set | offset (rise times) | timing | n | z q25 / median / q75 | mean log LR |"
        " a > c median | AUC a vs c |"
    )
    print("|---|---:|---|---:|---|---:|---:|---:|")
    for off in OFFSETS:
        for jit in JITTERS_S:
            null = np.array(pooled[("slide", off, jit)])
            for name in ("missed", "found", "slide", "rest"):
                z = np.array(pooled[(name, off, jit)])
                if not len(z):
                    continue
                q = np.percentile(z, [25, 50, 75])
                lr = float(np.mean(log_lr(z, median_h)))
                above = f"{100 * np.mean(z > np.median(null)):.0f} %" if len(null) else "-"
                area = f"{auc(z, null):.2f}" if name != "slide" else "-"
                timing = f"+-{1000 * jit:g} ms" if jit else "exact"
                print(
                    f"| {name} | {off:g} | {timing} | {len(z)} | "
                    f"{q[0]:.2f} / {q[1]:.2f} / {q[2]:.2f} | {lr:+.2f} | {above} | {area} |"
                )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=1)
    parser.add_argument("--kinds", default="snr10,constant")
    parser.add_argument("--layouts", default=None, help="comma list (default: every layout)")
    parser.add_argument("--forward", action="store_true", help="forward cases only")
    args = parser.parse_args(argv)
    kinds = args.kinds.split(",")
    plan = replace(sr.FULL, seeds=args.seeds)
    plan = replace(plan, variants={k: v for k, v in plan.variants.items() if k in kinds})
    todo = [
        c
        for c in sr.cases(plan)
        if (args.layouts is None or c.layout in args.layouts.split(","))
        and not (args.forward and c.reverse)
    ]
    with ProcessPoolExecutor(2) as pool:
        rows = [r for r in pool.map(job, todo, chunksize=2) if r]
    print(f"{len(todo)} cases (full plan, {args.seeds} seed(s), kinds {args.kinds})")
    for kind in kinds:
        report(kind, [r for r in rows if r["kind"] == kind])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""A late stop's own step with and without the earlier ridge pulse's course out.

For each judged stop cleared late (`stop_causes.job`'s cases, the default decoder or a
`--try` tuning) whose own step (the contact nearest the stop's start within 0.1 s) was
told a pulse by the report's due time, this prints the level after that contact's onset
to the hold (`WatchSettings.step_hold_s`) in level-noise units, as the watch reads it
(level - base), and with the earlier contact's pulse course out
(`detector.pulse_under.residual`: height and rise fitted over the level since that
contact's onset, carried on), and the verdict each gives by the watch's step test
(`PulseWatcher._is_step`'s `stays`: 6 noise units, 80 % within `step_rise_s`, not fallen
back by `drop_fraction`) - step or pulse - with the fit (height N, rise ms, rms N) and
the gap to the earlier onset. `--all` prints every late stop's step, whatever its
verdict; `--cases SEED,...` only those.

Run: `.venv/bin/python benchmarks/stop_pulse_under.py --seeds 2`.
"""

from __future__ import annotations

import argparse
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import plan_cases
import stop_causes
import stop_trends  # (its watcher patch notes each watch's noise: SEEN)

from grasplink.decoding.detector import pulse_under
from grasplink.decoding.detector.watch import WatchSettings, step_hold_samples
from grasplink.evaluation import slip_reporting as sr

SHOW_MS = (0, 10, 20, 30, 40, 60, 80, 100)


def stays(levels: np.ndarray, noise: float, step_rise: int, drop: float) -> bool:
    """`PulseWatcher._is_step`'s step test on a level (base out) from the onset on."""
    top = float(levels.max())
    if top < 6.0 * noise:
        return False
    rise = int(np.argmax(levels >= 0.8 * top))
    if rise > step_rise:
        return False
    return float(levels[rise:].min()) >= (1.0 - drop) * top


def job(case: sr.Case, tuning: dict, every: bool) -> tuple[sr.Case, list[str]]:
    stop_trends.SEEN.clear()
    rec = case.make()
    decoder = stop_causes._decoder(case, rec, tuning)
    decoder.rows, decoder.contacts, decoder.checks, decoder.arrived = [], [], [], []
    estimates, _ = stop_causes.ns.feed(decoder, rec.t_s, rec.force_n, sr.CHUNK)
    scored = sr.score(estimates, rec.truth)
    fs = rec.fs_hz
    settings = WatchSettings()
    half = max(0, round(settings.level_s * fs / 2.0))
    hold = step_hold_samples(fs, settings)
    step_rise = max(1, round(settings.step_rise_s * fs))
    x = np.asarray(rec.force_n, dtype=float)
    level = np.convolve(x, np.full(2 * half + 1, 1.0 / (2 * half + 1)), mode="same")
    lines = []
    for stop, _, c, verdict in stop_causes.late_stops(decoder, scored):
        if c is None:
            continue
        if verdict != "pulse" and not every:
            continue
        seen = stop_trends.SEEN.get(c.index)
        noise = seen["noise"] if seen else float("nan")
        n = c.index
        before = n - 2 * half - 1
        prev = [p for p, _ in decoder.contacts if p.index < n - 2]
        head = f"stop {stop.start_s:.3f} delay {stop.delay_s:.2f} contact {c.t_s:.3f} {verdict}"
        if n + hold + half >= len(x) or not prev or noise != noise:
            lines.append(head + ": no level to the hold / no earlier contact")
            continue
        p = prev[-1]
        plain = level[n : n + hold + 1] - level[before]
        base_p = level[max(0, p.index - 2 * half - 1)]
        res = pulse_under.residual(level[: n + hold + 1], 0, before, p.index, base_p, half, fs)
        j = [min(hold, round(ms * fs / 1e3)) for ms in SHOW_MS]
        shown = " ".join(f"{plain[i] / noise:6.1f}" for i in j)
        v0 = "step" if stays(plain, noise, step_rise, settings.drop_fraction) else "pulse"
        gap = 1e3 * (n - p.index) / fs
        if res is None:
            lines.append(f"{head} gap {gap:4.0f} ms | plain {shown} -> {v0} | no fit")
            continue
        r = res[n - before :]
        course = pulse_under.fit(
            level[p.index - half : before + 1] - base_p,
            np.arange(p.index - half, before + 1) - p.index, half, fs,
        )  # fmt: skip
        v1 = "step" if stays(r, noise, step_rise, settings.drop_fraction) else "pulse"
        shown_r = " ".join(f"{r[i] / noise:6.1f}" for i in j)
        fit = "" if course is None else (
            f"fit {course.height:.3f} N rise {1e3 * course.rise / fs:.0f} ms rms "
            f"{course.rms / noise:.1f} nu"
        )  # fmt: skip
        lines.append(
            f"{head} gap {gap:4.0f} ms {fit}\n      plain    {shown} -> {v0}\n"
            f"      residual {shown_r} -> {v1}"
        )
    return case, lines


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    plan_cases.add_plan_arguments(parser, ",".join(stop_causes.STOP_KINDS), 2, cases=True)
    parser.add_argument("--all", action="store_true", help="every late stop, any verdict")
    args = parser.parse_args(argv)
    todo = plan_cases.full_plan_cases(
        parser, args.kinds, args.seeds, args.cases, first_seed=args.first_seed
    )
    n = len(todo)
    with ProcessPoolExecutor(2) as pool:
        results = list(pool.map(job, todo, [args.tuning] * n, [args.all] * n, chunksize=2))
    print(f"{n} cases ({args.kinds}, full plan, {args.seeds} seed(s)), {args.tuning}")
    print(f"level - base in noise units at {SHOW_MS} ms after the onset")
    plan_cases.print_case_lines(results)
    return 0


if __name__ == "__main__":
    sys.exit(main())

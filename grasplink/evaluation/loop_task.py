"""The least-force task in the closed loop: does slip-speed feedback beat slip occurrence?

The grid is feedback mode (slip occurrence, slip speed) × the task's slip speeds (one to
four contraction levels of grip missing, `least_force.SPEEDS_MM_S`) × seeds, reflex off:
the question is the wearer's; and the same for objects that get wet mid-task (friction
that changes, `least_force.WET_SPEEDS_MM_S`). A trial *succeeds* when the object ends at
rest, on the skin, unbroken. The verdict per speed is Fisher's exact test on success;
*why* comes from what the wearer was shown and what the grip did: a crush is a grip past
the object's limit (too many levels), a drop one that was too little too late.

Drivers: benchmarks/bench_loop_task.py (docs/benchmarks/loop_task.md, .json, .png).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import scipy.stats

from grasplink.evaluation import least_force
from grasplink.evaluation.loop import (
    MODES,
    SKIN_END_MM,
    START_MM,
    START_S,
    ControllerFactory,
    Trial,
    dump_json,
    median_of,
    pct_of,
    run_trials,
)

TASK_MODES = ("slip_occurrence", "slip_speed")
SEEDS = tuple(range(1, 11))
QUICK_SEEDS = (1,)
SETTLE_S = 8.0  # two of the wearer's 4 s phases after the slowest slip would have left
ALPHA = 0.05  # Fisher's exact test, two-sided
HIGH_SPEEDS_MM_S = (20.0, 28.0)  # three and four levels missing: the thesis's "high speeds"


DRY, WET = least_force.DRY_TASK, least_force.WET_TASK
TASK_SPEEDS_MM_S = {DRY: least_force.SPEEDS_MM_S, WET: least_force.WET_SPEEDS_MM_S}


def grid(quick: bool) -> list[Trial]:
    seeds = QUICK_SEEDS if quick else SEEDS
    return [
        Trial(mode, False, speed, seed, settle_s=SETTLE_S, task=task)
        for task, speeds in TASK_SPEEDS_MM_S.items()
        for mode in TASK_MODES
        for speed in speeds
        for seed in seeds
    ]


def task_of(row: dict) -> str:
    return str(row.get("task", DRY))


def success(row: dict) -> bool:
    return bool(row["stopped"] and not row["crushed"])


def summarise(rows: Sequence[dict]) -> dict:
    """Shares (%) of success, crush, drop and still sliding; medians over the successes."""
    won = [r for r in rows if success(r)]
    return {
        "n": len(rows),
        "success_pct": pct_of([success(r) for r in rows]),
        "crushed_pct": pct_of([bool(r["crushed"]) for r in rows]),
        "dropped_pct": pct_of([bool(r["dropped"]) and not r["crushed"] for r in rows]),
        "sliding_pct": pct_of(
            [not r["stopped"] and not r["dropped"] and not r["crushed"] for r in rows]
        ),
        "distance_median_mm": median_of([r["slip_distance_mm"] for r in won]),
        "time_to_stop_median_s": median_of([r["time_to_stop_s"] for r in won]),
        "grip_mean_n": median_of([r["grip_mean_n"] for r in rows]),
        "i_emg": median_of([r["i_emg"] for r in rows]),
        "belt_latency_median_s": median_of([r["belt_latency_s"] for r in rows]),
        "shown_too_high_pct": pct_of([shown_too_high(r) for r in rows]),
        "shown_after_stop_median_s": median_of([r.get("slip_shown_after_stop_s") for r in rows]),
    }


def shown_too_high(row: dict) -> bool:
    """The slip belt ran faster than the level of the object's slip at the resting grip
    (the fastest it ever slid), so the display asked for more grip than was missing."""
    shown = row.get("slip_belt_max_mrad_s")
    if shown is None:
        return False
    level = least_force.TaskObject(row["speed_mm_s"]).levels_missing
    return bool(shown > least_force.SLIP_TABLE[level - 1][1])


def compare(a: dict, b: dict) -> dict:
    """Success of `a` against `b`: the difference in points with its 95 % interval
    (Agresti-Caffo: one success and one failure added to each group, so 0 % and 100 % keep
    a width) and Fisher's exact test; *beats* and *loses* need p < 0.05."""
    if not a["n"] or not b["n"]:
        return {"verdict": "ties", "diff_pct": None, "ci95_pct": None, "p": None}
    wins_a = round(a["success_pct"] * a["n"] / 100.0)
    wins_b = round(b["success_pct"] * b["n"] / 100.0)
    table = np.array([[wins_a, a["n"] - wins_a], [wins_b, b["n"] - wins_b]])
    p = float(scipy.stats.fisher_exact(table).pvalue)
    pa, pb = (wins_a + 1) / (a["n"] + 2), (wins_b + 1) / (b["n"] + 2)
    se = math.sqrt(pa * (1 - pa) / (a["n"] + 2) + pb * (1 - pb) / (b["n"] + 2))
    diff = 100.0 * (pa - pb)
    word = "ties"
    if p < ALPHA and wins_a / a["n"] != wins_b / b["n"]:
        word = "beats" if wins_a / a["n"] > wins_b / b["n"] else "loses"
    return {
        "verdict": word,
        "diff_pct": 100.0 * (wins_a / a["n"] - wins_b / b["n"]),
        "ci95_pct": [diff - 196.0 * se, diff + 196.0 * se],
        "p": p,
    }


def aggregate(rows: Sequence[dict]) -> dict:
    """Figures per mode and speed, per mode over the high speeds, and the comparisons, for
    the dry objects; the same under "wet" for the wet ones."""
    out = _aggregate([r for r in rows if task_of(r) == DRY], TASK_SPEEDS_MM_S[DRY])
    out["wet"] = _aggregate([r for r in rows if task_of(r) == WET], TASK_SPEEDS_MM_S[WET])
    return out


def _aggregate(rows: Sequence[dict], speeds: Sequence[float]) -> dict:
    out: dict[str, Any] = {"speeds": {}, "high": {}, "all": {}, "compare": {}}
    for mode in TASK_MODES:
        mine = [r for r in rows if r["mode"] == mode]
        out["speeds"][mode] = {
            f"{v:g}": summarise([r for r in mine if r["speed_mm_s"] == v]) for v in speeds
        }
        out["high"][mode] = summarise([r for r in mine if r["speed_mm_s"] in HIGH_SPEEDS_MM_S])
        out["all"][mode] = summarise(mine)
    speed, occurrence = "slip_speed", "slip_occurrence"
    out["compare"] = {
        **{
            f"{v:g}": compare(out["speeds"][speed][f"{v:g}"], out["speeds"][occurrence][f"{v:g}"])
            for v in speeds
        },
        "high": compare(out["high"][speed], out["high"][occurrence]),
        "all": compare(out["all"][speed], out["all"][occurrence]),
    }
    return out


def objects(wet: bool = False) -> list[dict]:
    """The task's objects, one per slip speed: what the physics asks of the wearer."""
    rows = []
    for v in TASK_SPEEDS_MM_S[WET if wet else DRY]:
        task = least_force.TaskObject(v, wet)
        rows.append(
            {
                "speed_mm_s": v,
                "load_n": task.load_n,
                "holding_grip_n": task.holding_grip_n,
                "stopping_level": task.stopping_level,
                "levels_missing": task.levels_missing,
                "crush_limit_n": task.crush_limit_n,
                "crossing_s": (SKIN_END_MM - START_MM) / v,
                "wetting_s": task.wetting_s(START_S) if wet else None,
                "friction_after": task.friction_after,
                "final_level": task.final_level,
            }
        )
    return rows


def run_report(
    out: Path,
    *,
    controllers_for: ControllerFactory,
    quick: bool = False,
    workers: int | None = None,
    log: Callable[[str], None] = print,
    dask: str | None = None,
) -> dict:
    """Run the task's grid (local cores, or the Dask scheduler at `dask`) and write
    loop_task.md, .json and .png into `out`."""
    trials = grid(quick)
    log(f"least-force task: {len(trials)} trials ({'quick' if quick else 'full'} grid)")
    from grasplink.evaluation.slip_reporting import git_state

    # the tree as the trials start: a commit made while they run is not what they ran
    run = {
        "started": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
        **git_state(Path(__file__).resolve().parents[2]),
    }
    rows = run_trials(trials, controllers_for, workers, log, dask)
    results: dict[str, Any] = {
        "quick": quick,
        "run": run,
        "grid": {
            "modes": list(TASK_MODES),
            "speeds_mm_s": list(least_force.SPEEDS_MM_S),
            "wet_speeds_mm_s": list(least_force.WET_SPEEDS_MM_S),
            "seeds": sorted({t.seed for t in trials}),
            "settle_s": SETTLE_S,
            "trials": len(trials),
        },
        "objects": objects(),
        "wet_objects": objects(wet=True),
        "figures": aggregate(rows),
        "trials": rows,
    }
    out.mkdir(parents=True, exist_ok=True)
    (out / "loop_task.json").write_text(dump_json(results))
    plot_report(results, out / "loop_task.png")
    (out / "loop_task.md").write_text(render(results))
    return results


def report_to(
    *,
    quick: bool,
    out: Path | None,
    controllers_for: ControllerFactory,
    workers: int | None = None,
    dask: str | None = None,
    log: Callable[[str], None] = print,
) -> tuple[dict, Path]:
    """What the drivers call: a bad worker count or an unreachable scheduler fails before
    any trial; docs/benchmarks/ of the checkout unless `out`; (results, out)."""
    from grasplink.evaluation.decoding_bench import default_out_dir
    from grasplink.evaluation.workers import open_workers

    open_workers(workers, dask).close()
    out = out if out is not None else default_out_dir()
    results = run_report(
        out, controllers_for=controllers_for, quick=quick, workers=workers, log=log, dask=dask
    )
    return results, out


def headline(results: dict) -> str:
    """One line for a console: the high speeds' verdict, and the wet objects'."""
    high = results["figures"]["compare"]["high"]
    wet = results["figures"].get("wet", {}).get("compare", {}).get("all")
    line = (
        f"least-force task, high speeds: slip speed {high['verdict']} slip occurrence "
        f"({high['diff_pct']:+.0f} points, Fisher p {high['p']:.2g})"
    )
    if wet and wet["p"] is not None:
        line += f"; wet objects: {wet['verdict']} ({wet['diff_pct']:+.0f}, p {wet['p']:.2g})"
    return line


def _f(value: float | None, digits: int = 0) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def render(results: dict) -> str:
    g, f = results["grid"], results["figures"]
    high = f["compare"]["high"]
    lines = [
        "# The least-force task: does slip-speed feedback beat slip occurrence?",
        "",
        "Generated by `benchmarks/bench_loop_task.py` (grasplink/evaluation/loop_task.py, "
        "least_force.py); do not edit by hand.",
        "",
        *_run_line(results.get("run")),
        "The headline loop (docs/benchmarks/loop.md) cannot tell the two apart: any grip "
        "above 5.76 N stops its slip, so the display changes how hard the wearer squeezes, "
        "not whether the slip stops. This task is the thesis's (ch. 2.3.3) made physical. "
        "The object is pulled out through a damper (`object.damped`), so while it slides its "
        "speed is the grip it lacks: "
        f"{least_force.LEVEL_SPAN_MM_S:g} mm/s per contraction level "
        f"({least_force.GRIP_STEP_N:g} N, damping "
        f"{least_force.DAMPING_N_S_PER_MM:.3f} N·s/mm). It breaks "
        f"{least_force.FRAGILITY_MARGIN_N:g} N above the grip of the level that stops it, so "
        "one level too many crushes it. The wearer (`wearer.virtual`, "
        "`slip_response_adds`) is told to hold with the least force: a slip shown at level k "
        "asks for k levels more than it held when the display came up, and a slip still "
        f"felt {least_force.REPEAT_S:g} s later for one more. The gateway's slip levels start "
        f"every {least_force.LEVEL_SPAN_MM_S:g} mm/s; slip occurrence runs the slip belt at "
        'its first level ("one level more"). Reflex off; decoder, skin (alpha0.1), noise, '
        "ridge dips, EMG and hand as in the headline loop.",
        "",
        f"Grid: {', '.join(MODES[m] for m in g['modes'])} × slip speeds "
        f"{', '.join(f'{v:g}' for v in g['speeds_mm_s'])} mm/s × {len(g['seeds'])} seed(s): "
        f"{g['trials']} trials. *Success*: at rest at the end, on the skin, not crushed.",
        "",
        "## The objects",
        "",
        "| slip speed at e1 mm/s | load N | grip that stops it N | level that stops it | "
        "levels missing | breaks above N | crosses the skin in s |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for o in results["objects"]:
        lines.append(
            f"| {o['speed_mm_s']:g} | {o['load_n']:.2f} | {o['holding_grip_n']:.2f} | "
            f"e{o['stopping_level']} | {o['levels_missing']} | {o['crush_limit_n']:g} | "
            f"{o['crossing_s']:.1f} |"
        )
    lines += [
        "",
        "## Verdict",
        "",
        f"**At high speeds ({', '.join(f'{v:g}' for v in HIGH_SPEEDS_MM_S)} mm/s): slip speed "
        f"{high['verdict']} slip occurrence**, success "
        f"{_f(f['high']['slip_speed']['success_pct'])} % against "
        f"{_f(f['high']['slip_occurrence']['success_pct'])} % "
        f"(difference {_f(high['diff_pct'])} points, 95 % interval {_ci(high)}, Fisher's "
        f"exact p = {_p(high)}; *beats* needs p < {ALPHA:g}).",
        "",
        *verdict_table(f, g["speeds_mm_s"]),
        "",
        *why(results),
        "",
        "## Per mode and speed",
    ]
    lines += [
        "",
        "| mode | slip speed mm/s | trials | success % | crushed % | dropped % | distance mm | "
        "time to stop s | grip N (median of means) | I_EMG | belt s | shown too fast % | "
        "slip shown after the stop s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for mode in g["modes"]:
        for key, s in sorted(f["speeds"][mode].items(), key=lambda item: float(item[0])):
            lines.append(
                f"| {MODES[mode]} | {key} | {s['n']} | {_f(s['success_pct'])} | "
                f"{_f(s['crushed_pct'])} | {_f(s['dropped_pct'])} | "
                f"{_f(s['distance_median_mm'])} | {_f(s['time_to_stop_median_s'], 2)} | "
                f"{_f(s['grip_mean_n'], 1)} | {_f(s['i_emg'], 2)} | "
                f"{_f(s['belt_latency_median_s'], 2)} | {_f(s['shown_too_high_pct'])} | "
                f"{_f(s['shown_after_stop_median_s'], 2)} |"
            )
    lines += ["", "![success against slip speed](loop_task.png)", ""]
    if "wet" in f and results.get("wet_objects"):
        lines += render_wet(results)
    return "\n".join(lines)


def render_wet(results: dict) -> list[str]:
    """The friction-that-changes section: the wet objects and the verdicts on them."""
    f = results["figures"]["wet"]
    every = f["compare"]["all"]
    lines = [
        "## Friction that changes: the object gets wet",
        "",
        "The same objects, except that one of the wearer's phases after a wearer adding a "
        "level per phase would hold it, the object gets wet: over "
        f"{least_force.WETTING_S:g} s its friction falls until the grip of the level that "
        f"held it lets it slide again at {least_force.RESLIP_MM_S:g} mm/s, one level short. "
        "It breaks above the level that holds it wet, so a grip one level too strong before "
        "the wetting no longer crushes it and never lets it slip again. "
        f"{least_force.SPEEDS_MM_S[-1]:g} mm/s is left out: it already needs the strongest "
        "level.",
        "",
        "| slip speed at e1 mm/s | gets wet at s | friction after | held dry by | held wet by "
        "| breaks above N |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for o in results["wet_objects"]:
        lines.append(
            f"| {o['speed_mm_s']:g} | {o['wetting_s']:g} | {o['friction_after']:.3f} | "
            f"e{o['stopping_level']} | e{o['final_level']} | {o['crush_limit_n']:g} |"
        )
    lines += [
        "",
        f"**Over every wet object: slip speed {every['verdict']} slip occurrence**, success "
        f"{_f(f['all']['slip_speed']['success_pct'])} % against "
        f"{_f(f['all']['slip_occurrence']['success_pct'])} % (difference "
        f"{_f(every['diff_pct'])} points, 95 % interval {_ci(every)}, Fisher's exact p = "
        f"{_p(every)}).",
        "",
        *verdict_table(f, results["grid"]["wet_speeds_mm_s"]),
        "",
    ]
    return lines


def verdict_table(figures: dict, speeds_mm_s: Sequence[float]) -> list[str]:
    """Per speed: each mode's outcome shares and the comparison."""
    lines = [
        "| slip speed mm/s | slip speed: success · crushed · dropped · sliding % | "
        "slip occurrence: success · crushed · dropped · sliding % | difference, 95 % interval "
        "| p | verdict |",
        "|---:|---|---|---:|---:|---|",
    ]
    for v in speeds_mm_s:
        key = f"{v:g}"
        a, b = figures["speeds"]["slip_speed"][key], figures["speeds"]["slip_occurrence"][key]
        c = figures["compare"][key]
        lines.append(
            f"| {key} | {_cells(a)} | {_cells(b)} | {_f(c['diff_pct'])}, {_ci(c)} | {_p(c)} "
            f"| {c['verdict']} |"
        )
    return lines


def why(results: dict) -> list[str]:
    """How each mode fails, and what the wearer was shown, from the figures."""
    f = results["figures"]
    lines = ["## Why", ""]
    for mode in results["grid"]["modes"]:
        s = f["all"][mode]
        crushed, dropped = s["crushed_pct"] or 0.0, s["dropped_pct"] or 0.0
        how = "crushing" if crushed > dropped else "dropping"
        lines.append(
            f"- **{MODES[mode].capitalize()}** fails mostly by {how}: "
            f"{_f(crushed)} % crushed, {_f(dropped)} % dropped over all speeds "
            f"(high speeds: {_f(f['high'][mode]['crushed_pct'])} % and "
            f"{_f(f['high'][mode]['dropped_pct'])} %). The belt ran a level faster than the "
            f"object ever slid in {_f(s['shown_too_high_pct'])} % of its trials (a display "
            "asking for more grip than was missing); slip still showed a median "
            f"{_f(s['shown_after_stop_median_s'], 1)} s after the object stopped, against the "
            f"wearer's {least_force.REPEAT_S:g} s before one more level."
        )
    same = identical_share([r for r in results.get("trials", []) if task_of(r) == DRY])
    if same:
        lines.append(
            "- Trials with the same seed and speed that ended the same way in both modes: "
            + ", ".join(f"{v} mm/s {pct:.0f} %" for v, pct in same.items())
            + ". Where the slip is first shown before any speed is known both modes show the "
            "occurrence level, and the speed comes too late to matter."
        )
    lines.append(
        "- Speed read too fast while the grip rises and slip shown after a stop are the "
        "decoder's (docs/benchmarks/slip_reporting.md): this task is as good as the speed "
        "it is shown."
    )
    return lines


def identical_share(rows: Sequence[dict]) -> dict[str, float]:
    """Per speed: the share of seeds whose outcome (success, crush, drop) was the same in
    both modes."""
    outcome: dict[tuple[str, float, int], tuple[bool, bool, bool]] = {
        (r["mode"], r["speed_mm_s"], r["seed"]): (
            success(r),
            bool(r["crushed"]),
            bool(r["dropped"]),
        )
        for r in rows
    }
    out = {}
    for v in sorted({r["speed_mm_s"] for r in rows}):
        seeds = sorted({r["seed"] for r in rows if r["speed_mm_s"] == v})
        pairs = [
            (outcome.get(("slip_speed", v, s)), outcome.get(("slip_occurrence", v, s)))
            for s in seeds
        ]
        pairs = [(a, b) for a, b in pairs if a is not None and b is not None]
        if pairs:
            out[f"{v:g}"] = 100.0 * sum(a == b for a, b in pairs) / len(pairs)
    return out


def _run_line(run: dict | None) -> list[str]:
    if not run:
        return []
    changed = run.get("decoder_changes") or []
    note = f" (decoder files changed since: {', '.join(changed)})" if changed else ""
    return [f"Run: {run['started']}, commit {run.get('commit') or '?'}{note}.", ""]


def _ci(c: dict) -> str:
    if c["ci95_pct"] is None:
        return "-"
    low, high = c["ci95_pct"]
    return f"[{low:.0f}, {high:.0f}]"


def _p(c: dict) -> str:
    return "-" if c["p"] is None else f"{c['p']:.2g}"


def _cells(s: dict) -> str:
    return " · ".join(
        _f(s[k]) for k in ("success_pct", "crushed_pct", "dropped_pct", "sliding_pct")
    )


def plot_report(results: dict, path: Path) -> None:
    """loop_task.png: success and crush shares against slip speed, per mode, ± 1 SE."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figures = results["figures"]["speeds"]
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), dpi=100)
    colours = {"slip_occurrence": "tab:orange", "slip_speed": "tab:green"}
    for ax, (field_name, label) in zip(
        axes, (("success_pct", "success [%]"), ("crushed_pct", "crushed [%]")), strict=True
    ):
        for mode, unordered in figures.items():
            # JSON keys come back sorted as text ("12" < "4"): order by speed
            by_speed = dict(sorted(unordered.items(), key=lambda item: float(item[0])))
            speeds = np.array([float(v) for v in by_speed])
            p = np.array(
                [np.nan if s[field_name] is None else s[field_name] for s in by_speed.values()]
            )
            n = np.array([max(s["n"], 1) for s in by_speed.values()])
            se = 100.0 * np.sqrt((p / 100.0) * (1 - p / 100.0) / n)
            ax.errorbar(
                speeds, p, yerr=se, color=colours[mode], marker="o", capsize=3, label=MODES[mode]
            )
        ax.set_xlabel("slip speed at the resting grip [mm/s] (8 mm/s = one level missing)")
        ax.set_ylabel(label)
        ax.set_ylim(-5, 105)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("least-force task: slip speed against slip occurrence feedback")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)

"""`grasplink skin design`: a multi-objective search for a skin's ridge layout (thesis ch. 5.3.4).

The thesis searched layouts of up to 12 spacings of 3-81 mm summing to the 84 mm skin with
a genetic algorithm for 96 hours per weight α, maximising α·accuracy + (1 − α)·resolution.
Here pymoo's NSGA-II searches the same space in minutes, with the fitness of any registered
decoder on simulated slips (`design_slips`) and the evaluations on `workers` (local cores
or a Dask cluster).

Encoding: a chromosome is 13 numbers in [0, 1] - the share x0 picking the number of
spacings N (2..12, fewer on a short skin), then 12 weights of which the first N are used
(the thesis's ∆ = {D1..D12, N}). Each spacing is 3 mm plus its weight's share of the rest
of the skin, rounded to whole mm by largest remainder (`spacings_of`), so every chromosome
*is* a valid layout: the sum constraint never needs a repair or a penalty, and SBX and
polynomial mutation work on the weights as on any real variables.

Objectives: accuracy A (the thesis's hit share: speed within 1/10, position within 1/10 of
the skin under the three peaks), the speed error (%) and position error (mm) behind it, and
resolution R = number of spacings / 10 (table 5.1's Max(R): 7 spacings, 8 ridges → 0.7).
With `alpha` the search minimises table 5.1's F = α·(1 − A) + (1 − α)·(1 − R); without it
(`--pareto`) it keeps the front of (speed error, position error, −R).

Reproducibility: a candidate's slips are drawn once per run (`plan_slips`, from the run's
seed), its noise seeded by a hash of its spacings and the run's seed, and pymoo's operators
by the run's seed, so a fixed number of generations gives the same layouts with any number
or kind of workers. A time budget stops after a number of generations that depends on the
machine.
"""

from __future__ import annotations

import csv
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from grasplink.decoding.registry import DECODERS, DEFAULT_DECODER, decoder_class
from grasplink.errors import ConfigError
from grasplink.evaluation import design_slips as ds
from grasplink.evaluation.workers import Workers
from grasplink.profiles.layouts import LAYOUTS_MM

MIN_SPACING_MM = 3.0  # a ridge (2.5 mm) and a gap: the thesis's lower bound
MAX_SPACINGS = 12  # the thesis's chromosome
THESIS_LENGTH_MM = 84.0
THESIS_SPEEDS = "10:100:5"
THESIS_ALPHAS = (0.1, 0.3, 0.5, 0.7, 0.9)
PARETO_ALPHA = 0.5  # --pareto writes the front member best at this α as layout.toml
POPULATION = 24
GENERATIONS = 15  # with POPULATION and SLIPS: < 10 min on 2 cores (docs/benchmarks/layouts.md)
SLIPS = 32  # per evaluation: ranks as 96 do at Kendall tau ~0.5 (docs/benchmarks/layouts.md)
CONFIRM_FACTOR = 4  # the finalists are scored again on a plan this many times longer
FINALISTS = 4
REFERENCES = ("alpha0.1", "alpha0.3", "alpha0.5", "alpha0.7", "alpha0.9", "fibonacci")

Layout = tuple[float, ...]


# -- settings ---------------------------------------------------------------------------------


def parse_speeds(text: str) -> tuple[float, ...]:
    """ "10:100:5" (start:stop:step, stop included) or "20,40,60" into speeds in mm/s."""
    stripped = text.strip()
    if ":" in stripped:
        parts = stripped.split(":")
        if len(parts) != 3:
            raise ConfigError(f"--speeds {text!r}: expected START:STOP:STEP in mm/s, e.g. 10:100:5")
        start, stop, step = (_number(p, text) for p in parts)
        if not step > 0:
            raise ConfigError(f"--speeds {text!r}: the step must be > 0 mm/s")
        count = math.floor((stop - start) / step + 1e-9) + 1
        speeds = tuple(round(start + i * step, 9) for i in range(max(0, count)))
    else:
        speeds = tuple(_number(p, text) for p in stripped.split(",") if p.strip())
    if not speeds:
        raise ConfigError(f"--speeds {text!r}: the speed grid is empty")
    bad = [v for v in speeds if not 0 < v <= 1000]
    if bad:
        raise ConfigError(f"--speeds {text!r}: speeds must be > 0 and <= 1000 mm/s, got {bad[0]:g}")
    return speeds


def _number(item: str, text: str) -> float:
    try:
        value = float(item)
    except ValueError:
        raise ConfigError(f"--speeds {text!r}: {item.strip()!r} is not a number of mm/s") from None
    if not math.isfinite(value):
        raise ConfigError(f"--speeds {text!r}: {item.strip()!r} is not finite")
    return value


@dataclass(frozen=True)
class DesignSettings:
    """What `grasplink skin design` was asked for (checked by `check` before any work)."""

    length_mm: float = THESIS_LENGTH_MM
    alpha: float | None = None  # None: the Pareto front
    speeds_mm_s: tuple[float, ...] = field(default_factory=lambda: parse_speeds(THESIS_SPEEDS))
    decoder: str = DEFAULT_DECODER
    generations: int | None = None
    budget_min: float | None = None
    population: int = POPULATION
    slips: int = SLIPS
    seed: int = 1

    def check(self) -> DesignSettings:
        """ConfigError naming the first bad setting (the decoder is imported here)."""
        if not math.isfinite(self.length_mm) or self.length_mm < 2 * MIN_SPACING_MM:
            raise ConfigError(
                f"--length-mm {self.length_mm:g}: a skin needs at least three ridges "
                f"{MIN_SPACING_MM:g} mm apart, so at least {2 * MIN_SPACING_MM:g} mm"
            )
        if self.alpha is not None and not 0.0 <= self.alpha <= 1.0:
            raise ConfigError(f"--alpha {self.alpha:g}: expected a weight in 0..1")
        if not self.speeds_mm_s:
            raise ConfigError("--speeds: the speed grid is empty")
        if self.decoder not in DECODERS:
            raise ConfigError(
                f"--decoder {self.decoder!r}: unknown decoder; "
                f"valid decoders: {', '.join(DECODERS)}"
            )
        decoder_class(self.decoder)  # a decoder whose module is missing fails now
        if self.generations is not None and self.generations < 1:
            raise ConfigError(f"--generations {self.generations}: expected at least 1")
        if self.budget_min is not None and not self.budget_min > 0:
            raise ConfigError(f"--budget-min {self.budget_min:g}: expected > 0 minutes")
        if self.generations is not None and self.budget_min is not None:
            raise ConfigError("give --generations G or --budget-min M, not both")
        if self.population < 4:
            raise ConfigError(f"--population {self.population}: expected at least 4")
        if self.slips < 1:
            raise ConfigError(f"--slips {self.slips}: expected at least 1 slip per evaluation")
        return self

    @property
    def max_spacings(self) -> int:
        return max(2, min(MAX_SPACINGS, math.floor(self.length_mm / MIN_SPACING_MM + 1e-9)))


# -- encoding and objectives ----------------------------------------------------------------


def spacings_of(x: Sequence[float], length_mm: float, max_spacings: int = MAX_SPACINGS) -> Layout:
    """The layout a chromosome encodes (see the module docstring); sums to `length_mm`."""
    count = 2 + min(int(float(x[0]) * (max_spacings - 1)), max_spacings - 2)
    weights = np.clip(np.asarray(x[1 : 1 + count], dtype=float), 0.0, 1.0) + 1e-6
    whole = math.floor(length_mm + 1e-9)
    free = whole - MIN_SPACING_MM * count
    raw = free * weights / weights.sum()
    base = np.floor(raw + 1e-9)
    order = np.argsort(-(raw - base), kind="stable")  # largest remainders first, then index
    base[order[: round(float(free - base.sum()))]] += 1.0
    spacings = [MIN_SPACING_MM + float(b) for b in base]
    spacings[-1] += round(length_mm - whole, 9)  # a fractional skin: the rest on the last one
    return tuple(spacings)


def resolution(spacings: Sequence[float]) -> float:
    """The thesis's resolution: the number of spacings over 10 (table 5.1's Max(R))."""
    return len(spacings) / 10.0


def fitness(alpha: float, accuracy: float, resolution_: float) -> float:
    """Table 5.1's F (minimised): α·(1 − A) + (1 − α)·(1 − R); 0.0937 for its α = 0.9 row."""
    return alpha * (1.0 - accuracy) + (1.0 - alpha) * (1.0 - resolution_)


@dataclass(frozen=True)
class Candidate:
    """One fitness evaluation, as a worker gets it (plain, picklable values)."""

    spacings_mm: Layout
    plan: tuple[ds.SlipPlan, ...]
    decoder: str
    seed: int


def evaluate(candidate: Candidate) -> dict[str, float]:
    """A candidate's figures: accuracy, speed and position error, resolution, CPU seconds."""
    started = time.process_time()
    scores = ds.score_layout(
        candidate.spacings_mm, candidate.plan, candidate.decoder, candidate.seed
    )
    figures = ds.summarise(scores)
    figures["resolution"] = resolution(candidate.spacings_mm)
    figures["cpu_s"] = time.process_time() - started
    return figures


def objectives(figures: dict[str, float], alpha: float | None) -> list[float]:
    if alpha is not None:
        return [fitness(alpha, figures["accuracy"], figures["resolution"])]
    return [figures["speed_error_pct"], figures["position_error_mm"], -figures["resolution"]]


class Evaluator:
    """Fitness of layouts on the run's slip plan, cached by layout (the result of a layout
    does not depend on when it is asked for, so the cache changes nothing but the time)."""

    def __init__(self, settings: DesignSettings, workers: Workers, plan: tuple, seed: int):
        self.settings = settings
        self.workers = workers
        self.plan = plan
        self.seed = seed
        self.cache: dict[Layout, dict[str, float]] = {}
        self.evaluations = 0

    def figures(self, layouts: Sequence[Layout]) -> list[dict[str, float]]:
        todo = list(dict.fromkeys(x for x in layouts if x not in self.cache))
        tasks = [Candidate(x, self.plan, self.settings.decoder, self.seed) for x in todo]
        for layout, result in zip(todo, self.workers.map(evaluate, tasks), strict=True):
            self.cache[layout] = result
        self.evaluations += len(todo)
        return [self.cache[x] for x in layouts]


# -- the search -------------------------------------------------------------------------------


@dataclass
class DesignResult:
    settings: DesignSettings
    population: list[tuple[Layout, dict[str, float]]]  # the final population, unique, best first
    finalists: dict[Layout, dict[str, float]]  # re-scored on the confirmation plan
    references: dict[str, dict[str, float]]  # table 5.1's layouts on the confirmation plan
    chosen: Layout
    generations: int
    evaluations: int
    wall_s: float
    cpu_s: float
    workers: str
    #: the host's 1-minute load average at the start and the end: what else the machine
    #: ran while `wall_s` was measured (None where the OS has none)
    load_avg: tuple[float | None, float | None] = (None, None)


def load_average() -> float | None:
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return None


def search(
    settings: DesignSettings, workers: Workers, log: Callable[[str], None] = print
) -> DesignResult:
    """Run NSGA-II, then score the finalists (and table 5.1's layouts) on a longer plan."""
    from pymoo.algorithms.moo.nsga2 import NSGA2
    from pymoo.core.duplicate import ElementwiseDuplicateElimination
    from pymoo.core.evaluator import Evaluator as PymooEvaluator
    from pymoo.core.problem import Problem
    from pymoo.problems.static import StaticProblem

    settings.check()
    started, load_at_start = time.monotonic(), load_average()
    plan = ds.plan_slips(settings.slips, settings.speeds_mm_s, settings.seed)
    evaluator = Evaluator(settings, workers, plan, settings.seed)
    length, most = settings.length_mm, settings.max_spacings
    key = settings.alpha if settings.alpha is not None else PARETO_ALPHA

    def same_layout(a: Any, b: Any) -> bool:
        return spacings_of(a.X, length, most) == spacings_of(b.X, length, most)

    # pymoo's ask-and-tell interface: the algorithm proposes, `evaluator` scores on `workers`
    problem = Problem(n_var=1 + most, n_obj=1 if settings.alpha is not None else 3, xl=0.0, xu=1.0)
    algorithm = NSGA2(
        pop_size=settings.population,
        eliminate_duplicates=ElementwiseDuplicateElimination(cmp_func=same_layout),
    )
    if settings.budget_min is not None:
        termination: tuple = ("time", settings.budget_min * 60.0)
    else:
        termination = ("n_gen", settings.generations or 1)
    log(
        f"searching {length:g} mm skins (≤ {most} spacings) for "
        + (f"α = {settings.alpha:g}" if settings.alpha is not None else "the Pareto front")
        + f" with {settings.decoder}: {settings.slips} slips per layout, population "
        f"{settings.population}, "
        + (
            f"{settings.budget_min:g} min budget"
            if settings.budget_min is not None
            else f"{settings.generations} generations"
        )
        + f", on {workers.describe()}"
    )
    algorithm.setup(problem, termination=termination, seed=settings.seed, verbose=False)
    generations = 0
    while algorithm.has_next():
        offspring = algorithm.ask()
        figures = evaluator.figures([spacings_of(x, length, most) for x in offspring.get("X")])
        values = np.array([objectives(f, settings.alpha) for f in figures])
        PymooEvaluator().eval(StaticProblem(problem, F=values), offspring)
        algorithm.tell(infills=offspring)
        generations += 1
        best = min((fitness(key, **_af(f)), x) for x, f in evaluator.cache.items())
        log(
            f"  generation {generations}: {evaluator.evaluations} layouts evaluated, "
            f"best F(α={key:g}) {best[0]:.4f} {_fmt_layout(best[1])}, "
            f"{time.monotonic() - started:.0f} s"
        )
    final = algorithm.result().pop
    population = _ranked(
        [spacings_of(x, length, most) for x in final.get("X")], evaluator, settings.alpha
    )
    finalists, references = confirm(settings, workers, [x for x, _ in population[:FINALISTS]])
    chosen = min(finalists, key=lambda x: fitness(key, **_af(finalists[x])))
    cpu = sum(f["cpu_s"] for f in evaluator.cache.values())
    cpu += sum(f["cpu_s"] for f in [*finalists.values(), *references.values()])
    return DesignResult(
        settings,
        population,
        finalists,
        references,
        chosen,
        generations,
        evaluator.evaluations,
        time.monotonic() - started,
        cpu,
        workers.describe(),
        (load_at_start, load_average()),
    )


def _af(figures: dict[str, float]) -> dict[str, float]:
    return {"accuracy": figures["accuracy"], "resolution_": figures["resolution"]}


def _ranked(
    layouts: Sequence[Layout], evaluator: Evaluator, alpha: float | None
) -> list[tuple[Layout, dict[str, float]]]:
    """The population's unique layouts, best first: by F for α, else front first, then F(0.5)."""
    unique = list(dict.fromkeys(layouts))
    figures = evaluator.figures(unique)
    front = pareto_mask([objectives(f, None) for f in figures])
    key = alpha if alpha is not None else PARETO_ALPHA
    order = sorted(
        range(len(unique)),
        key=lambda i: (alpha is None and not front[i], fitness(key, **_af(figures[i])), unique[i]),
    )
    return [(unique[i], {**figures[i], "pareto": float(front[i])}) for i in order]


def pareto_mask(points: Sequence[Sequence[float]]) -> list[bool]:
    """Which points no other point dominates (all objectives minimised)."""
    p = np.asarray(points, dtype=float)
    out = []
    for row in p:
        dominated = np.any(np.all(p <= row, axis=1) & np.any(p < row, axis=1))
        out.append(not bool(dominated))
    return out


def confirm(
    settings: DesignSettings, workers: Workers, finalists: Sequence[Layout]
) -> tuple[dict[Layout, dict[str, float]], dict[str, dict[str, float]]]:
    """The finalists (and, on an 84 mm skin, table 5.1's layouts) on a plan CONFIRM_FACTOR
    times longer with another seed: the pick is not the luckiest of many noisy scores."""
    seed = settings.seed + 1_000_003
    plan = ds.plan_slips(CONFIRM_FACTOR * settings.slips, settings.speeds_mm_s, seed)
    names = list(REFERENCES) if math.isclose(settings.length_mm, THESIS_LENGTH_MM) else []
    layouts = [*finalists, *(LAYOUTS_MM[n] for n in names)]
    tasks = [Candidate(tuple(x), plan, settings.decoder, seed) for x in layouts]
    results = workers.map(evaluate, tasks)
    found = dict(zip(finalists, results[: len(finalists)], strict=True))
    return found, dict(zip(names, results[len(finalists) :], strict=True))


# -- outputs ----------------------------------------------------------------------------------


def _fmt_layout(spacings: Sequence[float]) -> str:
    return ",".join(f"{s:g}" for s in spacings)


def reference_for(alpha: float | None) -> str:
    """Table 5.1's layout for the α nearest `alpha` (α = 0.5 for the front)."""
    a = PARETO_ALPHA if alpha is None else alpha
    return f"alpha{min(THESIS_ALPHAS, key=lambda t: (abs(t - a), t)):g}"


def write_outputs(result: DesignResult, out: Path) -> list[Path]:
    """DIR/front.csv, DIR/layout.toml, DIR/report.md and DIR/search.json (all figures)."""
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "front.csv", out / "layout.toml", out / "report.md", out / "search.json"]
    write_front(result, paths[0])
    paths[1].write_text(layout_toml(result))
    paths[2].write_text(render_report(result))
    paths[3].write_text(json.dumps(summary(result), indent=1) + "\n")
    return paths


def summary(result: DesignResult) -> dict[str, Any]:
    """What search.json keeps: the settings, the cost and every layout's figures."""
    return {
        "settings": asdict(result.settings),
        "chosen_mm": list(result.chosen),
        "generations": result.generations,
        "evaluations": result.evaluations,
        "wall_s": result.wall_s,
        "cpu_s": result.cpu_s,
        "workers": result.workers,
        "load_avg": list(result.load_avg),
        "population": [{"spacings_mm": list(x), **f} for x, f in result.population],
        "finalists": [{"spacings_mm": list(x), **f} for x, f in result.finalists.items()],
        "references": result.references,
    }


def write_front(result: DesignResult, path: Path) -> None:
    alphas = [result.settings.alpha] if result.settings.alpha is not None else list(THESIS_ALPHAS)
    with path.open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(
            [
                "spacings_mm",
                "ridges",
                "resolution",
                "accuracy",
                "speed_error_pct",
                "position_error_mm",
                "pareto",
                *(f"fitness_alpha{a:g}" for a in alphas),
                "confirmed_accuracy",
            ]
        )
        for layout, f in result.population:
            confirmed = result.finalists.get(layout)
            writer.writerow(
                [
                    " ".join(f"{s:g}" for s in layout),
                    len(layout) + 1,
                    f"{f['resolution']:.1f}",
                    f"{f['accuracy']:.4f}",
                    f"{f['speed_error_pct']:.2f}",
                    f"{f['position_error_mm']:.2f}",
                    int(f["pareto"]),
                    *(f"{fitness(a, **_af(f)):.4f}" for a in alphas),
                    "" if confirmed is None else f"{confirmed['accuracy']:.4f}",
                ]
            )


def layout_toml(result: DesignResult) -> str:
    s = result.settings
    f = result.finalists[result.chosen]
    alpha = s.alpha if s.alpha is not None else PARETO_ALPHA
    return "\n".join(
        [
            "# A ridge layout found by `grasplink skin design`; give this file wherever a layout",
            "# is asked for: --skin FILE, a scene's layout = \"FILE\", a skin node's layout.",
            f"spacings_mm = [{', '.join(f'{x:g}' for x in result.chosen)}]",
            "",
            "[design]",
            f"length_mm = {s.length_mm:g}",
            f"alpha = {alpha:g}"
            + ("  # the front's member best at this α" if s.alpha is None else ""),
            f'decoder = "{s.decoder}"',
            f"seed = {s.seed}",
            f"fitness = {fitness(alpha, **_af(f)):.4f}",
            f"accuracy = {f['accuracy']:.4f}",
            f"resolution = {f['resolution']:.1f}",
            "",
        ]
    )


def render_report(result: DesignResult) -> str:
    s = result.settings
    alpha = s.alpha if s.alpha is not None else PARETO_ALPHA
    what = f"α = {s.alpha:g}" if s.alpha is not None else "the Pareto front"
    speeds = f"{min(s.speeds_mm_s):g}-{max(s.speeds_mm_s):g} mm/s ({len(s.speeds_mm_s)} speeds)"
    lines = [
        f"# Skin layout search: {s.length_mm:g} mm, {what}",
        "",
        f"NSGA-II (pymoo), population {s.population}, {result.generations} generations, "
        f"{result.evaluations} layouts evaluated on {s.slips} slips each "
        f"({', '.join(ds.KINDS)}; {speeds}; both directions) decoded by `{s.decoder}`; "
        f"seed {s.seed}; {result.wall_s:.0f} s on {result.workers} ({result.cpu_s:.0f} CPU s).",
        "",
        f"Chosen layout: **{_fmt_layout(result.chosen)} mm** "
        f"({len(result.chosen) + 1} ridges), F(α={alpha:g}) = "
        f"{fitness(alpha, **_af(result.finalists[result.chosen])):.4f} on the confirmation set "
        f"({CONFIRM_FACTOR * s.slips} other slips, another seed).",
        "",
        "F = α·(1 − A) + (1 − α)·(1 − R), minimised (table 5.1); A: share of the decoder's "
        "answers from a decision's time after the third ridge contact with the speed within "
        "10 % and the position within 1/10 of the skin under the three peaks; R: spacings / 10.",
        "",
        "## Finalists and table 5.1 on the confirmation set",
        "",
        "| layout (mm) | ridges | A | speed error % | position error mm | R | F |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    rows = [(_fmt_layout(x), x, f) for x, f in result.finalists.items()]
    rows += [
        (f"{n}: {_fmt_layout(LAYOUTS_MM[n])}", LAYOUTS_MM[n], f)
        for n, f in result.references.items()
    ]
    for label, layout, f in rows:
        mark = " (chosen)" if tuple(layout) == result.chosen and label[0].isdigit() else ""
        lines.append(
            f"| {label}{mark} | {len(layout) + 1} | {f['accuracy']:.3f} | "
            f"{f['speed_error_pct']:.1f} | {f['position_error_mm']:.1f} | "
            f"{f['resolution']:.1f} | {fitness(alpha, **_af(f)):.4f} |"
        )
    ref = reference_for(s.alpha)
    if ref in result.references:
        mine = fitness(alpha, **_af(result.finalists[result.chosen]))
        theirs = fitness(alpha, **_af(result.references[ref]))
        verdict = "beats" if mine < theirs else "does not beat"
        lines += [
            "",
            f"The chosen layout {verdict} table 5.1's {ref} ({mine:.4f} vs {theirs:.4f}).",
        ]
    lines += [
        "",
        "## The final population",
        "",
        "Search fitness (the run's slip plan); `pareto`: not dominated on (speed error, "
        "position error, −R). All of it: front.csv.",
        "",
        "| layout (mm) | ridges | A | speed error % | position error mm | pareto | F |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for layout, f in result.population[:12]:
        lines.append(
            f"| {_fmt_layout(layout)} | {len(layout) + 1} | {f['accuracy']:.3f} | "
            f"{f['speed_error_pct']:.1f} | {f['position_error_mm']:.1f} | "
            f"{'yes' if f['pareto'] else ''} | {fitness(alpha, **_af(f)):.4f} |"
        )
    lines.append("")
    return "\n".join(lines)

"""A study's numbers, computed once: per pair, per method, per mark (`summarise`). The renderers (Markdown,
JSON, figures, TensorBoard) only format what this module computed, so every file of a report shows the same
numbers."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from miktcli.registry.runs import Run
from miktcli.stats.pairwise import compare
from miktcli.studies.grid import Grid, MethodSpec, PairSpec, cell_key, file_slug
from miktcli.studies.handover import HandoverFigures, PairHandover, handover_figures, pair_handover

RunOf = Callable[[str], Run | None]  # a cell key → its run, if one was started
PerSeed = dict[str, dict[str, np.ndarray]]  # method → measure → one value per completed seed


def first_reach(steps: np.ndarray, curve: np.ndarray, level: float) -> str:
    hit = np.nonzero(curve >= level)[0]
    return f"{int(steps[hit[0]]):,}" if len(hit) else "not reached"


def three_quarters_level(final: float) -> float:
    """"¾ of the baseline's final return", also for a final return ≤ 0, where 0.75·final would be *above*
    it: the level a quarter of |final| below final (equal to 0.75·final when final > 0)."""
    return final - 0.25 * abs(final)


def sample_std(values: np.ndarray, axis: int | None = None) -> np.ndarray | float:
    """Sample standard deviation (ddof 1); NaN for a single value, where it is undefined."""
    values = np.asarray(values, dtype=float)
    n = values.shape[axis] if axis is not None else values.size
    if n < 2:
        return np.full(np.delete(values.shape, axis), np.nan) if axis is not None else float("nan")
    return np.nanstd(values, axis=axis, ddof=1)


def mean_pm_std(values) -> str:
    values = np.asarray(values, dtype=float)
    std = sample_std(values)
    return f"{np.mean(values):,.0f} ± {std:,.0f}" if math.isfinite(std) else f"{np.mean(values):,.0f}"


def unusable(run: Run, rows: list[dict[str, Any]]) -> str | None:
    """Why a completed run's files cannot stand in the report, or None. Its curve must hold one row for each
    iteration its card says it trained, at that iteration's step, and its card must hold the teacher-free eval:
    a metrics file cut short, with rows lost at its start or in its middle (a run folder deleted while its
    cell trained is recreated by the next checkpoint), or edited, would otherwise shift every mark and mean
    without a word."""
    evaluated = run.card.result.get("eval_without_teacher")
    if not (isinstance(evaluated, dict) and isinstance(evaluated.get("return_mean"), int | float)):
        return f"{run.id}: its card has no teacher-free eval result"
    name = run.metrics_path.name
    if run.damaged_metric_lines:
        return f"{run.id}: {run.damaged_metric_lines} damaged line(s) in {name}"
    done = run.card.steps_done
    if not rows or rows[-1]["steps"] != done:
        ends = f"ends at {rows[-1]['steps']:,} steps" if rows else "is empty"
        return f"{run.id}: {name} {ends}, the run trained {done:,}"
    batch = run.card.config.ppo.batch_size
    steps = [r["steps"] for r in rows]
    expected = list(range(batch, done + 1, batch))
    if steps == expected:
        return None
    off = next((s for s in steps if s <= 0 or s % batch), None)
    if off is not None:
        return (f"{run.id}: {name} has a row at {off:,} steps, which is not one of its iterations "
                f"(every {batch:,} steps)")
    missing = sorted(set(expected) - set(steps))
    if missing:
        return (f"{run.id}: {name} lacks {len(missing)} of its {len(expected)} iterations' rows "
                f"(the first missing at {missing[0]:,} steps)")
    return f"{run.id}: {name} holds its iterations' rows more than once or out of order"


def completed_curves(grid: Grid, run_of: RunOf, pair: PairSpec, method: MethodSpec,
                     left_out: list[str] | None = None) -> tuple[list[Run], np.ndarray, np.ndarray]:
    """Completed runs of a cell group and their return curves on the common iteration grid. A completed run
    whose files are incomplete is left out of both, with the reason appended to `left_out`."""
    runs, curves, shared = [], [], set()
    for seed in grid.seeds_of(pair, method):
        run = run_of(cell_key(pair, method, seed))
        if run is None or run.card.status != "completed":
            continue
        rows = run.read_metrics()
        problem = unusable(run, rows)
        if problem is None and runs and not shared & {r["steps"] for r in rows}:
            # another rollout size whose iterations never coincide with the others': nothing to average
            problem = (f"{run.id}: logs every {run.card.config.ppo.batch_size:,} steps, at none of the steps "
                       f"{runs[0].id} logs at")
        if problem:
            if left_out is not None and problem not in left_out:
                left_out.append(problem)
            continue
        runs.append(run)
        curves.append([(r["steps"], np.nan if r["return_mean"] is None else r["return_mean"]) for r in rows])
        shared = {s for s, _ in curves[-1]} if len(runs) == 1 else shared & {s for s, _ in curves[-1]}
    if not curves:
        return [], np.zeros(0), np.zeros((0, 0))
    steps, values = align_by_step(curves)
    return runs, steps, values


def align_by_step(curves: list[list[tuple[int, float]]]) -> tuple[np.ndarray, np.ndarray]:
    """The curves at the steps they all logged, one row per curve. Runs of one grid usually log at the same
    steps; runs of another rollout size meet where their iterations coincide. By step, never by row index:
    the n-th row of one run need not be the n-th of another."""
    shared = sorted(set.intersection(*(set(s for s, _ in c) for c in curves)))
    at = [dict(c) for c in curves]
    return np.array(shared, dtype=int), np.array([[a[s] for s in shared] for a in at], dtype=float).reshape(
        len(curves), len(shared))


def partial_seed_labels(counts: dict[str, int], seeds: int | dict[str, int]) -> dict[str, str]:
    """Legend texts for the curves that average fewer seeds than the grid runs (`seeds`: for every curve, or
    curve by curve), so that a figure of a study under way cannot be read as a finished one (one seed also has
    no band)."""
    planned = seeds if isinstance(seeds, dict) else dict.fromkeys(counts, seeds)
    return {name: f"{name} ({n} of {planned[name]} seeds)" for name, n in counts.items() if n < planned[name]}


def compare_methods(per_seed: PerSeed) -> list[dict[str, Any]]:
    """Every method against every later one (grid order), on each per-seed measure, as the rows of
    comparisons.json. A side with fewer than two values is left out (nothing to test)."""
    rows: list[dict[str, Any]] = []
    methods = list(per_seed)
    for i, a in enumerate(methods):
        for b in methods[i + 1:]:
            for measure in per_seed[a]:
                # A run without a value (no episode finished yet) has nothing to compare; n says how many do.
                values_a, values_b = (v[np.isfinite(v)] for v in (per_seed[a][measure], per_seed[b][measure]))
                if len(values_a) < 2 or len(values_b) < 2:
                    continue
                c = compare(values_a, values_b)
                rows.append({"a": a, "b": b, "measure": measure, "n_a": c.n_a, "n_b": c.n_b,
                             "difference": c.difference, "p_improvement": c.p_improvement,
                             "p_value": c.p_value, "exact": c.exact, "smallest_p": c.smallest_p})
    return rows


Curve = list[tuple[float, float]]  # (steps, value)


@dataclass(frozen=True)
class MethodSummary:
    """One method of one pair: its completed, usable runs (none: every field below is empty)."""

    name: str
    runs: list[Run]
    steps: np.ndarray  # the common iteration grid of its curves
    curves: np.ndarray  # one return curve per run
    evals: np.ndarray  # the teacher-free final eval of each run
    reach: str = "—"  # steps to the baseline's final return
    reach_75: str = "—"  # steps to ¾ of it
    final_weights: dict[str, float] | None = None  # learned student weights (p_pi_j, p_vf_j), mean over runs
    weight_curves: dict[str, Curve] | None = None  # each weight over training, mean over runs
    planned: int = 0  # the seeds the grid plans for it on this pair (Grid.seeds_of)

    @property
    def n(self) -> int:
        return len(self.runs)

    @property
    def mean(self) -> np.ndarray:
        return np.nanmean(self.curves, 0)

    @property
    def std(self) -> np.ndarray:
        return sample_std(self.curves, axis=0)

    @property
    def mean_over_training(self) -> np.ndarray:
        """Area under the curve per step, per run: how much return the whole run collected, jump-start
        included."""
        return np.nanmean(self.curves, axis=1)

    @property
    def per_seed(self) -> dict[str, np.ndarray]:
        """The measures compared over seeds."""
        return {"final return": self.curves[:, -1], "mean over training": self.mean_over_training,
                "final eval (no teacher)": self.evals}

    def curve(self) -> Curve:
        return list(zip(self.steps.tolist(), self.mean.tolist(), strict=True))

    def band(self) -> list[tuple[float, float, float]]:
        """mean ± sample std at each step (no band for one seed)."""
        mean, band = self.mean, np.nan_to_num(self.std)
        return list(zip(self.steps.tolist(), (mean - band).tolist(), (mean + band).tolist(), strict=True))


@dataclass(frozen=True)
class PairSummary:
    name: str
    slug: str  # the pair's name in file names
    marks: dict[int, int]  # each step mark → the index of the last logged iteration at or before it (-1: none)
    mark_labels: list[str]  # the step each mark column names
    methods: list[MethodSummary]  # grid order, methods without runs included
    comparisons: list[dict[str, Any]]  # compare_methods of the methods with runs

    @property
    def with_runs(self) -> list[MethodSummary]:
        return [m for m in self.methods if m.runs]


@dataclass(frozen=True)
class TeacherVersion:
    ref: str  # name@vN
    sha256: str
    runs: list[str]  # the study's runs that trained with it


@dataclass(frozen=True)
class StudySummary:
    grid: Grid
    pairs: list[PairSummary]
    left_out: list[str]  # completed runs whose files could not be used, each with the reason
    cells: list[tuple[str, str, Run | None]]  # (cell key, run id, the run if the registry has it)
    # each teacher reference of the grid → the versions the study's runs used (more than one: a mix)
    teachers: dict[str, list[TeacherVersion]] = field(default_factory=dict)
    handovers: list[tuple[str, HandoverFigures]] = field(default_factory=list)  # cell key, its run's hand-over
    slowdowns: list[tuple[str, str, dict[str, Any]]] = field(default_factory=list)  # cell key, run id, record
    handover_pairs: list[PairHandover] = field(default_factory=list)  # per pair and method, with the baseline


def _mark_indices(marks: list[int], steps: np.ndarray | None) -> dict[int, int]:
    return {mark: int(np.searchsorted(steps, mark, side="right")) - 1 if steps is not None else -1
            for mark in marks}


def _weights(method_name: str, runs: list[Run]) -> tuple[dict[str, float] | None, dict[str, Curve] | None]:
    mixing = [r.card.result.get("final_mixing_learned") for r in runs]
    if not all(mixing):
        return None, None
    keys = sorted(mixing[0])
    final = {k: float(np.mean([m[k] for m in mixing])) for k in keys}
    curves = {}
    for k in keys:
        steps, values = align_by_step([[(row["steps"], row[k]) for row in r.read_metrics()] for r in runs])
        curves[f"{method_name} {k}"] = list(zip(steps.tolist(), values.mean(axis=0).tolist(), strict=True))
    return final, curves


def summarise(grid: Grid, cell_runs: dict[str, str], run_of: RunOf) -> StudySummary:
    """Every number a study report shows, from the completed runs the study's cells name."""
    left_out: list[str] = []
    data_of = {pair.name: {m.name: completed_curves(grid, run_of, pair, m, left_out) for m in grid.methods}
               for pair in grid.pairs}
    # Every run of a grid logs at the same iteration boundaries, so a pair with no finished run yet labels its
    # marks with another pair's logged steps: all tables then name the same columns.
    grid_steps = next((steps for data in data_of.values() for runs, steps, _ in data.values() if runs), None)
    pairs = []
    for pair in grid.pairs:
        data = data_of[pair.name]
        base_runs, _, base_curves = data[grid.baseline]
        base_final = float(np.nanmean(base_curves[:, -1])) if len(base_runs) else None
        any_steps = next((steps for runs, steps, _ in data.values() if runs), grid_steps)
        marks = _mark_indices(grid.marks or [grid.steps], any_steps)  # the grid keeps marks within 1…steps
        labels = [f"{int(any_steps[i]):,}" if i >= 0 else f"{m:,}" for m, i in marks.items()]
        methods = []
        for method in grid.methods:
            runs, steps, curves = data[method.name]
            if not runs:
                methods.append(MethodSummary(method.name, [], steps, curves, np.zeros(0),
                                             planned=len(grid.seeds_of(pair, method))))
                continue
            evals = np.asarray([r.card.result["eval_without_teacher"]["return_mean"] for r in runs])  # unusable
            reach = reach_75 = "—"
            if base_final is not None:
                mean = np.nanmean(curves, 0)
                reach, reach_75 = (first_reach(steps, mean, level)
                                   for level in (base_final, three_quarters_level(base_final)))
            final_weights, weight_curves = _weights(method.name, runs)
            methods.append(MethodSummary(method.name, runs, steps, curves, evals, reach, reach_75, final_weights,
                                         weight_curves, len(grid.seeds_of(pair, method))))
        comparisons = compare_methods({m.name: m.per_seed for m in methods if m.runs})
        pairs.append(PairSummary(pair.name, file_slug(pair.name), marks, labels, methods, comparisons))
    cells = [(key, run_id, run_of(key)) for key, run_id in cell_runs.items()]
    completed = [(key, run) for key, _, run in cells if run is not None and run.card.status == "completed"]
    handovers = [(key, f) for key, f in ((key, handover_figures(run)) for key, run in completed) if f is not None]
    slowdowns = [(key, run.id, record) for key, _, run in cells if run is not None
                 for record in run.card.result.get("slowdowns", [])]
    return StudySummary(grid, pairs, left_out, cells, teacher_versions(grid, {key: run for key, _, run in cells}),
                        handovers=handovers, slowdowns=slowdowns,
                        handover_pairs=handovers_by_pair(grid, pairs, [f for _, f in handovers]))


def handovers_by_pair(grid: Grid, pairs: list[PairSummary], figures: list[HandoverFigures]) -> list[PairHandover]:
    """Each pair's methods that recorded hand-overs, as seed means, beside the pair's baseline runs when the
    baseline trains from scratch (a baseline with teachers drops them too: no control, so no baseline runs)."""
    baseline = grid.baseline
    scratch = grid.baseline_trains_from_scratch
    by_run = {f.run: f for f in figures}
    out = []
    for pair in pairs:
        base = next((m.runs for m in pair.methods if m.name == baseline), []) if scratch else []
        base_rows: list[list[dict[str, Any]]] | None = None
        for method in pair.methods:
            seeds = [by_run[r.id] for r in method.runs if r.id in by_run]
            if seeds:
                base_rows = [r.read_metrics() for r in base] if base_rows is None else base_rows
                out.append(pair_handover(pair.name, method.name, seeds, baseline if scratch else "", base_rows))
    return out


def teacher_versions(grid: Grid, run_of_cell: dict[str, Run | None]) -> dict[str, list[TeacherVersion]]:
    """Which teacher version each of the grid's references meant, run by run (grid order, then run order)."""
    used: dict[str, dict[str, TeacherVersion]] = {}
    seen: set[str] = set()
    for pair in grid.pairs:
        for method in grid.methods:
            if not method.uses_teachers:
                continue
            for seed in grid.seeds_of(pair, method):
                run = run_of_cell.get(cell_key(pair, method, seed))
                if run is None or run.id in seen:
                    continue
                seen.add(run.id)
                for ref, teacher in zip(pair.teachers, run.card.teachers, strict=False):
                    version = f"{teacher.name}@v{teacher.version}"
                    entry = used.setdefault(ref, {}).setdefault(version, TeacherVersion(version, teacher.sha256, []))
                    entry.runs.append(run.id)
    return {ref: list(versions.values()) for ref, versions in used.items()}

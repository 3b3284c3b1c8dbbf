"""A study's numbers across its pairs (the "Across pairs" section of every report), after Agarwal et al. 2021:
each completed run's score normalised on its target between the random policy (0) and the grid's baseline
(1, PPO from scratch at the same budget), then the IQM and mean with 95 % stratified bootstrap intervals, the
probability of improvement and the performance profiles (miktcli.stats.across_tasks does the arithmetic).

Computed from the study's summary, so results.md, summary.json and the figures show the same numbers. Where
the section cannot be built (no completed baseline run, a baseline no better than random), it says why in
`missing` and `notes`: the report never fails on it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from miktcli.stats import across_tasks
from miktcli.studies.grid import Grid
from miktcli.studies.summary import MethodSummary, StudySummary

MEASURES = {"final return": "the mean training return over the last 100 episodes at the end of the run",
            "mean over training": "that curve averaged over the whole run (area under the curve)"}
PROFILE_MEASURE = "final return"
SEED = 0  # every interval of the section is reproducible from this seed
PROFILE_RESAMPLES = 2_000  # the profile's band is pointwise over 101 thresholds: fewer resamples suffice
PROFILE_POINTS = 101

Scores = dict[str, dict[str, np.ndarray]]  # method → pair → one normalised score per run


@dataclass(frozen=True)
class Normaliser:
    """The scale of one task: the random policy's return and the baseline's mean per measure."""

    task: str  # the target, or the pair where the baseline trains with teachers (its runs differ per pair)
    random: float | None  # None: no random-policy return for the target
    reference: dict[str, float]  # measure → mean of the baseline's completed runs (absent: none)
    runs: int  # the baseline's completed runs there
    initial: float | None = None  # the initial policy's return there (N(0, 1), unclipped), for the reader


@dataclass(frozen=True)
class MethodAggregate:
    name: str
    runs: int
    pairs: int
    iqm: across_tasks.Estimate
    mean: across_tasks.Estimate


@dataclass(frozen=True)
class Improvement:
    x: str
    y: str
    estimate: across_tasks.Estimate  # P(X > Y)
    pairs: int


@dataclass(frozen=True)
class MatchedComparison:
    """More teachers against fewer on the same tasks: each pair of `x` (two teachers or more) against the pair
    of `y` that has its first teacher alone and the same target, the method and its configuration the same."""

    x: str
    y: str
    tasks: int  # the pairs of x with a matching pair of y
    x_iqm: across_tasks.Estimate
    y_iqm: across_tasks.Estimate
    improvement: across_tasks.Estimate  # P(X > Y)

    @property
    def intervals_overlap(self) -> bool:
        return self.x_iqm.low <= self.y_iqm.high and self.y_iqm.low <= self.x_iqm.high


@dataclass(frozen=True)
class MeasureAggregate:
    measure: str
    methods: list[MethodAggregate]
    improvements: list[Improvement]
    per_pair: dict[str, dict[str, float]]  # pair → method → IQM of its normalised runs
    matched: list[MatchedComparison] = field(default_factory=list)


@dataclass(frozen=True)
class Profile:
    """A method's performance profile: the fraction of runs above each threshold, with its 95 % band."""

    name: str
    thresholds: list[float]
    fraction: list[float]
    low: list[float]
    high: list[float]


@dataclass(frozen=True)
class AcrossPairs:
    baseline: str
    steps: int
    pairs: list[str]  # every pair of the grid, in grid order
    baseline_from_scratch: bool  # its runs are shared by every pair of a target: one scale per target
    random_source: str  # where R_random came from, for the text
    n_resamples: int
    missing: str | None = None  # why there are no numbers at all
    notes: list[str] = field(default_factory=list)  # what was left out, and why
    normalisation: list[Normaliser] = field(default_factory=list)
    measures: list[MeasureAggregate] = field(default_factory=list)
    profiles: list[Profile] = field(default_factory=list)


def _values(m: MethodSummary, measure: str) -> np.ndarray:
    return m.per_seed[measure]


def _teachers(n: int) -> str:
    return f"{n} teacher{'s' if n != 1 else ''}"


def method_labels(grid: Grid) -> dict[tuple[str, str], str]:
    """(pair, method) → the method's name in the section: a method with teachers that the grid runs with
    different numbers of teachers is one entry per number ("mikt, 2 teachers"), so that pooling never mixes
    one-teacher and two-teacher runs; every other method keeps its name."""
    mixed = len({len(p.teachers) for p in grid.pairs}) > 1  # every method with teachers runs on every pair
    return {(p.name, m.name): (f"{m.name}, {_teachers(len(p.teachers))}" if mixed and m.uses_teachers else m.name)
            for p in grid.pairs for m in grid.methods}


def _first_teacher_pairs(grid: Grid) -> dict[str, str]:
    """Each pair of two teachers or more → the grid's pair with its first teacher alone and the same target."""
    alone = {(p.teachers[0], p.to): p.name for p in grid.pairs if len(p.teachers) == 1}
    return {p.name: alone[p.teachers[0], p.to] for p in grid.pairs
            if len(p.teachers) > 1 and (p.teachers[0], p.to) in alone}


def _baseline(summary: StudySummary) -> tuple[bool, dict[str, str], dict[str, MethodSummary]]:
    """Whether the baseline trains from scratch, each pair's task, and each task's baseline runs (the first
    pair of the task with completed ones)."""
    grid = summary.grid
    scratch = grid.baseline_trains_from_scratch
    task_of = {p.name: (p.to if scratch else p.name) for p in grid.pairs}
    runs: dict[str, MethodSummary] = {}
    for pair in summary.pairs:
        base = next(m for m in pair.methods if m.name == grid.baseline)
        if base.runs:
            runs.setdefault(task_of[pair.name], base)
    return scratch, task_of, runs


def baseline_targets(summary: StudySummary) -> list[str]:
    """The targets whose random-policy return the section needs: those where the baseline has completed runs."""
    _, task_of, runs = _baseline(summary)
    return list(dict.fromkeys(p.to for p in summary.grid.pairs if task_of[p.name] in runs))


def unavailable(summary: StudySummary, why: str, random_source: str = "—",
                n_resamples: int = across_tasks.RESAMPLES) -> AcrossPairs:
    """The section of a report that has no numbers, with the reason."""
    grid = summary.grid
    scratch, _, _ = _baseline(summary)
    return AcrossPairs(grid.baseline, grid.steps, [p.name for p in grid.pairs], scratch, random_source,
                       n_resamples, missing=why)


def across_pairs(summary: StudySummary, random: Mapping[str, float], random_source: str,
                 n_resamples: int = across_tasks.RESAMPLES, initial: Mapping[str, float] | None = None) -> AcrossPairs:
    """The section's numbers from the study's summary and each target's random-policy return (`initial`: each
    target's initial-policy return, shown beside it)."""
    grid = summary.grid
    notes: list[str] = []
    scratch, task_of, base_runs = _baseline(summary)
    target_of = {p.name: p.to for p in grid.pairs}
    if not base_runs:
        return unavailable(summary, f"no completed `{grid.baseline}` run yet: nothing to normalise by",
                           random_source, n_resamples)
    tasks = list(dict.fromkeys(task_of.values()))
    task_target = {task_of[p]: target_of[p] for p in task_of}
    normalisation, scale = [], {}  # scale: (measure, task) → (random, reference)
    for task in tasks:
        base = base_runs.get(task)
        rand = random.get(task_target[task])
        reference = {}
        for measure in MEASURES if base is not None else ():
            values = _values(base, measure)
            if np.isfinite(values).any():
                reference[measure] = float(np.mean(values[np.isfinite(values)]))
        normalisation.append(Normaliser(task, rand, reference, base.n if base else 0,
                                        (initial or {}).get(task_target[task])))
        pairs = ", ".join(p for p, t in task_of.items() if t == task)
        if base is None:
            notes.append(f"no completed `{grid.baseline}` run on {task} yet: its pairs ({pairs}) are left out")
            continue
        if rand is None:
            notes.append(f"no random-policy return for {task_target[task]}: its pairs ({pairs}) are left out")
            continue
        for measure in MEASURES:
            ref = reference.get(measure)
            if ref is None:  # no episode of its runs finished
                notes.append(f"`{grid.baseline}` has no {measure} on {task}: its pairs ({pairs}) are left out of "
                             f"the {measure}")
                continue
            if not ref > rand:  # normalising by a scale ≤ 0 would reverse every comparison
                notes.append(f"`{grid.baseline}` scores {ref:,.1f} ({measure}) on {task}, no better than the random "
                             f"policy's {rand:,.1f}: no scale to normalise on, its pairs ({pairs}) are left out "
                             f"of the {measure}")
                continue
            scale[measure, task] = (rand, ref)
    measures, scores_of = [], {}
    for measure in MEASURES:
        scores = _normalised(summary, measure, scale, task_of, notes)
        if scores:
            scores_of[measure] = _pooled(scores, grid.baseline, task_of if scratch else None)
            measures.append(_measure(summary, measure, scores, scores_of[measure], n_resamples))
    section = AcrossPairs(grid.baseline, grid.steps, [p.name for p in grid.pairs], scratch, random_source,
                          n_resamples, None, notes, normalisation, measures)
    if not measures:
        return dataclasses.replace(section, missing="no pair has a scale to normalise on")
    if PROFILE_MEASURE in scores_of:
        section.profiles.extend(_profiles(scores_of[PROFILE_MEASURE]))
    return section


def _normalised(summary: StudySummary, measure: str, scale: dict[tuple[str, str], tuple[float, float]],
                task_of: dict[str, str], notes: list[str]) -> Scores:
    scores: Scores = {}
    labels = method_labels(summary.grid)
    for pair in summary.pairs:
        if (measure, task_of[pair.name]) not in scale:
            continue
        rand, ref = scale[measure, task_of[pair.name]]
        for m in pair.with_runs:
            name = labels[pair.name, m.name]
            values = _values(m, measure)
            finite = values[np.isfinite(values)]
            if len(finite) < len(values):
                notes.append(f"{pair.name}, {m.name}: {len(values) - len(finite)} run(s) without a {measure} "
                             "(no episode finished) left out")
            if len(finite):
                scores.setdefault(name, {})[pair.name] = across_tasks.normalized(finite, rand, ref)
    order = dict.fromkeys(labels[p.name, m.name] for m in summary.grid.methods for p in summary.grid.pairs)
    return {name: scores[name] for name in order if name in scores}  # grid order, whichever pair ran it first


def _pooled(scores: Scores, baseline: str, task_of: dict[str, str] | None) -> Scores:
    """The scores an IQM, a mean or a profile pools: a baseline from scratch has one set of runs per target,
    shared by the target's pairs, so it enters once per target, not once per pair."""
    if task_of is None or baseline not in scores:
        return scores
    once: dict[str, np.ndarray] = {}
    for pair, values in scores[baseline].items():
        once.setdefault(task_of[pair], values)  # the same runs on each pair of the task: its first pair's
    return {**scores, baseline: once}


def _measure(summary: StudySummary, measure: str, scores: Scores, pooled: Scores,
             n_resamples: int) -> MeasureAggregate:
    """`scores` by pair (the per-pair comparisons), `pooled` as the IQMs and means count runs (_pooled)."""
    methods = [MethodAggregate(name, sum(len(v) for v in by_pair.values()), len(by_pair),
                               across_tasks.iqm_estimate(by_pair, n_resamples=n_resamples, seed=SEED),
                               across_tasks.mean_estimate(by_pair, n_resamples=n_resamples, seed=SEED))
               for name, by_pair in pooled.items()]
    names, improvements = list(scores), []
    for i, x in enumerate(names):
        for y in names[i + 1:]:
            shared = [p for p in scores[x] if p in scores[y]]
            if shared:
                estimate = across_tasks.probability_of_improvement_estimate(scores[x], scores[y],
                                                                         n_resamples=n_resamples, seed=SEED)
                improvements.append(Improvement(x, y, estimate, len(shared)))
    per_pair = {pair.name: {m: across_tasks.iqm({pair.name: scores[m][pair.name]})
                            for m in names if pair.name in scores[m]} for pair in summary.pairs}
    return MeasureAggregate(measure, methods, improvements, per_pair, _matched(summary.grid, scores, n_resamples))


def _matched(grid: Grid, scores: Scores, n_resamples: int) -> list[MatchedComparison]:
    """Each method with teachers, its pairs of several teachers against their first teacher alone (the same
    target, method and configuration), the tasks being the several-teacher pairs."""
    labels, alone_of = method_labels(grid), _first_teacher_pairs(grid)
    compared = []
    for m in grid.methods:
        by_count: dict[tuple[str, str], tuple[dict, dict]] = {}
        for pair, alone in alone_of.items():
            x, y = labels[pair, m.name], labels[alone, m.name]
            if x != y and pair in scores.get(x, {}) and alone in scores.get(y, {}):
                xs, ys = by_count.setdefault((x, y), ({}, {}))
                xs[pair], ys[pair] = scores[x][pair], scores[y][alone]
        for (x, y), (xs, ys) in by_count.items():
            compared.append(MatchedComparison(
                x, y, len(xs), across_tasks.iqm_estimate(xs, n_resamples=n_resamples, seed=SEED),
                across_tasks.iqm_estimate(ys, n_resamples=n_resamples, seed=SEED),
                across_tasks.probability_of_improvement_estimate(xs, ys, n_resamples=n_resamples, seed=SEED)))
    return compared


def _profiles(scores: Scores) -> list[Profile]:
    top = max(float(np.max(np.concatenate(list(v.values())))) for v in scores.values())
    taus = np.linspace(0.0, max(top, 1.0) * 1.05, PROFILE_POINTS)
    profiles = []
    for name, by_pair in scores.items():
        point, low, high = across_tasks.performance_profile_estimate(by_pair, taus, n_resamples=PROFILE_RESAMPLES,
                                                                  seed=SEED)
        profiles.append(Profile(name, taus.tolist(), point.tolist(), low.tolist(), high.tolist()))
    return profiles

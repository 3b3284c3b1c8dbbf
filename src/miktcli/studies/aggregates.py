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

from miktcli.methods import get_method
from miktcli.stats import across_tasks
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
class MeasureAggregate:
    measure: str
    methods: list[MethodAggregate]
    improvements: list[Improvement]
    per_pair: dict[str, dict[str, float]]  # pair → method → IQM of its normalised runs


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


def _baseline(summary: StudySummary) -> tuple[bool, dict[str, str], dict[str, MethodSummary]]:
    """Whether the baseline trains from scratch, each pair's task, and each task's baseline runs (the first
    pair of the task with completed ones)."""
    grid = summary.grid
    scratch = get_method(next(m.method for m in grid.methods if m.name == grid.baseline)).trains_from_scratch
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
                 n_resamples: int = across_tasks.RESAMPLES) -> AcrossPairs:
    """The section's numbers from the study's summary and each target's random-policy return."""
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
        normalisation.append(Normaliser(task, rand, reference, base.n if base else 0))
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
            scores_of[measure] = scores
            measures.append(_measure(summary, measure, scores, n_resamples))
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
    for pair in summary.pairs:
        if (measure, task_of[pair.name]) not in scale:
            continue
        rand, ref = scale[measure, task_of[pair.name]]
        for m in pair.with_runs:
            values = _values(m, measure)
            finite = values[np.isfinite(values)]
            if len(finite) < len(values):
                notes.append(f"{pair.name}, {m.name}: {len(values) - len(finite)} run(s) without a {measure} "
                             "(no episode finished) left out")
            if len(finite):
                scores.setdefault(m.name, {})[pair.name] = across_tasks.normalized(finite, rand, ref)
    order = [m.name for m in summary.grid.methods]  # grid order, whichever pair a method first ran on
    return {name: scores[name] for name in order if name in scores}


def _measure(summary: StudySummary, measure: str, scores: Scores, n_resamples: int) -> MeasureAggregate:
    methods = [MethodAggregate(name, sum(len(v) for v in by_pair.values()), len(by_pair),
                               across_tasks.iqm_estimate(by_pair, n_resamples=n_resamples, seed=SEED),
                               across_tasks.mean_estimate(by_pair, n_resamples=n_resamples, seed=SEED))
               for name, by_pair in scores.items()]
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
    return MeasureAggregate(measure, methods, improvements, per_pair)


def _profiles(scores: Scores) -> list[Profile]:
    top = max(float(np.max(np.concatenate(list(v.values())))) for v in scores.values())
    taus = np.linspace(0.0, max(top, 1.0) * 1.05, PROFILE_POINTS)
    profiles = []
    for name, by_pair in scores.items():
        point, low, high = across_tasks.performance_profile_estimate(by_pair, taus, n_resamples=PROFILE_RESAMPLES,
                                                                  seed=SEED)
        profiles.append(Profile(name, taus.tolist(), point.tolist(), low.tolist(), high.tolist()))
    return profiles

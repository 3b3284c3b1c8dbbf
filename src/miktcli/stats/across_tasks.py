"""Aggregates over many tasks (here: transfer pairs), after "Deep RL at the Edge of the Statistical Precipice"
(Agarwal et al., NeurIPS 2021) and its library rliable, with scipy doing the arithmetic.

A method's results are `{task: scores of its runs}` (any number of runs per task). Scores are first normalised per
task between a random policy and a reference (PPO from scratch at the same budget):
`(R − R_random) / (R_reference − R_random)`, so 0 is random and 1 is the reference.

- IQM: the interquartile mean (25 % trimmed mean) over all runs × tasks pooled, as rliable;
- intervals: percentile stratified bootstrap (every task's runs resampled within that task, as rliable);
- probability of improvement P(X > Y): per task the Mann–Whitney U/(n_x n_y) (ties count one half), averaged
  over the tasks both methods share;
- performance profile: for each threshold τ the fraction of a task's runs scoring above τ, averaged over tasks
  (with equal runs per task this is rliable's run-score distribution).

Pure arithmetic: no printing, no files, no plots.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats

TRIM = 0.25  # IQM: a quarter cut from each end
CONFIDENCE = 0.95
RESAMPLES = 10_000

Scores = Mapping[str, Sequence[float] | np.ndarray]  # task → one score per run


@dataclass(frozen=True)
class Estimate:
    """A point estimate and its bootstrap interval."""

    value: float
    low: float
    high: float


def normalized(returns: Sequence[float] | np.ndarray, random: float, reference: float) -> np.ndarray:
    """(R − R_random) / (R_reference − R_random): 0 at the random policy, 1 at the reference."""
    if not np.isfinite([random, reference]).all() or reference == random:
        raise ValueError(f"cannot normalise between random {random} and reference {reference}")
    return (np.asarray(returns, dtype=float) - random) / (reference - random)


def _tasks(scores: Scores) -> list[np.ndarray]:
    arrays = [np.asarray(v, dtype=float) for v in scores.values()]
    if not arrays or any(a.ndim != 1 or a.size == 0 for a in arrays):
        raise ValueError("every task needs at least one score")
    if not all(np.isfinite(a).all() for a in arrays):
        raise ValueError("scores must be finite")
    return arrays


def iqm(scores: Scores) -> float:
    """The interquartile mean of every run of every task, pooled."""
    return float(stats.trim_mean(np.concatenate(_tasks(scores)), TRIM))


def _pooled_iqm(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
    return stats.trim_mean(np.concatenate(samples, axis=axis), TRIM, axis=axis)


def _bootstrap(samples: list[np.ndarray], statistic: Callable[..., np.ndarray], n_resamples: int, seed: int,
               confidence: float) -> tuple[np.ndarray, np.ndarray]:
    """Percentile stratified bootstrap: scipy resamples each sample (a task's runs) on its own. A task of one
    run resamples to itself, which scipy refuses to do: it enters every resample as it is."""
    varying = [i for i, s in enumerate(samples) if s.size > 1]
    if not varying:  # nothing to resample: the interval is the point
        point = np.asarray(statistic(*samples))
        return point, point

    def with_fixed(*resampled: np.ndarray, axis: int = -1) -> np.ndarray:
        full = list(samples)
        for i, r in zip(varying, resampled, strict=True):
            full[i] = r
        batch = resampled[0].shape[:-1]
        return statistic(*(np.broadcast_to(s, (*batch, s.shape[-1])) for s in full), axis=-1)

    result = stats.bootstrap([samples[i] for i in varying], with_fixed, n_resamples=n_resamples, vectorized=True,
                             paired=False, confidence_level=confidence, method="percentile",
                             rng=np.random.default_rng(seed))
    return np.asarray(result.confidence_interval.low), np.asarray(result.confidence_interval.high)


def iqm_estimate(scores: Scores, n_resamples: int = RESAMPLES, seed: int = 0,
                 confidence: float = CONFIDENCE) -> Estimate:
    """The IQM with its stratified bootstrap interval."""
    samples = _tasks(scores)
    low, high = _bootstrap(samples, _pooled_iqm, n_resamples, seed, confidence)
    return Estimate(iqm(scores), float(low), float(high))


def _pooled_mean(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.concatenate(samples, axis=axis).mean(axis=axis)


def mean_estimate(scores: Scores, n_resamples: int = RESAMPLES, seed: int = 0,
                  confidence: float = CONFIDENCE) -> Estimate:
    """The mean over all runs × tasks pooled, with its stratified bootstrap interval (beside the IQM)."""
    samples = _tasks(scores)
    low, high = _bootstrap(samples, _pooled_mean, n_resamples, seed, confidence)
    return Estimate(float(np.concatenate(samples).mean()), float(low), float(high))


def _improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """U/(n_x n_y) along the last axis (vectorised over any leading resample axes)."""
    greater = x[..., :, None] > y[..., None, :]
    ties = x[..., :, None] == y[..., None, :]
    return (greater + 0.5 * ties).mean(axis=(-2, -1))


def _shared_tasks(x: Scores, y: Scores) -> list[str]:
    shared = [task for task in x if task in y]
    if not shared:
        raise ValueError("the two methods share no task")
    return shared


def probability_of_improvement(x: Scores, y: Scores) -> float:
    """P(X > Y): the chance a run of X beats a run of Y on the same task, averaged over their shared tasks."""
    tasks = _shared_tasks(x, y)
    xs, ys = _tasks({t: x[t] for t in tasks}), _tasks({t: y[t] for t in tasks})
    return float(np.mean([_improvement(a, b) for a, b in zip(xs, ys, strict=True)]))


def probability_of_improvement_estimate(x: Scores, y: Scores, n_resamples: int = RESAMPLES, seed: int = 0,
                                        confidence: float = CONFIDENCE) -> Estimate:
    """P(X > Y) with its stratified bootstrap interval (both methods' runs resampled within each task)."""
    tasks = _shared_tasks(x, y)
    xs, ys = _tasks({t: x[t] for t in tasks}), _tasks({t: y[t] for t in tasks})
    k = len(tasks)

    def statistic(*samples: np.ndarray, axis: int = -1) -> np.ndarray:
        return np.mean([_improvement(samples[i], samples[k + i]) for i in range(k)], axis=0)

    low, high = _bootstrap([*xs, *ys], statistic, n_resamples, seed, confidence)
    return Estimate(probability_of_improvement(x, y), float(low), float(high))


def _profile(samples: Sequence[np.ndarray], thresholds: np.ndarray) -> np.ndarray:
    """Mean over tasks of the fraction of runs above each threshold; thresholds on the last axis."""
    return np.mean([(s[..., :, None] > thresholds).mean(axis=-2) for s in samples], axis=0)


def performance_profile(scores: Scores, thresholds: Sequence[float] | np.ndarray) -> np.ndarray:
    """For each threshold τ, the fraction of runs scoring above τ (averaged over tasks)."""
    return _profile(_tasks(scores), np.asarray(thresholds, dtype=float))


def performance_profile_estimate(scores: Scores, thresholds: Sequence[float] | np.ndarray,
                                 n_resamples: int = 2_000, seed: int = 0,
                                 confidence: float = CONFIDENCE) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The profile and its pointwise stratified bootstrap band: (profile, low, high), one value per threshold."""
    samples, taus = _tasks(scores), np.asarray(thresholds, dtype=float)

    def statistic(*resampled: np.ndarray, axis: int = -1) -> np.ndarray:
        return np.moveaxis(_profile(resampled, taus), -1, 0)  # scipy wants the outputs first

    low, high = _bootstrap(samples, statistic, n_resamples, seed, confidence)
    return performance_profile(scores, taus), low, high

"""Comparing two methods from their per-seed results: what a table of means ± std cannot say.

With five seeds a method's spread can be as wide as the gap between two methods. Two numbers that assume
nothing about the distribution of returns say how far a difference is to be believed:

- the *probability of improvement* P(A > B): the fraction of (seed of A, seed of B) pairs in which A scores
  higher, ties counting half (Mann–Whitney's U over nA·nB; Agarwal et al., "Deep Reinforcement Learning at the
  Edge of the Statistical Precipice", NeurIPS 2021);
- the two-sided *permutation p-value* of the difference in means: the fraction of all ways to split the pooled
  results into groups of nA and nB whose difference in means is at least as large as the one observed. Exact
  (every split) up to EXACT_LIMIT splits, otherwise a fixed-seed Monte Carlo sample of MONTE_CARLO splits.

Few seeds cap what the test can show: with 5 against 5 no p below 2/252 ≈ 0.008 is possible (a split and its
mirror image differ equally), with 5 against 2 none below 1/21 ≈ 0.048, with 2 against 2 none below 1/3; so
`smallest_p` travels with every comparison.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np

EXACT_LIMIT = 200_000  # 10 against 10 seeds (184,756 splits) is still exact
MONTE_CARLO = 100_000


@dataclass(frozen=True)
class Comparison:
    n_a: int
    n_b: int
    difference: float  # mean(A) − mean(B)
    p_improvement: float  # P(A > B) over seed pairs, ties half
    p_value: float  # two-sided permutation test of the difference in means
    exact: bool  # every split enumerated (else Monte Carlo)
    smallest_p: float  # the smallest p-value these group sizes allow (distinct values, exact test)


def probability_of_improvement(a, b) -> float:
    a = np.asarray(a, dtype=float)[:, None]
    b = np.asarray(b, dtype=float)[None, :]
    return float(((a > b) + 0.5 * (a == b)).mean())


def permutation_p_value(a, b, seed: int = 0) -> tuple[float, bool]:
    """(two-sided p, exact?) for the difference in means of `a` and `b`."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    pooled = np.concatenate([a, b])
    n, k = len(pooled), len(a)
    exact = math.comb(n, k) <= EXACT_LIMIT
    if exact:
        members = np.array(list(itertools.combinations(range(n), k)))
    else:
        members = np.argsort(np.random.default_rng(seed).random((MONTE_CARLO, n)), axis=1)[:, :k]
    sum_a = pooled[members].sum(axis=1)
    differences = np.abs(sum_a / k - (pooled.sum() - sum_a) / (n - k))
    # "At least as large" up to float rounding: the observed split itself must count, however it was summed.
    tolerance = 1e-9 * max(1.0, float(np.abs(pooled).max()))
    as_large = int(np.count_nonzero(differences >= abs(a.mean() - b.mean()) - tolerance))
    if exact:
        return as_large / len(members), True
    return (as_large + 1) / (len(members) + 1), False  # the observed split is one of the possible ones


def compare(a, b) -> Comparison:
    """A against B; both need at least two values (one value has no spread to test against)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if len(a) < 2 or len(b) < 2:
        raise ValueError(f"a comparison needs at least two values on each side, got {len(a)} and {len(b)}")
    p_value, exact = permutation_p_value(a, b)
    splits = math.comb(len(a) + len(b), len(a))
    return Comparison(n_a=len(a), n_b=len(b), difference=float(a.mean() - b.mean()),
                      p_improvement=probability_of_improvement(a, b), p_value=p_value, exact=exact,
                      smallest_p=(2 if len(a) == len(b) else 1) / splits)

import numpy as np
import pytest
from scipy import stats

from miktcli.stats.across_tasks import (
    Estimate,
    iqm,
    iqm_estimate,
    mean_estimate,
    normalized,
    performance_profile,
    performance_profile_estimate,
    probability_of_improvement,
    probability_of_improvement_estimate,
)


def test_normalised_between_random_and_reference():
    assert normalized([100.0, 200.0, -50.0], random=0.0, reference=200.0).tolist() == [0.5, 1.0, -0.25]
    assert normalized([30.0], random=10.0, reference=50.0).tolist() == [0.5]
    with pytest.raises(ValueError, match="cannot normalise"):
        normalized([1.0], random=5.0, reference=5.0)


def test_iqm_pools_runs_over_tasks_and_cuts_a_quarter_each_end():
    assert iqm({"a": [1, 2, 3, 4], "b": [5, 6, 7, 8]}) == pytest.approx(4.5)  # mean of 3, 4, 5, 6
    assert iqm({"a": [0, 1, 2, 3, 100]}) == pytest.approx(2.0)  # int(5/4) = 1 cut each end
    with pytest.raises(ValueError, match="at least one score"):
        iqm({"a": []})


def test_iqm_interval_holds_the_point_is_seeded_and_collapses_on_constant_data():
    rng = np.random.default_rng(1)
    scores = {f"task{i}": rng.normal(i, 1.0, 5) for i in range(4)}
    est = iqm_estimate(scores, n_resamples=2000, seed=3)
    assert est.low < est.value < est.high
    assert iqm_estimate(scores, n_resamples=2000, seed=3) == est  # the same seed, the same interval
    assert iqm_estimate(scores, n_resamples=2000, seed=4) != est
    one_run = iqm_estimate({"a": [1.0, 2.0, 3.0], "b": [10.0]}, n_resamples=200)  # a task with a single run
    assert one_run.low <= one_run.value <= one_run.high
    mean = mean_estimate(scores, n_resamples=2000, seed=3)
    assert mean.value == pytest.approx(np.concatenate(list(scores.values())).mean())
    assert mean.low < mean.value < mean.high
    flat = iqm_estimate({"a": [2.0, 2.0, 2.0], "b": [2.0, 2.0]}, n_resamples=200)
    assert (flat.value, flat.low, flat.high) == pytest.approx((2.0, 2.0, 2.0))


def test_probability_of_improvement_is_mann_whitney_over_the_product_averaged_over_tasks():
    x, y = {"a": [1.0, 2.0, 3.0], "b": [5.0]}, {"a": [2.0, 2.0], "b": [1.0], "only-y": [9.0]}
    # task a: (0 + 0 + ½ + ½ + 1 + 1) / 6 = ½; task b: 1; the task only y has is left out
    assert probability_of_improvement(x, y) == pytest.approx(0.75)
    u = stats.mannwhitneyu(x["a"], y["a"]).statistic
    assert u / 6 == pytest.approx(0.5)
    assert probability_of_improvement(y, x) == pytest.approx(0.25)
    est = probability_of_improvement_estimate({"a": [3.0, 4.0, 5.0]}, {"a": [1.0, 2.0, 3.5]}, n_resamples=500)
    assert isinstance(est, Estimate) and est.low <= est.value <= est.high <= 1.0
    with pytest.raises(ValueError, match="share no task"):
        probability_of_improvement({"a": [1.0]}, {"b": [1.0]})


def test_performance_profile_averages_each_tasks_fraction_above_the_threshold():
    scores = {"a": [0.5, 1.5], "b": [2.0, 3.0, 4.0]}
    # τ = 1: a ½, b 1; τ = 3: a 0, b ⅓
    assert performance_profile(scores, [0.0, 1.0, 3.0, 5.0]).tolist() == pytest.approx([1.0, 0.75, 1 / 6, 0.0])
    point, low, high = performance_profile_estimate(scores, [0.0, 1.0, 3.0], n_resamples=300)
    assert point.shape == low.shape == high.shape == (3,)
    assert np.all(low <= point + 1e-12) and np.all(point <= high + 1e-12)
    assert (low[0], high[0]) == (1.0, 1.0)  # every run of every resample is above 0

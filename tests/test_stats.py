import pytest

import miktcli.stats.pairwise as stats
from miktcli.stats.pairwise import compare, permutation_p_value, probability_of_improvement


def test_probability_of_improvement_counts_seed_pairs_with_ties_half():
    # pairs (1,2) (1,3) (2,2) (2,3): only the tie counts, as one half
    assert probability_of_improvement([1, 2], [2, 3]) == 0.5 / 4
    assert probability_of_improvement([5, 6], [1, 2]) == 1.0
    a, b = [3.0, 1.0, 4.0], [1.0, 5.0]
    assert probability_of_improvement(a, b) + probability_of_improvement(b, a) == 1.0


def test_exact_permutation_p_values_by_hand():
    # 3 against 3: 20 splits; only the observed one and its mirror are as far apart
    assert permutation_p_value([1, 2, 3], [4, 5, 6]) == (0.1, True)
    # 2 against 2, pooled (2, 6, -6, -2): of the 6 splits, {2, 6} and {-6, -2} differ by 8
    assert permutation_p_value([2, 6], [-6, -2]) == (pytest.approx(1 / 3), True)
    # the same values on both sides: every split is at least as extreme
    assert permutation_p_value([1, 1, 1], [1, 1, 1]) == (1.0, True)
    # 5 against 2 with the two lowest on one side: one split of 21 is as extreme
    assert permutation_p_value([10, 11, 12, 13, 14], [0, 1]) == (pytest.approx(1 / 21), True)


def test_compare_reports_the_floor_its_seed_counts_allow():
    c = compare([3706, 3145, 2756, 2326, 2571], [2135, 630])
    assert c.difference == pytest.approx((3706 + 3145 + 2756 + 2326 + 2571) / 5 - (2135 + 630) / 2)
    assert c.p_improvement == 1.0 and c.exact
    assert c.smallest_p == pytest.approx(1 / 21) and c.p_value == pytest.approx(1 / 21)
    assert compare(list(range(5)), list(range(5, 10))).smallest_p == pytest.approx(2 / 252)
    with pytest.raises(ValueError, match="at least two values"):
        compare([1.0], [2.0, 3.0])


def test_large_groups_fall_back_to_a_seeded_monte_carlo_estimate(monkeypatch):
    monkeypatch.setattr(stats, "EXACT_LIMIT", 10)
    monkeypatch.setattr(stats, "MONTE_CARLO", 20_000)
    p, exact = permutation_p_value([1, 2, 3], [4, 5, 6])
    assert not exact and p == pytest.approx(0.1, abs=0.01)  # the exact value is 0.1
    assert permutation_p_value([1, 2, 3], [4, 5, 6]) == (p, False)  # seeded: the report does not change

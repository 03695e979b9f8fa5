"""Hill numbers, completeness and the iNEXT bootstrap population, checked against iNEXT's
published values and a hand-worked incidence table."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.scores.diversity import (
    asymptotic_hill,
    completeness,
    completeness_se,
    distinct_variance,
    diversity,
    diversity_table,
    estimated_population,
    hill_numbers,
    pooled_diversity,
    population_hill,
)
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.stats.intervals import studentized_interval

# Sackett et al. (2011) spiders, "Girdled" site: iNEXT's example abundance data
GIRDLED = np.array([46, 22, 17, 15, 15, 9, 8, 6, 6, 4, 2, 2, 2, 2] + [1] * 12)


def _diversity_stream(config=None):
    """diversity()'s stream in these tests: ("diversity",)."""
    return (config or BootstrapConfig()).rng("diversity")


def test_girdled_matches_inext_published_values():
    # iNEXT (Hsieh, Ma & Chao 2016) README, AsyEst and DataInfo of spider$Girdled:
    # n 168, S.obs 26, SC 0.9289; richness 26 -> 43.893, Shannon 12.060 -> 13.826,
    # Simpson 7.840 -> 8.175
    assert completeness(GIRDLED) == pytest.approx(0.9289, abs=1e-4)
    assert hill_numbers(GIRDLED, 168) == pytest.approx([26, 12.060, 7.840], abs=1e-3)
    assert asymptotic_hill(GIRDLED) == pytest.approx([43.893, 13.826, 8.175], abs=1e-3)


def test_rarefaction_by_hand():
    counts = np.array([2, 1, 1])  # n = 4
    # m = 2: q0 = sum 1 - C(4 - X, 2) / C(4, 2) = (1 - 1/6) + 2 (1 - 3/6) = 11/6
    # q2 = 1 / (1/2 + 1/2 * (2 * 1) / (4 * 3)) = 12 / 7
    q0, q1, q2 = hill_numbers(counts, 2)
    assert q0 == pytest.approx(11 / 6) and q2 == pytest.approx(12 / 7)
    # q1 at m = 2: f1(2) = 2 * 5/6 ... directly: pairs differ with prob 5/6 -> f1 = 5/3,
    # f2 = 1/6: exp(-(f1 * 1/2 log 1/2 + f2 * 1 log 1)) = exp(5/6 log 2)
    assert q1 == pytest.approx(np.exp(5 / 6 * np.log(2)))
    assert hill_numbers(counts, 1) == pytest.approx([1, 1, 1])


def test_extrapolation_rises_towards_the_asymptote():
    at = np.array([hill_numbers(GIRDLED, m) for m in (168, 250, 336, 5000)])
    assert np.all(np.diff(at[:, 0]) > 0) and np.all(np.diff(at[:, 1]) > 0)
    assert at[-1] == pytest.approx(asymptotic_hill(GIRDLED), rel=0.02)


def test_incidence_population_uses_singletons_over_sampling_units():
    # hand-worked table: 10 episodes; vocabulary items shown by 1, 1, 1, 2, 3, 5 of them
    freq = np.array([1, 1, 1, 2, 3, 5])
    n_units = 10
    q0 = (9 / 10) * 3 ** 2 / (2 * 1)  # Chao2: (T-1)/T Q1^2 / (2 Q2) = 4.05
    A = n_units * q0 / (n_units * q0 + 3)  # 40.5 / 43.5
    a = 3 / n_units * A  # Q1 / T * A: over the 10 units, not the 13 incidences
    b = 3 * 0.1 * 0.9 ** 10 + 0.2 * 0.8 ** 10 + 0.3 * 0.7 ** 10 + 0.5 * 0.5 ** 10
    p_detected, p_undetected = estimated_population(freq, n_units)
    assert len(p_undetected) == 5 and p_undetected == pytest.approx([a / 5] * 5)
    assert a == pytest.approx(0.279310, abs=1e-6)
    assert p_detected[0] == pytest.approx(0.1 * (1 - a / b * 0.9 ** 10))
    assert p_detected[-1] == pytest.approx(0.5 * (1 - a / b * 0.5 ** 10))


def test_all_distinct_labels_are_at_least_not_a_number():
    # 12 distinct of 12: the old Chao-Shen printed 7.45 bits; completeness 0.016 here
    d = diversity([f"L{i}" for i in range(12)], config=BootstrapConfig(n_resamples=200),
                  rng=_diversity_stream())
    assert d.completeness < 0.05 and d.asymptote_is_bound
    assert d.asymptote == pytest.approx([12, 12, 12])  # "at least" the sample's
    assert d.hill == pytest.approx([12, 12, 12])
    assert np.log2(d.hill[1]) <= np.log2(12) + 1e-9  # never above what 12 episodes show


def test_extrapolating_far_beyond_the_sample_is_a_lower_bound():
    d = diversity(["a", "a", "b", "c"], size=20, config=BootstrapConfig(n_resamples=200),
                  rng=_diversity_stream())
    assert d.method == "extrapolated" and d.hill_is_bound
    assert d.hill == pytest.approx(hill_numbers(np.array([2, 1, 1]), 4))
    assert np.isnan(d.hill_high).all()


def test_policies_compare_at_a_common_size():
    eps = pd.DataFrame({"env": "h", "policy": ["p"] * 20 + ["q"] * 10,
                        "seed": list(range(20)) + list(range(10)), "status": "ok",
                        "sdl": [f"L{i % 5}" for i in range(20)] + [f"L{i % 3}" for i in
                                                                   range(10)]})
    table = diversity_table(eps, BootstrapConfig(n_resamples=200)).set_index("policy")
    assert (table["size"] == 10).all()
    assert table.loc["p", "method"] == "interpolated" and table.loc["q", "method"] == "observed"
    assert table.loc["p", "hill_q0"] < 5  # rarefied from 20 to 10 episodes
    assert (table["hill_q0_low"] < table["hill_q0"]).all()


def test_one_label_only_still_has_an_interval():
    d = diversity(["a"] * 30, config=BootstrapConfig(n_resamples=200), rng=_diversity_stream())
    assert d.hill == pytest.approx([1, 1, 1]) and d.completeness == 1.0
    assert (d.hill_high > d.hill).all() and d.completeness_low < 1.0


def test_rarefying_many_samples_ignores_absent_labels():
    # (B, S) draws carry zeros for labels a draw did not show; they add nothing at m < n
    draws = np.array([[3, 1, 0, 0], [0, 2, 2, 0], [1, 1, 1, 1]])
    rows = [hill_numbers(row[row > 0], 2) for row in draws]
    assert hill_numbers(draws, 2) == pytest.approx(np.array(rows))


def test_population_hill_by_hand():
    # two equally likely labels, m = 2: q0 = 2 (1 - 1/4) = 1.5; the plug-in entropy is 0
    # (same label, prob 1/2) or log 2: q1 = exp(log(2) / 2); q2 = 1 / (1/2 + 1/2 * 1/2)
    assert population_hill(np.array([0.5, 0.5]), 2) == pytest.approx(
        [1.5, np.sqrt(2), 4 / 3])
    assert population_hill(np.array([1.0]), 5) == pytest.approx([1, 1, 1])


def test_population_hill_is_what_the_estimators_estimate():
    # the rarefied q0 is unbiased for the population's q0 at m, and 1 / q2 for its 1 / q2
    # (Simpson's concentration is a U-statistic); q2 itself is not (Jensen), nor q1
    p = np.array([0.4, 0.3, 0.15, 0.1, 0.05])
    draws = np.random.default_rng(0).multinomial(20, p, size=4000)
    at_m = hill_numbers(draws, 8)
    truth = population_hill(p, 8)
    assert at_m[:, 0].mean() == pytest.approx(truth[0], rel=0.005)
    assert (1 / at_m[:, 2]).mean() == pytest.approx(1 / truth[2], rel=0.005)
    assert at_m[:, 1].mean() == pytest.approx(truth[1], rel=0.03)
    assert at_m[:, 2].mean() > truth[2]  # the Jensen bias the intervals correct


def test_distinct_variance_is_that_of_the_bootstrap_population():
    counts = np.array([5, 3, 2, 2, 1, 1, 1])
    n = int(counts.sum())
    p_det, p_und = estimated_population(counts, n)
    q = 1 - (1 - np.r_[p_det, p_und]) ** n
    assert distinct_variance(counts, n) == pytest.approx(float((q * (1 - q)).sum()))
    # a row of many samples gives each sample's own
    rows = np.array([[5, 3, 2, 2, 1, 1, 1, 0], [0, 6, 4, 3, 1, 1, 0, 0]])
    assert distinct_variance(rows, n) == pytest.approx(
        [distinct_variance(r[r > 0], n) for r in rows])


def test_studentized_interval_by_hand():
    # t* = (draw - centre) / draw_se = -2, -1, 0, 1, 2 (level 0.6: quantiles -1.2, 1.2)
    draws = np.array([[8.0], [9.0], [10.0], [11.0], [12.0]])
    low, high = studentized_interval(np.array([20.0]), np.array([2.0]), draws,
                                     np.ones((5, 1)), np.array([10.0]), 0.6)
    assert low == pytest.approx([20 - 1.2 * 2]) and high == pytest.approx([20 + 1.2 * 2])
    # a skewed error gives an asymmetric interval, reflected about the estimate
    skewed = np.array([[9.0], [9.5], [10.0], [10.5], [14.0]])
    low, high = studentized_interval(np.array([20.0]), np.array([1.0]), skewed,
                                     np.ones((5, 1)), np.array([10.0]), 0.6)
    assert 20 - low[0] > high[0] - 20


def test_completeness_standard_error_is_estys():
    counts = np.array([6, 4, 3, 2, 2, 1, 1, 1])  # n 20, f1 3, f2 2
    assert completeness_se(counts) == pytest.approx(np.sqrt(3 * (1 - 3 / 20) + 2 * 2) / 20)
    # nothing seen once or twice: floored at one singleton's worth, 1 / n
    assert completeness_se(np.array([10, 5, 5])) == pytest.approx(1 / 20)
    assert completeness_se(np.array([[6, 4, 3, 2, 2, 1, 1, 1], [10, 5, 5, 0, 0, 0, 0, 0]])
                           ) == pytest.approx([completeness_se(counts), 1 / 20])
    labels = [f"L{i}" for i, c in enumerate(counts) for _ in range(c)]
    d = diversity(labels, config=BootstrapConfig(n_resamples=500), rng=_diversity_stream())
    assert 0 <= d.completeness_low < d.completeness < d.completeness_high <= 1


def test_hill_intervals_are_not_symmetric_and_stay_in_range():
    # studentized: the interval follows the skew of the error (q2 = 1 / concentration is
    # right-skewed), never the symmetric +- z sd of iNEXT, and stays within [1, m]
    labels = ["a"] * 4 + ["b"] * 3 + ["c"] * 2 + ["d", "e", "f"]
    d = diversity(labels, config=BootstrapConfig(n_resamples=2000), rng=_diversity_stream())
    assert (d.hill_low < d.hill).all() and (d.hill < d.hill_high).all()
    assert d.hill_high[2] - d.hill[2] > 1.2 * (d.hill[2] - d.hill_low[2])
    assert (d.hill_high <= len(labels)).all() and (d.hill_low >= 1).all()


def test_pooled_diversity_combines_independent_envs():
    labels = ["a"] * 6 + ["b"] * 4 + ["c"] * 3 + ["d", "d", "e", "f", "g"]
    config = BootstrapConfig(n_resamples=500)
    one = diversity(labels, config=config, rng=np.random.default_rng(1))
    two = diversity(labels, config=config, rng=np.random.default_rng(2))
    pooled = pooled_diversity([one, two], config.level)
    assert pooled.hill == pytest.approx(one.hill)
    assert pooled.se == pytest.approx(np.sqrt(one.se ** 2 + two.se ** 2) / 2)
    # the mean of two independent envs is known better than either
    assert (pooled.hill_high - pooled.hill_low < one.hill_high - one.hill_low).all()
    assert pooled.completeness_low < pooled.completeness < pooled.completeness_high


def test_estimates_that_rise_with_q_are_flagged_and_their_intervals_widened():
    # no label seen once: q0 at m > n stays S_obs = 6, while the inverse Simpson grows:
    # 1 / (1/20 + 0.95 * 16 / 156) = 6.78 > 6 (by hand)
    from tap_bench.bench.scores.diversity import diversity
    labels = [f"L{i}" for i in range(5) for _ in range(2)] + ["L5"] * 3
    d = diversity(labels, size=20, rng=_diversity_stream())
    assert d.hill[0] == pytest.approx(6.0) and d.hill[2] == pytest.approx(6.78, abs=0.01)
    assert d.hill_order_broken and d.row()["hill_order_broken"]
    for j in (0, 2):  # both intervals hold both estimates
        assert d.hill_low[j] <= min(d.hill[0], d.hill[2])
        assert d.hill_high[j] >= max(d.hill[0], d.hill[2])
    # a sample whose estimates are in order is not flagged
    ok = diversity(["a"] * 5 + ["b"] * 3 + ["c"] * 2 + ["d", "e"], rng=_diversity_stream())
    assert not ok.hill_order_broken
    assert ok.hill[0] >= ok.hill[1] >= ok.hill[2]


def test_asymptotes_out_of_order_are_not_reported():
    from tap_bench.bench.scores.diversity import _asymptote_in_order
    asym, broken = _asymptote_in_order(np.array([6.1, 7.3, 9.4]))
    assert broken and np.isnan(asym).all()
    asym, broken = _asymptote_in_order(np.array([9.0, 7.0, 5.0]))
    assert not broken and asym.tolist() == [9.0, 7.0, 5.0]

"""Hill numbers, completeness and the iNEXT bootstrap population, checked against iNEXT's
published values and a hand-worked incidence table."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tap_bench.bench.bootstrap import BootstrapConfig
from tap_bench.bench.diversity import (
    asymptotic_hill,
    completeness,
    diversity,
    estimated_population,
    hill_numbers,
)
from tap_bench.bench.scoring import diversity_table

# Sackett et al. (2011) spiders, "Girdled" site: iNEXT's example abundance data
GIRDLED = np.array([46, 22, 17, 15, 15, 9, 8, 6, 6, 4, 2, 2, 2, 2] + [1] * 12)


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
    d = diversity([f"L{i}" for i in range(12)], config=BootstrapConfig(n_resamples=200))
    assert d.completeness < 0.05 and d.asymptote_is_bound
    assert d.asymptote == pytest.approx([12, 12, 12])  # "at least" the sample's
    assert d.hill == pytest.approx([12, 12, 12])
    assert np.log2(d.hill[1]) <= np.log2(12) + 1e-9  # never above what 12 episodes show


def test_extrapolating_far_beyond_the_sample_is_a_lower_bound():
    d = diversity(["a", "a", "b", "c"], size=20, config=BootstrapConfig(n_resamples=200))
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
    d = diversity(["a"] * 30, config=BootstrapConfig(n_resamples=200))
    assert d.hill == pytest.approx([1, 1, 1]) and d.completeness == 1.0
    assert (d.hill_high > d.hill).all() and d.completeness_low < 1.0

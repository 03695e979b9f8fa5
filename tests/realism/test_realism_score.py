"""The realism score's likelihoods and meta-metric against hand-computed values."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from tap_bench.errors import ParameterError
from tap_bench.realism.score import (
    BERNOULLI_FEATURES,
    FEATURES,
    WOSAC_2025,
    FeatureSpec,
    agent_log_likelihoods,
    bernoulli_log_prob,
    histogram_log_prob,
    meta_metric,
    pooled,
)
from tap_bench.realism.summary import summarise
from tap_bench.stats.bootstrap import BootstrapConfig

SPEED = WOSAC_2025["linear_speed"]  # 10 bins of 2.5 m/s over [0, 25], pseudocount 0.1


def test_the_2025_weights():
    assert sum(s.weight for s in WOSAC_2025.values()) == pytest.approx(1.0)
    assert {f: WOSAC_2025[f].weight for f in FEATURES} == {
        "linear_speed": 0.05, "linear_acceleration": 0.05, "angular_speed": 0.05,
        "angular_acceleration": 0.05, "distance_to_nearest_object": 0.1,
        "collision_indication": 0.25, "time_to_collision": 0.1,
        "distance_to_road_edge": 0.05, "offroad_indication": 0.25,
        "traffic_light_violation": 0.05}
    assert BERNOULLI_FEATURES == ("collision_indication", "offroad_indication",
                                  "traffic_light_violation")


def test_a_constant_speed_agent_fills_one_bin():
    # K = 2 rollouts x T = 10 steps at 10 m/s: all 20 samples in bin 4 ([10, 12.5));
    # that bin holds 20 + 0.1, the nine others 0.1 each: 21.0 in all
    sim = np.full((1, 20), 10.0)
    same = histogram_log_prob(np.full((1, 10), 10.0), sim, SPEED)
    assert np.exp(same) == pytest.approx(np.full((1, 10), 20.1 / 21.0))
    slower = histogram_log_prob(np.array([[3.0, np.nan]]), sim, SPEED)
    assert np.exp(slower[0, 0]) == pytest.approx(0.1 / 21.0)
    assert np.isnan(slower[0, 1])
    # values beyond the range are clipped into the end bins (30 m/s: the top bin)
    top = histogram_log_prob(np.array([[30.0]]), np.array([[24.0, 26.0]]), SPEED)
    assert np.exp(top[0, 0]) == pytest.approx(2.1 / 3.0)


def test_the_likelihood_averages_log_probabilities_over_valid_steps():
    logged = {"linear_speed": np.array([[10.0, 10.0, 3.0, np.nan]])}
    sim = {"linear_speed": np.full((2, 1, 4), 10.0)}
    sim["linear_speed"][:, 0, 3] = np.nan  # an undefined simulated step is no sample
    table = agent_log_likelihoods(logged, sim, {"linear_speed": SPEED})
    assert table["terms"].tolist() == [3]
    # 2 x 3 = 6 samples: bin 4 holds 6.1 of 7.0
    expected = math.exp((2 * math.log(6.1 / 7.0) + math.log(0.1 / 7.0)) / 3)
    assert pooled(table, {"linear_speed": SPEED})["linear_speed"] == pytest.approx(expected)


def test_bernoulli_terms():
    spec = WOSAC_2025["collision_indication"]
    # 4 rollouts, the agent collides in one; the log does not (and, second agent, does)
    lp = bernoulli_log_prob(np.array([False, True]), np.array([[True, True], [False, False],
                                                               [False, False], [False, False]]),
                            spec)
    assert np.exp(lp) == pytest.approx([3.001 / 4.002, 1.001 / 4.002])


def test_meta_metric_is_the_weighted_sum():
    ones = dict.fromkeys(FEATURES, 1.0)
    assert meta_metric(ones) == pytest.approx(1.0)
    half = {**ones, "collision_indication": 0.5}
    assert meta_metric(half) == pytest.approx(1.0 - 0.25 * 0.5)
    # a histogram feature nobody has (no road edge) leaves its weight out, renormalised
    no_edge = {**half, "distance_to_road_edge": float("nan")}
    assert meta_metric(no_edge) == pytest.approx((0.875 - 0.05) / 0.95)


def test_feature_spec_checks_itself():
    with pytest.raises(ParameterError, match="bins"):
        FeatureSpec(0.1, 5.0, 1.0, 10)
    with pytest.raises(ParameterError, match="pseudocount"):
        FeatureSpec(0.1, pseudocount=0.0)


def _agents(values: dict[str, float]) -> pd.DataFrame:
    """Per-agent rows for scenes s0..s(n-1): one agent each whose every feature has the
    log-probability log(value) over one term."""
    rows = []
    for scene, v in values.items():
        for f in FEATURES:
            rows.append({"scenario_id": scene, "track_id": "1", "object_type": "vehicle",
                         "manoeuvre": "Straight" if scene != "s0" else "Left Turn",
                         "feature": f, "log_prob_sum": math.log(v), "terms": 1,
                         "simulated_rate": 0.0 if f in BERNOULLI_FEATURES else np.nan})
    return pd.DataFrame(rows)


def test_summary_means_scenes_and_groups_with_intervals():
    agents = _agents({"s0": 0.2, "s1": 0.6, "s2": 0.7, "s3": 0.9})
    config = BootstrapConfig(n_resamples=500, seed=3)
    out = summarise(agents, config)
    meta = out["overall"]["meta_metric"]
    assert meta["value"] == pytest.approx(np.mean([0.2, 0.6, 0.7, 0.9]))
    assert 0.2 <= meta["low"] < meta["value"] < meta["high"] <= 0.9
    assert out["by_manoeuvre"]["Left Turn"]["meta_metric"]["value"] == pytest.approx(0.2)
    assert out["by_manoeuvre"]["Straight"]["meta_metric"]["value"] == pytest.approx(
        np.mean([0.6, 0.7, 0.9]))
    assert out["by_object_type"]["vehicle"]["agents"] == 4
    assert json.dumps(summarise(agents, config)) == json.dumps(out)  # same seed, same intervals

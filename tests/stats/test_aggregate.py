"""rliable's aggregates over training seeds x scenes, on matrices small enough to check by
hand."""

from __future__ import annotations

import numpy as np
import pytest

from tap_bench.errors import ParameterError
from tap_bench.stats.aggregate import (
    iqm,
    mean_score,
    performance_profile,
    probability_of_improvement,
    stratified_bootstrap,
)


def rng() -> np.random.Generator:
    return np.random.default_rng(0)


def test_the_iqm_is_the_mean_of_the_middle_half():
    assert iqm(np.arange(1, 9).reshape(2, 4)) == pytest.approx(4.5)  # 3, 4, 5, 6
    assert iqm([[1, 2, 3, 4]]) == pytest.approx(2.5)  # 2, 3
    # 5 scores: the 2nd and 4th count for three quarters: (0.75*2 + 3 + 0.75*4) / 2.5
    assert iqm([[1, 2, 3, 4, 5]]) == pytest.approx(3.0)
    assert iqm([[0, 0, 0, 100]]) == pytest.approx(0.0)  # one outlier run does not move it
    assert iqm([[7.0]]) == 7.0


def test_a_stack_of_resamples_gives_each_ones_iqm():
    stack = np.random.default_rng(1).normal(size=(6, 3, 5))
    np.testing.assert_allclose(iqm(stack), [iqm(m) for m in stack])


def test_the_bootstrap_resamples_runs_within_each_scene_only():
    # scene 0 scores in [0, 1], scene 1 in [10, 11]: a resample that mixed scenes would put
    # a column mean outside its scene's range
    scores = np.array([[0.0, 10.0], [1.0, 11.0], [0.5, 10.2]])
    seen = []

    def column_means(sample: np.ndarray) -> float:
        seen.append(sample.mean(axis=0))
        return float(sample.mean())

    out = stratified_bootstrap(scores, column_means, rng=rng(), n_resamples=200)
    means = np.array(seen)
    assert (means[:, 0] <= 1).all() and (means[:, 1] >= 10).all()
    assert out.low < out.estimate < out.high
    # one run (a deterministic policy): nothing to resample, the interval is the point
    one = stratified_bootstrap(scores[:1], rng=rng(), n_resamples=100)
    assert one.low == one.high == one.estimate


def test_resampling_whole_runs_keeps_each_seeds_scenes_together():
    # seed 0 scores 0 on both scenes, seed 1 scores 1 on both: whole runs resampled give
    # column means that are equal in every resample; stratified ones need not
    scores = np.array([[0.0, 0.0], [1.0, 1.0]])
    seen = []

    def columns(sample: np.ndarray) -> float:
        seen.append(sample.mean(axis=0))
        return float(sample.mean())

    stratified_bootstrap(scores, columns, rng=rng(), n_resamples=200, unit="run")
    means = np.array(seen)
    assert (means[:, 0] == means[:, 1]).all()
    seen.clear()
    stratified_bootstrap(scores, columns, rng=rng(), n_resamples=200, unit="task")
    assert (np.array(seen)[:, 0] != np.array(seen)[:, 1]).any()
    with pytest.raises(ParameterError, match="unit"):
        stratified_bootstrap(scores, rng=rng(), unit="scene")


def test_the_probability_of_improvement_counts_ties_as_half():
    # scene 0: 1 > 0; scene 1: a tie
    assert probability_of_improvement([[1, 2]], [[0, 2]], rng=rng(),
                                      n_resamples=100).estimate == pytest.approx(0.75)
    # X's two seeds straddle Y's one: 1/2
    assert probability_of_improvement([[1], [3]], [[2]], rng=rng(),
                                      n_resamples=100).estimate == pytest.approx(0.5)
    better = probability_of_improvement([[5, 5], [6, 6]], [[1, 1]], rng=rng(),
                                        n_resamples=100)
    assert better.estimate == better.low == better.high == 1.0
    with pytest.raises(ParameterError, match="same"):
        probability_of_improvement([[1, 2]], [[1, 2, 3]], rng=rng())


def test_the_performance_profile_is_the_share_of_scores_above_each_threshold():
    share, low, high = performance_profile([[0.2, 0.8], [0.4, 0.9]], [0.0, 0.5, 0.85, 1.0],
                                           rng=rng(), n_resamples=200)
    np.testing.assert_allclose(share, [1.0, 0.5, 0.25, 0.0])
    assert (low <= share).all() and (share <= high).all()
    assert low[0] == high[0] == 1.0  # every resample is above 0


def test_bad_scores_and_settings_are_refused():
    with pytest.raises(ParameterError, match="NaN"):
        iqm([[1.0, np.nan]])
    with pytest.raises(ParameterError, match="n_runs, n_tasks"):
        iqm(np.zeros((2, 2, 2, 2)))
    with pytest.raises(ParameterError, match="level"):
        stratified_bootstrap([[1.0, 2.0]], rng=rng(), level=0.3)


def test_a_widened_interval_of_a_rate_stays_within_the_scores_range():
    # one at-fault collision in 24 episodes (3 seeds x 8 scenes): the draws widened for
    # 3 resampled seeds went below 0 (lower bound -0.009) before they were kept in range
    scores = np.zeros((3, 8))
    scores[0, 0] = 1.0
    for unit in ("task", "run"):
        for statistic in (iqm, mean_score):
            interval = stratified_bootstrap(scores, statistic, rng=rng(), unit=unit)
            assert 0.0 <= interval.low <= interval.estimate <= interval.high <= 1.0
    out = stratified_bootstrap(scores, mean_score, rng=rng(), unit="run")
    assert out.low == 0.0 and out.high > out.estimate


def test_intervals_of_generated_scores_stay_within_their_range():
    # generated agents: 2-6 seeds x 1-10 scenes, rare and common at-fault rates (0/1 scores)
    # and progress-like scores in [0, 1], both resampling units, both batched statistics
    gen = np.random.default_rng(7)
    for case in range(40):
        shape = (int(gen.integers(2, 7)), int(gen.integers(1, 11)))
        if case % 2:
            scores = (gen.random(shape) < gen.choice([0.02, 0.1, 0.5, 0.95])).astype(float)
        else:
            scores = np.clip(gen.normal(gen.random(), 0.3, shape), 0.0, 1.0)
        for unit in ("task", "run"):
            for statistic in (iqm, mean_score):
                out = stratified_bootstrap(scores, statistic, rng=np.random.default_rng(case),
                                           n_resamples=200, unit=unit)
                assert scores.min() <= out.low <= out.high <= scores.max(), (case, unit)

"""Bootstrap intervals: resampling weights, and coverage of a known difference at about the
nominal rate on synthetic data (the rates are printed; run with -s to see them)."""

from __future__ import annotations

import numpy as np
import pytest

from tap_bench.bench.bootstrap import (
    BootstrapConfig,
    percentile_interval,
    resample_weights,
    simultaneous_band,
    weighted_means,
)

REPLICATIONS = 400  # rate standard error about 0.011 at 0.95


def test_weights_rows_sum_to_n_and_keep_strata():
    strata = np.array(["a"] * 3 + ["b"] * 5)
    W = resample_weights(8, BootstrapConfig(n_resamples=200), strata=strata)
    assert W.shape == (200, 8)
    assert np.all(W.sum(axis=1) == 8)
    assert np.all(W[:, :3].sum(axis=1) == 3) and np.all(W[:, 3:].sum(axis=1) == 5)


def test_same_seed_same_weights_other_stream_other_weights():
    c = BootstrapConfig(n_resamples=100, seed=7)
    assert np.array_equal(resample_weights(10, c), resample_weights(10, c))
    assert not np.array_equal(resample_weights(10, c), resample_weights(10, c, stream=1))


def test_weighted_means_skip_nan():
    W = np.array([[1.0, 1.0, 1.0], [3.0, 0.0, 0.0]])
    out = weighted_means(W, np.array([1.0, np.nan, 3.0]))
    assert out == pytest.approx([2.0, 1.0])


def test_config_refuses_bad_values():
    with pytest.raises(ValueError, match="level"):
        BootstrapConfig(level=95)
    with pytest.raises(ValueError, match="n_resamples"):
        BootstrapConfig(n_resamples=10)


def _coverage_rate(make_sample, truth, n, config, stat=lambda W, x: W @ x / len(x)):
    hits = 0
    for r in range(REPLICATIONS):
        x = make_sample(np.random.default_rng(1000 + r), n)
        W = resample_weights(n, BootstrapConfig(config.n_resamples, config.level, seed=r))
        lo, hi = percentile_interval(stat(W, x), config.level)
        hits += lo <= truth <= hi
    return hits / REPLICATIONS


def test_paired_mean_difference_covers_the_true_difference_at_about_95():
    # per-seed A - B differences of a continuous measure, skewed: true difference 0.7
    def sample(rng, n):
        common = rng.gamma(2.0, 1.0, n)  # the seed's traffic, shared by A and B
        a = common + 0.7 + rng.exponential(1.0, n) - 1.0
        b = common + rng.normal(0, 0.5, n)
        return a - b

    rate = _coverage_rate(sample, 0.7, 40, BootstrapConfig(n_resamples=1000))
    print(f"paired mean difference, n=40 seeds: coverage {rate:.3f} (nominal 0.95)")
    assert 0.91 <= rate <= 0.985


def test_paired_label_frequency_difference_covers_at_about_95():
    # A shows label L on a seed with p 0.55, B with 0.35, correlated through the seed
    def sample(rng, n):
        u = rng.random(n)
        a = (u < 0.55).astype(float)
        b = (np.where(rng.random(n) < 0.7, u, rng.random(n)) < 0.35).astype(float)
        return a - b

    rate = _coverage_rate(sample, 0.20, 50, BootstrapConfig(n_resamples=1000))
    print(f"paired label frequency difference, n=50 seeds: coverage {rate:.3f} (nominal 0.95)")
    assert 0.91 <= rate <= 0.985


def test_probability_of_improvement_covers_at_about_95():
    # P(A better than B on a seed) with a known value: A - B ~ N(0.3, 1) -> Phi(0.3)
    from statistics import NormalDist

    truth = NormalDist().cdf(0.3)

    def sample(rng, n):
        return (rng.normal(0.3, 1.0, n) > 0).astype(float)

    rate = _coverage_rate(sample, truth, 60, BootstrapConfig(n_resamples=1000))
    print(f"probability of improvement, n=60 seeds: coverage {rate:.3f} (nominal 0.95)")
    assert 0.91 <= rate <= 0.985


def test_simultaneous_band_holds_all_labels_jointly():
    # 8 label frequency differences at once; the band should hold all of them ~95 % of the
    # time while separate 95 % intervals hold all of them much less often
    K, n = 8, 60
    pa = np.linspace(0.05, 0.2, K)
    pa = pa / pa.sum()
    pb = pa[::-1]
    truth = pa - pb
    joint_band = joint_pointwise = 0
    for r in range(300):
        rng = np.random.default_rng(r)
        a = rng.choice(K, n, p=pa)
        b = rng.choice(K, n, p=pb)
        x = np.zeros((n, K))
        x[np.arange(n), a] += 1
        x[np.arange(n), b] -= 1
        W = resample_weights(n, BootstrapConfig(1000, seed=r))
        boot = W @ x / n
        est = x.mean(0)
        lo, hi = simultaneous_band(est, boot, 0.95)
        plo, phi = percentile_interval(boot, 0.95)
        joint_band += np.all((lo <= truth) & (truth <= hi))
        joint_pointwise += np.all((plo <= truth) & (truth <= phi))
    print(f"8 labels jointly: band {joint_band / 300:.3f}, separate intervals "
          f"{joint_pointwise / 300:.3f} (nominal joint 0.95)")
    assert joint_band / 300 >= 0.90
    assert joint_pointwise / 300 < joint_band / 300


def test_wilson_interval_by_hand_and_at_zero():
    from tap_bench.bench.bootstrap import wilson_interval

    # 0 of 10: (0, z^2 / (n + z^2)) = (0, 0.2775) at 95 %
    low, high = wilson_interval(0, 10, 0.95)
    assert low == pytest.approx(0.0, abs=1e-12)
    assert high == pytest.approx(1.959964 ** 2 / (10 + 1.959964 ** 2), abs=1e-5)
    low, high = wilson_interval(5, 10, 0.95)
    assert (low, high) == pytest.approx((0.2366, 0.7634), abs=1e-4)

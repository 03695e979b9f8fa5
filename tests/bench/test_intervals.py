"""Intervals: values worked by hand, no zero width where a value is estimated, named random
streams, and coverage of a known truth at about the nominal rate at 30 seeds (rates
printed; run with -s). benchmarks/interval_coverage.py has the full table."""

from __future__ import annotations

from statistics import NormalDist

import numpy as np
import pytest

from tap_bench.errors import ParameterError
from tap_bench.stats.bootstrap import BootstrapConfig, named_rng, stream_key
from tap_bench.stats.intervals import (
    mean_interval,
    newcombe_interval,
    t_quantile,
    tango_band,
    tango_interval,
    welch_interval,
    wilson_interval,
)

REPLICATIONS = 1000  # a rate's standard error is about 0.007 at 0.95


def test_named_streams_depend_on_the_name_and_seed_only():
    c = BootstrapConfig(seed=7)
    one = c.rng("coverage", "highway", "random", "idm rollouts").random(5)
    two = c.rng("coverage", "highway", "random", "idm rollouts").random(5)
    other = c.rng("coverage", "merge", "random", "idm rollouts").random(5)
    assert np.array_equal(one, two) and not np.array_equal(one, other)
    assert not np.array_equal(one, BootstrapConfig(seed=8).rng(
        "coverage", "highway", "random", "idm rollouts").random(5))
    assert stream_key("a", 1) != stream_key("a", "1 ")
    assert np.array_equal(named_rng(7, "x").random(3), named_rng(7, "x").random(3))


def test_config_refuses_bad_values_naming_them():
    with pytest.raises(ParameterError, match="level"):
        BootstrapConfig(level=95)
    with pytest.raises(ParameterError, match="n_resamples"):
        BootstrapConfig(n_resamples=10)
    with pytest.raises(ParameterError, match="name"):
        BootstrapConfig().rng()


def test_student_t_quantiles_match_the_tables():
    assert t_quantile(0.975, 1) == pytest.approx(12.7062, abs=1e-4)
    assert t_quantile(0.975, 2) == pytest.approx(4.3027, abs=1e-4)
    assert t_quantile(0.975, 9) == pytest.approx(2.2622, abs=1e-4)
    assert t_quantile(0.975, 29) == pytest.approx(2.0452, abs=1e-4)


def test_wilson_by_hand_and_never_zero_width():
    low, high = wilson_interval(0, 30, 0.95)  # 0 novel of 30: not [0, 0]
    assert low == 0.0 and high == pytest.approx(1.959964 ** 2 / (30 + 1.959964 ** 2), abs=1e-5)
    assert wilson_interval(5, 10, 0.95) == pytest.approx((0.2366, 0.7634), abs=1e-4)
    low, high = wilson_interval(30, 30, 0.95)
    assert high == 1.0 and low < 1.0


def test_newcombe_by_hand():
    # Newcombe (1998) table II, example (a): 56/70 vs 48/80 -> 0.2 [0.0524, 0.3339]
    assert newcombe_interval(56, 70, 48, 80, 0.95) == pytest.approx((0.0524, 0.3339), abs=1e-4)


def test_tango_is_a_score_interval_never_degenerate():
    # no discordant pair in 30: the difference is estimated, not known: not [0, 0]
    low, high = tango_interval(0, 0, 30, 0.95)
    assert low < 0 < high and low == pytest.approx(-high)
    # every pair discordant one way (P(improvement) 1.00): the upper limit is 1, not [1, 1]
    low, high = tango_interval(30, 0, 30, 0.95)
    assert high == 1.0 and low < 0.9
    # at its limits the score statistic equals the normal quantile
    b, c, n = 8, 2, 40
    low, high = tango_interval(b, c, n, 0.95)
    from tap_bench.stats.intervals import _tango_z

    z = NormalDist().inv_cdf(0.975)
    assert _tango_z(np.array(low), b, c, n) == pytest.approx(z, abs=1e-6)
    assert _tango_z(np.array(high), b, c, n) == pytest.approx(-z, abs=1e-6)
    vec = tango_interval(np.array([b, 0]), np.array([c, 0]), np.array([n, 30]), 0.95)
    assert vec[0][0] == pytest.approx(low) and vec[1][1] == pytest.approx(tango_interval(
        0, 0, 30, 0.95)[1])


def test_tango_of_one_table_is_the_vectorised_bisection_bit_for_bit():
    """One table is bisected in Python floats (numpy's cost per call was most of the
    demo's paired comparisons): every table of up to 20, 30 and 40 pairs, at three levels
    and a band's critical value, gives the vectorised code's limits exactly; n = 0: NaN."""
    tables = [(b, c, n) for n in (*range(1, 21), 30, 40) for b in range(n + 1)
              for c in range(n + 1 - b)]
    b, c, n = (np.array(v, float) for v in zip(*tables, strict=True))
    for level, z in ((0.9, None), (0.95, None), (0.99, None), (0.95, 2.7)):
        low, high = tango_interval(b, c, n, level, z=z)
        one = np.array([tango_interval(int(x), int(y), int(m), level, z=z)
                        for x, y, m in tables])
        assert (one[:, 0] == low).all() and (one[:, 1] == high).all()
    assert all(np.isnan(tango_interval(0, 0, 0, 0.95)))


def test_constant_values_get_the_bounded_interval_not_a_point():
    low, high = mean_interval(np.full(30, 10.0), 0.95, bounds=(0.0, 10.0))  # TTC at its cap
    _, share = wilson_interval(0, 30, 0.95)
    assert high == 10.0 and low == pytest.approx(10.0 - 10.0 * share)
    assert np.isnan(mean_interval(np.full(30, 3.0), 0.95)).all()  # unbounded: not estimable
    low, high = welch_interval(np.full(6, 10.0), np.full(6, 10.0), 0.95, bounds=(0.0, 10.0))
    assert low < 0 < high


def _rate(hits: np.ndarray) -> float:
    return float(np.mean(hits))


def test_tango_paired_label_difference_covers_at_30_seeds():
    # A shows label L on a seed with p 0.55, B with 0.35, correlated through the seed
    rng = np.random.default_rng(0)
    n = 30
    u = rng.random((REPLICATIONS, n))
    a = u < 0.55
    b = np.where(rng.random((REPLICATIONS, n)) < 0.7, u, rng.random((REPLICATIONS, n))) < 0.35
    truth = 0.55 - 0.35
    lo, hi = tango_interval((a & ~b).sum(1), (b & ~a).sum(1), np.full(REPLICATIONS, n), 0.95)
    rate = _rate((lo <= truth) & (truth <= hi))
    print(f"Tango paired difference, 30 seeds: {rate:.3f}")
    assert 0.93 <= rate <= 0.97


@pytest.mark.parametrize(("replications", "window"), [
    (400, (0.92, 0.98)), pytest.param(REPLICATIONS, (0.93, 0.975), marks=pytest.mark.slow)])
def test_sidak_band_holds_all_labels_jointly_at_30_seeds(replications, window):
    """The band over 8 labels holds all 8 jointly 95 % of the time (400 replications in
    the fast suite, a window of about 2.7 standard errors; 1,000 in the slow one), where
    the separate intervals hold them less often."""
    K, n = 8, 30
    pa = np.linspace(0.05, 0.2, K)
    pa /= pa.sum()
    pb = pa[::-1]
    truth = pa - pb
    rng = np.random.default_rng(1)
    joint = pointwise = 0
    for _ in range(replications):
        la, lb = rng.choice(K, n, p=pa), rng.choice(K, n, p=pb)
        ina = la[:, None] == np.arange(K)
        inb = lb[:, None] == np.arange(K)
        b_, c_ = (ina & ~inb).sum(0), (inb & ~ina).sum(0)
        lo, hi = tango_band(ina & ~inb, inb & ~ina, 0.95, rng, 400)
        plo, phi = tango_interval(b_, c_, np.full(K, n), 0.95)
        joint += np.all((lo <= truth) & (truth <= hi))
        pointwise += np.all((plo <= truth) & (truth <= phi))
    print(f"8 labels jointly, 30 seeds: band {joint / replications:.3f}, separate intervals "
          f"{pointwise / replications:.3f}")
    assert window[0] <= joint / replications <= window[1]
    assert pointwise < joint


def test_wilson_covers_a_small_rate_at_30_episodes():
    rng = np.random.default_rng(2)
    x = rng.binomial(30, 0.1, REPLICATIONS)
    lo, hi = wilson_interval(x, np.full(REPLICATIONS, 30), 0.95)
    rate = _rate((lo <= 0.1) & (0.1 <= hi))
    print(f"Wilson, p 0.1, 30 episodes: {rate:.3f}")
    assert 0.93 <= rate <= 0.98


def test_paired_t_covers_a_skewed_difference_at_30_seeds():
    rng = np.random.default_rng(3)
    hits = []
    for _ in range(2 * REPLICATIONS):
        d = 0.7 + rng.exponential(1.0, 30) - 1.0 + rng.normal(0, 0.5, 30)
        lo, hi = mean_interval(d, 0.95)
        hits.append(lo <= 0.7 <= hi)
    rate = _rate(np.array(hits))
    print(f"paired t, skewed, 30 seeds: {rate:.3f}")
    assert 0.93 <= rate <= 0.97


def test_clustered_wilson_counts_scenes_not_tracks_by_hand():
    from tap_bench.stats.intervals import clustered_wilson_interval

    # read at Student's t with 5 - 1 degrees of freedom (2.776): Wilson's at that level
    t4 = 2.7764451
    # 5 scenes of 10 tracks: 2 agree on every track, 3 on none. p = 0.4 of 50; between
    # scenes 5/4 * (2 * 6^2 + 3 * 4^2) / 50^2 = 0.06, binomial 0.4 * 0.6 / 50 = 0.0048:
    # deff 12.5, kept at the largest scene (10): Wilson's interval of 2 of 5
    low, high, deff = clustered_wilson_interval([10, 10, 0, 0, 0], [10] * 5, 0.95)
    assert deff == 10
    assert (low, high) == pytest.approx(wilson_interval(2, 5, 0.95, z=t4))
    # every scene agrees on half its tracks: no excess between scenes, deff 1: 25 of 50
    low, high, deff = clustered_wilson_interval([5] * 5, [10] * 5, 0.95)
    assert deff == 1 and (low, high) == pytest.approx(wilson_interval(25, 50, 0.95, z=t4))
    # all agree: no variance to see, the scenes are the sample (deff = 10 tracks a scene)
    low, high, deff = clustered_wilson_interval([10] * 5, [10] * 5, 0.95)
    assert deff == 10 and (low, high) == pytest.approx(wilson_interval(5, 5, 0.95, z=t4))

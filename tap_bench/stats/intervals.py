"""Confidence intervals of the benchmark's statistics, one function per kind of statistic.

=================================  ===========================================================
statistic                          interval
=================================  ===========================================================
a proportion (crash rate, novelty  Wilson score interval (Wilson 1927)
rate, label agreement)
difference of two independent      Newcombe's hybrid score interval (Newcombe 1998, method 10),
proportions                        from the two Wilson intervals
difference of two paired           Tango's score interval (Tango 1998): per-label paired
proportions                        frequency differences, paired crash-rate differences and
                                   the probability of improvement (wins minus losses)
many paired differences at once    a simultaneous band over k labels: Tango intervals at
                                   the critical value z* that holds all k at once, the
                                   ``level`` quantile of max_j |Z_j| over a bootstrap of
                                   the pairs (each Z_j Tango's score statistic at the
                                   estimate: a sup-score band); between Tango's own level
                                   and the Sidak level ``level ** (1 / k)``
a proportion of tracks that come    Wilson's interval at the effective sample size n / deff
in scenes (agreement of WOMD        (Rao and Scott 1981): ``deff`` the design effect of the
tracks with Waymo's classifier)     scenes, the ratio estimator's between-scene variance
                                    over the binomial one; critical value t with G - 1
a mean, a paired mean difference   Student's t interval
a difference of independent means  Welch's t interval
a statistic whose value in the      the studentized bootstrap (bootstrap-t) interval: Hill
bootstrap population is known       numbers, sample completeness, coverage shares
=================================  ===========================================================

**No interval has zero width unless the value is known exactly.** Score intervals never do
(0 of 30 gives Wilson [0, 0.114]). A t interval does when every value is equal (a minimum
time to collision at its 10 s cap on every seed); for a measure with known bounds (its
entry's ``bounds``) the interval is then the range the mean can take if a share of
episodes up to the Wilson upper limit of "0 of n differ" took any other value in the bounds,
and for a measure without bounds it is NaN (not estimable), never a point.

Every function is vectorised where the tables need it and returns NaN for an empty sample.
``benchmarks/interval_coverage.py`` measures how often each interval holds the truth
(docs/benchmark.md has the table).
"""

from __future__ import annotations

import functools
import math
from statistics import NormalDist
from typing import Protocol

import numpy as np


class Measure(Protocol):
    """What an interval reads of a measure's entry (:class:`tap_bench.bench.measures.Measure`
    is one): whether its values are 0/1 (a rate), and the range its values can take."""

    @property
    def is_rate(self) -> bool: ...

    @property
    def bounds(self) -> tuple[float, float] | None: ...

__all__ = [
    "mean_interval",
    "measure_interval",
    "newcombe_interval",
    "paired_measure_interval",
    "clustered_wilson_interval",
    "sidak_level",
    "studentized_interval",
    "t_quantile",
    "tango_band",
    "tango_interval",
    "unpaired_measure_interval",
    "welch_interval",
    "wilson_interval",
    "z_value",
]


def z_value(level: float) -> float:
    """The standard normal quantile of a two-sided ``level`` (1.96 at 0.95)."""
    return NormalDist().inv_cdf(0.5 + level / 2)


def sidak_level(level: float, k: int) -> float:
    """The level of each of k intervals whose joint level is ``level`` (Sidak)."""
    return float(level) ** (1.0 / max(int(k), 1))


@functools.lru_cache(maxsize=256)
def t_quantile(p: float, df: int) -> float:
    """The p quantile of Student's t with ``df`` degrees of freedom (p in (0.5, 1)).

    Closed forms for df 1 and 2; otherwise the CDF is integrated (Simpson, 4001 points on
    [0, t], exact to about 1e-10) and inverted by bisection. numpy only: scipy is not a
    dependency.
    """
    if not 0.5 < p < 1 or df < 1:
        raise ValueError(f"t_quantile needs p in (0.5, 1) and df >= 1, got {p}, {df}.")
    if df == 1:
        return math.tan(math.pi * (p - 0.5))
    if df == 2:
        return (2 * p - 1) / math.sqrt(2 * p * (1 - p))
    log_c = math.lgamma((df + 1) / 2) - math.lgamma(df / 2) - 0.5 * math.log(df * math.pi)

    def cdf(t: float) -> float:
        x = np.linspace(0.0, t, 4001)
        f = np.exp(log_c - (df + 1) / 2 * np.log1p(x * x / df))
        h = t / 4000
        return 0.5 + h / 3 * (f[0] + f[-1] + 4 * f[1:-1:2].sum() + 2 * f[2:-1:2].sum())

    lo, hi = 0.0, 2.0 * NormalDist().inv_cdf(p) + 10.0
    for _ in range(80):
        mid = (lo + hi) / 2
        if cdf(mid) < p:
            lo = mid
        else:
            hi = mid
    return (lo + hi) / 2


def wilson_interval(successes, n, level: float, *, z: float | None = None) -> tuple:
    """Wilson score interval of a proportion ``successes / n``.

    Args:
        successes: count(s) of events (scalar or array).
        n: trials (scalar or array of the same shape).
        level: two-sided level, e.g. 0.95.
        z: the critical value to use instead of the level's normal quantile.

    Returns:
        (low, high) in [0, 1], floats or arrays; NaN where n is 0.
    """
    x = np.asarray(successes, dtype=float)
    m = np.asarray(n, dtype=float)
    z = z_value(level) if z is None else float(z)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = x / m
        centre = (p + z * z / (2 * m)) / (1 + z * z / m)
        half = z / (1 + z * z / m) * np.sqrt(p * (1 - p) / m + z * z / (4 * m * m))
    low = np.where(m > 0, np.clip(centre - half, 0.0, 1.0), np.nan)
    high = np.where(m > 0, np.clip(centre + half, 0.0, 1.0), np.nan)
    # exact at the edges: 0 events have a lower limit of 0, n events an upper limit of 1
    low = np.where(x == 0, 0.0, low) if np.ndim(low) else (0.0 if x == 0 and m > 0 else low)
    high = np.where(x == m, 1.0, high) if np.ndim(high) else (1.0 if x == m and m > 0 else high)
    if np.ndim(low) == 0:
        return float(low), float(high)
    return low, high


def clustered_wilson_interval(successes, trials, level: float) -> tuple[float, float, float]:
    """Wilson's interval of a proportion whose trials come in clusters (tracks in scenes).

    The share is ``sum(successes) / sum(trials)`` over the clusters; the tracks of one
    scene share its place and traffic, so they carry less than one independent trial each.
    The interval is Wilson's at the effective sample size ``n / deff`` (Rao and Scott
    1981), ``deff`` the design effect: the ratio estimator's between-cluster variance
    ``G / (G - 1) * sum (x_g - p n_g)^2 / n^2`` over the binomial ``p (1 - p) / n``, kept
    within [1, largest cluster]. With every cluster agreeing or every one failing (p 0 or 1,
    no variance to see) ``deff`` is the mean cluster size (the clusters are the sample).
    The variance is estimated from G clusters, so the critical value is Student's t with
    G - 1 degrees of freedom, not the normal one.

    Args:
        successes: (G,) successes per cluster.
        trials: (G,) trials per cluster (> 0).
        level: two-sided level.

    Returns:
        (low, high, deff); NaN with no trials.
    """
    x = np.asarray(successes, dtype=float)
    m = np.asarray(trials, dtype=float)
    keep = m > 0
    x, m = x[keep], m[keep]
    g, n = len(m), float(m.sum())
    if not n:
        return float("nan"), float("nan"), float("nan")
    p = float(x.sum()) / n
    if g < 2:
        deff = n
    elif 0 < p < 1:
        between = g / (g - 1) * float(((x - p * m) ** 2).sum()) / n ** 2
        deff = float(np.clip(between / (p * (1 - p) / n), 1.0, m.max()))
    else:
        deff = n / g
    # few scenes: the variance is estimated from G of them, read at Student's t (G - 1)
    z = t_quantile(0.5 + level / 2, g - 1) if g >= 2 else z_value(level)
    low, high = wilson_interval(p * n / deff, n / deff, level, z=z)
    return float(low), float(high), deff


def newcombe_interval(x1, n1, x2, n2, level: float) -> tuple:
    """Newcombe's hybrid score interval of ``x1/n1 - x2/n2`` (independent samples).

    Returns:
        (low, high) in [-1, 1]; NaN when either n is 0.
    """
    p1 = np.asarray(x1, float) / np.asarray(n1, float)
    p2 = np.asarray(x2, float) / np.asarray(n2, float)
    l1, u1 = (np.asarray(v, float) for v in wilson_interval(x1, n1, level))
    l2, u2 = (np.asarray(v, float) for v in wilson_interval(x2, n2, level))
    d = p1 - p2
    low = d - np.sqrt((p1 - l1) ** 2 + (u2 - p2) ** 2)
    high = d + np.sqrt((u1 - p1) ** 2 + (p2 - l2) ** 2)
    if np.ndim(low) == 0:
        return float(low), float(high)
    return low, high


def _tango_z(delta: np.ndarray, b: np.ndarray, c: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Tango's score statistic of a paired difference ``delta`` (restricted MLE of p01)."""
    A = 2 * n
    B = -b - c + (2 * n - b + c) * delta
    C = -c * delta * (1 - delta)
    p01 = (np.sqrt(np.maximum(B * B - 4 * A * C, 0.0)) - B) / (2 * A)
    var = n * (2 * p01 + delta * (1 - delta))
    num = b - c - n * delta
    with np.errstate(invalid="ignore", divide="ignore"):
        z = num / np.sqrt(np.maximum(var, 0.0))
        edge = np.where(np.abs(num) < 1e-12, 0.0, np.copysign(np.inf, num))
    return np.where(var > 1e-15, z, edge)


def tango_interval(b, c, n, level: float, *, z: float | None = None) -> tuple:
    """Tango's score interval of a difference of paired proportions ``(b - c) / n``.

    For a binary outcome observed on both members of n pairs (policy A and B on the same
    seed), ``b`` pairs have it for A only and ``c`` for B only; the estimate is
    ``(b - c) / n``, the difference of the two proportions. The interval is every delta
    whose score statistic (Tango 1998, eq. 3) is within the normal quantile, found by
    bisection (vectorised over arrays of tables).

    Args:
        b, c: discordant counts (scalars or arrays).
        n: pairs.
        level: two-sided level.
        z: the critical value to use instead of the level's normal quantile (a band).

    Returns:
        (low, high) in [-1, 1]; NaN where n is 0.
    """
    z = z_value(level) if z is None else float(z)
    if np.ndim(b) == 0 and np.ndim(c) == 0 and np.ndim(n) == 0:  # one table: Python floats
        return _tango_interval_one(float(b), float(c), float(n), z)
    b_, c_, n_ = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (b, c, n)))
    b_, c_, n_ = (np.atleast_1d(v).astype(float) for v in (b_, c_, n_))
    ok = n_ > 0
    safe_n = np.where(ok, n_, 1.0)
    est = (b_ - c_) / safe_n
    # both ends in one bisection over the tables twice (Z decreases in delta): the lower end
    # the smallest delta in [-1, est] with Z(delta) <= z, the upper the largest in [est, 1]
    # with Z(delta) >= -z; each element's steps are those of a bisection of its end alone
    m = len(est)
    b2, c2, n2 = np.r_[b_, b_], np.r_[c_, c_], np.r_[safe_n, safe_n]
    lower = np.r_[np.ones(m, bool), np.zeros(m, bool)]
    lo, hi = np.r_[np.full_like(est, -1.0), est], np.r_[est, np.ones_like(est)]
    ends = _tango_z(np.r_[lo[:m], hi[m:]], b2, c2, n2)
    at_edge = np.r_[ends[:m] <= z, ends[m:] >= -z]
    for _ in range(60):
        mid = (lo + hi) / 2
        zm = _tango_z(mid, b2, c2, n2)
        up = np.where(lower, zm > z, ~(zm < -z))  # the end lies above mid
        lo, hi = np.where(up, mid, lo), np.where(up, hi, mid)
    low = np.where(at_edge[:m], -1.0, hi[:m])
    high = np.where(at_edge[m:], 1.0, lo[m:])
    return np.where(ok, low, np.nan), np.where(ok, high, np.nan)


def _tango_z_one(delta: float, b: float, c: float, n: float) -> float:
    """:func:`_tango_z` of one table in Python floats: the same operations in the same
    order (IEEE doubles both), so the same bits, without numpy's cost per call."""
    A = 2 * n
    B = -b - c + (2 * n - b + c) * delta
    C = -c * delta * (1 - delta)
    p01 = (math.sqrt(max(B * B - 4 * A * C, 0.0)) - B) / (2 * A)
    var = n * (2 * p01 + delta * (1 - delta))
    num = b - c - n * delta
    if var > 1e-15:
        return num / math.sqrt(var)
    return 0.0 if abs(num) < 1e-12 else math.copysign(math.inf, num)


def _tango_interval_one(b: float, c: float, n: float, z: float) -> tuple[float, float]:
    """:func:`tango_interval` of one table (the same bisection, step for step)."""
    if not n > 0:
        return math.nan, math.nan
    est = (b - c) / n
    lo, hi = -1.0, est
    at_edge = _tango_z_one(lo, b, c, n) <= z
    for _ in range(60):
        mid = (lo + hi) / 2
        if _tango_z_one(mid, b, c, n) > z:
            lo = mid
        else:
            hi = mid
    low = -1.0 if at_edge else hi
    lo, hi = est, 1.0
    at_edge = _tango_z_one(hi, b, c, n) >= -z
    for _ in range(60):
        mid = (lo + hi) / 2
        if _tango_z_one(mid, b, c, n) < -z:
            hi = mid
        else:
            lo = mid
    return low, 1.0 if at_edge else lo


def tango_band(only_a: np.ndarray, only_b: np.ndarray, level: float,
               rng: np.random.Generator, n_resamples: int) -> tuple[np.ndarray, np.ndarray]:
    """A simultaneous band over k paired differences (the module docstring's sup-score band).

    Args:
        only_a, only_b: (n, k) bool: pair i shows outcome j for A only / for B only.
        level: joint level.
        rng: the random stream of the bootstrap of pairs.
        n_resamples: bootstrap resamples.

    Returns:
        (low, high), each (k,), holding all k differences at once with probability about
        ``level``; never narrower than the separate Tango intervals, never wider than the
        Sidak ones.
    """
    n, k = only_a.shape
    b, c = only_a.sum(0).astype(float), only_b.sum(0).astype(float)
    est = (b - c) / n
    weights = rng.multinomial(n, np.full(n, 1.0 / n), size=n_resamples).astype(float)
    bb, cb = weights @ only_a.astype(float), weights @ only_b.astype(float)
    zb = np.abs(_tango_z(np.broadcast_to(est, bb.shape), bb, cb, np.full(bb.shape, float(n))))
    z_star = float(np.quantile(np.nan_to_num(zb.max(axis=1), posinf=1e9), level))
    z_star = min(max(z_star, z_value(level)), z_value(sidak_level(level, k)))
    return tango_interval(b, c, np.full(k, n), level, z=z_star)


def _constant_bounds(value: float, n: int, level: float,
                     bounds: tuple[float, float] | None) -> tuple[float, float]:
    """The interval of a mean when all n values equal ``value`` (module docstring)."""
    if bounds is None:
        return float("nan"), float("nan")
    _, share = wilson_interval(0, n, level)  # largest share of other values
    lo_b, hi_b = bounds
    return value - (value - lo_b) * share, value + (hi_b - value) * share


def mean_interval(values, level: float, *, bounds: tuple[float, float] | None = None
                  ) -> tuple[float, float]:
    """Student's t interval of the mean of ``values`` (NaN values skipped).

    Also the interval of a paired mean difference: give the per-pair differences (and, for a
    bounded measure in [a, b], the bounds (a - b, b - a)).

    Args:
        values: (n,) sample.
        level: two-sided level.
        bounds: the values a measure can take: the interval stays inside them, and gives
            the all-equal case its width.

    Returns:
        (low, high); NaN with fewer than 2 values.
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    n = len(x)
    if n < 2:
        return float("nan"), float("nan")
    sd = float(np.std(x, ddof=1))
    mean = float(np.mean(x))
    if sd <= 1e-12 * max(1.0, abs(mean)):
        return _constant_bounds(mean, n, level, bounds)
    half = t_quantile(0.5 + level / 2, n - 1) * sd / math.sqrt(n)
    return _inside(mean - half, mean + half, bounds)


def _inside(low: float, high: float, bounds: tuple[float, float] | None
            ) -> tuple[float, float]:
    """An interval clipped to the values the statistic can take: a mean of a measure in
    [0, 10] never has an interval reaching 11 (a t interval is symmetric; the mean is not
    free to go beyond its bounds)."""
    if bounds is None:
        return low, high
    return max(low, bounds[0]), min(high, bounds[1])


def welch_interval(a, b, level: float, *, bounds: tuple[float, float] | None = None
                   ) -> tuple[float, float]:
    """Welch's t interval of ``mean(a) - mean(b)`` for independent samples (NaN skipped).

    Args:
        a, b: the two samples.
        level: two-sided level.
        bounds: the values the measure can take (for two constant samples).

    Returns:
        (low, high); NaN when a sample has fewer than 2 values.
    """
    xa = np.asarray(a, dtype=float)
    xb = np.asarray(b, dtype=float)
    xa, xb = xa[np.isfinite(xa)], xb[np.isfinite(xb)]
    na, nb = len(xa), len(xb)
    if na < 2 or nb < 2:
        return float("nan"), float("nan")
    va, vb = np.var(xa, ddof=1) / na, np.var(xb, ddof=1) / nb
    diff = float(xa.mean() - xb.mean())
    if va + vb <= 1e-24:
        if bounds is None:
            return float("nan"), float("nan")
        span = bounds[1] - bounds[0]
        return (_constant_bounds(diff, min(na, nb), level, (diff - span, diff + span))
            if span > 0 else (diff, diff))
    df = (va + vb) ** 2 / (va * va / (na - 1) + vb * vb / (nb - 1))
    half = t_quantile(0.5 + level / 2, max(1, math.floor(df))) * math.sqrt(va + vb)
    span = None if bounds is None else (bounds[0] - bounds[1], bounds[1] - bounds[0])
    return _inside(diff - half, diff + half, span)


# -- by measure: the interval a measure's entry calls for ---------------------------------------

def measure_interval(measure: Measure, values, level: float) -> tuple[float, float]:
    """The interval of the mean of one measure over episodes, as its entry says: Wilson's
    for a rate (values 0 or 1), Student's t bounded by its bounds otherwise.

    Args:
        measure: the measure's entry (its ``kind`` and ``bounds`` are read).
        values: (n,) per-episode values (NaN skipped).
        level: two-sided level.
    """
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if measure.is_rate:
        return wilson_interval(int(x.sum()), len(x), level)
    return mean_interval(x, level, bounds=measure.bounds)


def _span(bounds: tuple[float, float] | None) -> tuple[float, float] | None:
    """The values a difference of two bounded values can take."""
    return None if bounds is None else (bounds[0] - bounds[1], bounds[1] - bounds[0])


def paired_measure_interval(measure: Measure, a, b, level: float) -> tuple[float, float]:
    """The interval of the mean paired difference ``a - b`` of one measure (pairs: the same
    seed): Tango's score interval for a rate, Student's t of the differences otherwise.

    Args:
        measure: the measure's entry.
        a, b: (n,) per-pair values, without NaN.
        level: two-sided level.
    """
    va, vb = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if measure.is_rate:
        return tango_interval(int(((va > 0) & (vb == 0)).sum()),
                              int(((va == 0) & (vb > 0)).sum()), len(va), level)
    return mean_interval(va - vb, level, bounds=_span(measure.bounds))


def unpaired_measure_interval(measure: Measure, a, b, level: float) -> tuple[float, float]:
    """The interval of ``mean(a) - mean(b)`` of one measure for independent samples:
    Newcombe's hybrid score interval for a rate, Welch's t otherwise.

    Args:
        measure: the measure's entry.
        a, b: the two samples, without NaN.
        level: two-sided level.
    """
    xa, xb = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if measure.is_rate:
        return newcombe_interval(int(xa.sum()), len(xa), int(xb.sum()), len(xb), level)
    return welch_interval(xa, xb, level, bounds=measure.bounds)


def studentized_interval(estimate: np.ndarray, se: np.ndarray, draws: np.ndarray,
                         draw_se: np.ndarray, centre: np.ndarray, level: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """The studentized bootstrap (bootstrap-t) interval (Efron & Tibshirani 1993 ch. 12;
    Davison & Hinkley 1997 section 5.2.1).

    In each draw from the bootstrap population the truth is known (``centre``, e.g. the
    population's Hill numbers, :func:`~tap_bench.bench.scores.diversity.population_hill`),
    so ``t* = (draw - centre) / draw_se`` is a draw of the estimator's studentized error;
    the interval is ``estimate - t*_(1-a/2) se .. estimate - t*_(a/2) se``. Unlike
    ``estimate +- z sd`` it follows an error whose spread grows with the estimate (few
    singletons: a low richness with a narrow bootstrap spread), a skewed error, and the
    estimator's bias (the Jensen bias of q = 1, 2 at small n; the population's own value
    differs from the sample's).

    Args:
        estimate, se: (k,) the sample's values and standard errors.
        draws, draw_se: (B, k) the statistic and its standard error in each draw.
        centre: (k,) the statistic's value in the population.
        level: two-sided level.

    Returns:
        (low (k,), high (k,)); NaN where a standard error is 0 or not finite.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (np.asarray(draws, float) - centre) / draw_se
    alpha = 1 - level
    ok = np.isfinite(se) & (se > 0)
    t = np.nan_to_num(t, nan=0.0, posinf=1e6, neginf=-1e6)  # a draw with se 0: extreme
    lo_q, hi_q = np.quantile(t, [alpha / 2, 1 - alpha / 2], axis=0)
    return (np.where(ok, estimate - hi_q * se, np.nan),
            np.where(ok, estimate - lo_q * se, np.nan))

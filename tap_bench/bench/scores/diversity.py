"""Behaviour diversity: Hill numbers of a policy's ego labels, compared at a common sample
size, with sample completeness beside them (Chao et al. 2014; Hsieh, Ma & Chao 2016, the
iNEXT method).

Each episode gives one ego SDL label, so a policy's labels are **abundance data**: label i
was seen X_i times in n episodes. The Hill number of order q is the effective number of
labels: q = 0 counts distinct labels (richness), q = 1 is exp(Shannon entropy), q = 2 the
inverse Simpson concentration. A sample's Hill numbers grow with n, so policies are compared
at a **common sample size** m (default: the smallest n among the policies of an env, the
iNEXT ``estimateD`` default): below n by rarefaction (the expected value of a random
subsample of m episodes), above n by extrapolation:

==========  ===================================================  ============================
order       m < n (interpolation)                                m > n (extrapolation)
==========  ===================================================  ============================
q = 0       sum_i 1 - C(n - X_i, m) / C(n, m)                     S_obs + f0 (1 - A^(m - n)),
                                                                  A = n f0 / (n f0 + f1)
q = 1       exp(-sum_k k/m log(k/m) f_k(m)),                      D_n + (D_hat - D_n)
            f_k(m) = sum_i C(X_i, k) C(n - X_i, m - k) / C(n, m)  (1 - (1 - A1)^(m - n))
q = 2       1 / (1/m + (1 - 1/m) sum_i X_i (X_i - 1) / (n (n - 1)))   (the same)
==========  ===================================================  ============================

with f1, f2 the labels seen once and twice, f0 the Chao1 estimate of unseen labels
(``(n-1)/n f1^2 / (2 f2)``, or ``(n-1)/n f1 (f1-1) / 2`` when f2 = 0), D_hat the Chao et al.
(2013) entropy estimator and A1 = 2 f2 / ((n-1) f1 + 2 f2) (iNEXT's ``Dqhat.Ind``). At m = n
the three are the sample's own values. **Sample completeness** ``C_n = 1 - f1/n * A`` is
the estimated share of the policy's label distribution (by probability) that the sample
has already shown (Chao & Jost 2012).

**Asymptotes and "at least".** The asymptotic Hill numbers (Chao1 for q = 0, exp of the
Chao 2013 entropy for q = 1, the unbiased inverse Simpson for q = 2) estimate the
diversity of the policy's whole label distribution. They rest on f1 and f2, and when the
completeness is below :data:`MIN_COMPLETENESS` (most of the next episode's probability is on
labels not seen yet: 12 distinct labels in 12 episodes have C_n = 0.015) they are not
estimable: the table then holds the sample's value flagged ``asymptote_is_bound`` and the
report prints "at least ...". An extrapolation beyond twice the sample (m > 2 n, where
Chao et al. 2014 found it unreliable) or from a sample below that completeness is flagged
the same way.

**What the Hill numbers at m estimate** (Chao et al. 2014's qD(m),
:func:`population_hill`): the Hill number of the *expected* label-frequency profile of m
episodes: ``sum_i 1 - (1 - p_i)^m`` for q = 0 (the expected number of distinct labels),
``exp(E[H_m])`` for q = 1 (H_m the plug-in entropy of m episodes) and ``1 / (1/m + (1 - 1/m)
sum_i p_i^2)`` for q = 2. For q = 1, 2 this is not the mean of the sample's own Hill number
(Jensen: 10 episodes of a 30-label Zipf(1.2) distribution give q2 4.84 on average for an
estimand of 4.32); the intervals are for this estimand.

**Intervals: the studentized bootstrap from iNEXT's population.** The detected labels'
probabilities are shrunk and the f0 undetected labels are given the Good-Turing undetected
mass (:func:`estimated_population`, iNEXT's ``EstiBootComm``); ``n_resamples`` samples of n
episodes are drawn from it. iNEXT's own interval, ``estimate +- z sd`` over the draws,
covers less than its level at 10 to 100 episodes (``benchmarks/interval_coverage.py``;
figures in docs/benchmark.md), for three reasons: the sd is too small when the sample
shows few singletons, which is also when the estimate is low (the bootstrap sd grows with
the estimate, so the misses pile up on one side); the error is skewed; and q = 1, 2 are
biased at small n. The interval here is the **studentized bootstrap** (bootstrap-t; Efron &
Tibshirani 1993 ch. 12, Davison & Hinkley 1997 5.2.1,
:func:`~tap_bench.stats.intervals.studentized_interval`): in each draw the truth is the
population's own value (:func:`population_hill`; for completeness the draw's coverage),
``t* = (draw - truth) / se*`` with se* the draw's own standard error, and the interval is
``estimate - t*_hi se .. estimate - t*_lo se``. The standard errors (:func:`hill_variance`,
:func:`completeness_se`): for q = 0 the variance of the distinct count under the sample's
own iNEXT population (:func:`distinct_variance`), for q = 1, 2 the delta method's, for
completeness Esty's (1983), each floored at one episode's worth. Hill-number intervals are
clipped to [1, m], completeness to [0, 1]; a bias-corrected interval need not be centred
on the estimate.
A sample whose population has nothing undetected (no label seen once) gives draws that
cannot move; the interval is then +- n u for the Hill numbers and - u for completeness, u
the Wilson upper limit of 0 of n (at most that share of episodes could show a label not
seen yet), never a point. Measured coverage: docs/benchmark.md.

**Order.** A distribution's Hill numbers never rise with q (q0 >= q1 >= q2). Their
estimates can: at m > n a sample with no singletons gets q0 = S_obs while the inverse
Simpson's unbiased form keeps growing (roundabout IDM: q0 6.1 < q1 7.3 < q2 9.4). An
estimate at m that breaks the order is flagged (``hill_order_broken``) and the intervals of
each pair out of order are widened to their union (each then holds the other's estimate:
the data cannot tell them apart); asymptotes out of order are not reported (NaN, flagged
``asymptote_order_broken``), since they carry no interval to widen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tap_bench.errors import ParameterError
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.stats.intervals import studentized_interval, wilson_interval, z_value

if TYPE_CHECKING:
    import pandas as pd

__all__ = [
    "MIN_COMPLETENESS",
    "DiversityResult",
    "asymptotic_hill",
    "completeness",
    "completeness_se",
    "distinct_variance",
    "diversity",
    "diversity_table",
    "estimated_population",
    "hill_numbers",
    "hill_variance",
    "in_order",
    "pooled_diversity",
    "population_hill",
]

MIN_COMPLETENESS = 0.5
"""Below this sample completeness the asymptotic Hill numbers (and extrapolations) are
reported as "at least" the sample's value: more than half of the next episode's probability
lies on labels the sample has not shown, and Chao1's f1^2 / (2 f2) then rests on a handful
of doubletons."""

ORDERS = (0, 1, 2)


def _chao1_f0(f1: np.ndarray, f2: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Chao1's undetected count f0 (bias-corrected form when f2 = 0)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(f2 > 0, (n - 1) / n * f1 * f1 / (2 * np.maximum(f2, 1)),
                        (n - 1) / n * f1 * (f1 - 1) / 2)


def estimated_population(freq: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """iNEXT's bootstrap population: adjusted probabilities of the detected items and of the
    undetected ones (``EstiBootComm.Ind`` and ``EstiBootComm.Sam``).

    Args:
        freq: (k,) how many of the n sampling units show each detected item: for abundance
            data (one label per episode) the label counts, summing to n; for incidence data
            (an episode shows several vocabulary items) the number of episodes showing each
            item, each at most n.
        n: sampling units (episodes). The undetected mass is ``f1 / n * A`` with n the
            number of **sampling units** in both cases (not the total of ``freq``, which
            for incidence data counts incidences).

    Returns:
        (p_detected (k,), p_undetected (ceil f0,)): relative abundances (abundance data, in
        all summing to about 1) or detection probabilities per unit (incidence data).
    """
    freq = np.asarray(freq, dtype=float)
    freq = freq[freq > 0]
    if n <= 0 or not len(freq):
        return np.zeros(0), np.zeros(0)
    f1, f2 = float((freq == 1).sum()), float((freq == 2).sum())
    f0 = float(_chao1_f0(np.array(f1), np.array(f2), np.array(float(n))))
    A = n * f0 / (n * f0 + f1) if f1 > 0 else 1.0
    a = f1 / n * A  # the undetected mass (Good-Turing, shrunk by A)
    p = freq / n
    b = float((p * (1 - p) ** n).sum())
    w = a / b if f0 > 0 and b > 0 else 0.0
    p_detected = p * (1 - w * (1 - p) ** n)
    k0 = math.ceil(f0 - 1e-9)
    p_undetected = np.full(k0, a / k0) if k0 > 0 else np.zeros(0)
    return p_detected, p_undetected


def _log_factorials(n: int) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(np.log(np.arange(1, n + 1)))])


def _log_choose(lf: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """log C(a, b) elementwise; -inf where b < 0 or b > a."""
    a = np.asarray(a, dtype=np.int64)
    b = np.asarray(b, dtype=np.int64)
    bad = (b < 0) | (b > a)
    safe_a, safe_b = np.where(bad, 0, a), np.where(bad, 0, b)
    out = lf[safe_a] - lf[safe_b] - lf[safe_a - safe_b]
    return np.where(bad, -np.inf, out)


def _entropy_estimate(counts: np.ndarray, n: int) -> np.ndarray:
    """(B,) Chao et al. (2013) entropy estimator [nats] of each row of (B, S) counts."""
    x = counts.astype(float)
    harmonic = np.concatenate([[0.0], np.cumsum(1.0 / np.arange(1, n + 1))])
    xi = counts.astype(np.int64)
    # sum over 1 <= X_i <= n - 1 of X_i/n (psi(n) - psi(X_i)) = X_i/n (H_{n-1} - H_{X_i - 1})
    term = np.where((xi >= 1) & (xi <= n - 1),
                    x / n * (harmonic[n - 1] - harmonic[np.maximum(xi - 1, 0)]), 0.0)
    ue = term.sum(axis=1)
    f1 = (xi == 1).sum(axis=1).astype(float)
    f2 = (xi == 2).sum(axis=1).astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        A = np.where(f2 > 0, 2 * f2 / ((n - 1) * f1 + 2 * f2), 2 / ((n - 1) * f1 + 2))
    A = np.where(f1 > 0, A, 1.0)
    r = np.arange(1, n)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tail = ((1 - A[:, None]) ** r[None, :] / r[None, :]).sum(axis=1)
        extra = f1 / n * (1 - A) ** (1 - n) * (-np.log(A) - tail)
    extra = np.where((A < 1) & (f1 > 0), extra, 0.0)
    return ue + np.nan_to_num(extra, nan=0.0, posinf=0.0)


def hill_numbers(counts: np.ndarray, size: int) -> np.ndarray:
    """Hill numbers of order 0, 1, 2 at sample size ``size`` (module docstring's table).

    Args:
        counts: (S,) label counts of one sample, or (B, S) of B samples with equal totals n
            (zeros allowed).
        size: the sample size m (>= 1) to rarefy (m < n) or extrapolate (m > n) to.

    Returns:
        (3,) or (B, 3): the expected numbers of effective labels at m.
    """
    counts = np.asarray(counts)
    single = counts.ndim == 1
    x = np.atleast_2d(counts).astype(np.int64)
    n = int(x[0].sum())
    m = int(size)
    if n == 0 or m < 1:
        out = np.full((len(x), 3), np.nan)
        return out[0] if single else out
    xf = x.astype(float)
    present = x > 0
    s_obs = present.sum(axis=1).astype(float)
    f1 = (x == 1).sum(axis=1).astype(float)
    f2 = (x == 2).sum(axis=1).astype(float)
    simpson = (xf * (xf - 1)).sum(axis=1) / (n * (n - 1)) if n > 1 else np.zeros(len(x))
    q2 = 1.0 / (1.0 / m + (1 - 1.0 / m) * simpson)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = np.where(present, xf / n, 1.0)
        d1_n = np.exp(-(np.where(present, p * np.log(p), 0.0)).sum(axis=1))
    if m < n:
        lf = _log_factorials(n)
        q0 = np.where(present, 1 - np.exp(_log_choose(lf, n - x, m) - _log_choose(
            lf, np.array(n), np.array(m))), 0.0).sum(axis=1)  # absent labels add nothing
        k = np.arange(1, m + 1)
        log_cnm = _log_choose(lf, np.array(n), np.array(m))
        # f_k(m) for every row and k: sum over labels of C(X_i, k) C(n - X_i, m - k) / C(n, m)
        logs = (_log_choose(lf, x[:, :, None], k[None, None, :])
                + _log_choose(lf, (n - x)[:, :, None], (m - k)[None, None, :]) - log_cnm)
        fk = np.where(present[:, :, None], np.exp(logs), 0.0).sum(axis=1)
        q1 = np.exp(-(k / m * np.log(k / m) * fk).sum(axis=1))
    elif m == n:
        q0, q1 = s_obs, d1_n
    else:
        f0 = _chao1_f0(f1, f2, np.full(len(x), float(n)))
        with np.errstate(divide="ignore", invalid="ignore"):
            A0 = np.where(f1 > 0, n * f0 / (n * f0 + f1), 0.0)
        q0 = np.where(f1 > 0, s_obs + f0 * (1 - A0 ** (m - n)), s_obs)
        d_hat = np.exp(_entropy_estimate(x, n))
        with np.errstate(divide="ignore", invalid="ignore"):
            A1 = np.where(f2 > 0, 2 * f2 / ((n - 1) * f1 + 2 * f2), 2 / ((n - 1) * f1 + 2))
        A1 = np.where(f1 > 0, A1, 1.0)
        q1 = d1_n + (d_hat - d1_n) * (1 - (1 - A1) ** (m - n))
    out = np.column_stack([q0, q1, q2])
    return out[0] if single else out


def completeness(counts: np.ndarray) -> np.ndarray | float:
    """Sample completeness ``1 - f1/n * A`` of a sample (or of each row of (B, S) counts)."""
    counts = np.asarray(counts)
    x = np.atleast_2d(counts)
    n = x[0].sum()
    if n == 0:
        return float("nan") if counts.ndim == 1 else np.full(len(x), np.nan)
    f1 = (x == 1).sum(axis=1).astype(float)
    f2 = (x == 2).sum(axis=1).astype(float)
    f0 = _chao1_f0(f1, f2, np.full(len(x), float(n)))
    with np.errstate(divide="ignore", invalid="ignore"):
        A = np.where(f1 > 0, n * f0 / (n * f0 + f1), 1.0)
    out = 1 - f1 / n * np.nan_to_num(A, nan=1.0)
    return float(out[0]) if counts.ndim == 1 else out


def asymptotic_hill(counts: np.ndarray) -> np.ndarray:
    """(3,) asymptotic Hill numbers of a sample: Chao1, exp(Chao 2013 entropy), and the
    unbiased inverse Simpson (inf when no label was seen twice)."""
    x = np.asarray(counts, dtype=np.int64)
    x = x[x > 0]
    n = int(x.sum())
    if n == 0:
        return np.full(3, np.nan)
    f1, f2 = float((x == 1).sum()), float((x == 2).sum())
    q0 = len(x) + float(_chao1_f0(np.array(f1), np.array(f2), np.array(float(n))))
    q1 = float(np.exp(_entropy_estimate(x[None, :], n)[0]))
    s = float((x * (x - 1)).sum()) / (n * (n - 1)) if n > 1 else 0.0
    q2 = 1.0 / s if s > 0 else float("inf")
    return np.array([q0, q1, q2])


def population_hill(prob: np.ndarray, size: int) -> np.ndarray:
    """(3,) the Hill numbers q = 0, 1, 2 at sample size m of a known label distribution:
    what :func:`hill_numbers` estimates (Chao et al. 2014's qD(m), the Hill number of the
    expected label-frequency profile of m episodes).

    q0 = sum_i 1 - (1 - p_i)^m (the expected distinct labels), q1 = exp(E[H_m]) with H_m
    the plug-in entropy of m episodes, q2 = 1 / (1/m + (1 - 1/m) sum_i p_i^2).

    Args:
        prob: (S,) label probabilities (summing to 1; zeros allowed).
        size: m >= 1 episodes.
    """
    p = np.asarray(prob, dtype=float)
    p = p[p > 0]
    m = int(size)
    q0 = float(np.sum(1 - (1 - p) ** m))
    lf = _log_factorials(m)
    k = np.arange(1, m + 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        rest = (m - k)[None, :] * np.log1p(-np.minimum(p, 1.0))[:, None]
        rest = np.where((m - k)[None, :] == 0, 0.0, rest)  # p = 1: 0 * log 0 is 0
        log_pmf = (lf[m] - lf[k] - lf[m - k])[None, :] + k[None, :] * np.log(p)[:, None] + rest
    pmf = np.exp(np.where(np.isfinite(log_pmf), log_pmf, -np.inf))
    h = -float((pmf * (k / m * np.log(k / m))[None, :]).sum())
    q2 = 1.0 / (1.0 / m + (1 - 1.0 / m) * float(np.sum(p * p)))
    return np.array([q0, math.exp(h), q2])


def distinct_variance(counts: np.ndarray, n: int, *, weights: np.ndarray | None = None,
                      undetected_weight: float = 1.0,
                      max_undetected: np.ndarray | None = None) -> np.ndarray:
    """The variance of a (weighted) count of distinct items shown by n sampling units, under
    each sample's own bootstrap population (:func:`estimated_population`): the standard
    error that studentizes the richness-type statistics (module docstring).

    ``sum_i w_i q_i (1 - q_i)`` over the population's items, q_i = 1 - (1 - p_i)^n the
    chance that item i is shown (items taken as independent: the multinomial's small
    negative covariances are left out, which errs on the wide side).

    Args:
        counts: (S,) or (B, S) detections per item of one sample or of B samples (zeros
            allowed: the item is not in that sample).
        n: sampling units of each sample.
        weights: (S,) each item's weight w_i (default 1: the distinct count).
        undetected_weight: the weight of each undetected item of the population.
        max_undetected: (B,) at most this many undetected items count (a reference's
            unseen items); default no limit.

    Returns:
        (B,) or a float: the variances.
    """
    x = np.atleast_2d(np.asarray(counts, dtype=float))
    w_item = np.ones(x.shape[1]) if weights is None else np.asarray(weights, float)
    f1 = (x == 1).sum(axis=1).astype(float)
    f2 = (x == 2).sum(axis=1).astype(float)
    f0 = _chao1_f0(f1, f2, np.full(len(x), float(n)))
    with np.errstate(divide="ignore", invalid="ignore"):
        A = np.where(f1 > 0, n * f0 / (n * f0 + f1), 1.0)
        a = np.where(f1 > 0, f1 / n * A, 0.0)
        p = x / n
        b = (p * (1 - p) ** n).sum(axis=1)
        shrink = np.where((f0 > 0) & (b > 0), a / b, 0.0)
    p_det = p * (1 - shrink[:, None] * (1 - p) ** n)
    q = 1 - (1 - np.clip(p_det, 0.0, 1.0)) ** n
    var = (np.where(x > 0, q * (1 - q), 0.0) * w_item * w_item).sum(axis=1)
    k0 = np.where(f1 > 0, np.ceil(f0 - 1e-9), 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        q_und = 1 - (1 - np.where(k0 > 0, a / np.maximum(k0, 1), 0.0)) ** n
    if max_undetected is not None:
        k0 = np.minimum(k0, max_undetected)
    var = var + k0 * undetected_weight ** 2 * q_und * (1 - q_und)
    return var if np.ndim(counts) == 2 else float(var[0])


def hill_variance(counts: np.ndarray, n: int, hill: np.ndarray) -> np.ndarray:
    """(3,) or (B, 3) variances that studentize the Hill numbers ``hill`` (at any m) of
    samples of n episodes: q = 0 the distinct count's (:func:`distinct_variance`); q = 1
    the delta method's ``D^2 (sum p log^2 p - H^2) / n``; q = 2 ``D^4 (1 - 1/m)^2 4 (sum
    p^3 - (sum p^2)^2) / n``, p the sample's relative frequencies. Each is floored at
    ``(D / n)^2`` (one episode's worth), since a sample of distinct labels gives the delta
    method 0.

    Args:
        counts: (S,) or (B, S) label counts (totals n).
        n: episodes.
        hill: (3,) or (B, 3) the Hill numbers being studentized.
    """
    x = np.atleast_2d(np.asarray(counts, dtype=float))
    d = np.atleast_2d(np.asarray(hill, dtype=float))
    p = x / n
    with np.errstate(divide="ignore", invalid="ignore"):
        log_p = np.where(x > 0, np.log(np.where(x > 0, p, 1.0)), 0.0)
    h = -(p * log_p).sum(axis=1)
    v1 = np.maximum((p * log_p ** 2).sum(axis=1) - h * h, 0.0) / n * d[:, 1] ** 2
    s2 = (p * p).sum(axis=1)
    v2 = 4 * np.maximum((p ** 3).sum(axis=1) - s2 * s2, 0.0) / n * d[:, 2] ** 4
    var = np.column_stack([distinct_variance(x, n), v1, v2])
    var = np.maximum(var, (d / n) ** 2)
    return var if np.ndim(counts) == 2 else var[0]


def completeness_se(counts: np.ndarray) -> np.ndarray | float:
    """Esty's (1983) standard error of the sample completeness's error Ĉ - C, from his
    normal limit law for the Good-Turing coverage estimator (C is the sample's own
    coverage, itself random): ``sqrt(f1 (1 - f1/n) + 2 f2) / n``, floored at ``1 / n``
    (one singleton's worth; 0 when nothing was seen once or twice).

    Args:
        counts: (S,) or (B, S) label counts (totals n).

    Returns:
        a float, or (B,).
    """
    x = np.atleast_2d(np.asarray(counts))
    n = float(x[0].sum())
    if n == 0:
        return float("nan") if np.ndim(counts) == 1 else np.full(len(x), np.nan)
    f1 = (x == 1).sum(axis=1).astype(float)
    f2 = (x == 2).sum(axis=1).astype(float)
    se = np.maximum(np.sqrt(np.maximum(f1 * (1 - f1 / n) + 2 * f2, 0.0)), 1.0) / n
    return float(se[0]) if np.ndim(counts) == 1 else se


@dataclass(frozen=True)
class DiversityResult:
    """The diversity of one policy's labels (module docstring).

    Attributes:
        n: episodes with a label.
        n_distinct: distinct labels.
        size: the common sample size m the Hill numbers are given at.
        method: ``"interpolated"`` (m < n), ``"observed"`` (m = n) or ``"extrapolated"``.
        hill: (3,) Hill numbers q = 0, 1, 2 at m; hill_low, hill_high: their intervals.
        hill_is_bound: the values at m are lower bounds (an unreliable extrapolation).
        completeness, completeness_low, completeness_high: sample completeness at n.
        asymptote: (3,) asymptotic Hill numbers, or the sample's values when
            ``asymptote_is_bound``.
        asymptote_is_bound: completeness below :data:`MIN_COMPLETENESS`: "at least".
        hill_order_broken: the estimates at m rise with q somewhere; the intervals of the
            pairs out of order are their union (module docstring, Order).
        asymptote_order_broken: the asymptotes rose with q; those out of order are NaN.
        draws: (B, 4) the bootstrap draws of (q0, q1, q2 at m, completeness's error), for
            pooling.
        centre: (3,) the Hill numbers at m of the bootstrap population (the draws' truth).
        se: (4,) the standard errors that studentize (q0, q1, q2, completeness);
        draws_se: (B, 4) the same in each draw (pooling).
    """

    n: int
    n_distinct: int
    size: int
    method: str
    hill: np.ndarray
    hill_low: np.ndarray
    hill_high: np.ndarray
    hill_is_bound: bool
    completeness: float
    completeness_low: float
    completeness_high: float
    asymptote: np.ndarray
    asymptote_is_bound: bool
    draws: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 4)))
    hill_order_broken: bool = False
    asymptote_order_broken: bool = False
    centre: np.ndarray = field(repr=False, default_factory=lambda: np.full(3, np.nan))
    se: np.ndarray = field(repr=False, default_factory=lambda: np.full(4, np.nan))
    draws_se: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 4)))

    def row(self) -> dict:
        """The scalar fields as a dict (a row of the diversity table)."""
        out: dict = {"n": self.n, "n_distinct": self.n_distinct, "size": self.size,
                     "method": self.method}
        for j, q in enumerate(ORDERS):
            out[f"hill_q{q}"] = float(self.hill[j])
            out[f"hill_q{q}_low"] = float(self.hill_low[j])
            out[f"hill_q{q}_high"] = float(self.hill_high[j])
        out["hill_is_bound"] = self.hill_is_bound
        out["completeness"] = self.completeness
        out["completeness_low"] = self.completeness_low
        out["completeness_high"] = self.completeness_high
        for j, q in enumerate(ORDERS):
            out[f"asymptote_q{q}"] = float(self.asymptote[j])
        out["asymptote_is_bound"] = self.asymptote_is_bound
        out["hill_order_broken"] = self.hill_order_broken
        out["asymptote_order_broken"] = self.asymptote_order_broken
        return out


def in_order(hill: np.ndarray, low: np.ndarray, high: np.ndarray
             ) -> tuple[np.ndarray, np.ndarray, bool]:
    """(low, high, broken): Hill-number estimates (q0, q1, q2) that rise with q somewhere
    (beyond rounding) have the intervals of each pair out of order widened to their union;
    ``broken`` says so. NaN bounds (a one-sided "at least") are left as they are."""
    low, high = np.array(low, float), np.array(high, float)
    broken = False
    for j in range(len(hill) - 1):
        if hill[j + 1] > hill[j] * (1 + 1e-9) + 1e-9:
            broken = True
            for bound, pick in ((low, np.fmin), (high, np.fmax)):
                both = pick(bound[j], bound[j + 1])
                if np.isfinite(bound[j]) and np.isfinite(bound[j + 1]):
                    bound[j] = bound[j + 1] = both
            # each interval holds both estimates
            for k in (j, j + 1):
                if np.isfinite(low[k]):
                    low[k] = min(low[k], hill[j], hill[j + 1])
                if np.isfinite(high[k]):
                    high[k] = max(high[k], hill[j], hill[j + 1])
    return low, high, broken


def _asymptote_in_order(asym: np.ndarray) -> tuple[np.ndarray, bool]:
    """Asymptotes with those out of order (rising with q) set to NaN, and whether any was."""
    asym = np.array(asym, float)
    bad = np.zeros(len(asym), bool)
    for j in range(len(asym) - 1):
        if asym[j + 1] > asym[j] * (1 + 1e-9) + 1e-9:
            bad[j] = bad[j + 1] = True
    asym[bad] = np.nan
    return asym, bool(bad.any())


def _empty(size: int) -> DiversityResult:
    nan3 = np.full(3, np.nan)
    return DiversityResult(0, 0, size, "observed", nan3, nan3, nan3, True, float("nan"),
                           float("nan"), float("nan"), nan3, True, np.full((0, 4), np.nan))


def diversity(labels, *, rng: np.random.Generator | None = None, size: int | None = None,
              config: BootstrapConfig | None = None) -> DiversityResult:
    """Hill numbers q = 0, 1, 2 of a policy's labels at a common sample size, completeness,
    asymptotes and intervals (module docstring).

    Args:
        labels: (n,) the policy's ego SDL labels, one per episode (NA dropped).
        size: the common sample size m; default n (the sample's own values).
        config: the level and bootstrap resamples (and the seed of the default stream).
        rng: the random stream the draws come from, named by the caller
            (``config.rng("diversity", env, policy)``);
            default ``config.rng("diversity")``.

    Returns:
        :class:`DiversityResult`.
    """
    config = config or BootstrapConfig()
    rng = config.rng("diversity") if rng is None else rng
    lab = np.asarray([v for v in labels if isinstance(v, str)], dtype=object)
    n = len(lab)
    if size is not None and (isinstance(size, bool) or not isinstance(size, int | np.integer)
                             or size < 1):
        raise ParameterError("size", size, "a positive integer (episodes)")
    m = int(size) if size is not None else n
    if n == 0:
        return _empty(m)
    _, counts = np.unique(lab.astype(str), return_counts=True)
    hill = hill_numbers(counts, m)
    comp = float(completeness(counts))
    p_det, p_und = estimated_population(counts, n)
    prob = np.r_[p_det, p_und]
    prob = prob / prob.sum()
    draws = rng.multinomial(n, prob, size=config.n_resamples)
    # completeness estimates the sample's own coverage (the probability of the labels it
    # shows), itself random: its error in a draw is the estimate minus that coverage
    shown = (draws > 0) @ prob
    boot = np.column_stack([hill_numbers(draws, m), completeness(draws) - shown])
    centre = population_hill(prob, m)
    se = np.r_[np.sqrt(hill_variance(counts, n, hill)), completeness_se(counts)]
    draws_se = np.column_stack([np.sqrt(hill_variance(draws, n, boot[:, :3])),
                                completeness_se(draws)])
    low, high = studentized_interval(np.r_[hill, comp], se, boot, draws_se,
                                     np.r_[centre, 0.0], config.level)
    _, u = wilson_interval(0, n, config.level)
    stuck = ~np.isfinite(low) | ~np.isfinite(high) | (high - low <= 0)
    if np.any(stuck):  # nothing undetected to draw: bound what n episodes can add
        low = np.where(stuck, np.r_[hill - n * u, comp - u], low)
        high = np.where(stuck, np.r_[hill + n * u, comp], high)
    comp_low, comp_high = max(0.0, float(low[3])), min(1.0, float(high[3]))
    low, high = np.maximum(low[:3], 1.0), np.minimum(high[:3], float(m))
    method = "interpolated" if m < n else "observed" if m == n else "extrapolated"
    reliable = comp >= MIN_COMPLETENESS
    hill_bound = method == "extrapolated" and (m > 2 * n or not reliable)
    if hill_bound:  # the sample's value, which the expected value at m > n is at least
        hill = hill_numbers(counts, n)
        low, high = hill.copy(), np.full(3, np.nan)
    asym = asymptotic_hill(counts) if reliable else hill_numbers(counts, n)
    low, high, broken = in_order(hill, low, high)
    asym, asym_broken = _asymptote_in_order(asym) if reliable else (asym, False)
    return DiversityResult(
        n=n, n_distinct=len(counts), size=m, method=method, hill=hill, hill_low=low,
        hill_high=high, hill_is_bound=bool(hill_bound), completeness=comp,
        completeness_low=comp_low, completeness_high=comp_high, asymptote=asym,
        asymptote_is_bound=not reliable, draws=boot, centre=centre,
        se=se, draws_se=draws_se, hill_order_broken=broken,
        asymptote_order_broken=asym_broken)


def pooled_diversity(results: list[DiversityResult], level: float) -> DiversityResult:
    """The mean over envs of per-env diversities (each env's figures at its own common
    size). Hill-number intervals: the studentized bootstrap
    (:func:`~tap_bench.stats.intervals.studentized_interval`) of the per-draw means of the
    envs' draws against the mean of their populations' values, with the envs' standard
    errors combined as for independent envs (``sqrt(sum se^2) / E``, per draw likewise);
    completeness: Esty's standard errors combined the same way."""
    results = [r for r in results if r.n > 0]
    if not results:
        return _empty(0)
    z = z_value(level)
    hill = np.mean([r.hill for r in results], axis=0)
    comp = float(np.mean([r.completeness for r in results]))
    draws = np.mean([r.draws for r in results], axis=0)
    centre = np.mean([r.centre for r in results], axis=0)
    e = len(results)
    se = np.sqrt(np.sum([r.se ** 2 for r in results], axis=0)) / e
    draws_se = np.sqrt(np.sum([r.draws_se ** 2 for r in results], axis=0)) / e
    low, high = studentized_interval(np.r_[hill, comp], se, draws, draws_se,
                                     np.r_[centre, 0.0], level)
    sd = np.nanstd(draws, axis=0)
    low = np.where(np.isfinite(low), low, np.r_[hill, comp] - z * sd)
    high = np.where(np.isfinite(high), high, np.r_[hill, comp] + z * sd)
    comp_low, comp_high = max(0.0, float(low[3])), min(1.0, float(high[3]))
    low, high = low[:3], high[:3]
    bound = any(r.hill_is_bound for r in results)
    if bound:
        low, high = hill.copy(), np.full(3, np.nan)
    methods = {r.method for r in results}
    low, high, broken = in_order(hill, np.maximum(low, 0.0), high)
    asym, asym_broken = _asymptote_in_order(np.mean([r.asymptote for r in results], axis=0))
    return DiversityResult(
        n=sum(r.n for r in results), n_distinct=sum(r.n_distinct for r in results),
        size=round(float(np.mean([r.size for r in results]))),
        method=methods.pop() if len(methods) == 1 else "mixed", hill=hill,
        hill_low=low, hill_high=high, hill_is_bound=bound,
        completeness=comp, completeness_low=comp_low, completeness_high=comp_high,
        asymptote=asym,
        asymptote_is_bound=any(r.asymptote_is_bound for r in results), draws=draws,
        centre=centre, se=se, draws_se=draws_se, hill_order_broken=broken,
        asymptote_order_broken=asym_broken or any(r.asymptote_order_broken for r in results))


def diversity_table(episodes: pd.DataFrame, config: BootstrapConfig,
                    size: int | None = None) -> pd.DataFrame:
    """Hill numbers of every policy's ego labels per env, at the env's common sample size
    (default: the smallest number of labelled episodes among the env's policies), and pooled
    (``env == "all"``: the mean of the per-env figures): a row of
    :meth:`DiversityResult.row` each, with env and policy. Streams ``("diversity", env,
    policy)``.

    Args:
        episodes: the episode table (failed and unlabelled episodes are left out).
        config: the level, resamples and seed.
        size: the common sample size of every env (default: as above).
    """
    import pandas as pd

    from tap_bench.bench.scores.compare import ALL_ENVS

    ok = episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()]
    rows, per_policy = [], {}
    for env, sub in ok.groupby("env", sort=True):
        n_of = sub.groupby("policy").size()
        m = size if size is not None else int(n_of.min())
        for policy in sorted(n_of.index):
            d = diversity(sub.loc[sub["policy"] == policy, "sdl"].to_numpy(object), size=m,
                          config=config, rng=config.rng("diversity", env, policy))
            per_policy.setdefault(policy, []).append(d)
            rows.append({"env": str(env), "policy": policy, **d.row()})
    if ok["env"].nunique() > 1:
        for policy, results in sorted(per_policy.items()):
            rows.append({"env": ALL_ENVS, "policy": policy,
                         **pooled_diversity(results, config.level).row()})
    return pd.DataFrame(rows)

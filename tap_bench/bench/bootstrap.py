"""Seeded, vectorised bootstrap intervals.

Every interval in :mod:`tap_bench.bench` comes from here, so the unit of resampling, the
method and the level are stated in one place:

- a **resampling weight matrix** ``W`` of shape (B, n): row b holds how often each of the n
  units (seeds, episodes, trajectories) was drawn in resample b. Each row sums to n, and to
  each stratum's size within a stratum when ``strata`` is given (a bootstrap stratified by
  env keeps every env's number of seeds). Any statistic that is a (weighted) mean of
  per-unit values is then one matrix product, ``W @ x / n``, for all B resamples at once;
  a paired comparison is the same product on per-seed differences.
- **percentile intervals** (Efron & Tibshirani 1993, ch. 13) of those resampled statistics,
  at ``level`` (0.95 by default), from ``n_resamples`` (2000) resamples drawn by
  ``numpy.random.default_rng(seed)``: the same seed gives the same interval.
- **simultaneous bands** over many statistics at once (per-label frequency differences):
  the max-|t| bootstrap band (Davison & Hinkley 1997, sec. 5.3 / "sup-t" bands), whose
  joint coverage is ``level`` rather than each interval's.

The tests check, on synthetic data with a known difference, that the intervals cover it at
about their nominal rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tap_bench.errors import ParameterError

__all__ = [
    "BootstrapConfig",
    "wilson_interval",
    "percentile_interval",
    "resample_weights",
    "simultaneous_band",
    "weighted_means",
]


@dataclass(frozen=True)
class BootstrapConfig:
    """How intervals are computed.

    Attributes:
        n_resamples: bootstrap resamples B (>= 100).
        level: two-sided confidence level in (0, 1), e.g. 0.95.
        seed: seed of ``numpy.random.default_rng``; the same seed gives the same intervals.
    """

    n_resamples: int = 2000
    level: float = 0.95
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.n_resamples, bool) or not isinstance(self.n_resamples, int) \
                or self.n_resamples < 100:
            raise ParameterError("n_resamples", self.n_resamples, "an integer >= 100")
        if not isinstance(self.level, float | int) or not 0.5 <= float(self.level) < 1:
            raise ParameterError("level", self.level, "a number in [0.5, 1), e.g. 0.95")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise ParameterError("seed", self.seed, "a non-negative integer")

    def rng(self, stream: int = 0) -> np.random.Generator:
        """A generator for one named use of the config (``stream``), so that two statistics
        computed from the same config do not share random numbers by accident."""
        return np.random.default_rng([self.seed, stream])

    def describe(self, unit: str) -> str:
        """One line for reports: method, level, resamples, seed and the unit resampled."""
        return (f"{self.level:.0%} percentile bootstrap intervals, {self.n_resamples} "
                f"resamples of {unit}, seed {self.seed}")


def resample_weights(n: int, config: BootstrapConfig, *, strata: np.ndarray | None = None,
                     stream: int = 0) -> np.ndarray:
    """The (B, n) matrix of how often each unit is drawn in each bootstrap resample.

    Args:
        n: number of units (seeds, episodes, trajectories).
        config: resamples and seed.
        strata: (n,) labels; when given, each resample draws, within every stratum, as many
            units as the stratum has (a stratified bootstrap).
        stream: which random stream of the config to use (see :meth:`BootstrapConfig.rng`).

    Returns:
        float64 array (B, n); each row sums to n (and to each stratum's size within it).
    """
    rng = config.rng(stream)
    B = config.n_resamples
    weights = np.zeros((B, n))
    if n == 0:
        return weights
    if strata is None:
        groups = [np.arange(n)]
    else:
        strata = np.asarray(strata)
        if strata.shape != (n,):
            raise ParameterError("strata", strata.shape, f"of shape ({n},)")
        _, codes = np.unique(strata, return_inverse=True)
        groups = [np.flatnonzero(codes == g) for g in range(codes.max() + 1)]
    offsets = (np.arange(B) * n)[:, None]
    for members in groups:
        draws = members[rng.integers(0, len(members), size=(B, len(members)))]
        weights += np.bincount((offsets + draws).ravel(), minlength=B * n).reshape(B, n)
    return weights


def weighted_means(weights: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Means of ``values`` under each resample's weights, skipping NaN values.

    Args:
        weights: (B, n) from :func:`resample_weights` (or a single (n,) row of ones for the
            estimate itself).
        values: (n,) or (n, k) per-unit values; NaN marks a unit without a value.

    Returns:
        (B,) or (B, k) (or () / (k,) for a 1-D ``weights``); NaN where a resample holds no
        unit with a value.
    """
    values = np.asarray(values, dtype=float)
    present = ~np.isnan(values)
    if present.all():
        return weights @ values / weights.sum(axis=-1, keepdims=values.ndim > 1)
    # sums and counts in one pass over the weights
    both = np.concatenate([np.where(present, values, 0.0), present.astype(float)], axis=-1) \
        if values.ndim > 1 else np.column_stack([np.where(present, values, 0.0), present])
    prod = weights @ both
    k = both.shape[-1] // 2
    with np.errstate(invalid="ignore", divide="ignore"):
        out = prod[..., :k] / prod[..., k:]
    return out if values.ndim > 1 else out[..., 0]


def percentile_interval(resampled: np.ndarray, level: float) -> tuple[np.ndarray, np.ndarray]:
    """Percentile interval of resampled statistics along axis 0 (NaN resamples skipped).

    Args:
        resampled: (B,) or (B, k) statistics of the bootstrap resamples.
        level: two-sided level, e.g. 0.95.

    Returns:
        (low, high), each of shape () or (k,); NaN where every resample is NaN.
    """
    alpha = (1.0 - level) / 2.0
    resampled = np.asarray(resampled, dtype=float)
    if resampled.ndim == 1:
        resampled = resampled[:, None]
        squeeze = True
    else:
        squeeze = False
    nan = np.isnan(resampled)
    if not nan.any():  # the common case, one vectorised call
        low, high = np.quantile(resampled, [alpha, 1 - alpha], axis=0)
    else:
        low = np.full(resampled.shape[1], np.nan)
        high = np.full(resampled.shape[1], np.nan)
        clean = ~nan.any(axis=0)
        if clean.any():
            low[clean], high[clean] = np.quantile(resampled[:, clean], [alpha, 1 - alpha],
                                                  axis=0)
        partial = ~clean & ~nan.all(axis=0)
        if partial.any():
            low[partial], high[partial] = np.nanquantile(resampled[:, partial],
                                                         [alpha, 1 - alpha], axis=0)
    if squeeze:
        return low[0], high[0]
    return low, high


def simultaneous_band(estimate: np.ndarray, resampled: np.ndarray, level: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """A max-|t| band that holds all k statistics at once with probability about ``level``.

    With se_j the bootstrap standard error of statistic j, the band is
    ``estimate_j +- q * se_j`` where q is the ``level`` quantile over resamples of
    ``max_j |resampled_bj - estimate_j| / se_j``. Statistics with se 0 (a label no resample
    moves) get a zero-width band.

    Args:
        estimate: (k,) the statistics on the data.
        resampled: (B, k) the statistics on the resamples.
        level: joint level, e.g. 0.95.

    Returns:
        (low, high), each (k,).
    """
    estimate = np.asarray(estimate, dtype=float)
    resampled = np.asarray(resampled, dtype=float)
    se = np.nanstd(resampled, axis=0)
    moving = se > 0
    if not moving.any():
        return estimate.copy(), estimate.copy()
    t = np.abs(resampled[:, moving] - estimate[moving]) / se[moving]
    q = float(np.nanquantile(np.nanmax(t, axis=1), level))
    return estimate - q * se, estimate + q * se


def wilson_interval(successes: int, n: int, level: float) -> tuple[float, float]:
    """Wilson score interval of a proportion (Wilson 1927).

    Used for a single rate such as a policy's collision rate, where the percentile bootstrap
    collapses to a zero-width interval when no episode (or every episode) crashed.

    Args:
        successes: count of events.
        n: trials (episodes).
        level: two-sided level, e.g. 0.95.

    Returns:
        (low, high) in [0, 1]; (nan, nan) when n is 0.
    """
    from statistics import NormalDist

    if n <= 0:
        return float("nan"), float("nan")
    z = NormalDist().inv_cdf(0.5 + level / 2)
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, float(centre - half)), min(1.0, float(centre + half))

"""The threshold objective J(Theta) of SPEC section 3, exact in O(log n) per evaluation.

For a partition holding the sorted samples x_l .. x_{r-1} (m = r - l of them), the sum of
all pairwise distances is::

    sum_{l <= i < j < r} (x_j - x_i) = sum_{i=l}^{r-1} (2i - l - r + 1) x_i
                                     = 2 (S2[r] - S2[l]) - (l + r - 1) (S1[r] - S1[l])

with prefix sums S1[k] = sum_{i<k} x_i and S2[k] = sum_{i<k} i x_i. A partition is a
contiguous range of the sorted array found by binary search, so each evaluation costs
O(log n). The two terms are of order n^2 |x| while their difference is of order m^2 times
the partition's spread, so plain float64 prefix sums lose up to 1e-5 relative at 233,000
samples. Here the prefix sums are double-double (a float64 pair hi + lo, built with
error-free transformations: Knuth's TwoSum on numpy's sequential cumulative sum and
Veltkamp's split for the products i x_i), and the difference is taken in double-double too,
which keeps mu_p to about 1e-15 relative.

mu_p = pairsum / C(m, 2), and J = sum over pairs of partitions (mu_p - mu_q)^2.
Thresholds that leave a partition with fewer than two samples, or that are out of order,
give J = +inf.
"""

from __future__ import annotations

import numpy as np

from tap_bench.errors import ParameterError

__all__ = ["SortedSamples"]

_SPLIT = 134217729.0  # 2^27 + 1, Veltkamp's splitter for float64


def _two_sum(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = a + b
    bb = s - a
    return s, (a - (s - bb)) + (b - bb)


def _quick_two_sum(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    s = a + b
    return s, b - (s - a)


def _split(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    c = _SPLIT * a
    hi = c - (c - a)
    return hi, a - hi


def _dd_add(ah, al, bh, bl):
    s, e = _two_sum(ah, bh)
    return _quick_two_sum(s, e + (al + bl))


def _dd_mul_small_int(ah, al, k):
    """(ah + al) * k for integers 0 <= k < 2^26 held as float64."""
    h, lo = _split(ah)
    p, e = _two_sum(h * k, lo * k)  # both products exact: 26 + 26 bits
    return _quick_two_sum(p, e + al * k)


def _dd_prefix(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Prefix sums P[k] = sum_{i<k} values_i as double-double, (n+1,) each."""
    hi = np.zeros(len(values) + 1)
    np.cumsum(values, out=hi[1:])  # numpy accumulates sequentially: hi[k+1] = fl(hi[k] + v_k)
    a, b, s = hi[1:-1], values[1:], hi[2:]
    bb = s - a
    err = (a - (s - bb)) + (b - bb)  # exact rounding error of each addition
    lo = np.zeros_like(hi)
    np.cumsum(err, out=lo[2:])
    return hi, lo


class SortedSamples:
    """One distribution's samples, sorted once, ready for exact partition statistics.

    Args:
        samples: (n,) float64 values (e.g. one-second mean speeds [m/s]).

    Attributes:
        x: (n,) sorted samples.
    """

    def __init__(self, samples: np.ndarray):
        x = np.sort(np.asarray(samples, dtype=np.float64))
        if not np.all(np.isfinite(x)):
            raise ParameterError("samples", "non-finite values", "",
                message="samples must be finite")
        if len(x) >= 2**26:
            raise ParameterError("samples", len(x), "",
                message="at most 2^26 samples per distribution")
        self.x = x
        i = np.arange(len(x), dtype=np.float64)
        self._s1 = _dd_prefix(x)
        xh, xl = _split(x)
        s2h = _dd_prefix(i * xh)  # i < 2^26 and xh has 26 bits: exact products
        s2l = _dd_prefix(i * xl)
        self._s2 = _dd_add(s2h[0], s2h[1], s2l[0], s2l[1])

    def __len__(self) -> int:
        return len(self.x)

    def bounds(self, thetas: np.ndarray) -> np.ndarray:
        """Partition edges: (K, d) thresholds -> (K, d + 2) indices 0, #(x <= theta_1), ..., n.

        Partition p holds x <= theta_p and x > theta_{p-1} (SPEC section 3's rules).
        """
        thetas = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
        k = thetas.shape[0]
        inner = np.searchsorted(self.x, thetas, side="right")
        return np.hstack([np.zeros((k, 1), dtype=np.int64), inner,
                          np.full((k, 1), len(self.x), dtype=np.int64)])

    def feasible(self, thetas: np.ndarray) -> np.ndarray:
        """(K,) bool: thresholds increasing and every partition holding two samples or more."""
        b = self.bounds(thetas)
        ordered = np.all(np.diff(np.atleast_2d(thetas), axis=1) > 0, axis=1)
        return ordered & np.all(np.diff(b, axis=1) >= 2, axis=1)

    def partition_stats(self, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sizes and mean pairwise distances mu_p of every partition.

        Args:
            thetas: (K, d) thresholds, each row increasing.

        Returns:
            (counts, mu): (K, d + 1) int64 and float64; mu is NaN where a partition holds
            fewer than two samples.
        """
        return self._stats(self.bounds(thetas))

    def _stats(self, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lo_idx, hi_idx = b[:, :-1], b[:, 1:]
        m = hi_idx - lo_idx
        s1h, s1l = self._s1
        s2h, s2l = self._s2
        d1h, d1l = _dd_add(s1h[hi_idx], s1l[hi_idx], -s1h[lo_idx], -s1l[lo_idx])
        d2h, d2l = _dd_add(s2h[hi_idx], s2l[hi_idx], -s2h[lo_idx], -s2l[lo_idx])
        coef = (lo_idx + hi_idx - 1).astype(np.float64)
        ph, pl = _dd_mul_small_int(d1h, d1l, np.maximum(coef, 0.0))
        ph = np.where(coef < 0, 0.0, ph)  # only for empty partitions at index 0
        pl = np.where(coef < 0, 0.0, pl)
        sh, sl = _dd_add(2.0 * d2h, 2.0 * d2l, -ph, -pl)
        pairsum = sh + sl
        pairs = m * (m - 1) / 2.0
        with np.errstate(invalid="ignore", divide="ignore"):
            mu = np.where(m >= 2, pairsum / pairs, np.nan)
        return m, mu

    def objective(self, thetas: np.ndarray) -> np.ndarray:
        """J for each row of ``thetas`` ((K, d) -> (K,)); +inf where a row is infeasible."""
        thetas = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
        if len(thetas) == 0:
            return np.zeros(0)
        ordered = np.all(np.diff(thetas, axis=1) > 0, axis=1)
        return np.where(ordered, self._objective(self.bounds(thetas)), np.inf)

    def objective_at_ranks(self, ranks: np.ndarray) -> np.ndarray:
        """J when the partitions end at the given split ranks ((K, d) ints in 1..n-1).

        Equal to :meth:`objective` at thresholds between x[r-1] and x[r] where those differ;
        no binary search needed.
        """
        ranks = np.atleast_2d(np.asarray(ranks, dtype=np.int64))
        k = len(ranks)
        b = np.hstack([np.zeros((k, 1), dtype=np.int64), ranks,
                       np.full((k, 1), len(self.x), dtype=np.int64)])
        return self._objective(b)

    def _objective(self, b: np.ndarray) -> np.ndarray:
        counts, mu = self._stats(b)
        # sum over pairs p < q of (mu_p - mu_q)^2 = P * sum_p (mu_p - mean mu)^2 (stable)
        centred = mu - np.nanmean(mu, axis=1, keepdims=True)
        j = mu.shape[1] * np.nansum(centred**2, axis=1)
        return np.where(np.all(counts >= 2, axis=1), j, np.inf)

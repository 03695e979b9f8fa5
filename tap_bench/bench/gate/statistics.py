"""The regression gate's test statistics, shared by the gate and its power.

:mod:`tap_bench.bench.gate.regression` tests a run against its baseline with these;
:mod:`tap_bench.bench.gate.power` computes how often the same rule fires. Both import this
module, so the gate imports the power module and never the other way round.
"""

from __future__ import annotations

import math

import numpy as np

from tap_bench.bench.measures import MEASURES

__all__ = ["direction", "hypergeom_tails", "is_rate", "tv"]


def direction(metric: str) -> int:
    """+1 when a higher value of ``metric`` is better (speed, TTC), -1 when lower is better
    (crashes, jerk), 0 for ``label_tv`` (a change of behaviour has no better side); read
    from the measure's registry entry."""
    if metric not in MEASURES:
        return 0
    return 1 if MEASURES[metric].higher_is_better else -1


def is_rate(metric: str) -> bool:
    """A measure whose values are 0 or 1 (its entry's kind is "rate")."""
    return metric in MEASURES and MEASURES[metric].is_rate


def hypergeom_tails(x: int, n_run: int, n_base: int, ones: int
                    ) -> tuple[float, float, float, float]:
    """Fisher's exact test: with ``ones`` of n_run + n_base values 1, P(X >= x), P(X <=
    x), P(X = its largest value) and P(X = its smallest) for X the ones among the run's
    n_run."""
    total = math.comb(n_run + n_base, n_run)
    lo, hi = max(0, ones - n_base), min(ones, n_run)
    pmf = {k: math.comb(ones, k) * math.comb(n_run + n_base - ones, n_run - k) / total
           for k in range(lo, hi + 1)}
    return (sum(v for k, v in pmf.items() if k >= x), sum(v for k, v in pmf.items()
                                                           if k <= x), pmf[hi], pmf[lo])


def tv(codes_b: np.ndarray, codes_r: np.ndarray, k: int) -> np.ndarray:
    """(F,) total variation distance between rows of two (F, n) code matrices (integer
    label codes in [0, k))."""
    F, nb = codes_b.shape
    nr = codes_r.shape[1]
    offsets = (np.arange(F) * k)[:, None]
    cb = np.bincount((offsets + codes_b).ravel(), minlength=F * k).reshape(F, k)
    cr = np.bincount((offsets + codes_r).ravel(), minlength=F * k).reshape(F, k)
    return 0.5 * np.abs(cb / nb - cr / nr).sum(axis=1)

"""The regression gate's power: the smallest change of each metric it can detect at a
suite's seed count, and the seeds a margin needs.

For a metric of one (env, policy) with per-episode standard deviation sd over n seeds, the
gate fires on a change d when d exceeds the margin and its test's p-value, Holm-adjusted
over the check's m tests, is below alpha; the first Holm step needs p < alpha / m. At power
1 - beta (0.8) the **minimum detectable effect** is

    MDE = (z_{1 - alpha / (2 m)} + z_{1 - beta}) * sd * sqrt(2 / n),

the two-sample normal approximation. For a paired run (same seeds) the standard deviation
of the per-seed difference is sd * sqrt(2 (1 - rho)); rho is unknown before the change, so
rho = 0 is taken: conservative, since a deterministic simulator makes rho positive. The
crash rate uses Cohen's h (the arcsine scale), where the MDE depends on the baseline rate
p0: the smallest p1 - p0 with 2 asin(sqrt(p1)) - 2 asin(sqrt(p0)) above the same bound.
The seeds needed for a change of one margin are the n at which the MDE equals the margin.
The label distribution's total variation distance is not a mean; its row gives the 1 -
alpha / m quantile of the TV between two samples of n episodes from the observed label
distribution (the smallest TV that can be significant), simulated.

A metric whose MDE exceeds its margin cannot reliably be gated at this seed count: the
gate would miss a change of one margin more often than 1 - power; :func:`power_table`
flags it (``too_small``) and the report and ``bench check --power`` warn about it.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from tap_bench.bench.bootstrap import named_rng
from tap_bench.bench.intervals import z_value
from tap_bench.bench.measures import MEASURES
from tap_bench.bench.suite import GateConfig, gate_metrics

__all__ = ["POWER", "power_summary", "power_table"]

POWER = 0.8
"""The power at which the minimum detectable effect is given."""

_TV_DRAWS = 2000


def _crash_mde(p0: float, n: int, zsum: float) -> float:
    h = zsum * math.sqrt(2.0 / n)
    a0 = math.asin(math.sqrt(min(max(p0, 0.0), 1.0)))
    up = math.sin(min(a0 + h / 2, math.pi / 2)) ** 2 - p0
    down = p0 - math.sin(max(a0 - h / 2, 0.0)) ** 2
    return float(max(up, down))


def _crash_seeds(p0: float, margin: float, zsum: float) -> float:
    p1 = min(p0 + margin, 1.0)
    h = abs(2 * math.asin(math.sqrt(p1)) - 2 * math.asin(math.sqrt(min(max(p0, 0.0), 1.0))))
    return math.inf if h == 0 else math.ceil(2 * (zsum / h) ** 2)


def _tv_threshold(labels: np.ndarray, n: int, level: float, seed: int, key: tuple) -> float:
    """The ``level`` quantile of the TV between two samples of n from ``labels``."""
    _, counts = np.unique(labels, return_counts=True)
    p = counts / counts.sum()
    rng = named_rng(seed, "gate power", *key, n)
    a = rng.multinomial(n, p, size=_TV_DRAWS) / n
    b = rng.multinomial(n, p, size=_TV_DRAWS) / n
    return float(np.quantile(0.5 * np.abs(a - b).sum(axis=1), level))


def power_table(episodes: pd.DataFrame, config: GateConfig, *, n_tests: int | None = None
                ) -> pd.DataFrame:
    """Minimum detectable effect and seeds needed per (env, policy, metric).

    Args:
        episodes: the episode table of a run (or a baseline's episodes): the spread of each
            metric and the number of seeds come from it.
        config: the gate's alpha, margins and seed.
        n_tests: tests of a check (default: every (env, policy) cell x the gate metrics).

    Returns:
        env, policy, metric, n (seeds), sd, margin, mde, seeds_for_margin, too_small.
    """
    ok = episodes[episodes["status"] == "ok"] if "status" in episodes.columns else episodes
    cells = sorted(set(map(tuple, ok[["env", "policy"]].drop_duplicates().to_numpy())))
    m = n_tests or len(cells) * len(gate_metrics())
    alpha = config.alpha / max(m, 1)
    zsum = z_value(1 - alpha) + z_value(2 * POWER - 1)
    floor = m / (config.n_permutations + 1)
    rows = []
    for env, policy in cells:
        sub = ok[(ok["env"] == env) & (ok["policy"] == policy)]
        n = len(sub)
        for metric in gate_metrics():
            margin = config.margin(metric)
            row = {"env": env, "policy": policy, "metric": metric, "n": n, "margin": margin}
            if metric == "label_tv":
                lab = sub["sdl"].fillna("(no label)").astype(str).to_numpy()
                mde = _tv_threshold(lab, n, 1 - alpha, config.seed, (env, policy)) if n else \
                    math.nan
                need = next((k for k in (n, 2 * n, 4 * n, 8 * n, 16 * n, 32 * n) if k and
                             _tv_threshold(lab, k, 1 - alpha, config.seed, (env, policy))
                             <= margin), math.inf) if n else math.inf
                rows.append({**row, "sd": math.nan, "mde": mde, "seeds_for_margin": need})
                continue
            x = pd.to_numeric(sub[metric], errors="coerce").to_numpy(float)
            x = x[np.isfinite(x)]
            if len(x) < 2:
                rows.append({**row, "sd": math.nan, "mde": math.nan,
                             "seeds_for_margin": math.nan})
                continue
            if MEASURES[metric].is_rate:  # a proportion: its own MDE and sample size
                p0 = float(x.mean())
                mde = _crash_mde(p0, len(x), zsum)
                need = _crash_seeds(p0, margin, zsum)
                sd = math.sqrt(p0 * (1 - p0))
            else:
                sd = float(np.std(x, ddof=1))
                mde = zsum * sd * math.sqrt(2.0 / len(x))
                need = math.ceil(2 * (zsum * sd / margin) ** 2) if margin > 0 else math.inf
            rows.append({**row, "sd": sd, "mde": mde, "seeds_for_margin": need})
    out = pd.DataFrame(rows, columns=["env", "policy", "metric", "n", "sd", "margin", "mde",
                                      "seeds_for_margin"])
    if floor >= config.alpha:  # no test can ever reach Holm's alpha
        out["mde"] = math.inf
        out["seeds_for_margin"] = math.inf
    out["seeds_for_margin"] = out["seeds_for_margin"].astype(float)
    out["too_small"] = (out["mde"] > out["margin"]).to_numpy(bool)
    return out


def power_summary(table: pd.DataFrame) -> pd.DataFrame:
    """Per metric: margin, median and largest MDE over the cells, the seeds the worst cell
    needs for its margin, and how many cells cannot detect a change of one margin."""
    if table.empty:
        return table
    g = table.groupby("metric", sort=False)
    out = pd.DataFrame({
        "margin": g["margin"].first(), "n": g["n"].min(),
        "mde_median": g["mde"].median(), "mde_max": g["mde"].max(),
        "seeds_for_margin": g["seeds_for_margin"].max(),
        "cells_too_small": g["too_small"].sum().astype(int), "cells": g.size()})
    return out.reset_index()

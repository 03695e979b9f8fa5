"""The regression gate's power: how often the gate's own rule catches a given worsening.

The gate (:mod:`tap_bench.bench.gate.regression`) fails a metric of one (env, policy) cell when it
moved the worse way by more than its margin **and** its one-sided test, after the
weighted Holm correction, is below alpha. Its power against a worsening ``e`` is the
probability of both together; this module computes it for the rule as it is, not for a
normal approximation of another test:

- **the level a test gets**: the metric's share of alpha in its cell
  (:meth:`GateConfig.share`), divided by the cells in play. In a **paired** check (the
  baseline's seeds) a cell whose episodes did not change has no seed that differs, cannot
  reach alpha and is left out (Tarone's reduction), so a change in one cell is tested at
  ``alpha * share``; in an **unpaired** check (other seeds) every cell is in play:
  ``alpha * share / cells``. This is the first step of the step-down procedure; later
  steps only raise the power, so the figures are lower bounds in that respect.
- **rates** (values 0 and 1, the crash rate): exact. The baseline's episodes are as
  recorded. Unpaired: the run's episodes are independent with rate p0 + e. Paired, the
  verdict's figure assumes **nested** crashes: the run keeps the baseline's crashes and
  each other seed turns to a crash with the probability that raises the rate by e (a
  policy change that adds crashes and removes none: the most favourable case).
  :func:`afresh_rate_power` gives the power when every seed's outcome is drawn **afresh**
  (independent of the baseline's, rate p0 + e: seeds that crashed may not crash again),
  lower, since seeds that stop crashing count against the change; ``bench check --power``
  prints both. The paired test is McNemar's (the binomial on the seeds that differ), the
  unpaired one Fisher's exact test, as the gate computes them.
- **means** (speed, headway, TTC, jerk): simulated, ``DRAWS`` draws of the run from the
  baseline's values resampled and shifted by e the worse way, paired at random with the
  baseline's seeds (correlation 0 between run and baseline, which is conservative: a
  deterministic simulator makes it positive); the permutation tests' p-values by their
  normal approximation (the sign-flip statistic's permutation variance is sum d^2), with
  the floor 1 / (P + 1) of P random permutations.
- ``label_tv``: simulated: the run's labels drawn from the baseline's distribution with a
  share e moved to a label it never had (a TV of e), the permutation test with 199
  permutations per draw.

The worsening a check is asked to catch is ``detect`` margins (:class:`GateConfig`,
default 2.5: a crash rate 25 points higher, with its 0.10 margin). A cell and metric
whose power there is below :data:`POWER` is **underpowered**; ``bench check`` says so
and exits 3 unless ``--allow-underpowered``. A worsening that cannot happen (a crash rate
of 0.9 cannot rise 25 points) is not counted.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from tap_bench.bench.gate.statistics import direction, hypergeom_tails, is_rate, tv
from tap_bench.bench.suite import GateConfig, gate_metrics
from tap_bench.stats.bootstrap import named_rng

__all__ = ["DRAWS", "POWER", "afresh_rate_power", "power_summary", "power_table",
           "rule_power"]

POWER = 0.8
"""The power a check must have at its ``detect`` worsening."""
DRAWS = 2000
"""Simulated draws per (cell, metric) for a mean."""
_TV_DRAWS = 100
_TV_PERMUTATIONS = 999
_BLAS_ONE_THREAD = 200_000  # (rows, d) @ (d, k) products below this use one thread
_SEED_GRID = (1, 1.5, 2, 3, 4, 6, 8, 12, 16)  # multiples of n tried for the seeds needed


def _binomial_pmf(n: int, p: float) -> np.ndarray:
    k = np.arange(n + 1)
    logc = np.array([math.lgamma(n + 1) - math.lgamma(i + 1) - math.lgamma(n - i + 1)
                     for i in k])
    with np.errstate(divide="ignore"):
        out = logc + k * np.log(p) + (n - k) * np.log1p(-p) if 0 < p < 1 else None
    if out is None:
        pmf = np.zeros(n + 1)
        pmf[0 if p <= 0 else n] = 1.0
        return pmf
    return np.exp(out)


def _rate_power(base: np.ndarray, sign: int, effect: float, margin: float, level: float,
                n_run: int, paired: bool) -> float:
    """Exact power of the gate's rule on a rate (see the module docstring)."""
    worse_is_one = sign < 0  # crashes: a 1 is worse
    b = base if worse_is_one else 1 - base  # now 1 is the worse outcome
    n_b, c0 = len(b), int(b.sum())
    p0 = c0 / n_b
    p1 = p0 + effect
    if p1 > 1 + 1e-12:
        return math.nan
    p1 = min(p1, 1.0)
    total = 0.0
    if paired:
        # the run keeps the baseline's worse outcomes; each other seed turns worse with the
        # probability that raises the rate by the effect
        q = 1.0 if c0 == n_b else min(1.0, (p1 - p0) * n_b / (n_b - c0))
        for up, pu in enumerate(_binomial_pmf(n_b - c0, q)):
            if pu >= 1e-15 and up / n_b > margin and 0.5 ** up <= level:
                total += pu
        return float(total)
    for x, px in enumerate(_binomial_pmf(n_run, p1)):
        if px < 1e-15 or x / n_run - p0 <= margin:
            continue
        p = hypergeom_tails(x, n_run, n_b, x + c0)[0]
        if p <= level:
            total += px
    return float(total)


def afresh_rate_power(base: np.ndarray, effect: float, margin: float, level: float) -> float:
    """Exact power of the gate's paired rule on a rate (1 the worse outcome, e.g. a crash)
    when the run's outcome on every seed is drawn afresh: independent of the baseline's,
    1 with probability p0 + ``effect`` (p0 the baseline's rate). The rule fires when
    (up - down) / n > ``margin`` and McNemar's one-sided p, P(Bin(up + down, 1/2) >= up),
    is at most ``level`` (up: seeds 0 -> 1, down: 1 -> 0). NaN when p0 + effect > 1."""
    b = np.asarray(base, float)
    n, c0 = len(b), int(b.sum())
    p1 = c0 / n + effect
    if p1 > 1 + 1e-12:
        return math.nan
    p1 = min(p1, 1.0)
    ups = _binomial_pmf(n - c0, p1)  # baseline 0 -> run 1
    downs = _binomial_pmf(c0, 1.0 - p1)  # baseline 1 -> run 0
    total = 0.0
    for up, pu in enumerate(ups):
        if pu < 1e-15:
            continue
        for down, pdown in enumerate(downs):
            if pdown < 1e-15 or (up - down) / n <= margin:
                continue
            k = up + down
            p = sum(math.comb(k, i) for i in range(up, k + 1)) / 2.0 ** k
            if p <= level:
                total += pu * pdown
    return float(total)


def _mean_power(base: np.ndarray, sign: int, effect: float, margin: float, level: float,
                n_run: int, paired: bool, floor: float, rng: np.random.Generator) -> float:
    """Simulated power of the gate's rule on a mean (see the module docstring)."""
    from statistics import NormalDist

    shift = -sign * effect  # the worse way
    z_level = NormalDist().inv_cdf(1 - level) if level < 1 else -math.inf
    if level < floor:
        return 0.0
    if paired:
        n = len(base)
        # each seed worsens by the effect, plus a perturbation as large as the baseline's
        # seeds differ from one another (correlation 0.5 between run and baseline)
        noise = rng.choice(base - base.mean(), size=(DRAWS, n))
        worse = effect + -sign * noise
        total = worse.sum(axis=1)
        scale = np.sqrt((worse ** 2).sum(axis=1))
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(scale > 0, total / scale, 0.0)
        fire = (total / n > margin) & (z >= z_level)
        return float(fire.mean())
    run = rng.choice(base, size=(DRAWS, n_run)) + shift
    b_mean = base.mean()
    worse = -sign * (run.mean(axis=1) - b_mean)
    pooled_var = ((base - b_mean) ** 2).sum() + ((run - run.mean(axis=1, keepdims=True)) ** 2
                                                  ).sum(axis=1)
    var = pooled_var / (len(base) + n_run - 1)
    se = np.sqrt(var * (1 / len(base) + 1 / n_run))
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.where(se > 0, worse / se, 0.0)
    return float(((worse > margin) & (z >= z_level)).mean())


def _swapped_tv(base: np.ndarray, run: np.ndarray, swap: np.ndarray,
                counts_b: np.ndarray, counts_r: np.ndarray) -> np.ndarray:
    """(P,) label_tv of each permutation of a paired check: ``gate_stats.tv`` of the
    baseline's and the run's codes after each permutation traded the two sides of the
    seeds it marks, float for float, without building the (P, n) permuted code matrices.

    Args:
        base, run: (d,) the label codes of the seeds whose two sides differ.
        swap: (P, d) True where a permutation trades that seed's two sides.
        counts_b, counts_r: (k,) label counts of the whole baseline and run (n seeds each).
    """
    n = int(counts_b.sum())
    k = len(counts_b)
    one_hot = np.eye(k)
    # a traded seed moves one count from its baseline label to its run label on the
    # baseline's side and back on the run's: the moves are one (P, d) @ (d, k) product of
    # small integers (exact in floats), in row blocks small enough that BLAS stays on one
    # thread (its threads spin between calls and cost more than they save here)
    step = one_hot[run] - one_hot[base]
    rows = max(1, _BLAS_ONE_THREAD // max(step.size, 1))
    moved = swap.astype(float) @ step if rows >= len(swap) else np.concatenate(
        [part.astype(float) @ step for part in np.split(swap, range(rows, len(swap), rows))])
    return 0.5 * np.abs((counts_b + moved) / n - (counts_r - moved) / n).sum(axis=1)


def _tv_power(labels: np.ndarray, effect: float, margin: float, level: float, n_run: int,
              paired: bool, rng: np.random.Generator) -> float:
    """Simulated power of the gate's rule on label_tv (see the module docstring); NaN when
    the level is below what :data:`_TV_PERMUTATIONS` permutations can resolve."""
    if effect > 1 or level < 1.0 / (_TV_PERMUTATIONS + 1):
        return math.nan
    _, codes = np.unique(labels, return_inverse=True)
    k = int(codes.max()) + 2  # one label the baseline never had
    n_b = len(codes)
    counts_b = np.bincount(codes, minlength=k)
    fired = 0
    for _ in range(_TV_DRAWS):
        if paired:
            run = codes.copy()
            redraw = rng.random(n_b) < 0.5  # the perturbation of a changed policy
            # rng.choice(codes, size) draws these same integers: the same stream
            run[redraw] = codes[rng.integers(0, n_b, size=int(redraw.sum()))]
            run[rng.random(n_b) < effect] = k - 1
            counts_r = np.bincount(run, minlength=k)
            observed = 0.5 * np.abs(counts_b / n_b - counts_r / n_b).sum()  # tv()
            if observed <= margin:
                continue
            differ = np.flatnonzero(codes != run)
            swap = rng.random((_TV_PERMUTATIONS, len(differ))) >= 0.5
            perm = _swapped_tv(codes[differ], run[differ], swap, counts_b, counts_r)
        else:
            run = codes[rng.integers(0, n_b, size=n_run)]
            run[rng.random(n_run) < effect] = k - 1
            observed = tv(codes[None, :], run[None, :], k)[0]
            if observed <= margin:
                continue
            pooled = np.r_[codes, run]
            shuffled = pooled[np.argsort(rng.random((_TV_PERMUTATIONS, len(pooled))),
                                         axis=1)]
            perm = tv(shuffled[:, :n_b], shuffled[:, n_b:], k)
        exceed = (perm >= observed - 1e-12).sum()
        fired += (1 + exceed) / (1 + _TV_PERMUTATIONS) <= level
    return fired / _TV_DRAWS


def rule_power(base: np.ndarray | pd.Series, metric: str, config: GateConfig, *,
               cells: int = 1, paired: bool = True, n_run: int | None = None,
               effect: float | None = None, seed_key: tuple = ()) -> float:
    """The probability that the gate fails ``metric`` of one cell when it worsened by
    ``effect``.

    Args:
        base: the baseline's values of the cell (for ``label_tv``: its labels).
        metric: a gate metric.
        config: the gate (alpha, margins, weights, permutations, detect).
        cells: cells in play (1 for a paired check, every cell for an unpaired one).
        paired: the run has the baseline's seeds.
        n_run: the run's episodes (default: as many as the baseline's).
        effect: the worsening in the metric's unit (default: ``detect`` margins).
        seed_key: names the random stream of a simulated power.

    Returns:
        The power in [0, 1]; NaN when the worsening cannot happen (a rate beyond 1) or the
        baseline has fewer than 2 values.
    """
    margin = config.margin(metric)
    effect = config.detect * margin if effect is None else float(effect)
    level = config.alpha * config.share(metric) / max(cells, 1)
    floor = 1.0 / (config.n_permutations + 1)
    rng = named_rng(config.seed, "gate power", metric, *seed_key)
    if metric == "label_tv":
        labels = np.asarray(base, dtype=object).astype(str)
        n_run = n_run or len(labels)
        return _tv_power(labels, effect, margin, level, n_run,
                         paired and n_run == len(labels), rng) if len(labels) else math.nan
    x = pd.to_numeric(pd.Series(base), errors="coerce").to_numpy(float)
    x = x[np.isfinite(x)]
    if len(x) < 2:
        return math.nan
    n_run = n_run or len(x)
    paired = paired and n_run == len(x)
    sign = direction(metric)
    if is_rate(metric) and np.isin(x, (0.0, 1.0)).all():
        return _rate_power(x, sign, effect, margin, level, n_run, paired)
    return _mean_power(x, sign, effect, margin, level, n_run, paired, floor, rng)


def power_table(episodes: pd.DataFrame, config: GateConfig, *, cells: int | None = None,
                paired: bool = True, n_run: int | None = None,
                n_tests: int | None = None) -> pd.DataFrame:
    """The gate's power per (env, policy, metric) at the ``detect`` worsening, and the seeds
    that would give it :data:`POWER`.

    Args:
        episodes: the baseline's (or a run's) episode table: env, policy, seed, sdl and
            the measures (``status`` other than ``"ok"`` skipped).
        config: the gate.
        cells: cells in play in an unpaired check (default: every cell of ``episodes``).
        paired: a check on the same seeds (one changed cell in play) or on other seeds.
        n_run: the run's episodes per cell (default: the baseline's).
        n_tests: accepted for old callers: cells = n_tests / metrics.

    Returns:
        env, policy, metric, n, n_run, margin, effect (the worsening, in the metric's
        unit), level (the test's share of alpha), power, seeds_for_power (the seeds per
        side that reach :data:`POWER`, inf beyond 16 times n), underpowered.
    """
    ok = episodes[episodes["status"] == "ok"] if "status" in episodes.columns else episodes
    keys = sorted(set(map(tuple, ok[["env", "policy"]].drop_duplicates().to_numpy())))
    if cells is None:
        cells = n_tests // len(gate_metrics()) if n_tests else len(keys)
    in_play = 1 if paired else max(cells, 1)
    rows = []
    for env, policy in keys:
        sub = ok[(ok["env"] == env) & (ok["policy"] == policy)]
        for metric in gate_metrics():
            values = (sub["sdl"].fillna("(no label)") if metric == "label_tv"
                      else sub[metric])
            n = len(values)
            run_n = n_run or n
            margin = config.margin(metric)
            kw = dict(cells=in_play, paired=paired, seed_key=(env, policy))
            power = rule_power(values.to_numpy(), metric, config, n_run=run_n, **kw)
            need = math.nan
            if np.isfinite(power):
                need = math.inf
                for factor in _SEED_GRID:
                    k = max(2, math.ceil(run_n * factor))
                    if factor == 1:
                        p = power
                    elif paired:
                        # more paired seeds: the baseline's values resampled to k seeds
                        idx = named_rng(config.seed, "gate seeds", env, policy, metric,
                                        k).integers(0, n, k)
                        p = rule_power(values.to_numpy()[idx], metric, config, n_run=k, **kw)
                    else:
                        p = rule_power(values.to_numpy(), metric, config, n_run=k, **kw)
                    if p >= POWER:
                        need = float(k)
                        break
            rows.append({"env": env, "policy": policy, "metric": metric, "n": n,
                         "n_run": run_n, "margin": margin,
                         "effect": config.detect * margin,
                         "level": config.alpha * config.share(metric) / in_play,
                         "power": power, "seeds_for_power": need})
    out = pd.DataFrame(rows, columns=["env", "policy", "metric", "n", "n_run", "margin",
                                      "effect", "level", "power", "seeds_for_power"])
    out["underpowered"] = (out["power"] < POWER).to_numpy(bool)
    return out


def power_summary(table: pd.DataFrame) -> pd.DataFrame:
    """Per metric: margin, the worsening asked for, the median and smallest power over the
    cells, the seeds the weakest cell needs, and how many cells are underpowered."""
    if table.empty:
        return table
    g = table.groupby("metric", sort=False)
    out = pd.DataFrame({
        "margin": g["margin"].first(), "effect": g["effect"].first(), "n": g["n_run"].min(),
        "power_median": g["power"].median(), "power_min": g["power"].min(),
        "seeds_for_power": g["seeds_for_power"].max(),
        "cells_underpowered": g["underpowered"].sum().astype(int), "cells": g.size()})
    return out.reset_index()

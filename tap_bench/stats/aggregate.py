"""RL agents over training seeds and scenes, aggregated as rliable recommends.

Agarwal et al. (2021), "Deep Reinforcement Learning at the Edge of the Statistical Precipice"
(NeurIPS): an RL agent is the set of its training runs, so a figure is computed over runs x
tasks, with an interval that says how much it would move with other training seeds. Here a
*run* is a training seed (a deterministic policy, such as IDM or the human, has one run) and
a *task* is a scene.

**Data contract.** ``scores``: a float array of shape ``(n_runs, n_tasks)`` per agent, one
score per training seed (row) and scene (column); every agent compared has the same tasks
in the same column order; NaN is not allowed (leave out a scene where a score is missing,
for every agent). Which way is better is the caller's: pass scores where higher is better
(negate a cost, e.g. ``-crashed``).

- :func:`iqm`: the interquartile mean, the mean of the middle 50% of the ``n_runs x
  n_tasks`` scores pooled (25% trimmed from each end, fractional end points weighted);
  robust to outlier runs, less noisy than the median.
- :func:`stratified_bootstrap`: the interval of any such statistic: the runs of each task
  are resampled with replacement, each task on its own (stratified by task), the statistic
  recomputed on every resample, and the percentile interval taken. The tasks stay fixed: the
  interval is over training seeds, for these scenes. rliable's stratification assumes a
  run of one task is independent of a run of another (Atari: one training per game and
  seed). An agent trained once per seed on all scenes carries that seed's luck into every
  scene; ``unit="run"`` resamples whole runs (every scene of a drawn seed together), which
  holds its level there where the stratified one does not (measured:
  ``benchmarks/agents_interval_coverage.py``, docs/agents.md). Either way the draws are
  widened about the estimate by ``sqrt(n / (n - 1))`` for n runs (a bootstrap over n units
  sees ``(n - 1) / n`` of their variance): with 3 seeds, by 1.22.
- :func:`probability_of_improvement`: P(X > Y), the probability that a run of agent X beats
  a run of Y on a task drawn at random: the Mann-Whitney statistic per task (ties count a
  half), averaged over tasks; with its stratified bootstrap interval (X's and Y's runs
  resampled on their own, task by task).
- :func:`performance_profile`: the run-score distribution, the share of the ``n_runs x
  n_tasks`` scores above each threshold tau, with pointwise stratified bootstrap bands.

How often each interval holds its nominal level with few seeds is measured by
``benchmarks/agents_interval_coverage.py`` (docs/agents.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tap_bench.errors import ParameterError
from tap_bench.stats.bootstrap import cluster_factor

__all__ = ["BATCHED", "UNITS", "Interval", "iqm", "mean_score", "performance_profile",
           "probability_of_improvement", "stratified_bootstrap", "stratified_resample"]


@dataclass(frozen=True)
class Interval:
    """A point estimate with its two-sided percentile interval at ``level``."""

    estimate: float
    low: float
    high: float
    level: float


def _scores(scores: np.ndarray, name: str = "scores") -> np.ndarray:
    """``scores`` as a float ``(n_runs, n_tasks)`` array, checked."""
    array = np.asarray(scores, dtype=float)
    if array.ndim == 1:
        array = array[None, :]
    if array.ndim != 2 or array.shape[0] < 1 or array.shape[1] < 1:
        raise ParameterError(name, np.shape(scores), "an array of shape (n_runs, n_tasks) "
                             "with at least one run and one task")
    if not np.isfinite(array).all():
        raise ParameterError(name, "NaN or infinite values", "finite scores", message=(
            f"{name}: {int((~np.isfinite(array)).sum())} score(s) are NaN or infinite; "
            "leave the scene out for every agent, or give it a score."))
    return array


def iqm(scores: np.ndarray) -> float | np.ndarray:
    """The interquartile mean of the pooled ``(n_runs, n_tasks)`` scores: the mean of the
    middle half, the lowest and highest quarter cut (an end value cut in part counts by the
    part kept, so it is defined for any number of scores). A stack of shape ``(k, n_runs,
    n_tasks)`` (bootstrap resamples) gives the ``k`` IQMs."""
    array = np.asarray(scores, dtype=float)
    if array.ndim == 3:
        flat = np.sort(array.reshape(len(array), -1), axis=1)
    else:
        flat = np.sort(_scores(array).ravel())[None, :]
    n = flat.shape[1]
    lo, hi = 0.25 * n, 0.75 * n  # keep the order positions [lo, hi)
    positions = np.arange(n)
    weights = np.clip(np.minimum(positions + 1, hi) - np.maximum(positions, lo), 0.0, 1.0)
    values = flat @ weights / weights.sum()
    return values if array.ndim == 3 else float(values[0])


def mean_score(scores: np.ndarray) -> float | np.ndarray:
    """The mean of the pooled ``(n_runs, n_tasks)`` scores (of each of a ``(k, n_runs,
    n_tasks)`` stack): the aggregate of a rate, such as at-fault collisions per episode."""
    array = np.asarray(scores, dtype=float)
    if array.ndim == 3:
        return array.mean(axis=(1, 2))
    return float(_scores(array).mean())


BATCHED = (iqm, mean_score)
"""Statistics that take a stack of resamples at once (computed in one pass)."""


UNITS = ("task", "run")
"""What the bootstrap resamples: ``"task"``, the runs of each task on their own (rliable's
stratified bootstrap: a run is one training per task, as on Atari); ``"run"``, whole runs,
every task of a drawn run together (one trained model per seed drives every scene, so a
seed's scores on different scenes share that seed's luck)."""


def stratified_resample(rng: np.random.Generator, n_runs: int, n_tasks: int,
                        draws: int, unit: str = "task") -> np.ndarray:
    """Row indexes of ``draws`` bootstrap resamples: shape ``(draws, n_runs, n_tasks)``,
    column ``m`` holding ``n_runs`` runs of task ``m`` drawn with replacement: each task on
    its own (``unit="task"``, stratified by task), or the same runs for every task
    (``unit="run"``: a drawn run brings all its tasks)."""
    if unit not in UNITS:
        raise ParameterError("unit", unit, f"one of {UNITS}")
    if unit == "run":
        rows = rng.integers(0, n_runs, size=(draws, n_runs, 1))
        return np.broadcast_to(rows, (draws, n_runs, n_tasks))
    return rng.integers(0, n_runs, size=(draws, n_runs, n_tasks))


def _spread(boot: np.ndarray, estimate: np.ndarray | float, n_units: int) -> np.ndarray:
    """Bootstrap draws scaled about the estimate by ``sqrt(G / (G - 1))`` for G resampled
    units (:func:`tap_bench.stats.bootstrap.cluster_factor`): a bootstrap over G units
    sees ``(G - 1) / G`` of the sampling variance, which with 3 seeds is two thirds of it.
    Unchanged for fewer than 2 units (nothing is resampled)."""
    factor = cluster_factor(n_units)
    if not np.isfinite(factor):
        return boot
    return estimate + factor * (boot - estimate)


def _check_level(level: float, n_resamples: int) -> None:
    if not 0.5 <= level < 1:
        raise ParameterError("level", level, "a two-sided level in [0.5, 1), e.g. 0.95")
    if isinstance(n_resamples, bool) or not isinstance(n_resamples, int) or n_resamples < 100:
        raise ParameterError("n_resamples", n_resamples, "an integer >= 100")


def stratified_bootstrap(scores: np.ndarray, statistic: Callable[[np.ndarray], float] = iqm,
                         *, rng: np.random.Generator, level: float = 0.95,
                         n_resamples: int = 2000, unit: str = "task") -> Interval:
    """``statistic`` of ``scores`` (``(n_runs, n_tasks)``) with its stratified bootstrap
    percentile interval (see the module docstring).

    Args:
        scores: one agent's scores.
        statistic: a function of a ``(n_runs, n_tasks)`` array (default :func:`iqm`).
        rng: the random stream of the resamples (named by what it draws).
        level: two-sided level.
        n_resamples: bootstrap resamples (>= 100).
        unit: what is resampled (:data:`UNITS`): ``"task"`` (stratified) or ``"run"``.

    The draws are widened about the estimate for the few units resampled (``_spread``);
    for the batched statistics (:data:`BATCHED`, means of some of the scores) the widened
    draws are kept within the scores' range, so an at-fault rate's interval never goes
    below 0.
    """
    x = _scores(scores)
    _check_level(level, n_resamples)
    n_runs, n_tasks = x.shape
    cols = np.arange(n_tasks)
    samples = x[stratified_resample(rng, n_runs, n_tasks, n_resamples, unit), cols]
    if statistic in BATCHED:
        boot = np.asarray(statistic(samples), dtype=float)
    else:
        boot = np.array([statistic(sample) for sample in samples], dtype=float)
    estimate = float(statistic(x))
    alpha = (1 - level) / 2
    spread = _spread(boot, estimate, n_runs)
    if statistic in BATCHED:  # a mean of some of the scores: never beyond their range
        spread = np.clip(spread, x.min(), x.max())
    low, high = np.quantile(spread, [alpha, 1 - alpha])
    return Interval(estimate, float(low), float(high), level)


def _improvement(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """P(X > Y) of two ``(..., runs, tasks)`` stacks on the same tasks: per task the share of
    run pairs where X's score is higher (ties a half), averaged over tasks."""
    a, b = x[..., :, None, :], y[..., None, :, :]
    per_task = (a > b).mean(axis=(-3, -2)) + 0.5 * (a == b).mean(axis=(-3, -2))
    return per_task.mean(axis=-1)


def probability_of_improvement(x: np.ndarray, y: np.ndarray, *, rng: np.random.Generator,
                               level: float = 0.95, n_resamples: int = 2000,
                               unit: str = "task") -> Interval:
    """The probability that agent X improves on agent Y, P(X > Y), with its stratified
    bootstrap interval (each agent's runs resampled on their own, task by task).

    Args:
        x, y: scores ``(n_runs_x, n_tasks)`` and ``(n_runs_y, n_tasks)``, higher better,
            the same tasks in the same order.
        rng: the random stream of the resamples.
        level: two-sided level.
        n_resamples: bootstrap resamples (>= 100).
        unit: what is resampled (:data:`UNITS`), each agent's runs on their own.
    """
    x, y = _scores(x, "x"), _scores(y, "y")
    if x.shape[1] != y.shape[1]:
        raise ParameterError("y", y.shape, f"{x.shape[1]} tasks, as x has", message=(
            f"x has {x.shape[1]} tasks and y {y.shape[1]}: compare agents on the same "
            "scenes, in the same order."))
    _check_level(level, n_resamples)
    n_tasks = x.shape[1]
    cols = np.arange(n_tasks)
    rows_x = stratified_resample(rng, x.shape[0], n_tasks, n_resamples, unit)
    rows_y = stratified_resample(rng, y.shape[0], n_tasks, n_resamples, unit)
    boot = _improvement(x[rows_x, cols], y[rows_y, cols])
    estimate = float(_improvement(x, y))
    varying = [n for n in (x.shape[0], y.shape[0]) if n > 1]  # the side with fewer runs
    boot = np.clip(_spread(boot, estimate, min(varying, default=1)), 0.0, 1.0)
    alpha = (1 - level) / 2
    low, high = np.quantile(boot, [alpha, 1 - alpha])
    return Interval(estimate, float(low), float(high), level)


def performance_profile(scores: np.ndarray, thresholds: np.ndarray, *,
                        rng: np.random.Generator, level: float = 0.95,
                        n_resamples: int = 2000, unit: str = "task"
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The run-score distribution: the share of the ``(n_runs, n_tasks)`` scores above each
    threshold (shape ``(len(thresholds),)``), and its pointwise stratified bootstrap band
    (low, high: the same shape).

    Args:
        scores: one agent's scores.
        thresholds: the taus, any order.
        rng: the random stream of the resamples.
        level: two-sided level of each point's band.
        n_resamples: bootstrap resamples (>= 100).
        unit: what is resampled (:data:`UNITS`).
    """
    x = _scores(scores)
    _check_level(level, n_resamples)
    taus = np.asarray(thresholds, dtype=float).ravel()
    n_runs, n_tasks = x.shape
    cols = np.arange(n_tasks)

    samples = x[stratified_resample(rng, n_runs, n_tasks, n_resamples, unit), cols]
    flat = samples.reshape(n_resamples, -1)
    boot = (flat[:, :, None] > taus[None, None, :]).mean(axis=1)
    share = (x.ravel()[:, None] > taus[None, :]).mean(axis=0)
    boot = np.clip(_spread(boot, share[None, :], n_runs), 0.0, 1.0)
    alpha = (1 - level) / 2
    return share, np.quantile(boot, alpha, axis=0), np.quantile(boot, 1 - alpha, axis=0)

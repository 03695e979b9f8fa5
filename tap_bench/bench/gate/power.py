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
- ``label_tv``: simulated: ``_TV_DRAWS`` draws of the run's labels from the baseline's
  distribution with a share e moved to a label it never had (a TV of e), each tested by
  the permutation test with ``_TV_PERMUTATIONS`` random permutations. Paired, the share
  of a draw's permutations that reach its TV is exact where it can be enumerated (seeds
  with the same pair of labels are exchangeable: a permutation's TV depends only on how
  many of each pair it trades), and the draw fires with that share's binomial
  probability; the draws that give the same cell are counted together.

The worsening a check is asked to catch is ``detect`` margins (:class:`GateConfig`,
default 2.5: a crash rate 25 points higher, with its 0.10 margin). A cell and metric
whose power there is below :data:`POWER` is **underpowered**; ``bench check`` says so
and exits 3 unless ``--allow-underpowered``. A worsening that cannot happen (a crash rate
of 0.9 cannot rise 25 points) is not counted.
"""

from __future__ import annotations

import copy
import functools
import math
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.gate.statistics import direction, is_rate, tv
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


@functools.lru_cache(maxsize=1024)
def _binomial_pmf(n: int, p: float) -> np.ndarray:
    """(n + 1,) P(Bin(n, p) = k) for k = 0..n, read-only (kept for the next call with the
    same n and p: the label_tv power asks for the same small n at p = 1/2 thousands of
    times)."""
    pmf = _binomial_pmf_made(n, p)
    pmf.flags.writeable = False
    return pmf


def _binomial_pmf_made(n: int, p: float) -> np.ndarray:
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
    comb_total = math.comb(n_run + n_b, n_run)
    for x, px in enumerate(_binomial_pmf(n_run, p1)):
        if px < 1e-15 or x / n_run - p0 <= margin:
            continue
        if _fisher_upper(x, n_run, n_b, x + c0, comb_total) <= level:
            total += px
    return float(total)


def _fisher_upper(x: int, n_run: int, n_b: int, ones: int, comb_total: int) -> float:
    """Fisher's one-sided p, P(X >= x), as
    :func:`~tap_bench.bench.gate.statistics.hypergeom_tails` gives it (the same
    terms, summed in the same order), from the upper tail's terms alone: each term's two
    binomial coefficients follow from the last one's by one exact integer step.

    Args:
        x: the run's ones.
        n_run: the run's values.
        n_b: the baseline's values.
        ones: the ones of both together.
        comb_total: C(n_run + n_b, n_run).
    """
    rest = n_run + n_b - ones
    k, hi = max(x, ones - n_b, 0), min(ones, n_run)
    if k > hi:
        return 0
    a, b = math.comb(ones, k), math.comb(rest, n_run - k)
    p = 0.0
    while True:
        p += a * b / comb_total
        if k == hi:
            return p
        a = a * (ones - k) // (k + 1)  # C(ones, k + 1)
        b = b * (n_run - k) // (rest - n_run + k + 1)  # C(rest, n_run - k - 1)
        k += 1


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


@functools.lru_cache(maxsize=256)
def _most_exceeding(level: float) -> int:
    """The most of :data:`_TV_PERMUTATIONS` permutations that may reach the observed TV
    for the test to fire at ``level``: the largest m with (1 + m) / (1 + P) <= level."""
    return int(np.count_nonzero((1 + np.arange(_TV_PERMUTATIONS + 1))
                                / (1 + _TV_PERMUTATIONS) <= level)) - 1


def _binomial_cdf_at_most(m: int, n: int, q: float) -> float:
    """P(Bin(n, q) <= m)."""
    if m < 0:
        return 0.0
    if m >= n or q <= 0:
        return 1.0
    if q >= 1:
        return 0.0
    x = np.arange(m + 1)
    logc = np.array([math.lgamma(n + 1) - math.lgamma(i + 1) - math.lgamma(n - i + 1)
                     for i in range(m + 1)])
    return float(min(1.0, np.exp(logc + x * math.log(q) + (n - x) * math.log1p(-q)).sum()))


def _product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` of small integers in floats (exact), in row blocks small enough that BLAS
    stays on one thread (its threads spin between calls and cost more than they save)."""
    rows = max(1, _BLAS_ONE_THREAD // max(a.shape[1] * b.shape[1], 1))
    if rows >= len(a):
        return a @ b
    return np.concatenate([part @ b for part in np.split(a, range(rows, len(a), rows))])


def _swap_fires(pairs: np.ndarray, k: int, margin: float, level: float, repeats: int,
                rng: np.random.Generator) -> float:
    """How many of ``repeats`` draws of one cell the paired label_tv test fires on, in
    expectation over their random permutations (:data:`_TV_PERMUTATIONS` of them, p =
    (1 + exceed) / (1 + P), as :func:`_tv_power` models the gate).

    A permutation trades the two sides of each seed with probability 1/2. Seeds with the
    same (baseline label, run label) pair are exchangeable, so a permutation's TV depends
    only on how many seeds of each pair it trades (independent binomials). When their
    joint law has at most P combinations it is enumerated: it gives exactly the share q of
    permutations at least as far apart as observed, and the test fires when at most m of
    the P permutations reach it (m the largest count with (1 + m) / (1 + P) <= level), with
    probability P(Bin(P, q) <= m). Otherwise each draw's P permutations are drawn (a fair
    coin per seed that differs) and counted, 0 or 1 per draw.

    Args:
        pairs: (k, k) seed counts by (baseline label, run label).
        k: labels.
        margin: the rule's margin on the TV.
        level: the test's level.
        repeats: draws that gave this cell.
        rng: draws the permutations of a cell too large to enumerate.
    """
    n = int(pairs.sum())
    counts_b, counts_r = pairs.sum(axis=1), pairs.sum(axis=0)
    observed = 0.5 * np.abs(counts_b / n - counts_r / n).sum()  # gate_stats.tv
    if observed <= margin:
        return 0.0
    base, run = np.nonzero(pairs * (1 - np.eye(k, dtype=pairs.dtype)))
    sizes = pairs[base, run]
    one_hot = np.eye(k)
    step = one_hot[run] - one_hot[base]  # a traded seed's run label joins the baseline's
    if math.prod(int(c) + 1 for c in sizes) <= _TV_PERMUTATIONS + 1:
        traded = np.indices(tuple(int(c) + 1 for c in sizes)).reshape(len(sizes), -1).T
        weight = np.ones(len(traded))
        for t, c in enumerate(sizes):
            weight *= _binomial_pmf(int(c), 0.5)[traded[:, t]]
        moved = _product(traded.astype(float), step)
        perm = 0.5 * np.abs((counts_b + moved) / n - (counts_r - moved) / n).sum(axis=1)
        q = float(weight[perm >= observed - 1e-12].sum())
        return repeats * _binomial_cdf_at_most(_most_exceeding(level), _TV_PERMUTATIONS, q)
    step = np.repeat(step, sizes, axis=0)  # one row per seed that differs
    # a fair coin per seed and permutation, as random bits (8 per byte drawn)
    coins = np.unpackbits(rng.integers(0, 256, size=(repeats * _TV_PERMUTATIONS,
                                                     (len(step) + 7) // 8), dtype=np.uint8),
                          axis=1, count=len(step))
    moved = _product(coins.astype(float), step)
    perm = 0.5 * np.abs((counts_b + moved) / n - (counts_r - moved) / n).sum(axis=1)
    exceed = (perm >= observed - 1e-12).reshape(repeats, _TV_PERMUTATIONS).sum(axis=1)
    return float(((1 + exceed) / (1 + _TV_PERMUTATIONS) <= level).sum())


def _tv_power(labels: np.ndarray, effect: float, margin: float, level: float, n_run: int,
              paired: bool, rng: np.random.Generator) -> float:
    """Simulated power of the gate's rule on label_tv (see the module docstring); NaN when
    the level is below what :data:`_TV_PERMUTATIONS` permutations can resolve.

    Paired: the :data:`_TV_DRAWS` runs are drawn together; the draws that gave the same
    cell (its seed counts by baseline and run label) are counted together
    (:func:`_swap_fires`). Unpaired: each permutation's label counts on the baseline's side
    drawn from their multivariate hypergeometric law."""
    if effect > 1 or level < 1.0 / (_TV_PERMUTATIONS + 1):
        return math.nan
    _, codes = np.unique(labels, return_inverse=True)
    k = int(codes.max()) + 2  # one label the baseline never had
    n_b = len(codes)
    if paired:
        # the perturbation of a changed policy: half the seeds redrawn from the baseline's
        # labels, then a share ``effect`` moved to the new label
        runs = np.where(rng.random((_TV_DRAWS, n_b)) < 0.5,
                        codes[rng.integers(0, n_b, size=(_TV_DRAWS, n_b))], codes)
        runs[rng.random((_TV_DRAWS, n_b)) < effect] = k - 1
        cell = (np.arange(_TV_DRAWS)[:, None] * k * k + codes * k + runs).ravel()
        pairs = np.bincount(cell, minlength=_TV_DRAWS * k * k).reshape(_TV_DRAWS, k * k)
        distinct, inverse = np.unique(pairs, axis=0, return_inverse=True)
        repeats = np.bincount(inverse.ravel(), minlength=len(distinct))
        return sum(_swap_fires(row.reshape(k, k), k, margin, level, int(r), rng)
                   for row, r in zip(distinct, repeats, strict=True)) / _TV_DRAWS
    counts_b = np.bincount(codes, minlength=k)
    fired = 0
    for _ in range(_TV_DRAWS):
        run = codes[rng.integers(0, n_b, size=n_run)]
        run[rng.random(n_run) < effect] = k - 1
        observed = tv(codes[None, :], run[None, :], k)[0]
        if observed <= margin:
            continue
        # a random permutation of the pooled episodes puts a multivariate hypergeometric
        # draw of the pooled label counts on the baseline's side: drawn as counts, not as
        # (P, n_b + n_run) shuffled matrices; TV as gate_stats.tv computes it from counts
        pooled = counts_b + np.bincount(run, minlength=k)
        side_b = rng.multivariate_hypergeometric(pooled, n_b, size=_TV_PERMUTATIONS)
        perm = 0.5 * np.abs(side_b / n_b - (pooled - side_b) / n_run).sum(axis=1)
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
    return _power(base, metric, margin=margin,
                  effect=config.detect * margin if effect is None else float(effect),
                  level=config.alpha * config.share(metric) / max(cells, 1),
                  floor=1.0 / (config.n_permutations + 1),
                  sign=direction(metric), rate=is_rate(metric),
                  rng=named_rng(config.seed, "gate power", metric, *seed_key),
                  paired=paired, n_run=n_run)


def _power(base: np.ndarray | pd.Series, metric: str, *, margin: float, effect: float,
           level: float, floor: float, sign: int, rate: bool, rng: np.random.Generator,
           paired: bool, n_run: int | None) -> float:
    """:func:`rule_power` with the gate's figures resolved: ``margin`` and ``effect`` in the
    metric's unit, ``level`` the test's share of alpha, ``floor`` the smallest p-value of
    its permutations, ``sign`` the metric's better direction
    (:func:`~tap_bench.bench.gate.statistics.direction`), ``rate`` whether it is a rate,
    ``rng`` the stream of a simulated power."""
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
    if rate and np.isin(x, (0.0, 1.0)).all():
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
    metrics = gate_metrics()
    if cells is None:
        cells = n_tests // len(metrics) if n_tests else len(keys)
    in_play = 1 if paired else max(cells, 1)
    # the gate's figures of each metric, resolved once for every cell
    floor = 1.0 / (config.n_permutations + 1)
    margins = {metric: config.margin(metric) for metric in metrics}
    figures = {metric: dict(margin=margins[metric], effect=config.detect * margins[metric],
                            floor=floor, paired=paired, sign=direction(metric),
                            rate=is_rate(metric),
                            level=config.alpha * config.share(metric) / in_play)
               for metric in metrics}
    rows = []
    for env, policy in keys:
        sub = ok[(ok["env"] == env) & (ok["policy"] == policy)]
        for metric in metrics:
            values = (sub["sdl"].fillna("(no label)") if metric == "label_tv"
                      else sub[metric]).to_numpy()
            run_n = n_run or len(values)
            # the cell's random streams: the power's (each evaluation starts it afresh)
            # and, paired, the baseline's values resampled to each multiple of the seeds
            stream = named_rng(config.seed, "gate power", metric, env, policy)
            sizes = [max(2, math.ceil(run_n * factor)) for factor in _SEED_GRID[1:]]
            picks = {k: named_rng(config.seed, "gate seeds", env, policy, metric,
                                  k).integers(0, len(values), k)
                     for k in sizes if paired and len(values)}
            power, need = _seeds_for_power(values, metric, figures[metric], stream, run_n,
                                           sizes, picks)
            f = figures[metric]
            rows.append({"env": env, "policy": policy, "metric": metric, "n": len(values),
                         "n_run": run_n, "margin": f["margin"], "effect": f["effect"],
                         "level": f["level"], "power": power, "seeds_for_power": need})
    out = pd.DataFrame(rows, columns=["env", "policy", "metric", "n", "n_run", "margin",
                                      "effect", "level", "power", "seeds_for_power"])
    out["underpowered"] = (out["power"] < POWER).to_numpy(bool)
    return out


def _seeds_for_power(values: np.ndarray, metric: str, figures: dict[str, Any],
                     stream: np.random.Generator, run_n: int, sizes: list[int],
                     picks: dict[int, np.ndarray]) -> tuple[float, float]:
    """(the power of one cell and metric with ``run_n`` episodes, the seeds per side that
    reach :data:`POWER`: the first of ``sizes`` that does, inf when none, NaN when the power
    is undefined). Each evaluation draws from a fresh copy of ``stream``; paired, the
    baseline's values are resampled with ``picks`` (size -> indices), unpaired they are
    kept and only the run grows."""
    power = _power(values, metric, rng=copy.deepcopy(stream), n_run=run_n, **figures)
    if not np.isfinite(power):
        return power, math.nan
    if power >= POWER:
        return power, float(max(2, run_n))
    for k in sizes:
        base = values[picks[k]] if figures["paired"] else values
        if _power(base, metric, rng=copy.deepcopy(stream), n_run=k, **figures) >= POWER:
            return power, float(k)
    return power, math.inf


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

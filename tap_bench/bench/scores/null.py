"""The same-policy null of coverage and novelty: what a policy that drives like
the reference would score, and how far a policy is from it.

A finite reference never shows everything its own policy does: a policy held against
rollouts of itself on fresh seeds scores well above 0 % novel and well below 100 %
coverage (docs/benchmark.md has the figures). So a novelty rate means little until it
stands beside that figure. The reference's trajectories are split in
two halves at random: one half is the reference, the other drives like it by construction.

For one split (halves ``R`` and ``P`` of the reference, ``m`` trajectories each):

- the **same-policy figure**: the coverage of ``R`` by ``P`` and the share of ``P`` whose
  label ``R`` never shows (:mod:`~tap_bench.bench.scores.coverage`,
  :mod:`~tap_bench.bench.scores.novelty`: whole labels, or the labels of segments for a
  ``"segments"`` reference);
- the **policy at the same sizes**: ``m`` of the policy's episodes against the same ``R``:
  the episodes on ``P``'s seeds when the reference is rollouts of the same seeds
  (``paired``: the two sides meet the same traffic), else ``m`` drawn at random;
- the **difference**: policy minus same-policy figure.

Coverage grows with the number of episodes and the reference's size, so the difference is
taken at these half sizes, where both sides are on equal terms (the policy's own coverage
of the whole reference stands beside it). Each figure is the mean over ``splits`` random
splits.

**Interval.** The difference's interval is a bootstrap: each draw splits the reference at
random, resamples each half with replacement (and the policy's episodes with the probe
half, by seed when paired, else on their own: by whole episodes when they are windows cut
from episodes, a cluster bootstrap) and recomputes the difference. A corpus of several
trajectories a scene (WOMD vehicles: ``Reference.scenes``) is not resampled trajectory by
trajectory: the vehicles of one scene share its place and traffic, and another corpus
would hold other scenes. Each draw then builds its corpus from whole scenes drawn with
replacement (as many trajectories as the reference has, the last scene cut) and splits
that at random, so the draws carry the spread between scenes; with S scenes the draws are
then widened about their mean by ``sqrt(S / (S - 1))`` (S drawn from S show
``(S - 1) / S`` of the variance) and read at Student's t with S - 1 degrees of freedom
(``t / z``), as the gap's per-label intervals are. Resampling
repeats trajectories, which lowers the distinct labels a draw can show, so the draws are
re-centred on the estimate (``estimate + draw - mean(draws)``). One draw is one split,
while the estimate averages many, so the draws' spread holds the split-to-split spread
the estimate has averaged away: the draws are shrunk about their mean by
``sqrt((var(draws) - var(splits)) / var(draws))``, ``var(splits)`` the spread of the
estimate's own splits. The interval is the percentile interval of the shrunk draws; where
they cannot move (every half shows the same labels) it is the estimate +- the Wilson upper
limit of 0 of m (what m trajectories could show unseen), never zero-width.
``benchmarks/null_coverage.py`` measures its coverage, with and without the shrinking
(docs/benchmark.md, "The same-policy null").
"""

from __future__ import annotations

from dataclasses import dataclass
from decimal import Decimal

import numpy as np
import pandas as pd

from tap_bench.bench.scores.coverage import Reference, unit_items
from tap_bench.stats.bootstrap import BootstrapConfig, cluster_factor, cluster_indices
from tap_bench.stats.intervals import t_quantile, wilson_interval, z_value

__all__ = ["NullResult", "halves_text", "pooled_null", "same_policy_null"]

SPLITS = 200
"""Random splits whose mean is the estimate."""


def halves_text(half: float, null: float, diff: float, low: float, high: float, *,
                percent: str = "%") -> str:
    """``halves: policy 28% vs same policy 50%: -22 pts [-35, -9]``: the policy's and the
    same-policy figure at the half sizes the difference is taken at (fractions in [0, 1]),
    and the difference with its interval (fractions). The figures get as many decimals
    (0, 1 or 2) as it takes for the shown ones to subtract to the shown difference. Where
    even 2 decimals do not (the policy's figure is the same-policy figure plus the
    difference, and three roundings need not agree: 38.444 + 20.111 = 58.555), the policy's
    figure is shown as the sum of the two shown ones, 0.01 points from its own rounding.
    ``percent``: the sign after a percentage (``" %"`` in the report's tables)."""

    def shown(x: float, digits: int, sign: str = "") -> str:
        return f"{round(100 * x, digits) + 0:{sign}.{digits}f}"  # + 0: no "-0"

    for digits in range(3):  # 28% - 50% = -22 pts, or 28.4% - 50.1% = -21.7 pts
        policy = shown(half, digits)
        if Decimal(policy) - Decimal(shown(null, digits)) == Decimal(shown(diff, digits)):
            break
    else:  # 2 decimals: the policy's figure from the two shown beside it
        policy = f"{Decimal(shown(null, digits)) + Decimal(shown(diff, digits)) + 0:.2f}"
    return (f"halves: policy {policy}{percent} vs same policy "
            f"{shown(null, digits)}{percent}: {shown(diff, digits, '+')} pts "
            f"[{shown(low, digits, '+')}, {shown(high, digits, '+')}]")

METHOD = "shrunk"
"""How the interval is read from the draws: ``"recentred"`` (see the module docstring) or
``"shrunk"`` (the draws' spread less one split's own spread, the estimate averaging
many splits)."""

_CHUNK = 20_000_000
"""Largest draws x trajectories x labels array built at once."""


@dataclass(frozen=True)
class NullResult:
    """A policy against the same-policy null of one reference (see the module docstring).

    Attributes:
        m: trajectories of each half (the sizes the figures are taken at).
        paired: whether the policy's episodes were taken on the probe half's seeds.
        coverage, null_coverage: the policy's and the same-policy coverage of a half.
        coverage_diff, coverage_diff_low, coverage_diff_high: their difference and interval.
        novel_rate, null_novel_rate: the policy's and the same-policy share of novel
            episodes against a half.
        novel_diff, novel_diff_low, novel_diff_high: their difference and interval.
        draws: (B, 2) bootstrap draws of the two differences, centred on the estimates
            (for pooling).
    """

    m: int
    paired: bool
    coverage: float
    null_coverage: float
    coverage_diff: float
    coverage_diff_low: float
    coverage_diff_high: float
    novel_rate: float
    null_novel_rate: float
    novel_diff: float
    novel_diff_low: float
    novel_diff_high: float
    draws: np.ndarray

    def coverage_row(self) -> dict:
        """The fields that go beside a coverage row."""
        return {"null_m": self.m, "null_paired": self.paired, "half_coverage": self.coverage,
                "null_coverage": self.null_coverage, "coverage_diff": self.coverage_diff,
                "coverage_diff_low": self.coverage_diff_low,
                "coverage_diff_high": self.coverage_diff_high}

    def novelty_row(self) -> dict:
        """The fields that go beside a novelty row."""
        return {"null_m": self.m, "null_paired": self.paired, "half_novel_rate": self.novel_rate,
                "null_novel_rate": self.null_novel_rate, "novel_diff": self.novel_diff,
                "novel_diff_low": self.novel_diff_low, "novel_diff_high": self.novel_diff_high}


def _nan_result(paired: bool) -> NullResult:
    nan = float("nan")
    return NullResult(0, paired, nan, nan, nan, nan, nan, nan, nan, nan, nan, nan,
                      np.zeros((0, 2)))


def _incidence(labels: np.ndarray, reference: Reference, vocab: dict[str, int]) -> np.ndarray:
    """(n, K) bool: which items (whole labels, or segment labels) each trajectory shows."""
    out = np.zeros((len(labels), len(vocab)), bool)
    per = ([(lab,) for lab in labels] if reference.kind != "segments"
           else unit_items(labels, reference.axes))
    for i, items in enumerate(per):
        out[i, [vocab[x] for x in items]] = True
    return out


def _shown(matrix: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(D, K) bool: the items any of the trajectories ``idx[d]`` (D, k) of ``matrix``
    shows."""
    D, k = idx.shape
    K = matrix.shape[1]
    step = max(1, _CHUNK // max(1, k * K))
    out = np.empty((D, K), bool)
    for s in range(0, D, step):
        out[s:s + step] = matrix[idx[s:s + step]].any(axis=1)
    return out


def _figures(ref: np.ndarray, probe: np.ndarray, probe_idx: np.ndarray,
             ref_shown: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(D,) coverage of each draw's reference half by ``probe[probe_idx[d]]`` and (D,)
    share of those trajectories showing an item the half never shows."""
    shown = _shown(probe, probe_idx)
    k_ref = ref_shown.sum(axis=1)
    cov = (shown & ref_shown).sum(axis=1) / np.maximum(k_ref, 1)
    D, m = probe_idx.shape
    novel = np.empty(D)
    step = max(1, _CHUNK // max(1, m * probe.shape[1]))
    for s in range(0, D, step):
        units = probe[probe_idx[s:s + step]]  # (d, m, K)
        novel[s:s + step] = (units & ~ref_shown[s:s + step, None, :]).any(axis=2).mean(axis=1)
    return cov, novel


def _draws(ref: np.ndarray, agent: np.ndarray, paired: bool, m: int, D: int,
           rng: np.random.Generator, resample: bool, clusters: np.ndarray | None = None,
           scenes: np.ndarray | None = None) -> np.ndarray:
    """(D, 6): per draw, policy coverage, same-policy coverage, policy novel share,
    same-policy novel share, and the two differences. ``clusters`` (n,): the policy's
    units resampled by whole clusters (windows of one episode), unpaired only. ``scenes``
    (N,): the reference's scenes; a resampled draw then builds its corpus from whole
    scenes drawn with replacement (N trajectories, the last scene cut) before splitting
    it, where without them each half is resampled trajectory by trajectory."""
    N, n = len(ref), len(agent)
    half = N // 2
    perm = np.argsort(rng.random((D, N)), axis=1)
    r_idx, p_idx = perm[:, :half], perm[:, half:half + m]
    if resample and scenes is not None:  # a corpus of whole scenes, split as the data is
        corpus = cluster_indices(rng, scenes, D, N)
        r_idx = np.take_along_axis(corpus, r_idx, axis=1)
        p_idx = np.take_along_axis(corpus, p_idx, axis=1)
    elif resample:
        r_idx = np.take_along_axis(r_idx, rng.integers(0, half, (D, half)), axis=1)
        p_idx = np.take_along_axis(p_idx, rng.integers(0, m, (D, m)), axis=1)
    if paired:
        a_idx = p_idx
    elif resample and clusters is not None:
        a_idx = cluster_indices(rng, clusters, D, m)
    elif resample:
        a_idx = rng.integers(0, n, (D, m))
    else:
        a_idx = np.argsort(rng.random((D, n)), axis=1)[:, :m]
    ref_shown = _shown(ref, r_idx)
    cov_a, nov_a = _figures(ref, agent, a_idx, ref_shown)
    cov_r, nov_r = _figures(ref, ref, p_idx, ref_shown)
    return np.column_stack([cov_a, cov_r, nov_a, nov_r, cov_a - cov_r, nov_a - nov_r])


def same_policy_null(labels: np.ndarray, reference: Reference, *,
                     seeds: np.ndarray | None = None,
                     clusters: np.ndarray | None = None,
                     rng: np.random.Generator | None = None,
                     config: BootstrapConfig | None = None,
                     splits: int = SPLITS) -> NullResult:
    """A policy's coverage and novelty beside the same-policy figure of ``reference``.

    Args:
        labels: (n,) the policy's labels (NA dropped), one per episode, on the
            reference's axes.
        reference: a corpus reference (whole labels or segments) with its ``units``.
        seeds: (n,) the seeds of the policy's episodes; with the reference's ``seeds`` (the
            reference is rollouts) the two are paired on the seeds both have (unpaired when
            fewer than 4 are common).
        clusters: (n,) the episode each of the policy's units was cut from (windows:
            :func:`tap_bench.bench.scores.windows.window_episode`); the policy's units are then
            resampled by whole episodes (a cluster bootstrap), since the windows of one
            episode are not independent. Unpaired comparisons only (windows are never
            paired); None: each unit its own episode.
        config: resamples and level (and the seed of the default stream).
        rng: the random stream the splits and draws come from, named by the caller
            (``config.rng("null", env, policy, reference, unit)``);
            default ``config.rng("null", reference.description)``.
        splits: random splits averaged for the estimates.

    Returns:
        :class:`NullResult` (NaN figures when the reference has fewer than 4 trajectories
        or the policy none).
    """
    config = config or BootstrapConfig()
    rng = config.rng("null", reference.description) if rng is None else rng
    lab = np.asarray(labels, dtype=object)
    units = np.asarray(reference.units, dtype=object)
    paired = seeds is not None and reference.seeds is not None
    keep = pd.notna(lab).astype(bool) if len(lab) else np.zeros(0, bool)
    lab = lab[keep]
    if clusters is not None:
        clusters = np.asarray(clusters, dtype=object)[keep]
    if paired:
        mine = dict(zip(np.asarray(seeds)[keep].tolist(), lab, strict=True))
        theirs = dict(zip(np.asarray(reference.seeds).tolist(), units, strict=True))
        common = sorted(set(mine) & set(theirs))
        if len(common) >= 4:
            lab = np.array([mine[s] for s in common], dtype=object)
            units = np.array([theirs[s] for s in common], dtype=object)
        else:  # other seeds than the reference's: nothing to pair
            paired = False
    if len(units) < 4 or not len(lab):
        return _nan_result(paired)
    # a corpus of several trajectories a scene (WOMD vehicles): the bootstrap draws whole
    # scenes (rollouts paired by seed: the seeds)
    scenes = None if paired or reference.scenes is None else np.asarray(reference.scenes)
    items = sorted({x for row in ([(u,) for u in np.r_[units, lab]]
                                  if reference.kind != "segments"
                                  else unit_items(np.r_[units, lab], reference.axes))
                    for x in row})
    vocab = {x: j for j, x in enumerate(items)}
    ref = _incidence(units, reference, vocab)
    agent = _incidence(lab, reference, vocab)
    m = len(units) - len(units) // 2
    if not paired:
        m = min(m, len(agent))
    per_split = _draws(ref, agent, paired, m, splits, rng, resample=False)
    point = per_split.mean(axis=0)
    boot = _draws(ref, agent, paired, m, config.n_resamples, rng, resample=True,
                  clusters=None if paired else clusters, scenes=scenes)[:, 4:6]
    centre = boot.mean(axis=0)
    if METHOD == "shrunk":  # one split's own spread is not the estimate's: take it out
        v_boot, v_split = boot.var(axis=0), per_split[:, 4:6].var(axis=0)
        factor = np.sqrt(np.clip(v_boot - v_split, 0, None) / np.where(v_boot > 0, v_boot, 1))
        boot = centre + (boot - centre) * factor
    if scenes is not None:  # S scenes drawn from S: CR1 and Student's t with S - 1
        S = len(set(scenes.tolist()))
        boot = centre + (boot - centre) * cluster_factor(S) * (
            t_quantile(0.5 + config.level / 2, S - 1) / z_value(config.level) if S > 1
            else 1.0)
    alpha = 1 - config.level
    draws = boot - centre + point[4:6]
    lo, hi = np.quantile(draws, [alpha / 2, 1 - alpha / 2], axis=0)
    # draws that cannot move (every half shows the same labels): never a zero-width
    # interval; at most the Wilson upper limit of 0 of m of each side could differ unseen
    _, u = wilson_interval(0, m, config.level)
    still = hi - lo < 1e-12
    lo, hi = np.where(still, point[4:6] - u, lo), np.where(still, point[4:6] + u, hi)
    lo, hi = np.clip(lo, -1.0, 1.0), np.clip(hi, -1.0, 1.0)
    return NullResult(
        m=int(m), paired=paired, coverage=float(point[0]), null_coverage=float(point[1]),
        coverage_diff=float(point[4]), coverage_diff_low=float(lo[0]),
        coverage_diff_high=float(hi[0]), novel_rate=float(point[2]),
        null_novel_rate=float(point[3]), novel_diff=float(point[5]),
        novel_diff_low=float(lo[1]), novel_diff_high=float(hi[1]), draws=draws)


def pooled_null(results: list[NullResult], coverage_weights: list[float],
                novelty_weights: list[float], level: float) -> NullResult:
    """Pool per-env nulls as the per-env coverages and novelty rates are pooled: coverage
    figures weighted by each env's reference labels (K), novelty by its episodes; the envs
    are independent, so the interval is ``estimate +- z sd`` with the sd of that weighted
    sum of the envs' draws."""
    ok = [(r, c, v) for r, c, v in zip(results, coverage_weights, novelty_weights,
                                       strict=True) if r.m > 0]
    if not ok:
        return _nan_result(False)
    rs = [r for r, _, _ in ok]
    wc = np.array([c for _, c, _ in ok], float)
    wv = np.array([v for _, _, v in ok], float)
    wc, wv = wc / wc.sum(), wv / wv.sum()

    def mean(field: str, w: np.ndarray) -> float:
        return float(sum(x * getattr(r, field) for x, r in zip(w, rs, strict=True)))

    z = z_value(level)
    sd = [float(np.sqrt(sum((x * np.std(r.draws[:, j])) ** 2
                            for x, r in zip(w, rs, strict=True))))
          for j, w in ((0, wc), (1, wv))]
    cd, nd = mean("coverage_diff", wc), mean("novel_diff", wv)
    return NullResult(
        m=sum(r.m for r in rs), paired=all(r.paired for r in rs),
        coverage=mean("coverage", wc), null_coverage=mean("null_coverage", wc),
        coverage_diff=cd, coverage_diff_low=max(-1.0, cd - z * sd[0]),
        coverage_diff_high=min(1.0, cd + z * sd[0]), novel_rate=mean("novel_rate", wv),
        null_novel_rate=mean("null_novel_rate", wv), novel_diff=nd,
        novel_diff_low=max(-1.0, nd - z * sd[1]), novel_diff_high=min(1.0, nd + z * sd[1]),
        draws=np.zeros((0, 2)))

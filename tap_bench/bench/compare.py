"""Matched comparison of two policies A and B (SPEC section 6, issue 6 part 1).

Both functions read the episode table (:mod:`tap_bench.bench.episodes`).

**Paired by seed** (:func:`paired_comparison`). A seed is the same initial traffic for every
policy, so A's and B's episodes on one (env, seed) form a pair, and the pair is the unit of
resampling. Reported per env and pooled over envs (``env == "all"``; the bootstrap then
resamples seeds within each env, so every env keeps its weight):

- ``agreement``: share of pairs whose ego SDL labels are equal;
- per label L: ``freq_a - freq_b``, the difference in the share of pairs whose ego label is
  L, with a percentile interval and a simultaneous (max-|t|) band over all labels of the
  table, so that "some label differs" can be read off the band without a multiple-testing
  correction;
- per measure: the mean of A, of B, the mean paired difference A - B, and the probability
  of improvement P(A better than B on the same seed), ties counting one half (the paired
  form of rliable's probability of improvement).

An episode that failed in either policy, or whose ego has no label, drops its pair from the
label statistics (the count is reported); "(no label)" is its own label when only the
label is missing.

**Matched by SDL** (:func:`matched_by_label`). Episodes of A and B (any seed) are grouped by
the ego's label within an env, exactly or within ``d_sim`` edit distance of a label that
both produce (:mod:`tap_bench.similarity`), and the measures are compared inside each
group: does A drive more safely than B *when both do the same manoeuvre*? Unpaired, so the
episodes of A and of B in a group are resampled independently.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.bench.bootstrap import (
    BootstrapConfig,
    percentile_interval,
    resample_weights,
    simultaneous_band,
    weighted_means,
)
from tap_bench.bench.measures import MEASURES, Measure
from tap_bench.errors import LabelTableError, ParameterError, did_you_mean
from tap_bench.similarity.sdl_distance import label_set, levenshtein_matrix

__all__ = ["NO_LABEL", "PairedComparison", "matched_by_label", "paired_comparison"]

NO_LABEL = "(no label)"
"""The label of an episode whose ego carries none (a record shorter than 1 s)."""
ALL_ENVS = "all"


@dataclass(frozen=True)
class PairedComparison:
    """The result of :func:`paired_comparison`.

    Attributes:
        summary: one row per env (and ``"all"``): env, policy_a, policy_b, n_pairs,
            n_dropped (pairs lost to a failed episode), agreement, agreement_low,
            agreement_high.
        measures: one row per env and measure: measure, higher_is_better, n, mean_a, mean_b,
            diff (A - B), diff_low, diff_high, p_improvement (P(A better)), p_low, p_high.
        labels: one row per env and label: label, freq_a, freq_b, diff, diff_low, diff_high,
            band_low, band_high (simultaneous over the env's labels).
        method: how the intervals were computed, for the report.
    """

    summary: pd.DataFrame
    measures: pd.DataFrame
    labels: pd.DataFrame
    method: str


def _pairs(episodes: pd.DataFrame, a: str, b: str) -> tuple[pd.DataFrame, pd.Series]:
    """(pairs of ok episodes sorted by env and seed, pairs lost to a failed episode per env)."""
    for name in (a, b):
        if not (episodes["policy"] == name).any():
            known = sorted(episodes["policy"].unique())
            raise LabelTableError(f"no episodes of policy {name!r}; the table has "
                                  f"{', '.join(map(repr, known))}.")
    mine = episodes[episodes["policy"].isin([a, b])]
    left = mine[mine["policy"] == a].drop(columns="policy")
    right = mine[mine["policy"] == b].drop(columns="policy")
    both = left.merge(right, on=["env", "seed"], suffixes=("_a", "_b"))
    ok = (both["status_a"] == "ok") & (both["status_b"] == "ok")
    dropped = (~ok).groupby(both["env"]).sum()
    pairs = both[ok.to_numpy()].sort_values(["env", "seed"], kind="stable")
    return pairs.reset_index(drop=True), dropped


def paired_comparison(episodes: pd.DataFrame, a: str, b: str, *,
                      config: BootstrapConfig | None = None,
                      measures: tuple[Measure, ...] = MEASURES) -> PairedComparison:
    """Compare policies ``a`` and ``b`` seed by seed (see the module docstring).

    Args:
        episodes: the episode table holding both policies.
        a, b: policy names.
        config: bootstrap resamples, level and seed.
        measures: the measures to compare (those absent from the table are skipped).

    Returns:
        :class:`PairedComparison`.

    Raises:
        LabelTableError: a policy has no episodes, or A and B share no (env, seed).
    """
    config = config or BootstrapConfig()
    pairs, dropped = _pairs(episodes, a, b)
    if pairs.empty:
        raise LabelTableError(
            f"policies {a!r} and {b!r} share no (env, seed) with both episodes ok; run them on "
            "the same envs and seeds to pair them.")
    envs = sorted(pairs["env"].unique())
    env_of = pairs["env"].to_numpy()
    # one resampling of seeds per env; the pooled bootstrap resamples within every env,
    # which is the per-env resamplings side by side (pairs are sorted by env)
    weights = {env: resample_weights(int((env_of == env).sum()), config, stream=k)
               for k, env in enumerate(envs)}
    groups = [(env, env_of == env, weights[env]) for env in envs]
    if len(envs) > 1:
        groups.append((ALL_ENVS, np.ones(len(pairs), bool),
                       np.hstack([weights[env] for env in envs])))
    summary, measure_rows, label_rows = [], [], []
    for env, mask, W in groups:
        sub = pairs[mask]
        lab_a = sub["sdl_a"].fillna(NO_LABEL).to_numpy(str)
        lab_b = sub["sdl_b"].fillna(NO_LABEL).to_numpy(str)
        agree = (lab_a == lab_b).astype(float)
        lo, hi = percentile_interval(W @ agree / len(sub), config.level)
        n_drop = int(dropped.sum()) if env == ALL_ENVS else int(dropped.get(env, 0))
        summary.append({"env": env, "policy_a": a, "policy_b": b, "n_pairs": len(sub),
                        "n_dropped": n_drop, "agreement": agree.mean(), "agreement_low": lo,
                        "agreement_high": hi})
        measure_rows += _measure_rows(env, sub, W, measures, config)
        label_rows += _label_rows(env, lab_a, lab_b, W, config)
    return PairedComparison(
        summary=pd.DataFrame(summary), measures=pd.DataFrame(measure_rows),
        labels=pd.DataFrame(label_rows),
        method=config.describe("seeds (pairs of episodes), stratified by env when pooled")
        + "; label bands simultaneous (max-|t|) over each env's labels")


def _measure_rows(env: str, sub: pd.DataFrame, W: np.ndarray, measures, config) -> list[dict]:
    present = [m for m in measures if f"{m.name}_a" in sub.columns]
    if not present:
        return []
    va = np.column_stack([sub[f"{m.name}_a"].to_numpy(float, na_value=np.nan) for m in present])
    vb = np.column_stack([sub[f"{m.name}_b"].to_numpy(float, na_value=np.nan) for m in present])
    both = ~(np.isnan(va) | np.isnan(vb))
    diff = np.where(both, va - vb, np.nan)
    sign = np.array([1.0 if m.higher_is_better else -1.0 for m in present])
    better = np.where(both, (sign * diff > 0) + 0.5 * (diff == 0), np.nan)
    # every measure's difference and improvement in one product with the weights
    boot = weighted_means(W, np.hstack([diff, better]))
    lo, hi = percentile_interval(boot, config.level)
    k = len(present)
    rows = []
    for j, m in enumerate(present):
        if not both[:, j].any():
            continue
        rows.append({"env": env, "measure": m.name, "higher_is_better": m.higher_is_better,
                     "n": int(both[:, j].sum()), "mean_a": float(np.mean(va[both[:, j], j])),
                     "mean_b": float(np.mean(vb[both[:, j], j])),
                     "diff": float(np.nanmean(diff[:, j])), "diff_low": lo[j],
                     "diff_high": hi[j], "p_improvement": float(np.nanmean(better[:, j])),
                     "p_low": lo[k + j], "p_high": hi[k + j]})
    return rows


def _label_rows(env: str, lab_a: np.ndarray, lab_b: np.ndarray, W: np.ndarray,
                config: BootstrapConfig) -> list[dict]:
    names, codes = np.unique(np.concatenate([lab_a, lab_b]), return_inverse=True)
    n = len(lab_a)
    onehot_diff = np.zeros((n, len(names)))
    onehot_diff[np.arange(n), codes[:n]] += 1.0
    onehot_diff[np.arange(n), codes[n:]] -= 1.0
    estimate = onehot_diff.mean(axis=0)
    boot = W @ onehot_diff / n
    lo, hi = percentile_interval(boot, config.level)
    band_lo, band_hi = simultaneous_band(estimate, boot, config.level)
    freq_a = np.bincount(codes[:n], minlength=len(names)) / n
    freq_b = np.bincount(codes[n:], minlength=len(names)) / n
    order = np.argsort(-np.abs(estimate), kind="stable")
    return [{"env": env, "label": names[j], "freq_a": freq_a[j], "freq_b": freq_b[j],
             "diff": estimate[j], "diff_low": lo[j], "diff_high": hi[j],
             "band_low": band_lo[j], "band_high": band_hi[j]} for j in order]


def matched_by_label(episodes: pd.DataFrame, a: str, b: str, *, metric: str = "exact",
                     d_sim: float = 0, min_group: int = 2,
                     config: BootstrapConfig | None = None,
                     measures: tuple[Measure, ...] = MEASURES) -> pd.DataFrame:
    """Compare A and B inside groups of episodes that do the same (or a near) manoeuvre.

    Groups are formed per env. With ``metric="exact"`` (g_SDL, ``d_sim`` 0) a group is every
    episode with one label L that both A and B produce. With ``metric="levenshtein"`` a
    group is anchored at each label L that both produce and holds every episode of A and B
    whose label is within ``d_sim`` token edits of L (groups may then overlap).

    Args:
        episodes: the episode table holding both policies.
        a, b: policy names.
        metric: ``"exact"`` or ``"levenshtein"`` (:mod:`tap_bench.similarity`).
        d_sim: the largest distance inside a group (``<=``).
        min_group: groups with fewer episodes of A or of B are left out.
        config: bootstrap resamples, level and seed; episodes of A and of B are resampled
            independently within the group.
        measures: the measures compared.

    Returns:
        one row per group and measure: env, label (the anchor), n_a, n_b, measure,
        higher_is_better, mean_a, mean_b, diff (A - B), diff_low, diff_high; sorted by
        env and group size.
    """
    config = config or BootstrapConfig()
    if metric not in ("exact", "levenshtein"):
        raise did_you_mean("metric", metric, ("exact", "levenshtein"))
    if metric == "exact" and d_sim != 0:
        raise ParameterError("metric", metric, "",
            message="metric 'exact' (g_SDL) is 0 or 1: use d_sim=0, or metric "
                    "'levenshtein' for near labels.")
    ok = episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()
                  & episodes["policy"].isin([a, b])]
    rows = []
    stream = 0
    for env, sub in ok.groupby("env", sort=True):
        is_a = (sub["policy"] == a).to_numpy()
        lab = sub["sdl"].to_numpy(str)
        names, codes = np.unique(lab, return_inverse=True)
        shared = np.intersect1d(codes[is_a], codes[~is_a])
        present = [m for m in measures if m.name in sub.columns]
        x = np.column_stack([sub[m.name].to_numpy(float, na_value=np.nan) for m in present]) \
            if present else np.zeros((len(sub), 0))
        if metric == "exact":
            within = np.eye(len(names), dtype=bool)
        else:
            within = _levenshtein_within(names, d_sim)
        for anchor in shared:
            member = within[anchor][codes]
            ma, mb = member & is_a, member & ~is_a
            if ma.sum() < min_group or mb.sum() < min_group:
                continue
            Wa = resample_weights(int(ma.sum()), config, stream=50_000 + 2 * stream)
            Wb = resample_weights(int(mb.sum()), config, stream=50_001 + 2 * stream)
            stream += 1
            boot = weighted_means(Wa, x[ma]) - weighted_means(Wb, x[mb])
            lo, hi = percentile_interval(boot, config.level)
            for j, m in enumerate(present):
                xa, xb = x[ma, j], x[mb, j]
                if np.isnan(xa).all() or np.isnan(xb).all():
                    continue
                rows.append({"env": env, "label": names[anchor], "n_a": int(ma.sum()),
                             "n_b": int(mb.sum()), "measure": m.name,
                             "higher_is_better": m.higher_is_better,
                             "mean_a": float(np.nanmean(xa)), "mean_b": float(np.nanmean(xb)),
                             "diff": float(np.nanmean(xa) - np.nanmean(xb)),
                             "diff_low": lo[j], "diff_high": hi[j]})
    out = pd.DataFrame(rows, columns=["env", "label", "n_a", "n_b", "measure",
                                      "higher_is_better", "mean_a", "mean_b", "diff",
                                      "diff_low", "diff_high"])
    if len(out):
        size = out["n_a"] + out["n_b"]
        out = out.assign(_size=-size).sort_values(["env", "_size", "label"], kind="stable")
        out = out.drop(columns="_size").reset_index(drop=True)
    return out


def _levenshtein_within(names: np.ndarray, d_sim: float) -> np.ndarray:
    """(u, u) bool: label j within ``d_sim`` token edits of label i."""
    table = pd.DataFrame({"scenario_id": [f"l{i}" for i in range(len(names))],
                          "track_id": "0", "sdl": names})
    sides = [sdl.parse_sdl(str(text)) for text in names]
    table["lateral"] = [sdl.join(lat) for lat, _ in sides]
    table["longitudinal"] = [sdl.join(lon) for _, lon in sides]
    ls = label_set(table)
    # label_set keeps labels in order of first use, which is the order of ``names`` here
    return levenshtein_matrix(ls) <= d_sim

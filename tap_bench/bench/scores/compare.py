"""Matched comparison of two policies A and B (SPEC section 6).

:func:`compare_policies` makes the run's comparison tables, every (A, B) pair of policies
at once, with both kinds below. Both kinds read the episode table
(:mod:`tap_bench.bench.episodes`). Labels are always compared within one env: a label is
the pair (env, label), so a roundabout label never matches a highway one. The intervals
are those of :mod:`tap_bench.stats.intervals`.

**Paired by seed** (:func:`paired_comparison`). A seed is the same initial traffic for every
policy, so A's and B's episodes on one (env, seed) form a pair. Reported per env, and pooled
over envs (``env == "all"``) as the **pair-weighted mean of the per-env figures** (every
pair counts once):

- ``agreement``: share of pairs whose ego SDL labels are equal (Wilson interval);
- per env and label L (no pooled row: a label belongs to its env): ``freq_a - freq_b``, the
  difference in the share of pairs whose ego label is L, with Tango's paired score
  interval, and a simultaneous band over the env's labels (Tango intervals at a critical
  value calibrated by a bootstrap of the pairs, :func:`~tap_bench.stats.intervals.tango_band`), so
  that "some label differs" can be read off the band without a multiple-testing correction;
- per measure: the mean of A, of B, the mean paired difference A - B (Tango for the crash
  rate, a paired t interval otherwise), and the probability of improvement P(A better than
  B on the same seed), ties counting one half: ``0.5 + (wins - losses) / (2 n)``, with
  Tango's interval of ``(wins - losses) / n`` carried over.

An episode that failed in either policy, or whose ego has no label, drops its pair from the
label statistics (the count is reported); "(no label)" is its own label when only the
label is missing.

**Matched by SDL** (:func:`matched_by_label`). Episodes of A and B (any seed) are grouped by
the ego's label within an env, exactly or within ``d_sim`` edit distance of a label that
both produce (:mod:`tap_bench.similarity`), and the measures are compared inside each
group: does A drive more safely than B *when both do the same manoeuvre*? Unpaired: Welch
intervals for the measures, Newcombe's for the crash rate. A group with fewer than
:data:`MIN_GROUP` episodes of either policy is listed with its sizes but not tested.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.bench.measures import MEASURES, SCENE_MEASURES, Measure
from tap_bench.errors import LabelTableError, ParameterError, did_you_mean
from tap_bench.similarity.sdl_distance import label_set, levenshtein_matrix
from tap_bench.stats.bootstrap import BootstrapConfig
from tap_bench.stats.intervals import (
    paired_measure_interval,
    tango_band,
    tango_interval,
    unpaired_measure_interval,
    wilson_interval,
)

__all__ = ["MIN_GROUP", "NO_LABEL", "Comparisons", "PairedComparison", "compare_policies",
           "matched_by_label", "paired_comparison"]

NO_LABEL = "(no label)"
"""The label of an episode whose ego carries none (a record shorter than 1 s)."""
ALL_ENVS = "all"
MIN_GROUP = 5
"""Fewest episodes of each policy for a label group to be tested: below it Welch's interval
of a mean difference covers far less than its level on the skewed measures of rollouts
(``benchmarks/interval_coverage.py``: 3 vs 3 episodes cover well under 0.90), and a group
of 3 against 2 says nothing a reader should act on."""


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


@dataclass(frozen=True)
class Comparisons:
    """The comparison tables of a run (:func:`compare_policies`), every pair's rows one
    under the other, each with ``policy_a`` and ``policy_b``.

    Attributes:
        paired: :attr:`PairedComparison.summary` of each pair.
        measures: :attr:`PairedComparison.measures` of each pair.
        labels: :attr:`PairedComparison.labels` of each pair.
        matched: :func:`matched_by_label` of each pair.
        method: how the paired intervals were made ("" when no pair was compared).
        skipped: the pairs with nothing to pair, and why (one line each).
    """

    paired: pd.DataFrame
    measures: pd.DataFrame
    labels: pd.DataFrame
    matched: pd.DataFrame
    method: str
    skipped: tuple[str, ...]


def compare_policies(episodes: pd.DataFrame, comparisons: list[tuple[str, str]],
                     config: BootstrapConfig) -> Comparisons:
    """Every (A, B) pair of ``comparisons`` matched by label (:func:`matched_by_label`) and
    paired by seed (:func:`paired_comparison`), as one table of each kind; a pair with
    nothing to pair (every episode of one policy failed) is listed in ``skipped`` and has
    no rows (its label-matched rows neither)."""
    parts: dict[str, list[pd.DataFrame]] = {"paired": [], "measures": [], "labels": [],
                                            "matched": []}
    method, skipped = "", []
    for a, b in comparisons:
        try:
            matched = matched_by_label(episodes, a, b, config=config)
            pc = paired_comparison(episodes, a, b, config=config)
        except LabelTableError as err:
            skipped.append(f"{a} vs {b}: {err}")
            continue
        method = pc.method
        parts["paired"].append(pc.summary)
        parts["measures"].append(pc.measures.assign(policy_a=a, policy_b=b))
        parts["labels"].append(pc.labels.assign(policy_a=a, policy_b=b))
        parts["matched"].append(matched.assign(policy_a=a, policy_b=b))
    return Comparisons(**{kind: _stacked(frames) for kind, frames in parts.items()},
                       method=method, skipped=tuple(skipped))


def _stacked(frames: list[pd.DataFrame]) -> pd.DataFrame:
    """The non-empty ``frames`` one under the other (an empty frame without any)."""
    frames = [f for f in frames if len(f)]
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


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
                      measures: tuple[Measure, ...] | None = None) -> PairedComparison:
    """Compare policies ``a`` and ``b`` seed by seed (see the module docstring).

    Args:
        episodes: the episode table holding both policies.
        a, b: policy names; B is the reference (differences are A - B).
        config: the interval level (``config.level``).
        measures: the measures to compare (those absent from the table are skipped);
            default: every registered measure and every measure of recorded scenes (on
            real scenes the at-fault crash rate beside all collisions, SPEC section 8).

    Returns:
        :class:`PairedComparison`.

    Raises:
        LabelTableError: a policy has no episodes, or A and B share no (env, seed).
    """
    config = config or BootstrapConfig()
    if measures is None:
        measures = (*MEASURES, *SCENE_MEASURES)
    pairs, dropped = _pairs(episodes, a, b)
    if pairs.empty:
        raise LabelTableError(
            f"policies {a!r} and {b!r} share no (env, seed) with both episodes ok; run them on "
            "the same envs and seeds to pair them.")
    envs = sorted(pairs["env"].unique())
    env_of = pairs["env"].to_numpy()
    groups = [(env, env_of == env) for env in envs]
    if len(envs) > 1:
        groups.append((ALL_ENVS, np.ones(len(pairs), bool)))
    summary, agreed, measure_rows, label_rows = [], [], [], []
    for env, mask in groups:
        sub = pairs[mask]
        lab_a = sub["sdl_a"].fillna(NO_LABEL).to_numpy(str)
        lab_b = sub["sdl_b"].fillna(NO_LABEL).to_numpy(str)
        agreed.append(int((lab_a == lab_b).sum()))
        n_drop = int(dropped.sum()) if env == ALL_ENVS else int(dropped.get(env, 0))
        summary.append({"env": env, "policy_a": a, "policy_b": b, "n_pairs": len(sub),
                        "n_dropped": n_drop, "agreement": agreed[-1] / len(sub)})
        measure_rows += _measure_rows(env, sub, measures, config.level)
        if env != ALL_ENVS:  # a label is (env, label): no pooled label rows
            label_rows += _label_rows(env, lab_a, lab_b, config,
                                      config.rng("paired band", env, a, b))
    summary_table = pd.DataFrame(summary)
    # the agreements' Wilson intervals, every group's in one call
    summary_table["agreement_low"], summary_table["agreement_high"] = wilson_interval(
        np.array(agreed), summary_table["n_pairs"].to_numpy(), config.level)
    return PairedComparison(
        summary=summary_table, measures=pd.DataFrame(measure_rows),
        labels=pd.DataFrame(label_rows),
        method=(f"{config.level:.0%} intervals over pairs of episodes (A and B on one seed); "
                "agreement: Wilson; label frequency differences, crash-rate differences and "
                "the probability of improvement: Tango's paired score interval; label bands: "
                "Tango at a sup-score critical value (bootstrap of pairs) over each env's "
                "labels; other measure differences: "
                "paired t. 'all' pools every pair of every env."))


def _measure_rows(env: str, sub: pd.DataFrame, measures, level: float) -> list[dict]:
    rows = []
    for m in measures:
        if f"{m.name}_a" not in sub.columns:
            continue
        va = sub[f"{m.name}_a"].to_numpy(float, na_value=np.nan)
        vb = sub[f"{m.name}_b"].to_numpy(float, na_value=np.nan)
        both = ~(np.isnan(va) | np.isnan(vb))
        n = int(both.sum())
        if not n:
            continue
        va, vb = va[both], vb[both]
        diff = va - vb
        sign = 1.0 if m.higher_is_better else -1.0
        wins, losses = int((sign * diff > 0).sum()), int((sign * diff < 0).sum())
        d_lo, d_hi = tango_interval(wins, losses, n, level)
        # a rate: a difference of paired proportions (Tango); a mean: Student's t
        lo, hi = paired_measure_interval(m, va, vb, level)
        rows.append({"env": env, "measure": m.name, "higher_is_better": m.higher_is_better,
                     "n": n, "mean_a": float(va.mean()), "mean_b": float(vb.mean()),
                     "diff": float(diff.mean()), "diff_low": lo, "diff_high": hi,
                     "p_improvement": 0.5 + (wins - losses) / (2 * n),
                     "p_low": 0.5 + d_lo / 2, "p_high": 0.5 + d_hi / 2})
    return rows


def _label_rows(env: str, lab_a: np.ndarray, lab_b: np.ndarray, config: BootstrapConfig,
                rng: np.random.Generator) -> list[dict]:
    level = config.level
    names, codes = np.unique(np.concatenate([lab_a, lab_b]), return_inverse=True)
    n = len(lab_a)
    k = len(names)
    in_a = np.zeros((n, k), bool)
    in_b = np.zeros((n, k), bool)
    in_a[np.arange(n), codes[:n]] = True
    in_b[np.arange(n), codes[n:]] = True
    only_a = (in_a & ~in_b).sum(axis=0)
    only_b = (in_b & ~in_a).sum(axis=0)
    estimate = (only_a - only_b) / n
    lo, hi = tango_interval(only_a, only_b, np.full(k, n), level)
    band_lo, band_hi = tango_band(in_a & ~in_b, in_b & ~in_a, level, rng, config.n_resamples)
    freq_a = in_a.sum(axis=0) / n
    freq_b = in_b.sum(axis=0) / n
    order = np.argsort(-np.abs(estimate), kind="stable")
    return [{"env": env, "label": names[j], "freq_a": freq_a[j], "freq_b": freq_b[j],
             "diff": estimate[j], "diff_low": lo[j], "diff_high": hi[j],
             "band_low": band_lo[j], "band_high": band_hi[j]} for j in order]


MATCHED_COLUMNS = ("env", "label", "n_a", "n_b", "tested", "measure", "higher_is_better",
                   "mean_a", "mean_b", "diff", "diff_low", "diff_high", "note")


def matched_by_label(episodes: pd.DataFrame, a: str, b: str, *, metric: str = "exact",
                     d_sim: float = 0, min_group: int = MIN_GROUP,
                     config: BootstrapConfig | None = None,
                     measures: tuple[Measure, ...] = MEASURES) -> pd.DataFrame:
    """Compare A and B inside groups of episodes that do the same (or a near) manoeuvre.

    Groups are formed per env. With ``metric="exact"`` (g_SDL, ``d_sim`` 0) a group is every
    episode with one label L that both A and B produce. With ``metric="levenshtein"`` a
    group is anchored at each label L that both produce and holds every episode of A and B
    whose label is within ``d_sim`` token edits of L (groups may then overlap).

    Args:
        episodes: the episode table holding both policies.
        a, b: policy names (B is the reference: differences are A - B).
        metric: ``"exact"`` or ``"levenshtein"`` (:mod:`tap_bench.similarity`).
        d_sim: the largest distance inside a group (``<=``).
        min_group: groups with fewer episodes of A or of B are listed (one row, ``tested``
            False, measure NA) but not tested.
        config: the interval level.
        measures: the measures compared.

    Returns:
        one row per tested group and measure, and one per untested group:
        :data:`MATCHED_COLUMNS`; sorted by env and group size.
    """
    config = config or BootstrapConfig()
    if metric not in ("exact", "levenshtein"):
        raise did_you_mean("metric", metric, ("exact", "levenshtein"))
    if metric == "exact" and d_sim != 0:
        raise ParameterError("d_sim", d_sim, "0 with metric 'exact' (g_SDL is 0 or 1)",
                             hint="Use metric 'levenshtein' for near labels.")
    if isinstance(min_group, bool) or not isinstance(min_group, int) or min_group < 2:
        raise ParameterError("min_group", min_group, "an integer >= 2")
    ok = episodes[(episodes["status"] == "ok") & episodes["sdl"].notna()
                  & episodes["policy"].isin([a, b])]
    rows = []
    for env, sub in ok.groupby("env", sort=True):
        is_a = (sub["policy"] == a).to_numpy()
        lab = sub["sdl"].to_numpy(str)
        names, codes = np.unique(lab, return_inverse=True)
        shared = np.intersect1d(codes[is_a], codes[~is_a])
        present = [m for m in measures if m.name in sub.columns]
        within = (np.eye(len(names), dtype=bool) if metric == "exact" else
            _levenshtein_within(names, d_sim))
        for anchor in shared:
            member = within[anchor][codes]
            ma, mb = member & is_a, member & ~is_a
            key = {"env": env, "label": names[anchor], "n_a": int(ma.sum()),
                   "n_b": int(mb.sum())}
            if ma.sum() < min_group or mb.sum() < min_group:
                rows.append({**key, "tested": False,
                             "note": f"fewer than {min_group} episodes of a policy: not "
                             "tested"})
                continue
            for m in present:
                xa = sub[m.name].to_numpy(float, na_value=np.nan)[ma]
                xb = sub[m.name].to_numpy(float, na_value=np.nan)[mb]
                xa, xb = xa[np.isfinite(xa)], xb[np.isfinite(xb)]
                if len(xa) < min_group or len(xb) < min_group:
                    continue
                lo, hi = unpaired_measure_interval(m, xa, xb, config.level)
                rows.append({**key, "tested": True, "measure": m.name,
                             "higher_is_better": m.higher_is_better,
                             "mean_a": float(xa.mean()), "mean_b": float(xb.mean()),
                             "diff": float(xa.mean() - xb.mean()), "diff_low": lo,
                             "diff_high": hi, "note": ""})
    out = pd.DataFrame(rows, columns=list(MATCHED_COLUMNS))
    if len(out):
        out["tested"] = out["tested"].astype(bool)
        out["note"] = out["note"].fillna("")
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

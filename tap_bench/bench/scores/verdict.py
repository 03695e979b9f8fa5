"""The answer a run gives: per policy, against the reference, in words a reader can act on.

Safety first, then efficiency, then behaviour, each claim with its interval:

1. **safety**: the paired differences (policy - reference, same seeds) of the crash rate,
   the minimum TTC and the minimum time headway (``paired_measures``), pooled over the
   envs and per env. A policy is **less safe** when any of them is worse with its
   interval clear of 0 (pooled or in any env, the worst named), **safer** when one is
   better that way and none worse, else "no safety difference detected" (with the
   intervals, which say how small a difference the seeds could have shown);
2. **efficiency**: the mean speed (faster / slower / no difference detected) and the
   RMS jerk (smoother / harsher);
3. **behaviour**: how often the two choose the same label on a seed (``paired``), and the
   labels whose frequency differs most with its interval clear of 0 (``paired_labels``).

A policy that is less safe is never "better": the overall word is **less safe**,
whatever its speed (a random policy that crashes on most seeds is faster than
IDM). The intervals are those of the tables they come from (``methods`` in
``summary.json``), each at the run's level on its own: a per-env claim is one of (envs x 3)
safety intervals, not corrected across them (the regression gate corrects; this is a
reading of the run). This module adds no statistics, so it costs nothing to build.

Beside the verdict, :func:`one_outcome_cells` names the (env, policy) cells whose seeds all
gave one outcome: their intervals do not come from independent samples.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from tap_bench.bench.measures import MEASURES, SCENE_MEASURES, Measure, measure_entry

__all__ = ["EFFICIENCY_ROLES", "SAFETY_ROLES", "one_outcome_cells", "verdict_lines",
           "verdict_table"]

SAFETY_ROLES = ("safety",)
"""The measure roles (:attr:`~tap_bench.bench.measures.Measure.role`) of the safety family:
the crash rate, min TTC and min headway built in (and off-road and red-light rates of
recorded scenes), in registration order."""
EFFICIENCY_ROLES = ("progress", "comfort")
"""The roles of the efficiency family: mean speed (faster / slower) and RMS jerk (smoother /
harsher) built in; each entry's ``words`` say how it differs."""


def _family(roles: tuple[str, ...]) -> list[Measure]:
    """The registered entries of ``roles``, in registration order (no name listed here)."""
    return [m for m in (*MEASURES, *SCENE_MEASURES) if m.role in roles]


def _side(row: Any) -> int:
    """+1: better with the interval clear of 0; -1: worse; 0: not clear."""
    lo, hi = float(row.diff_low), float(row.diff_high)
    if not (np.isfinite(lo) and np.isfinite(hi)):
        lo = hi = float(row.diff)  # a zero-width interval (every seed the same)
        if lo == 0:
            return 0
    sign = 1 if bool(row.higher_is_better) else -1
    if lo > 0 or hi < 0:
        return sign if lo > 0 else -sign
    return 0


def _fmt(measure: str, diff: float, lo: float, hi: float) -> str:
    entry = measure_entry(measure)
    if entry is None:
        name, unit, scale = measure, "", 1.0
    else:  # a rate's difference in percentage points
        name, scale = entry.label, entry.scale
        unit = "points" if entry.is_rate else entry.display_unit
    if np.isfinite(lo) and np.isfinite(hi):
        interval = f" [{scale * lo:+.2f}, {scale * hi:+.2f}]"
    else:
        interval = " (every seed the same)"
    return f"{name} {scale * diff:+.2f} {unit}{interval}"


def verdict_table(paired_measures: pd.DataFrame, paired: pd.DataFrame | None = None,
                  paired_labels: pd.DataFrame | None = None) -> pd.DataFrame:
    """One row per (policy, area) with the verdict and the claims behind it.

    Args:
        paired_measures: :attr:`Scores.paired_measures` (env incl. "all", measure,
            higher_is_better, diff, diff_low, diff_high, policy_a, policy_b).
        paired: :attr:`Scores.paired` (label agreement per env).
        paired_labels: :attr:`Scores.paired_labels` (per-label frequency differences).

    Returns:
        policy, reference, area (safety, efficiency, behaviour), word, evidence (the
        claims with their intervals, most telling first), and ``overall`` (the policy's
        word: less safe / safer / ...), in policy order.
    """
    pm = paired_measures
    if pm is None or pm.empty:
        return pd.DataFrame(columns=["policy", "reference", "area", "word", "evidence",
                                     "overall"])
    rows = []
    for (policy, reference), sub in pm.groupby(["policy_a", "policy_b"], sort=False):
        if not (sub["env"] == "all").any() and sub["env"].nunique() == 1:
            sub = sub.assign(env="all")  # one env: it is the pooled figure
        worse, better = [], []
        safety = [m.name for m in _family(SAFETY_ROLES)]
        for measure in safety:
            for r in sub[sub["measure"] == measure].itertuples():
                side = _side(r)
                where = "pooled" if r.env == "all" else r.env
                text = f"{_fmt(measure, r.diff, r.diff_low, r.diff_high)} ({where})"
                (worse if side < 0 else better if side > 0 else []).append(
                    (r.env != "all", -abs(float(r.diff)) * measure_entry(measure).scale,
                     text))
        if worse:
            word, claims = "less safe", worse
        elif better:
            word, claims = "safer", better
        else:
            word = "no safety difference detected"
            claims = [(False, 0.0, f"{_fmt(r.measure, r.diff, r.diff_low, r.diff_high)} "
                       "(pooled)") for r in sub[(sub["env"] == "all")
                                                & sub["measure"].isin(safety)].itertuples()]
        claims.sort(key=lambda c: (c[0], c[1]))  # pooled first, then the largest
        rows.append({"policy": policy, "reference": reference, "area": "safety",
                     "word": word, "evidence": "; ".join(c[2] for c in claims[:4])})
        eff = []
        words = []
        for entry in _family(EFFICIENCY_ROLES):
            pooled = sub[(sub["env"] == "all") & (sub["measure"] == entry.name)]
            for r in pooled.itertuples():
                side = _side(r)
                good, bad = entry.words
                words.append(good if side > 0 else bad if side < 0 else
                             f"no {entry.label} difference detected")
                eff.append(f"{_fmt(entry.name, r.diff, r.diff_low, r.diff_high)} (pooled)")
        rows.append({"policy": policy, "reference": reference, "area": "efficiency",
                     "word": ", ".join(words) or "not measured", "evidence": "; ".join(eff)})
        rows.append({"policy": policy, "reference": reference, "area": "behaviour",
                     **_behaviour(policy, reference, paired, paired_labels)})
    out = pd.DataFrame(rows)
    overall = {}
    for policy, sub in out.groupby("policy", sort=False):
        safety = sub.loc[sub["area"] == "safety", "word"].iloc[0]
        eff = sub.loc[sub["area"] == "efficiency", "word"].iloc[0]
        overall[policy] = (safety if safety != "no safety difference detected"
                           else f"as safe as far as the seeds show; {eff}")
    out["overall"] = out["policy"].map(overall)
    return out


def _behaviour(policy: str, reference: str, paired: pd.DataFrame | None,
               labels: pd.DataFrame | None) -> dict[str, str]:
    bits = []
    word = "no label difference detected"
    if paired is not None and len(paired):
        p = paired[(paired["policy_a"] == policy) & (paired["policy_b"] == reference)]
        pooled, per_env = p[p["env"] == "all"], p[p["env"] != "all"]
        if len(pooled):
            r = pooled.iloc[0]
            head = (f"same label on {100 * r.agreement:.0f} % [{100 * r.agreement_low:.0f}, "
                    f"{100 * r.agreement_high:.0f}] of the seeds")
        elif len(per_env):
            share = float((per_env["agreement"] * per_env["n_pairs"]).sum()
                          / per_env["n_pairs"].sum())
            head = f"same label on {100 * share:.0f} % of the seeds"
        else:
            head = ""
        if head:
            spread = ", ".join(f"{r.env} {100 * r.agreement:.0f} %" for r in
                               per_env.itertuples())
            bits.append(head + (f" ({spread})" if len(per_env) > 1 else ""))
    if labels is not None and len(labels):
        lab = labels[(labels["policy_a"] == policy) & (labels["policy_b"] == reference)]
        clear = lab[(lab["diff_low"] > 0) | (lab["diff_high"] < 0)]
        if len(clear):
            word = "behaves differently"
            top = clear.reindex(clear["diff"].abs().sort_values(ascending=False).index)[:3]
            bits += [f"'{r.label}' {100 * r.diff:+.0f} points [{100 * r.diff_low:+.0f}, "
                     f"{100 * r.diff_high:+.0f}] ({r.env})" for r in top.itertuples()]
    return {"word": word, "evidence": "; ".join(bits)}


def one_outcome_cells(episodes: pd.DataFrame) -> pd.DataFrame:
    """The (env, policy) cells whose finished episodes all have one outcome: the same
    label and the same measures (to 1e-9) on every seed, so the seeds are not independent
    samples (a scene that does not vary with its seed, or a policy that ignores it).

    Args:
        episodes: an episode table (:data:`tap_bench.bench.episodes.EPISODE_COLUMNS`).

    Returns:
        env, policy, n (finished episodes, at least 2), one row per such cell.
    """
    ok = episodes[episodes["status"] == "ok"] if "status" in episodes.columns else episodes
    cols = ["sdl", *(m.name for m in MEASURES if m.name in ok.columns)]
    rows = []
    for (env, policy), sub in ok.groupby(["env", "policy"], sort=True):
        if len(sub) < 2:
            continue
        key = pd.DataFrame({c: (sub[c].astype("string").fillna("<NA>") if c == "sdl" else
                                pd.to_numeric(sub[c], errors="coerce").round(9)
                                .astype("string").fillna("<NA>")) for c in cols})
        if len(key.drop_duplicates()) == 1:
            rows.append({"env": env, "policy": policy, "n": len(sub)})
    return pd.DataFrame(rows, columns=["env", "policy", "n"])


def verdict_lines(table: pd.DataFrame) -> list[str]:
    """The verdict as plain-text lines, one block per policy (the demo prints them)."""
    lines = []
    for policy, sub in table.groupby("policy", sort=False):
        ref = sub["reference"].iloc[0]
        lines.append(f"{policy} vs {ref}: {sub['overall'].iloc[0].upper()}")
        for r in sub.itertuples():
            lines.append(f"  {r.area}: {r.word}" + (f": {r.evidence}" if r.evidence else ""))
    return lines

"""Agreement with a reference policy on the same scenes: on recorded WOMD scenes, how often a
policy did what the human did (SPEC section 8).

On a real scene the policy ``log`` replays the human who drove it, so its labels are the
log's. A policy and the human are paired by scenario (a seed of a WOMD env is a scenario's
index in its files: the same scene, the same start) and their ego labels compared axis by
axis: the lateral sequence, the longitudinal sequence, the interaction sequence (SPEC 7) and
the whole SDL label. The agreement is a proportion of paired scenes, with its Wilson score
interval (:func:`tap_bench.stats.intervals.wilson_interval`, whose coverage
``benchmarks/interval_coverage.py`` measures).

Beside it, per policy, the closed-loop measures of recorded scenes (off road, route
progress, red lights run, distance to the human's path) and collisions, with the reference's
own values: a human whose boxes overlap another's in the log has a non-zero collision rate,
and that is the floor a policy is read against.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tap_bench.bench.measures import MEASURES, SCENE_MEASURES
from tap_bench.stats.intervals import wilson_interval

__all__ = ["AGREEMENT_AXES", "AGREEMENT_COLUMNS", "SCENE_SUMMARY_MEASURES",
           "agreement_with_reference", "scene_summary", "scene_summary_measures"]

AGREEMENT_AXES = ("lateral", "longitudinal", "interaction", "sdl")
"""The label axes compared, in report order (``sdl`` is lateral and longitudinal together)."""
AGREEMENT_COLUMNS = ("env", "policy", "axis", "pairs", "agree", "share", "low", "high")
"""Columns of :func:`agreement_with_reference`'s table."""
def scene_summary_measures() -> tuple[str, ...]:
    """Measures :func:`scene_summary` averages per policy (those the episodes carry): the
    safety rates of :data:`~tap_bench.bench.measures.MEASURES` (the crash rate built in) and
    every measure of recorded scenes (:data:`~tap_bench.bench.measures.SCENE_MEASURES`),
    read from the entries, not named here."""
    return (*(m.name for m in MEASURES if m.role == "safety" and m.is_rate),
            *(m.name for m in SCENE_MEASURES))


SCENE_SUMMARY_MEASURES = scene_summary_measures()
"""The built-in :func:`scene_summary_measures` (crash rate, at-fault crash rate, off road,
route progress, red light, log ADE and FDE), kept for old imports; :func:`scene_summary`
asks again each call."""


def _ok(episodes: pd.DataFrame) -> pd.DataFrame:
    if "status" in episodes.columns:
        return episodes[episodes["status"].fillna("ok").to_numpy() == "ok"]
    return episodes


def agreement_with_reference(episodes: pd.DataFrame, reference: str = "log", *,
                             level: float = 0.95) -> pd.DataFrame:
    """How often each policy's ego label equals the reference's on the same scene.

    Args:
        episodes: the episode table (:mod:`tap_bench.bench.episodes`): env, policy, seed and
            the label columns; failed episodes are left out, and so are the pairs in which
            either side has no label on an axis.
        reference: the reference policy (``log``, the human, on recorded scenes).
        level: the intervals' two-sided level.

    Returns:
        one row per (env, policy other than the reference, axis): ``pairs`` compared,
        ``agree`` (equal labels), ``share`` and its Wilson interval ``low``, ``high``.
        Empty when the reference did not run.
    """
    ok = _ok(episodes)
    axes = [a for a in AGREEMENT_AXES if a in ok.columns]
    ref = ok[ok["policy"] == reference][["env", "seed", *axes]]
    rows = []
    if ref.empty:
        return pd.DataFrame(columns=list(AGREEMENT_COLUMNS))
    others = ok[ok["policy"] != reference]
    pairs = others.merge(ref, on=["env", "seed"], suffixes=("", "_ref"))
    for (env, policy), group in pairs.groupby(["env", "policy"], sort=True):
        for axis in axes:
            mine = group[axis].astype("string")
            theirs = group[f"{axis}_ref"].astype("string")
            both = (mine.notna() & theirs.notna()).to_numpy(bool)
            n = int(both.sum())
            agree = int((mine[both] == theirs[both]).sum())
            low, high = wilson_interval(agree, n, level)
            rows.append({"env": env, "policy": policy, "axis": axis, "pairs": n,
                         "agree": agree, "share": agree / n if n else np.nan,
                         "low": low, "high": high})
    return pd.DataFrame(rows, columns=list(AGREEMENT_COLUMNS))


def scene_summary(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per (env, policy): episodes and the mean of each closed-loop measure of recorded
    scenes (:func:`scene_summary_measures` present in the table; NaN values left out)."""
    ok = _ok(episodes)
    present = [m for m in scene_summary_measures() if m in ok.columns]
    table = ok[["env", "policy", *present]].copy()
    for col in present:
        table[col] = pd.to_numeric(table[col].astype("Float64"), errors="coerce")
    out = table.groupby(["env", "policy"], sort=True).agg(
        episodes=("policy", "size"), **{m: (m, "mean") for m in present})
    return out.reset_index()

"""The realism score over scenes: means, groups (object type, manoeuvre) and intervals.

Input: the concatenated per-agent tables of :func:`tap_bench.realism.rollouts.score_scene`
(one row per scene, agent and feature). A scene's value of a feature (or of the meta-metric)
pools its agents' log-probabilities (:func:`tap_bench.realism.score.pooled`); the score over
scenes is the mean of the scenes' values, as WOSAC averages its per-scenario metrics. A
group (the vehicles; the agents whose logged manoeuvre is a left turn) is scored the same
way on its own agents, over the scenes that have some.

Intervals: percentile bootstrap over scenes (scenes drawn with replacement, every statistic
recomputed), the stream named ``("realism", "scenes")`` under the seed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.realism.score import BERNOULLI_FEATURES, FEATURES, WOSAC_2025, FeatureSpec, pooled
from tap_bench.stats.bootstrap import BootstrapConfig

__all__ = ["VERSION", "scene_values", "summarise"]

VERSION = ("WOSAC 2025 sim agents (challenge_2025_sim_agents_config): histogram and "
           "Bernoulli likelihoods, meta-metric weights as published")
"""The definition the score follows."""

STATS = (*FEATURES, "meta_metric")
RATES = {"collision_indication": "collision", "offroad_indication": "offroad",
         "traffic_light_violation": "traffic_light_violation"}


def scene_values(agents: pd.DataFrame, specs: Mapping[str, FeatureSpec] = WOSAC_2025
                 ) -> pd.DataFrame:
    """One row per scene: each feature's likelihood and the meta-metric over its agents,
    ``agents`` (evaluated agents), and the simulated rates of collision, off-road and
    traffic-light violation (mean over agents of the share of rollouts)."""
    rows = []
    for scene, group in agents.groupby("scenario_id", sort=False):
        row: dict[str, Any] = {"scenario_id": scene, **pooled(group, specs),
                               "agents": int(group.loc[group["feature"] == FEATURES[0],
                                                       "track_id"].nunique())}
        for feature, name in RATES.items():
            at = group["feature"] == feature
            row[f"simulated_{name}_rate"] = float(group.loc[at, "simulated_rate"].mean()) \
                if at.any() else float("nan")
        rows.append(row)
    return pd.DataFrame(rows)


def _interval(values: np.ndarray, weights: np.ndarray, level: float) -> tuple[float, float]:
    """Percentile interval of the weighted means ``weights @ values / weights.sum()`` of
    bootstrap resamples (NaN values and empty resamples skipped)."""
    ok = np.isfinite(values)
    if ok.sum() < 2:
        return float("nan"), float("nan")
    w = weights[:, ok]
    total = w.sum(axis=1)
    means = (w @ values[ok])[total > 0] / total[total > 0]
    lo, hi = np.quantile(means, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def _block(values: pd.DataFrame, weights: np.ndarray, config: BootstrapConfig,
           index: pd.Index) -> dict[str, Any]:
    """Mean and interval of every statistic over the scenes of ``values`` (aligned on
    ``index``: the scenes of the resample weights)."""
    aligned = values.set_index("scenario_id").reindex(index)
    out: dict[str, Any] = {"scenes": int(aligned["meta_metric"].notna().sum())}
    for name in (*STATS, *[c for c in values.columns if c.startswith("simulated_")]):
        v = aligned[name].to_numpy(float)
        lo, hi = _interval(v, weights, config.level)
        finite = v[np.isfinite(v)]
        out[name] = {"value": float(finite.mean()) if len(finite) else float("nan"),
                     "low": lo, "high": hi}
    return out


def summarise(agents: pd.DataFrame, config: BootstrapConfig | None = None,
              specs: Mapping[str, FeatureSpec] = WOSAC_2025) -> dict[str, Any]:
    """The realism score of a run: overall, per object type and per manoeuvre.

    Args:
        agents: rows of :func:`~tap_bench.realism.rollouts.score_scene` for every scene.
        config: bootstrap resamples, level and seed.
        specs: the features.

    Returns:
        ``{"definition", "weights", "scenes", "agents", "overall": {stat: {value, low,
        high}}, "by_object_type": {type: {...}}, "by_manoeuvre": {label: {...}},
        "per_scene": [...]}``, every ``{...}`` with ``scenes`` and ``agents`` counts.
    """
    config = config or BootstrapConfig()
    per_scene = scene_values(agents, specs)
    index = pd.Index(per_scene["scenario_id"])
    rng = config.rng("realism", "scenes")
    n = len(index)
    weights = rng.multinomial(n, np.full(n, 1 / n), size=config.n_resamples).astype(float) \
        if n else np.zeros((config.n_resamples, 0))
    first = agents["feature"] == FEATURES[0]
    out: dict[str, Any] = {
        "definition": VERSION,
        "weights": {name: spec.weight for name, spec in specs.items()},
        "bins": {name: {"low": s.low, "high": s.high, "bins": s.bins,
                        "pseudocount": s.pseudocount} if s.bins else
                 {"bernoulli": True, "pseudocount": s.pseudocount}
                 for name, s in specs.items()},
        "scenes": n,
        "agents": int(first.sum()),
        "interval": f"{config.level:.0%} percentile bootstrap over scenes, "
                    f"{config.n_resamples} resamples, seed {config.seed}",
        "overall": _block(per_scene, weights, config, index),
    }
    for key, column in (("by_object_type", "object_type"), ("by_manoeuvre", "manoeuvre")):
        groups = {}
        for value, rows in agents.groupby(column, sort=True):
            block = _block(scene_values(rows, specs), weights, config, index)
            block["agents"] = int((rows["feature"] == FEATURES[0]).sum())
            groups[str(value)] = block
        out[key] = groups
    out["per_scene"] = per_scene.to_dict(orient="records")
    out["bernoulli_features"] = list(BERNOULLI_FEATURES)
    return out

"""The realism score over scenes: means, groups (object type, manoeuvre) and intervals.

Input: the per-agent tables of :func:`tap_bench.realism.rollouts.score_scene` (one row per
scene, agent and feature). A scene's value of a feature (or of the meta-metric) pools its
agents' log-probabilities (:func:`tap_bench.realism.score.pooled`); the score over scenes is
the mean of the scenes' values, as WOSAC averages its per-scenario metrics. A group (the
vehicles; the agents whose logged manoeuvre is a left turn) is scored the same way on its
own agents, over the scenes that have some.

:class:`SceneScores` takes the tables one scene at a time and keeps only each scene's values
(a row per scene and group), so a run over any number of scenes holds no agent's rows
longer than its scene; :func:`summarise` is the same over one table of many scenes.

Intervals: percentile bootstrap over scenes (scenes drawn with replacement, every statistic
recomputed), the stream named ``("realism", "scenes")`` under the seed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from tap_bench.errors import ParameterError
from tap_bench.realism.score import BERNOULLI_FEATURES, FEATURES, WOSAC_2025, FeatureSpec, pooled
from tap_bench.stats.bootstrap import BootstrapConfig

__all__ = ["VERSION", "SceneScores", "scene_values", "summarise"]

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
            row[f"simulated_{name}_rate"] = (float(group.loc[at, "simulated_rate"].mean())
                if at.any() else float("nan"))
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


GROUPS = (("by_object_type", "object_type"), ("by_manoeuvre", "manoeuvre"))
"""The groups scored on their own agents: result key, agent table column."""
KEPT_ROWS = 512
"""Scene values gathered before they are joined into one table (fewer small tables)."""


class SceneScores:
    """The realism score gathered one scene at a time.

    :meth:`add` takes one scene's rows of :func:`~tap_bench.realism.rollouts.score_scene`
    and keeps only its values (:func:`scene_values` over all its agents and over each
    object type's and manoeuvre's agents: a few rows a scene); :meth:`summary` gives what
    :func:`summarise` gives for all the scenes' rows in one table, float for float.

    Args:
        specs: the features.
    """

    def __init__(self, specs: Mapping[str, FeatureSpec] = WOSAC_2025) -> None:
        self.specs = specs
        self._tables: dict[str, list[pd.DataFrame]] = {"overall": [],
                                                       **{k: [] for k, _ in GROUPS}}
        self._pending: dict[str, list[pd.DataFrame]] = {k: [] for k in self._tables}
        self.scenes = 0
        self._seen: set[str] = set()

    def add(self, agents: pd.DataFrame) -> None:
        """Keep one scene's values.

        Args:
            agents: the scene's rows (one ``scenario_id``); no rows: the scene adds nothing
                (it has no evaluated agent, as in :func:`summarise`).

        Raises:
            ParameterError: the scenario was added before.
        """
        if not len(agents):
            return
        scene = str(agents["scenario_id"].iat[0])
        if scene in self._seen:
            raise ParameterError("agents", f"scenario {scene}", "the rows of a scenario "
                                 "not added before (a scene is added once, its rows "
                                 "together)")
        self._seen.add(scene)
        self._keep("overall", self._values(agents, None))
        for key, column in GROUPS:
            for value, rows in agents.groupby(column, sort=True):
                self._keep(key, self._values(rows, str(value)))
        self.scenes += 1

    def _values(self, rows: pd.DataFrame, group: str | None) -> pd.DataFrame:
        values = scene_values(rows, self.specs)
        values["agent_rows"] = int((rows["feature"] == FEATURES[0]).sum())
        if group is not None:
            values["group"] = group
        return values

    def _keep(self, key: str, values: pd.DataFrame) -> None:
        pending = self._pending[key]
        pending.append(values)
        if len(pending) >= KEPT_ROWS:
            self._tables[key].append(pd.concat(pending, ignore_index=True))
            pending.clear()

    def _table(self, key: str) -> pd.DataFrame:
        frames = [*self._tables[key], *self._pending[key]]
        if not frames:
            return pd.DataFrame(columns=["scenario_id", *STATS, "agents", "agent_rows",
                                         "group"])
        return pd.concat(frames, ignore_index=True)

    def summary(self, config: BootstrapConfig | None = None) -> dict[str, Any]:
        """The realism score of the scenes added (:func:`summarise`'s result)."""
        config = config or BootstrapConfig()
        overall = self._table("overall")
        per_scene = overall.drop(columns=["agent_rows"])
        index = pd.Index(per_scene["scenario_id"])
        rng = config.rng("realism", "scenes")
        n = len(index)
        weights = rng.multinomial(n, np.full(n, 1 / n), size=config.n_resamples).astype(
            float) if n else np.zeros((config.n_resamples, 0))
        specs = self.specs
        out: dict[str, Any] = {
            "definition": VERSION,
            "weights": {name: spec.weight for name, spec in specs.items()},
            "bins": {name: {"low": s.low, "high": s.high, "bins": s.bins,
                            "pseudocount": s.pseudocount} if s.bins else
                     {"bernoulli": True, "pseudocount": s.pseudocount}
                     for name, s in specs.items()},
            "scenes": n,
            "agents": int(overall["agent_rows"].sum()),
            "interval": f"{config.level:.0%} percentile bootstrap over scenes, "
                        f"{config.n_resamples} resamples, seed {config.seed}",
            "overall": _block(per_scene, weights, config, index),
        }
        for key, _ in GROUPS:
            table = self._table(key)
            groups = {}
            for value in sorted(table["group"].unique()):
                rows = table[table["group"] == value]
                block = _block(rows.drop(columns=["group", "agent_rows"]), weights, config,
                               index)
                block["agents"] = int(rows["agent_rows"].sum())
                groups[str(value)] = block
            out[key] = groups
        out["per_scene"] = per_scene.to_dict(orient="records")
        out["bernoulli_features"] = list(BERNOULLI_FEATURES)
        return out


def summarise(agents: pd.DataFrame, config: BootstrapConfig | None = None,
              specs: Mapping[str, FeatureSpec] = WOSAC_2025) -> dict[str, Any]:
    """The realism score of a run: overall, per object type and per manoeuvre.

    Args:
        agents: rows of :func:`~tap_bench.realism.rollouts.score_scene` for every scene
            (rows of one ``scenario_id`` are one scene, wherever they are).
        config: bootstrap resamples, level and seed.
        specs: the features.

    Returns:
        ``{"definition", "weights", "scenes", "agents", "overall": {stat: {value, low,
        high}}, "by_object_type": {type: {...}}, "by_manoeuvre": {label: {...}},
        "per_scene": [...]}``, every ``{...}`` with ``scenes`` and ``agents`` counts.
    """
    scores = SceneScores(specs)
    for _, scene in agents.groupby("scenario_id", sort=False):
        scores.add(scene)
    return scores.summary(config)

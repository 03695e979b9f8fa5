"""Scenarios matched across data sets: each highway-env episode beside
its nearest WOMD scenarios by scenario-level SDL.

The scenario-level SDL and its distance are :mod:`tap_bench.similarity.scenario_sdl`'s
(Scenario2Vector: actors, their actions, scene elements; weighted set distance). This
module only puts the two data sets side by side: for every simulated episode, the ``top``
nearest WOMD scenarios, with the policy's ego label beside the label of WOMD's ego (the
self-driving car) and of the human-driven vehicles there, so a policy's response reads
against what drivers did in a similar situation.

Actors are the tracks that come within ``radius`` metres of the ego at a common time step
(both data sets record far more of the road than the ego interacts with: 20 highway-env
vehicles over a kilometre, up to 128 WOMD agents).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tap_bench.errors import LabelTableError
from tap_bench.similarity.scenario_sdl import rank_scenarios, scenario_set

__all__ = ["DEFAULT_RADIUS", "match_scenarios"]

DEFAULT_RADIUS = 50.0  # [m] actors are the tracks within this distance of the ego


def _ego_label(labels: pd.DataFrame, level: str) -> pd.Series:
    """scenario_id -> the ego's SDL label at ``level`` (its longest segment)."""
    table = labels[labels["level"] == level] if "level" in labels.columns else labels
    table = table[table["is_ego"].fillna(False).to_numpy(bool)]
    dur = (table["t_end"] - table["t_start"]).to_numpy(float)
    table = table.iloc[np.argsort(-dur, kind="stable")].drop_duplicates("scenario_id")
    return table.set_index("scenario_id")["sdl"].astype(str)


def _other_labels(labels: pd.DataFrame, level: str) -> pd.Series:
    """scenario_id -> the most common label of the scenario's other vehicles (with count)."""
    table = labels[labels["level"] == level] if "level" in labels.columns else labels
    table = table[~table["is_ego"].fillna(False).to_numpy(bool)]
    if "object_type" in table.columns:
        table = table[table["object_type"] == "vehicle"]
    if table.empty:
        return pd.Series(dtype=str)
    counts = table.groupby(["scenario_id", "sdl"]).size().rename("n").reset_index()
    total = counts.groupby("scenario_id")["n"].transform("sum")
    counts = counts.sort_values(["scenario_id", "n", "sdl"], ascending=[True, False, True])
    top = counts.drop_duplicates("scenario_id")
    return pd.Series([f"{s} ({n}/{t} vehicles)" for s, n, t in
                      zip(top["sdl"], top["n"], total[top.index], strict=True)],
                     index=top["scenario_id"].to_numpy())


def match_scenarios(sim_labels: pd.DataFrame, sim_trajectories: pd.DataFrame | None,
                    womd_labels: pd.DataFrame, womd_trajectories: pd.DataFrame | None, *,
                    level: str = "maneuver", top: int = 3,
                    radius: float | None = DEFAULT_RADIUS) -> pd.DataFrame:
    """The ``top`` nearest WOMD scenarios of every simulated episode.

    Args:
        sim_labels: label table of the rollouts (all tracks; ``is_ego``, ``env``,
            ``policy``, ``seed``).
        sim_trajectories: their trajectory table (needed for ``radius``).
        womd_labels: label table of the WOMD scenarios (``is_ego`` marks the SDC).
        womd_trajectories: their trajectory table (needed for ``radius``).
        level: SDL level of the actions.
        top: matches per episode.
        radius: actors within this distance of the ego [m]; None: every track.

    Returns:
        one row per (episode, match): env, policy, seed, scenario_id, ego_sdl, rank,
        womd_scenario_id, distance, same_actions, the six distance counts, womd_ego_sdl,
        womd_vehicles_sdl (the most common label of WOMD's other vehicles).
    """
    for name, table in (("simulated", sim_labels), ("WOMD", womd_labels)):
        if "is_ego" not in table.columns:
            raise LabelTableError(f"{name} labels need an is_ego column to match scenarios "
                                  "by what happens around the ego.")
    use_radius = (radius if sim_trajectories is not None and womd_trajectories is not None
        else None)
    sim = scenario_set(sim_labels, sim_trajectories, level=level, radius=use_radius,
                       source="simulated labels")
    womd = scenario_set(womd_labels, womd_trajectories, level=level, radius=use_radius,
                        source="WOMD labels")
    sim_ego = _ego_label(sim_labels, level)
    womd_ego = _ego_label(womd_labels, level)
    womd_others = _other_labels(womd_labels, level)
    ids = sim_labels.drop_duplicates("scenario_id").set_index("scenario_id")
    rows = []
    for i, sid in enumerate(sim.scenario_ids):
        ranked = rank_scenarios(sim.description(i), womd, top=top)
        meta = ids.loc[sid]
        for r in ranked.to_dict("records"):
            rows.append({
                "env": meta.get("env", ""), "policy": meta.get("policy", ""),
                "seed": meta.get("seed", pd.NA), "scenario_id": sid,
                "ego_sdl": sim_ego.get(sid, pd.NA), "rank": r["rank"],
                "womd_scenario_id": r["scenario_id"], "distance": r["distance"],
                "same_actions": r["same_actions"],
                **{k: r[k] for k in r if k.startswith(("missing_", "extra_"))},
                "womd_ego_sdl": womd_ego.get(r["scenario_id"], pd.NA),
                "womd_vehicles_sdl": womd_others.get(r["scenario_id"], pd.NA)})
    return pd.DataFrame(rows)

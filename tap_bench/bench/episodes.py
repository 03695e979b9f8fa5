"""The benchmark's episode table: one row per (env, policy, seed) with the ego's label and
its safety and efficiency measures.

Every score of :mod:`tap_bench.bench` (comparisons, coverage, unique manoeuvres, the gate)
reads this one table:

=================  =========================================================================
column             what
=================  =========================================================================
``env``            scenario name (``highway``); ``""`` for data without envs
``policy``         policy name
``seed``           int; the same seed is the same initial traffic for every policy
``scenario_id``    the episode's scenario id in the trajectory and label tables
``status``         ``"ok"``, or ``"error"`` for an episode that failed (kept, not scored)
``error``          why it failed ("" when ok)
``sdl``            the ego's SDL label at the chosen level; NA when the ego has no label
``lateral``        its lateral sequence
``longitudinal``   its longitudinal sequence
``interaction``    its interaction sequence (SPEC 7), when the labels carry one
``return``         sum of rewards (rollouts only)
measures           ``crashed``, ``mean_speed``, ``min_headway_s``, ``min_ttc_s``,
                   ``rms_jerk``, ``duration_s`` (:mod:`tap_bench.bench.measures`)
=================  =========================================================================

The ego's label is the label of its longest valid segment (highway-env egos have exactly
one; an ego with gaps in its record keeps its main stretch).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.bench.measures import MEASURES, EgoSteps, ego_measures
from tap_bench.errors import LabelTableError, ParameterError, TrajectoryTableError
from tap_bench.labelling import tap
from tap_bench.pathframe import LaneMap

__all__ = ["EPISODE_COLUMNS", "ego_labels", "episode_table", "episodes_from_table"]

EPISODE_COLUMNS = ("env", "policy", "seed", "scenario_id", "status", "error", "sdl", "lateral",
                   "longitudinal", "return", *(m.name for m in MEASURES), "duration_s")
"""Columns of the episode table, in order."""

_LABEL_FIELDS = ("sdl", "lateral", "longitudinal")
_SHARED = ("crashed", "mean_speed", "duration_s", "scenario_id")
"""Columns both the ego measures and a rollout's episode table carry (recorded scenes' too
have a ``scenario_id``: merged on both sides it was suffixed away and read as NA)."""


def _ego_mask(table: pd.DataFrame, source: str) -> np.ndarray:
    if "is_ego" in table.columns:
        return table["is_ego"].fillna(False).to_numpy(bool)
    per_scenario = table.groupby("scenario_id", sort=False)["track_id"].nunique()
    if (per_scenario > 1).any():
        sid = per_scenario.index[np.argmax(per_scenario.to_numpy() > 1)]
        raise LabelTableError(
            f"{source}: scenario {sid!r} has {per_scenario[sid]} tracks and no is_ego column "
            "says which one the policy drove; add a boolean is_ego column.")
    return np.ones(len(table), bool)


def ego_labels(labels: pd.DataFrame, level: str, *, source: str = "label table"
               ) -> pd.DataFrame:
    """The ego's label of every scenario of a label table at ``level``.

    Args:
        labels: a label table (SPEC section 1) with ``is_ego`` (or one track per scenario).
        level: the SDL level to take.
        source: a name for the table in error messages.

    Returns:
        one row per scenario: scenario_id, sdl, lateral, longitudinal, interaction (when
        labelled) and the identifying columns env, policy, seed present in the input.
    """
    missing = [c for c in ("scenario_id", "track_id", *_LABEL_FIELDS) if c not in labels]
    if missing:
        raise LabelTableError(f"{source}: missing column(s) {', '.join(missing)}; a label "
                              "table comes from 'tap-bench label' or tap_bench.label().")
    # the rows taken by position, one frame made at the end (no filtered frame a step)
    rows = np.arange(len(labels))
    if "level" in labels.columns:
        at_level = labels["level"].to_numpy() == level
        if not at_level.any():
            present = set(labels["level"].unique())
            raise LabelTableError(f"{source}: no rows at level {level!r}; it holds "
                                  f"{', '.join(sorted(map(str, present)))}. Label it with "
                                  f"--level {level} or --level all.")
        rows = rows[at_level]
    if "is_ego" in labels.columns:
        rows = rows[labels["is_ego"].fillna(False).to_numpy(bool)[rows]]
    else:
        rows = rows[_ego_mask(labels.iloc[rows], source)]
    duration = ((labels["t_end"].to_numpy(float) - labels["t_start"].to_numpy(float))[rows]
        if "t_end" in labels else np.zeros(len(rows)))
    rows = rows[np.lexsort((-duration,))]
    # the first (longest) row of each scenario, in that order (drop_duplicates keep="first")
    codes, _ = pd.factorize(labels["scenario_id"].take(rows), use_na_sentinel=False)
    rows = rows[np.sort(np.unique(codes, return_index=True)[1])]
    keep = ["scenario_id", *_LABEL_FIELDS, *(c for c in ("interaction", "env", "policy",
                                                        "seed") if c in labels.columns)]
    out = labels[keep].take(rows).reset_index(drop=True)
    if "interaction" in out.columns:  # episodes compare by what happened, not by track ids
        out["interaction"] = out["interaction"].map(sdl.anonymous_others).astype("string")
    return out


def episode_table(*, labels: pd.DataFrame | None = None,
                  trajectories: pd.DataFrame | None = None,
                  episodes: pd.DataFrame | None = None, level: str = "action",
                  policy: str | None = None, source: str = "input",
                  map_table: pd.DataFrame | LaneMap | None = None,
                  steps: EgoSteps | None = None) -> pd.DataFrame:
    """Build the episode table from what is at hand.

    Args:
        labels: label table of the trajectories (the ego's label is taken from it).
        trajectories: trajectory table; gives the measures (and ``crashed``).
        episodes: a rollout's episode table (:data:`tap_bench.sim.rollout.EPISODE_COLUMNS`);
            gives ``return``, ``status`` and the failed episodes.
        level: SDL level of the ego label.
        policy: the policy name when the tables have no ``policy`` column.
        source: a name for error messages (a file path).
        map_table: lane centre lines along which an ego's path goes on beyond its record
            for the measures (:func:`~tap_bench.bench.measures.ego_measures`); None: an arc.
        steps: the ego's steps of ``trajectories`` where the caller has them already.

    Returns:
        the episode table (:data:`EPISODE_COLUMNS`), sorted by env, policy and seed.

    Raises:
        LabelTableError, TrajectoryTableError: a table lacks what the benchmark needs; the
            message names the column and the fix.
    """
    if labels is None and trajectories is None and episodes is None:
        raise ParameterError("labels, trajectories, episodes", None, "",
            message="episode_table needs labels, trajectories or episodes.")
    out = None
    if trajectories is not None:
        out = ego_measures(trajectories, map_table, steps=steps)  # every scenario with an ego
    if labels is not None:
        ego = ego_labels(labels, level, source=source)
        if out is None:
            out = ego
        else:
            out = _with_labels(out, ego[["scenario_id", *_LABEL_FIELDS,
                                         *(["interaction"] if "interaction" in ego else [])]])
    if out is not None:
        out = _fill_ids(out, policy, source)
    if episodes is not None:
        eps = episodes.copy()
        if policy is not None and "policy" not in eps:
            eps["policy"] = policy
        for col in ("env", "policy", "seed"):
            if col not in eps:
                raise TrajectoryTableError(f"{source}: the episode table has no {col!r} column; "
                                           "it comes from tap_bench.rollout().", column=col)
        # columns both tables carry: the trajectories' value, else the rollout's (a failed
        # episode has no trajectory)
        eps = eps.rename(columns={c: f"_{c}" for c in _SHARED if c in eps.columns})
        eps["seed"] = eps["seed"].astype(np.int64)
        if out is None:
            out = eps.rename(columns={f"_{c}": c for c in _SHARED})
        else:
            out = _with_rollout(out, eps)
            for col in _SHARED:
                if f"_{col}" not in out:
                    continue
                out[col] = (out[col].where(out[col].notna(), out.pop(f"_{col}"))
                    if col in out else out.pop(f"_{col}"))
    for col in EPISODE_COLUMNS:
        if col not in out.columns:
            out[col] = _default(col)
    out["status"] = out["status"].fillna("ok")
    out["error"] = out["error"].fillna("")
    out["env"] = out["env"].fillna("").astype(str)
    out["crashed"] = out["crashed"].astype("boolean")
    for col in (*_LABEL_FIELDS, *(["interaction"] if "interaction" in out else [])):
        out[col] = out[col].astype("string")
    dup = out.duplicated(["env", "policy", "seed"], keep=False)
    if dup.any():
        row = out[dup].iloc[0]
        raise LabelTableError(
            f"{source}: env {row['env']!r}, policy {row['policy']!r}, seed {row['seed']} occurs "
            "in several scenarios; one seed is one episode. Give each run its own seeds or "
            "split the tables.")
    out = out[list(EPISODE_COLUMNS) + [c for c in out.columns if c not in EPISODE_COLUMNS]]
    return out.sort_values(["env", "policy", "seed"], kind="stable").reset_index(drop=True)


def _with_labels(out: pd.DataFrame, ego: pd.DataFrame) -> pd.DataFrame:
    """``out.merge(ego, on="scenario_id", how="left")`` (``ego``: one row per scenario):
    the label columns taken by position where every scenario of ``out`` has its label
    (the batch's case, without a merge's hashing and copies); the merge itself otherwise
    (its missing values, its suffixes)."""
    fields = [c for c in ego.columns if c != "scenario_id"]
    pos = (pd.Index(ego["scenario_id"]).get_indexer(out["scenario_id"])
        if len(out) and ego["scenario_id"].is_unique else None)
    if pos is None or (pos < 0).any() or any(c in out.columns for c in fields):
        return out.merge(ego, on="scenario_id", how="left")
    return pd.concat([out, ego[fields].take(pos).reset_index(drop=True)], axis=1)


_KEYS = ["env", "policy", "seed"]


def _with_rollout(out: pd.DataFrame, eps: pd.DataFrame) -> pd.DataFrame:
    """``out.merge(eps, on=["env", "policy", "seed"], how="outer")`` up to the order of its
    rows (the episode table is sorted by these keys afterwards): where both tables hold the
    same episodes once each under keys of one dtype (a batch's measures and its rollout
    rows), ``eps``' columns are taken by position, without the merge's hashing, sorting and
    copies; the merge itself otherwise (its missing values, its dtypes, its suffixes)."""
    def keys(table: pd.DataFrame) -> list[tuple]:
        return list(zip(*(table[c].tolist() for c in _KEYS), strict=True))

    fields = [c for c in eps.columns if c not in _KEYS]
    simple = (len(out) == len(eps) > 0 and not any(c in out.columns for c in fields)
        and all(out[c].dtype == eps[c].dtype for c in _KEYS)
        and not any(out[c].isna().any() or eps[c].isna().any() for c in _KEYS))
    if simple:
        position = {key: k for k, key in enumerate(keys(eps))}
        pos = [position.get(key, -1) for key in keys(out)]
        simple = len(position) == len(eps) and len(set(pos)) == len(pos) and -1 not in pos
    if not simple:
        return out.merge(eps, on=_KEYS, how="outer")
    taken = eps[fields].take(np.asarray(pos, np.int64)).reset_index(drop=True)
    return pd.concat([out, taken], axis=1)


def _default(col: str):
    if col in ("status",):
        return "ok"
    if col in ("error", "env"):
        return ""
    if col in _LABEL_FIELDS or col in ("scenario_id",):
        return pd.NA
    return np.nan


def _fill_ids(out: pd.DataFrame, policy: str | None, source: str) -> pd.DataFrame:
    if "policy" not in out.columns:
        if policy is None:
            raise LabelTableError(f"{source}: no 'policy' column; name the policy (--name / "
                                  "policy=...) or add the column.")
        out["policy"] = policy
    elif policy is not None:
        out["policy"] = out["policy"].fillna(policy)
    if "seed" not in out.columns or out["seed"].isna().any():
        raise LabelTableError(
            f"{source}: every episode needs a 'seed' (the initial traffic it was run on) to be "
            "paired with another policy; rollouts write it. Add an integer seed column.")
    out["seed"] = out["seed"].astype(np.int64)
    if "env" not in out.columns:
        out["env"] = ""
    return out


def episodes_from_table(table: pd.DataFrame, *, level: str, thresholds: str = "paper",
                        policy: str | None = None, source: str = "input",
                        interactions: str | None = None
                        ) -> tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame | None]:
    """The episode table of a trajectory table or of a label table.

    A table with an ``sdl`` column is a label table (measures then stay NaN unless it carries
    them); any other is a trajectory table, labelled here with ``thresholds`` at every
    level, whose measures are computed too; ``interactions`` labels the interaction axis
    too (:func:`tap_bench.labelling.tap`).

    Returns:
        (episode table, label table, trajectory table or None).
    """
    if "sdl" in table.columns:
        return (episode_table(labels=table, level=level, policy=policy, source=source),
            table, None)
    labels = tap(table, thresholds, source=source, interactions=interactions).labels("all")
    eps = episode_table(labels=labels, trajectories=table, level=level, policy=policy,
                        source=source)
    return eps, labels, table

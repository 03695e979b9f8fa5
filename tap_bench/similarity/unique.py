"""Unique behaviours: labels no other trajectory has (TAP paper section 6.4, SPEC section 5).

A trajectory (one labelled valid segment of a track) is **unique** at a level when no other
trajectory of the data set carries its SDL label at that level: the similarity search with
d_sim = 0 returns nothing for it. The paper found 395 unique trajectories among 25,889 of
WOMD, most with many actions in a short window.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from tap_bench import sdl
from tap_bench.similarity.sdl_distance import LabelSet, label_set

__all__ = ["label_counts", "unique_labels"]


def _levels(labels: pd.DataFrame | LabelSet, level: str | None) -> list[str | None]:
    if level == "all":
        if isinstance(labels, LabelSet) or "level" not in labels.columns:
            return [None]
        present = set(labels["level"].astype(str))
        return [lv for lv in sdl.LEVELS if lv in present]
    return [level]


def label_counts(labels: pd.DataFrame | LabelSet, level: str | None = None, *,
                 axes=None) -> pd.DataFrame:
    """How many trajectories carry each distinct label, with an example of each.

    Args:
        labels: a label table (SPEC section 1) or an encoded :class:`LabelSet`.
        level: the SDL level, ``"all"`` for every level in the table, or None when the table
            holds a single level.
        axes: the axes a label is made of (default lateral and longitudinal).

    Returns:
        One row per distinct label: level, sdl (the label on the axes), one column per axis
        (lateral, longitudinal, interaction), count, share (of the level's trajectories),
        n_<axis> (tokens on each axis), n_actions (tokens on every axis), and the first
        trajectory with it (scenario_id, track_id, segment); most common first, ties by
        label.
    """
    frames = []
    for lv in _levels(labels, level):
        ls = label_set(labels, lv, axes=axes)
        first = ls.table.take(ls.first_row)
        parts = [[sdl.join(side) for side in sdl.parse_sdl(str(text), axes=ls.axes)]
                 for text in ls.labels]
        out = pd.DataFrame({"level": ls.level, "sdl": ls.labels.astype(str)})
        for j, axis in enumerate(ls.axes):
            out[axis] = [p[j] for p in parts]
        out["count"] = ls.counts
        out["share"] = ls.counts / len(ls)
        for axis in ls.axes:
            out[f"n_{axis}"] = ls.n_on(axis)
        out["n_actions"] = ls.n_tokens.sum(axis=1)
        out["scenario_id"] = first["scenario_id"].to_numpy()
        out["track_id"] = first["track_id"].to_numpy()
        if "segment" in first.columns:
            out["segment"] = first["segment"].to_numpy()
        frames.append(out.sort_values(["count", "sdl"], ascending=[False, True],
                                      kind="stable"))
    return pd.concat(frames, ignore_index=True)


def unique_labels(labels: pd.DataFrame | LabelSet, level: str | None = None, *,
                  axes=None) -> pd.DataFrame:
    """The trajectories whose label no other trajectory has, at one level or at each.

    Args:
        labels: a label table or an encoded :class:`LabelSet`.
        level: the SDL level, ``"all"`` for each level of the table, or None when the table
            holds a single level.
        axes: the axes a label is made of (default lateral and longitudinal; with
            ``interaction``, a trajectory is unique when no other does the same *and* meets
            the same relations).

    Returns:
        The label-table rows of the unique trajectories plus n_<axis> per axis and
        n_actions; per level, those with the most actions first (the paper's observation: a
        dense sequence of actions makes a label rare), ties in table order.
    """
    frames = []
    for lv in _levels(labels, level):
        ls = label_set(labels, lv, axes=axes)
        rows = np.flatnonzero(ls.counts[ls.code] == 1)
        out = ls.table.take(rows).reset_index(drop=True)
        code = ls.code[rows]
        for axis in ls.axes:
            out[f"n_{axis}"] = ls.n_on(axis)[code]
        out["n_actions"] = ls.n_tokens[code].sum(axis=1)
        frames.append(out.sort_values("n_actions", ascending=False, kind="stable"))
    return pd.concat(frames, ignore_index=True)

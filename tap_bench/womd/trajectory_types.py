"""Waymo's trajectory-type classifier, and how far TAP labels agree with it.

WOMD's motion metrics bucket each track by a coarse trajectory type (``ClassifyTrack`` in
waymo-open-dataset), computed from two states only: the one at the current time index (10)
and the last valid one after it. It is an independent reference for TAP's lateral and
longitudinal labels: a track it calls ``LEFT_TURN`` should carry a Left Turn or a Left Merge,
a ``STATIONARY`` one a Stopped label. The constants are those of
``../shared/data/womd/README.md``. ``benchmarks/bench_womd_agreement.py`` prints the
agreement table of WOMD files (vehicles, paper thresholds, maneuver level).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

__all__ = ["AGREEMENT_RULES", "TRAJECTORY_TYPES", "agreement_table", "classify_trajectories",
           "label_agreement"]

MAX_STATIONARY_SPEED = 2.0
"""Below this speed at both ends [m/s] (and a short displacement) a track is STATIONARY."""
MAX_STATIONARY_DISPLACEMENT = 3.0
"""Longest start-to-end displacement of a STATIONARY track [m]."""
MAX_STRAIGHT_HEADING_CHANGE = np.pi / 6
"""Largest |heading change| of the STRAIGHT family [rad]."""
MAX_STRAIGHT_LATERAL = 2.5
"""Largest |lateral offset| (in the start heading frame) of a STRAIGHT track [m]."""
MAX_U_TURN_LONGITUDINAL = 0.0
"""A turn ending behind its start (longitudinal offset below this [m]) is a U-turn."""
START_INDEX = 10
"""WOMD's current time index: the classifier starts from this step."""

TRAJECTORY_TYPES = ("STATIONARY", "STRAIGHT", "STRAIGHT_LEFT", "STRAIGHT_RIGHT", "LEFT_TURN",
                    "LEFT_U_TURN", "RIGHT_TURN", "RIGHT_U_TURN")


@dataclass(frozen=True)
class Rule:
    """What TAP labels agree with a trajectory type.

    Attributes:
        axis: ``lateral`` or ``longitudinal``.
        any_of: agreement when one of these labels occurs on that axis...
        only: ...or, when set, when every label on that axis is this one.
        text: the rule in words, for the docs.
    """

    axis: str
    any_of: tuple[str, ...] = ()
    only: str | None = None
    text: str = ""


AGREEMENT_RULES = {
    "STATIONARY": Rule("longitudinal", any_of=("Stopped",), text="a Stopped label"),
    "STRAIGHT": Rule("lateral", only="Straight", text="lateral labels all Straight"),
    "STRAIGHT_LEFT": Rule("lateral", any_of=("Left Turn", "Left Merge"),
                          text="a Left Turn or Left Merge"),
    "STRAIGHT_RIGHT": Rule("lateral", any_of=("Right Turn", "Right Merge"),
                           text="a Right Turn or Right Merge"),
    "LEFT_TURN": Rule("lateral", any_of=("Left Turn", "Left Merge"),
                      text="a Left Turn or Left Merge"),
    "LEFT_U_TURN": Rule("lateral", any_of=("Left Turn",), text="a Left Turn"),
    "RIGHT_TURN": Rule("lateral", any_of=("Right Turn", "Right Merge"),
                       text="a Right Turn or Right Merge"),
    "RIGHT_U_TURN": Rule("lateral", any_of=("Right Turn",), text="a Right Turn"),
}
"""The agreement rule of each trajectory type (maneuver-level labels)."""


def classify_trajectories(table: pd.DataFrame, *, start_index: int = START_INDEX
                          ) -> pd.DataFrame:
    """Waymo's trajectory type of every track valid at ``start_index``.

    Args:
        table: a trajectory table whose tracks have one row per step from the scenario's
            first step (as read from WOMD), with ``valid``, ``vx`` and ``vy``.
        start_index: the step the classification starts from (WOMD: 10).

    Returns:
        One row per classified track: ``scenario_id``, ``track_id``, ``trajectory_type``,
        ``dx``, ``dy`` (end minus start in the start heading frame [m]),
        ``heading_change`` [rad, in (-pi, pi]], ``max_speed`` (of start and end [m/s]),
        ``displacement`` [m]. Tracks invalid at ``start_index`` or with no valid state
        after it are left out.
    """
    rows = table.sort_values(["scenario_id", "track_id", "t"], kind="stable")
    step = rows.groupby(["scenario_id", "track_id"], sort=False).cumcount().to_numpy()
    valid = rows["valid"].to_numpy(dtype=bool)
    keys = ["scenario_id", "track_id"]
    start = rows[(step == start_index) & valid]
    end = rows[(step > start_index) & valid].groupby(keys, sort=False).tail(1)
    pair = start.merge(end, on=keys, suffixes=("_0", "_1"))
    dx0 = pair["x_1"].to_numpy() - pair["x_0"].to_numpy()
    dy0 = pair["y_1"].to_numpy() - pair["y_0"].to_numpy()
    h0 = pair["heading_0"].to_numpy()
    dx = np.cos(h0) * dx0 + np.sin(h0) * dy0
    dy = -np.sin(h0) * dx0 + np.cos(h0) * dy0
    turn = np.angle(np.exp(1j * (pair["heading_1"].to_numpy() - h0)))
    speed = np.maximum(np.hypot(pair["vx_0"], pair["vy_0"]), np.hypot(pair["vx_1"],
                                                                        pair["vy_1"]))
    displacement = np.hypot(dx0, dy0)
    kind = np.select(
        [(speed < MAX_STATIONARY_SPEED) & (displacement < MAX_STATIONARY_DISPLACEMENT),
         (np.abs(turn) < MAX_STRAIGHT_HEADING_CHANGE) & (np.abs(dy) < MAX_STRAIGHT_LATERAL),
         (np.abs(turn) < MAX_STRAIGHT_HEADING_CHANGE) & (dy < 0),
         np.abs(turn) < MAX_STRAIGHT_HEADING_CHANGE,
         (dy < 0) & (dx < MAX_U_TURN_LONGITUDINAL),
         dy < 0,
         dx < MAX_U_TURN_LONGITUDINAL],
        ["STATIONARY", "STRAIGHT", "STRAIGHT_RIGHT", "STRAIGHT_LEFT", "RIGHT_U_TURN",
         "RIGHT_TURN", "LEFT_U_TURN"],
        default="LEFT_TURN")
    return pd.DataFrame({"scenario_id": pair["scenario_id"], "track_id": pair["track_id"],
                         "trajectory_type": kind, "dx": dx, "dy": dy, "heading_change": turn,
                         "max_speed": speed, "displacement": displacement})


def label_agreement(types: pd.DataFrame, labels: pd.DataFrame) -> pd.DataFrame:
    """Per classified track, whether its TAP labels agree with its trajectory type.

    Args:
        types: from :func:`classify_trajectories`.
        labels: a TAP label table at one level (maneuver recommended); a track's segments
            are taken together.

    Returns:
        ``types`` with ``lateral`` and ``longitudinal`` (the labels of all the track's
        segments, joined by `` / ``; empty when none was long enough to label),
        ``labelled`` (bool: the track carries labels) and ``agrees`` (bool; false when
        unlabelled).
    """
    keys = ["scenario_id", "track_id"]
    per_track = labels.sort_values([*keys, "t_start"]).groupby(keys, sort=False).agg(
        lateral=("lateral", " / ".join), longitudinal=("longitudinal", " / ".join)
    ).reset_index()
    out = types.merge(per_track, on=keys, how="left")
    out[["lateral", "longitudinal"]] = out[["lateral", "longitudinal"]].fillna("")

    def agrees(row) -> bool:
        rule = AGREEMENT_RULES[row["trajectory_type"]]
        text = row[rule.axis]
        tokens = [t.strip() for part in text.split(" / ") for t in part.split(">") if t.strip()]
        if rule.only is not None:
            return bool(tokens) and all(t == rule.only for t in tokens)
        return any(t in rule.any_of for t in tokens)

    out["labelled"] = out["lateral"] != ""
    out["agrees"] = (out.apply(agrees, axis=1).astype(bool) if len(out)
                     else pd.Series(dtype=bool))
    return out


def agreement_table(per_track: pd.DataFrame) -> pd.DataFrame:
    """Per trajectory type: tracks classified, tracks labelled (a valid segment of 1 s or
    more), labelled tracks whose labels agree, their share, and the rule."""
    rows = []
    for kind in (*TRAJECTORY_TYPES, "all"):
        sel = per_track if kind == "all" else per_track[per_track["trajectory_type"] == kind]
        if not len(sel):
            continue
        labelled = int(sel["labelled"].sum())
        agree = int(sel["agrees"].sum())
        rows.append({"trajectory_type": kind, "tracks": len(sel), "labelled": labelled,
                     "agree": agree,
                     "agreement": round(agree / labelled, 3) if labelled else float("nan"),
                     "TAP labels that agree": "" if kind == "all"
                     else AGREEMENT_RULES[kind].text})
    return pd.DataFrame(rows)

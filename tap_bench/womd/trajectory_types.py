"""Waymo's trajectory-type classifier, and how far TAP labels agree with it.

WOMD's motion metrics bucket each track by a coarse trajectory type (``ClassifyTrack`` in
waymo-open-dataset), computed from two states only: the one at the current time index (10,
i.e. 1 s) and the last valid one after it. It is an independent reference for TAP's
lateral labels. The constants are those of ``../shared/data/womd/README.md``.

The comparison is strict and on the classifier's own window: TAP's per-step labels from
the start step to the track's last valid step (labelled on the whole track), reduced to one
lateral category (:data:`TAP_CATEGORIES`), which must be the one the type allows
(:data:`STRICT_RULES`): STATIONARY and STRAIGHT only Straight; STRAIGHT_LEFT a left merge
or turn and nothing to the right; LEFT_TURN and LEFT_U_TURN a Left Turn and no turn or merge
to the right (and the mirror images). Beside it: the direction alone (left, right, none),
and the longitudinal side (STATIONARY: every label Stopped; the others: not all Stopped),
which differ by definition (Waymo's stationary is below 2 m/s, TAP's Stopped at most
0.1 m/s). :func:`tap_bench.womd.validation.validate_womd` and ``tap-bench validate`` write
the tables.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

__all__ = ["STRICT_RULES", "TAP_CATEGORIES", "TRAJECTORY_TYPES", "agreement_table",
           "classify_trajectories", "confusion_table", "label_agreement"]

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


TAP_CATEGORIES = ("Straight", "Left Merge", "Left Turn", "Left Turn and Merge", "Right Merge",
                  "Right Turn", "Right Turn and Merge", "Left and Right", "unlabelled")
"""TAP's lateral labels in the classifier's window, as one category: which turns and merges
occur (Straight: none; "Left and Right": some of each side)."""

STRICT_RULES = {
    "STATIONARY": (("Straight",), "Straight only"),
    "STRAIGHT": (("Straight",), "Straight only"),
    "STRAIGHT_LEFT": (("Left Merge", "Left Turn", "Left Turn and Merge"),
                      "a left merge or turn, nothing to the right"),
    "STRAIGHT_RIGHT": (("Right Merge", "Right Turn", "Right Turn and Merge"),
                       "a right merge or turn, nothing to the left"),
    "LEFT_TURN": (("Left Turn", "Left Turn and Merge"),
                  "a Left Turn, no turn or merge to the right"),
    "LEFT_U_TURN": (("Left Turn", "Left Turn and Merge"),
                    "a Left Turn, no turn or merge to the right"),
    "RIGHT_TURN": (("Right Turn", "Right Turn and Merge"),
                   "a Right Turn, no turn or merge to the left"),
    "RIGHT_U_TURN": (("Right Turn", "Right Turn and Merge"),
                     "a Right Turn, no turn or merge to the left"),
}
"""Per trajectory type: the TAP categories that agree with it, and the rule in words."""

_SIDE = {"STATIONARY": "none", "STRAIGHT": "none", "STRAIGHT_LEFT": "left",
         "STRAIGHT_RIGHT": "right", "LEFT_TURN": "left", "LEFT_U_TURN": "left",
         "RIGHT_TURN": "right", "RIGHT_U_TURN": "right"}


def _step_index(table: pd.DataFrame) -> np.ndarray:
    """(n_rows,) the time step of each row, from ``t``: steps since the scenario's first
    time stamp, in units of the scenario's median step (WOMD: about 0.1002 s)."""
    t = table["t"].to_numpy(dtype=np.float64)
    scenario = table["scenario_id"].to_numpy()
    frame = pd.DataFrame({"s": scenario, "t": t})
    t0 = frame.groupby("s", sort=False)["t"].transform("min").to_numpy()
    stamps = frame.drop_duplicates().sort_values(["s", "t"])
    gaps = stamps.groupby("s", sort=False)["t"].diff()
    dt = gaps.groupby(stamps["s"], sort=False).median()
    step = pd.Series(scenario).map(dt).to_numpy(dtype=np.float64)
    step = np.where(np.isfinite(step) & (step > 0), step, 0.1)
    return np.round((t - t0) / step).astype(np.int64)


def classify_trajectories(table: pd.DataFrame, *, start_index: int = START_INDEX
                          ) -> pd.DataFrame:
    """Waymo's trajectory type of every track valid at ``start_index``.

    Args:
        table: a trajectory table with ``valid``, ``vx`` and ``vy`` (as read from WOMD).
            Steps are counted from ``t`` (steps since the scenario's first time stamp), so
            a table without its invalid rows is classified the same.
        start_index: the step the classification starts from (WOMD: 10, at 1 s).

    Returns:
        One row per classified track: ``scenario_id``, ``track_id``, ``trajectory_type``,
        ``dx``, ``dy`` (end minus start in the start heading frame [m]),
        ``heading_change`` [rad, in (-pi, pi]], ``max_speed`` (of start and end [m/s]),
        ``displacement`` [m], and the classifier's window: ``t_start`` (the start step's
        time [s]) and ``t_end`` (the last valid step's time [s]). Tracks invalid at
        ``start_index`` or with no valid state after it are left out.
    """
    keys = ["scenario_id", "track_id"]
    rows = table.reset_index(drop=True)
    rows = rows.assign(_step=_step_index(rows))
    valid = (rows["valid"].to_numpy(dtype=bool) if "valid" in rows.columns else
        np.ones(len(rows), dtype=bool))
    rows = rows[valid]
    if "vx" not in rows.columns or "vy" not in rows.columns:
        rows = rows.assign(vx=rows["speed"] * np.cos(rows["heading"]),
                           vy=rows["speed"] * np.sin(rows["heading"]))
    start = rows[rows["_step"] == start_index].drop_duplicates(keys)
    after = rows[rows["_step"] > start_index]
    end = after.loc[after.groupby(keys, sort=False)["_step"].idxmax()]
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
    out = pd.DataFrame({"scenario_id": pair["scenario_id"], "track_id": pair["track_id"],
                        "trajectory_type": kind, "dx": dx, "dy": dy, "heading_change": turn,
                        "max_speed": speed, "displacement": displacement,
                        "t_start": pair["t_0"].to_numpy(), "t_end": pair["t_1"].to_numpy()})
    return out.sort_values(keys, kind="stable").reset_index(drop=True)


def _category(lateral: pd.Series) -> np.ndarray:
    """TAP category (:data:`TAP_CATEGORIES`) of each ``" > "``-joined lateral sequence."""
    text = lateral.fillna("").astype(str)
    tokens = {name: text.str.contains(name, regex=False).to_numpy()
              for name in ("Left Turn", "Left Merge", "Right Turn", "Right Merge")}
    left = tokens["Left Turn"] | tokens["Left Merge"]
    right = tokens["Right Turn"] | tokens["Right Merge"]

    def side(turn: np.ndarray, merge: np.ndarray, name: str) -> np.ndarray:
        return np.where(turn & merge, f"{name} Turn and Merge",
                        np.where(turn, f"{name} Turn", f"{name} Merge"))

    return np.select([text.to_numpy() == "", left & right, left, right],
                     ["unlabelled", "Left and Right",
                      side(tokens["Left Turn"], tokens["Left Merge"], "Left"),
                      side(tokens["Right Turn"], tokens["Right Merge"], "Right")],
                     default="Straight")


def _window_sequences(types: pd.DataFrame, steps: pd.DataFrame, level: str) -> pd.DataFrame:
    """Per classified track, its ``level`` labels in the classifier's window as ``" > "``
    sequences (runs of one label; `` / `` between valid segments)."""
    keys = ["scenario_id", "track_id"]
    cols = [f"{level}_lateral", f"{level}_longitudinal"]
    part = steps[[*keys, "segment", "t", *cols]].merge(types[[*keys, "t_start", "t_end"]],
                                                        on=keys)
    eps = 1e-6
    part = part[(part["t"] >= part["t_start"] - eps) & (part["t"] <= part["t_end"] + eps)]
    part = part.sort_values([*keys, "t"], kind="stable").reset_index(drop=True)
    out = part[keys].drop_duplicates().reset_index(drop=True)
    if not len(part):
        return out.assign(lateral="", longitudinal="")
    track = part[keys].ne(part[keys].shift()).any(axis=1).to_numpy()
    segment = track | (part["segment"].to_numpy() != part["segment"].shift().to_numpy())
    for col, name in zip(cols, ("lateral", "longitudinal"), strict=True):
        values = part[col].astype(str).to_numpy()
        change = segment.copy()
        change[1:] |= values[1:] != values[:-1]
        runs = part.loc[change, keys].assign(
            label=values[change], sep=np.where(track[change], "",
                                               np.where(segment[change], " / ", " > ")))
        runs["text"] = runs["sep"] + runs["label"]
        joined = runs.groupby(keys, sort=False)["text"].agg("".join).reset_index()
        out = out.merge(joined.rename(columns={"text": name}), on=keys, how="left")
    return out


def label_agreement(types: pd.DataFrame, steps: pd.DataFrame, *, level: str = "maneuver"
                    ) -> pd.DataFrame:
    """Per classified track, TAP's labels in the classifier's window and the agreement.

    Args:
        types: from :func:`classify_trajectories`.
        steps: TAP's per-step table (:meth:`tap_bench.TapResult.steps`): ``scenario_id``,
            ``track_id``, ``segment``, ``t`` and ``<level>_lateral``,
            ``<level>_longitudinal``.
        level: the TAP level compared (maneuver: turns and merges without intensities).

    Returns:
        ``types`` with ``lateral`` and ``longitudinal`` (the labels in the window; empty
        when no labelled step falls in it), ``labelled`` (bool), ``tap_category``
        (:data:`TAP_CATEGORIES`), ``strict`` (the category is one :data:`STRICT_RULES`
        allows), ``direction`` (TAP's side, left, right or none, is the type's; a track
        with both sides never agrees) and ``longitudinal_agrees`` (STATIONARY: every label
        Stopped; moving types: not every label Stopped); all false when unlabelled.
    """
    keys = ["scenario_id", "track_id"]
    seqs = _window_sequences(types, steps, level)
    out = types.merge(seqs, on=keys, how="left")
    out[["lateral", "longitudinal"]] = out[["lateral", "longitudinal"]].fillna("")
    out["labelled"] = out["lateral"] != ""
    category = _category(out["lateral"])
    out["tap_category"] = category
    kind = out["trajectory_type"].to_numpy()
    allowed = np.array([cat in STRICT_RULES[k][0] for k, cat in zip(kind, category,
                                                                     strict=True)], dtype=bool)
    tap_side = np.select([np.char.startswith(category.astype(str), "Left and"),
                          np.char.startswith(category.astype(str), "Left"),
                          np.char.startswith(category.astype(str), "Right"),
                          category == "Straight"], ["both", "left", "right", "none"],
                         default="unlabelled")
    side = np.array([_SIDE[k] for k in kind], dtype=object)
    lon = out["longitudinal"].str.replace(" / ", " > ", regex=False).str.split(" > ")
    all_stopped = lon.map(lambda tokens: bool(tokens) and all(t == "Stopped" for t in tokens)
                          ).to_numpy(dtype=bool)
    labelled = out["labelled"].to_numpy()
    out["strict"] = allowed & labelled
    out["direction"] = (tap_side == side) & labelled
    out["longitudinal_agrees"] = np.where(kind == "STATIONARY", all_stopped, ~all_stopped
                                          ) & labelled
    return out


def agreement_table(per_track: pd.DataFrame) -> pd.DataFrame:
    """Per trajectory type (and ``all``): tracks, labelled tracks, the scenes they come
    from, and among the labelled tracks the strict lateral agreement, the direction-only
    agreement and the longitudinal one (counts, shares, and each share's 95 % interval
    ``<name>_low`` / ``<name>_high`` over scenes: the tracks of one scene are not
    independent, :func:`tap_bench.stats.intervals.clustered_wilson_interval`), with the
    strict rule in words."""
    from tap_bench.stats.intervals import clustered_wilson_interval

    rows = []
    for kind in (*TRAJECTORY_TYPES, "all"):
        sel = per_track if kind == "all" else per_track[per_track["trajectory_type"] == kind]
        if not len(sel):
            continue
        labelled = int(sel["labelled"].sum())
        scene = (sel["scenario_id"].astype(str) if "scenario_id" in sel.columns
                 else pd.Series(np.arange(len(sel)).astype(str), index=sel.index))
        done = sel["labelled"].astype(bool)
        row = {"trajectory_type": kind, "tracks": len(sel), "labelled": labelled,
               "scenes": int(scene[done].nunique())}
        for col in ("strict", "direction", "longitudinal_agrees"):
            agree = int(sel[col].sum())
            name = "longitudinal" if col == "longitudinal_agrees" else col
            row[name] = agree
            row[f"{name}_share"] = round(agree / labelled, 3) if labelled else float("nan")
            per_scene = sel[done].groupby(scene[done], sort=False)[col].agg(["sum", "size"])
            low, high, _ = clustered_wilson_interval(per_scene["sum"], per_scene["size"],
                                                     0.95)
            row[f"{name}_low"], row[f"{name}_high"] = round(low, 3), round(high, 3)
        row["strict rule"] = "" if kind == "all" else STRICT_RULES[kind][1]
        rows.append(row)
    return pd.DataFrame(rows)


def confusion_table(per_track: pd.DataFrame) -> pd.DataFrame:
    """Tracks per trajectory type (rows) and TAP category in its window (columns), with
    totals; every type and category appears, zeros included."""
    table = pd.crosstab(pd.Categorical(per_track["trajectory_type"],
                                       categories=TRAJECTORY_TYPES),
                        pd.Categorical(per_track["tap_category"], categories=TAP_CATEGORIES),
                        dropna=False)
    table.index.name, table.columns.name = "trajectory_type", None
    table.index = table.index.astype(str)
    table.columns = table.columns.astype(str)
    table["total"] = table.sum(axis=1)
    table.loc["total"] = table.sum(axis=0)
    return table

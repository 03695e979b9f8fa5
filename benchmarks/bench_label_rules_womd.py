"""Issue 21's label and measure figures on the real WOMD samples (``../shared/data/womd``).

Run with any version of the code (``PYTHONPATH=<checkout>``): it uses only what every
version since the interaction axis has (``tap(..., interactions="all")``, the kinematics,
``ego_measures``), so the figures before and after a change come from one script.

- **turn runs that barely turn**: maneuver-level Left/Right Turn runs whose net heading
  change over the run is under 3 degrees (SPEC 4.5 removes runs that cross w_str on noise);
  likewise accelerate/decelerate runs whose speed change disagrees with their label;
- **reversing**: steps flagged reversing, tracks with a ``Reversing`` label, and the lateral
  label of each track that reverses 5 m or more;
- **relations of still vehicles** (SPEC 7's guards): relation runs other than Free Driving
  and Following, and Following runs, whose ego track never moves (speed under 1 m/s
  throughout), and the counts on moving egos only;
- **measures of the self-driving cars**: min headway, min TTC (NaN: no leader) and RMS
  jerk of each of the four SDCs.

Usage: ``python benchmarks/bench_label_rules_womd.py [--data DIR]``.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from machine import report

import tap_bench as tb

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "womd"
FILES = ("motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord",
         "motion_data_one_example.tfrecord", "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")
RELATION_NAMES = ("Free Driving", "Following", "Cut-in", "Cut-out", "Overtaking",
                  "Being Overtaken", "Lead Braking")


def _runs(codes: np.ndarray, segment: np.ndarray):
    change = np.r_[True, (codes[1:] != codes[:-1]) | (segment[1:] != segment[:-1])]
    start = np.flatnonzero(change)
    stop = np.r_[start[1:], len(codes)]
    return start, stop


def turn_figures(result) -> dict:
    kin, rows, seg = result.kinematics, result.step_rows, result.step_segment
    lat = result.step_labels.maneuver_lateral
    start, stop = _runs(lat, seg)
    turn = (lat[start] == 1) | (lat[start] == 2)  # Left Turn, Right Turn
    h = kin.heading[rows]
    net = np.abs(h[stop[turn] - 1] - h[start[turn]])
    lon = result.step_labels.maneuver_longitudinal
    ls, le = _runs(lon, seg)
    dv = kin.v[rows][le - 1] - kin.v[rows][ls]
    dur = (le - ls) / 10.0
    acc, dec = lon[ls] == 1, lon[ls] == 2
    th = result.thresholds
    return {"turn_runs": int(turn.sum()),
            "turn_runs_under_3_deg": int((net < np.radians(3)).sum()),
            "share_under_3_deg": round(float((net < np.radians(3)).mean()), 4) if turn.any()
            else None,
            "accelerate_runs": int(acc.sum()),
            "accelerate_runs_disagreeing": int((dv[acc] / dur[acc] <= th.a_acc).sum()),
            "decelerate_runs": int(dec.sum()),
            "decelerate_runs_disagreeing": int((dv[dec] / dur[dec] > th.a_dec).sum())}


def reversing_figures(result, table: pd.DataFrame) -> dict:
    kin = result.kinematics
    labels = result.labels("maneuver")
    rev = labels["longitudinal"].str.contains("Reversing")
    out = {"reversing_steps": int(kin.reversing.sum()),
           "tracks_labelled_reversing": int(rev.sum()), "reversing_tracks": []}
    steps = result.steps()
    back = steps[steps["reversing"]]
    for (sid, tid), sub in back.groupby(["scenario_id", "track_id"]):
        rows = result.step_rows[sub.index.to_numpy()]
        dist = float(np.hypot(np.diff(kin.x[rows]), np.diff(kin.y[rows])).sum())
        if dist < 5.0:
            continue
        turned = float(np.degrees(kin.heading[rows[-1]] - kin.heading[rows[0]]))
        row = labels[(labels["scenario_id"] == sid) & (labels["track_id"] == tid)].iloc[0]
        out["reversing_tracks"].append({"scenario_id": sid, "track_id": tid,
                                        "backs_m": round(dist, 1),
                                        "turns_deg": round(turned, 1),
                                        "sdl": row["sdl"]})
    return out


def relation_figures(result, table: pd.DataFrame) -> dict:
    segs = result.segments("maneuver")
    rel = segs[segs["axis"] == "interaction"].copy()
    top = table.groupby(["scenario_id", "track_id"])["speed"].max()
    rel["still"] = [bool(top.get((s, t), 0.0) < 1.0) for s, t in
                    zip(rel["scenario_id"], rel["track_id"], strict=True)]
    rel["still_other"] = [isinstance(o, str) and bool(top.get((s, o), 0.0) < 1.0) for s, o in
                          zip(rel["scenario_id"], rel["other_track_id"], strict=True)]
    other = ~rel["label"].isin(["Free Driving", "Following"])
    following = rel["label"] == "Following"
    counts = rel.groupby("label").size().to_dict()
    moving = rel[~rel["still"]].groupby("label").size().to_dict()
    return {"runs_by_relation": counts, "runs_by_relation_moving_egos": moving,
            "other_relation_runs": int(other.sum()),
            "other_relation_runs_of_still_egos": int((other & rel["still"]).sum()),
            "other_relation_runs_with_a_still_other": int((other & rel["still_other"]).sum()),
            "following_runs": int(following.sum()),
            "following_runs_of_still_egos": int((following & rel["still"]).sum()),
            "following_following_sequences": int(result.labels("maneuver")["interaction"]
                                                 .fillna("").str.contains(
                                                     r"Following > Following\b").sum())}


def measure_figures(table: pd.DataFrame) -> list[dict]:
    from tap_bench.bench.measures import ego_measures
    sdc = table.assign(is_ego=table["is_ego"].fillna(False).astype(bool)) \
        if "is_ego" in table.columns else None
    if sdc is None:
        return []
    m = ego_measures(sdc)
    return [{"scenario_id": r.scenario_id, "min_headway_s": _round(r.min_headway_s),
             "min_ttc_s": _round(r.min_ttc_s), "rms_jerk": _round(r.rms_jerk)}
            for r in m.itertuples()]


def _round(x) -> float | None:
    return None if not np.isfinite(x) else round(float(x), 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DATA)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    from tap_bench.sources.ingest import read_womd
    table = read_womd([args.data / f for f in FILES])
    result = tb.tap(table, "paper", interactions="all")
    figures = {"tracks": int(table.groupby(["scenario_id", "track_id"]).ngroups),
               "turns": turn_figures(result),
               "reversing": reversing_figures(result, table),
               "relations": relation_figures(result, table),
               "sdc_measures": measure_figures(table)}
    report("label_rules_womd", figures, data=str(args.data), thresholds="paper",
           level="maneuver")


if __name__ == "__main__":
    main()

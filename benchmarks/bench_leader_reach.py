"""Which leaders the two leader-search rules find: a flat 100 m ahead (the safety measures'
until issue 22) against 60 m or 4 s at the ego's speed (SPEC 7's range, the interaction
axis's; now both).

For every ego step of the tables given (the real WOMD samples, every moving vehicle an ego
in turn; highway-env rollouts, the policy's vehicle the ego), the leader along the ego's
path under each rule (:func:`tap_bench.pathframe.nearest_leader` with either reach), and:

- steps with a leader under each rule, and those with a leader under one rule only: where
  it lies (``s`` centre to centre) and its time gap ``s / v``;
- per episode (the ego of a scenario): min headway and min TTC under each rule (the flat
  100 m by replacing the reach the measures use), how many change, by how much, and how
  many episodes turn from a minimum into "no leader".

    python benchmarks/bench_leader_reach.py [--rollouts FILE.parquet] [--data DIR]

``--rollouts``: a trajectory table of highway-env rollouts (every vehicle recorded, the
ego marked ``is_ego``), e.g. ``tap-bench rollout highway idm 0-19 -o FILE``.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from machine import report

import tap_bench.bench.measures as measures_module
from tap_bench.pathframe import Paths, leader_reach, nearest_leader, path_frame
from tap_bench.tableio import read_table

FLAT = 100.0
"""[m] the measures' old flat reach."""
FILES = ("motion_data_one_example.tfrecord", "motion_data_one_scenario.tfrecord",
         "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl", "womd_scenario_input.tfrecord")


def every_vehicle_an_ego(table: pd.DataFrame) -> pd.DataFrame:
    """One scenario per moving vehicle of ``table`` (faster than 1 m/s at some step), that
    vehicle its ego, every other agent of its scene around it."""
    table = table[table["object_type"].astype(str).isin(["vehicle", "cyclist"])
                  if "object_type" in table else slice(None)]
    moving = table.groupby(["scenario_id", "track_id"])["speed"].max() > 1.0
    out = []
    for (sid, track), _ in moving[moving].items():
        scene = table[table["scenario_id"] == sid]
        out.append(scene.assign(scenario_id=f"{sid}/{track}",
                                is_ego=(scene["track_id"] == track).to_numpy()))
    return pd.concat(out, ignore_index=True)


def leaders(table: pd.DataFrame) -> pd.DataFrame:
    """Per ego step: speed, and ``s`` of the leader under each rule (NaN: none)."""
    table = table[table["valid"].fillna(False).astype(bool)] if "valid" in table else table
    table = table.sort_values(["scenario_id", "track_id", "t"], kind="stable")
    table = table.reset_index(drop=True)
    scene, _ = pd.factorize(table["scenario_id"], sort=False)
    step = np.rint(table["t"].to_numpy(float) * 10).astype(np.int64)
    key = scene.astype(np.int64) * (step.max() - step.min() + 1) + step - step.min()
    is_ego = table["is_ego"].fillna(False).to_numpy(bool)
    ego = np.flatnonzero(is_ego)
    cut = np.r_[True, (scene[ego][1:] != scene[ego][:-1]) | (np.diff(step[ego]) != 1)]
    start = ego[np.flatnonzero(cut)]
    stop = np.r_[ego[np.flatnonzero(cut)[1:] - 1] + 1, ego[-1] + 1]
    track, _ = pd.factorize(table["scenario_id"].astype(str) + "|"
                            + table["track_id"].astype(str), sort=False)
    speed = table["speed"].to_numpy(float)
    paths = Paths(scene=scene.astype(np.int64), key=key, track=track.astype(np.int64),
                  x=table["x"].to_numpy(float), y=table["y"].to_numpy(float),
                  heading=table["heading"].to_numpy(float), speed=speed, start=start,
                  stop=stop)
    ego_row, _ = paths.ego_rows()
    v = speed[ego_row]
    reach = leader_reach(v)
    frame = path_frame(paths, ~is_ego, ahead=np.maximum(reach, FLAT), behind=1.0,
                       lateral=1.8)
    out = pd.DataFrame({"scenario_id": table["scenario_id"].to_numpy()[ego_row], "v": v,
                        "reach": reach})
    for name, r in (("flat", np.full(len(v), FLAT)), ("reach", reach)):
        pair = nearest_leader(frame, r)
        s = np.full(len(v), np.nan)
        s[pair >= 0] = frame.s[pair[pair >= 0]]
        out[f"s_{name}"] = s
    return out


def step_figures(steps: pd.DataFrame) -> dict:
    flat, reach = steps["s_flat"].notna(), steps["s_reach"].notna()
    only_flat = steps[flat & ~reach]
    only_reach = steps[reach & ~flat]
    moving = steps["v"] > 1.0
    gap_s = (only_flat["s_flat"] / only_flat["v"].clip(lower=0.1))
    return {
        "ego_steps": len(steps),
        "with_a_leader_flat_100m": int(flat.sum()),
        "with_a_leader_60m_or_4s": int(reach.sum()),
        "only_flat": len(only_flat),
        "only_flat_moving": int((flat & ~reach & moving).sum()),
        "only_flat_s_quantiles_m": [round(float(q), 1) for q in
                                    only_flat["s_flat"].quantile([0.1, 0.5, 0.9])]
        if len(only_flat) else [],
        "only_flat_time_gap_quantiles_s": [round(float(q), 1) for q in
                                           gap_s[only_flat["v"] > 1].quantile([0.1, 0.5, 0.9])]
        if (only_flat["v"] > 1).any() else [],
        "only_60m_or_4s": len(only_reach),
        "different_leader": int((flat & reach & (steps["s_flat"] != steps["s_reach"])).sum()),
    }


def episode_figures(table: pd.DataFrame) -> dict:
    """Min headway and TTC per episode under each rule."""
    new = measures_module.ego_measures(table)
    original = measures_module.leader_reach
    measures_module.leader_reach = lambda speed, *a, **k: np.full(np.shape(speed), FLAT)
    try:
        old = measures_module.ego_measures(table)
    finally:
        measures_module.leader_reach = original
    out = {"episodes": len(new)}
    for col in ("min_headway_s", "min_ttc_s"):
        a, b = old[col].to_numpy(float), new[col].to_numpy(float)
        both = np.isfinite(a) & np.isfinite(b)
        diff = np.abs(a - b)[both]
        out[col] = {
            "with_a_value_flat_100m": int(np.isfinite(a).sum()),
            "with_a_value_60m_or_4s": int(np.isfinite(b).sum()),
            "value_to_no_leader": int((np.isfinite(a) & ~np.isfinite(b)).sum()),
            "no_leader_to_value": int((~np.isfinite(a) & np.isfinite(b)).sum()),
            "changed_value": int((diff > 1e-9).sum()),
            "largest_change_s": round(float(diff.max()), 3) if len(diff) else 0.0,
            "values_lost": [round(float(x), 2) for x in
                            np.sort(a[np.isfinite(a) & ~np.isfinite(b)])[:12]],
            "mean_flat_100m": round(float(np.nanmean(a)), 3) if np.isfinite(a).any() else None,
            "mean_60m_or_4s": round(float(np.nanmean(b)), 3) if np.isfinite(b).any() else None,
        }
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path,
                        default=Path(__file__).resolve().parents[2] / "shared/data/womd")
    parser.add_argument("--rollouts", type=Path)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    figures = {}
    t0 = time.process_time()
    if all((args.data / f).exists() for f in FILES):
        from tap_bench.sources.ingest import read_womd
        womd = read_womd([args.data / f for f in FILES])
        egos = every_vehicle_an_ego(womd)
        figures["womd_every_moving_vehicle"] = step_figures(leaders(egos))
        figures["womd_every_moving_vehicle"].update(episodes=episode_figures(egos))
        figures["womd_sdc"] = episode_figures(womd)
    if args.rollouts:
        roll = read_table(args.rollouts)
        for (env, policy), sub in roll.groupby(["env", "policy"], sort=True):
            sub = sub.reset_index(drop=True)
            figures[f"{env} {policy}"] = {**step_figures(leaders(sub)),
                                          "episodes": episode_figures(sub)}
    figures["cpu_s"] = round(time.process_time() - t0, 1)
    report("leader_reach", figures, flat_m=FLAT, rule="max(60 m, 4 s x speed)",
           rollouts=str(args.rollouts) if args.rollouts else None)


if __name__ == "__main__":
    main()

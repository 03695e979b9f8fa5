"""Lane changes in highway-env: yaw-rate peaks and TAP labels, default vs realistic setting.

1. A scripted lane change (empty 3-lane highway, ego alone in the middle lane at 25 m/s,
   LANE_LEFT or LANE_RIGHT at t = 2 s): peak yaw rate each way, the time to cover 10 % to
   90 % of the 4 m offset, and TAP's maneuver label of the ego.
2. IDM/MOBIL rollouts on tap_bench/highway-v0 (every vehicle): among the tracks that move
   sideways by more than 3 m (a lane change), the distribution of the peak |yaw rate|, and
   the share that TAP labels as a merge (Left Merge or Right Merge) at the maneuver level.

Usage: python benchmarks/bench_rollout_lane_change.py [--seeds 0-19]
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from machine import report

import tap_bench
from tap_bench.sim import episode_trajectories, make_env, rollout
from tap_bench.sim.policies import CHEAP_OBSERVATION


def scripted(setting: str, action: int) -> dict:
    env = make_env("highway", lane_change=setting, duration=10,
                   config={"vehicles_count": 0, "initial_lane_id": 1,
                           "observation": CHEAP_OBSERVATION})
    env.reset(seed=0)
    for k in range(10):
        env.step(action if k == 2 else 1)
    table = episode_trajectories(env)
    ego = table[table["is_ego"]]
    w = np.diff(np.unwrap(ego["heading"].to_numpy())) / 0.1
    offset = np.abs(ego["y"].to_numpy() - ego["y"].iloc[0])
    t = ego["t"].to_numpy()
    duration = t[np.argmax(offset > 3.6)] - t[np.argmax(offset > 0.4)]
    labels = tap_bench.label(ego, level="maneuver")
    return {"peak_left_rad_s": round(float(w.max()), 3),
            "peak_right_rad_s": round(float(-w.min()), 3),
            "offset_10_to_90_percent_s": round(float(duration), 1),
            "tap_maneuver_lateral": labels["lateral"].iloc[0]}


def in_traffic(setting: str, seeds: str) -> dict:
    table, _ = rollout("highway", "idm", seeds, lane_change=setting, progress=False)
    peaks, merges, n = [], 0, 0
    labels = tap_bench.label(table, level="maneuver").set_index(["scenario_id", "track_id"])
    for key, track in table.groupby(["scenario_id", "track_id"], sort=False):
        if len(track) < 20 or np.ptp(track["y"].to_numpy()) < 3.0 or track["crashed"].any():
            continue
        w = np.diff(np.unwrap(track["heading"].to_numpy())) / 0.1
        peaks.append(np.abs(w).max())
        n += 1
        lateral = labels.loc[key, "lateral"] if key in labels.index else ""
        lateral = lateral.iloc[0] if hasattr(lateral, "iloc") else lateral
        merges += "Merge" in lateral
    peaks = np.asarray(peaks)
    return {"lane_changing_tracks": n,
            "peak_abs_yaw_rate_median_rad_s": round(float(np.median(peaks)), 3),
            "peak_abs_yaw_rate_p95_rad_s": round(float(np.percentile(peaks, 95)), 3),
            "labelled_as_merge_share": round(merges / max(n, 1), 3)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-19")
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    figures = {}
    for setting in ("default", "realistic"):
        figures[setting] = {"scripted_left": scripted(setting, 0),
                            "scripted_right": scripted(setting, 2),
                            "idm_traffic": in_traffic(setting, args.seeds)}
    report("rollout_lane_change", figures, seeds=args.seeds, env="tap_bench/highway-v0",
           policy="idm", speed_m_s=25)


if __name__ == "__main__":
    main()

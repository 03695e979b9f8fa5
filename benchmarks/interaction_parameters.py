"""The data behind the interaction axis's parameters (docs/interactions.md).

On the real WOMD samples (every vehicle as an ego) and on highway-env rollouts (IDM/MOBIL
on the highway scenario, seeds 0-9), in every ego's path frame:

1. ``|d|`` of the agents driving the same way ahead (0 < s <= 60 m): the corridor
   half-width must separate the ego's lane (|d| near 0) from the next lanes (about one lane
   width); the table shows the valley between them.
2. the time gap ``s / v`` of the nearest agent in the corridor (the leader, looked for up
   to 60 m ahead) at ego speeds above 5 m/s: how much of car following lies within the 4 s
   range.
3. the speed of agents the ego passes beside its corridor: why parked cars (< 2 m/s) are
   not "overtaken".

Usage: ``python benchmarks/interaction_parameters.py [--seeds 10]``.
"""

from __future__ import annotations

import argparse
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from machine import report

import tap_bench as tb
from tap_bench.kinematics import compute_kinematics
from tap_bench.pathframe import SAME_DIRECTION, Paths, path_frame
from tap_bench.trajectories import HZ, validate_and_index

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "womd"
FILES = ("motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord",
         "motion_data_one_example.tfrecord", "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")
BINS = np.arange(0, 6.5, 0.5)


def frames(table: pd.DataFrame):
    checked = validate_and_index(table)
    kin = compute_kinematics(checked)
    idx = kin.index
    vehicle = np.ones(len(kin.t), bool)
    if "object_type" in checked:
        kind = pd.Series(checked["object_type"]).astype(str).to_numpy()
        vehicle = kind == "vehicle"
    seg_vehicle = vehicle[idx.segment_start] & (idx.segment_length >= 10)
    scen, _ = pd.factorize(pd.Series(checked["scenario_id"]))
    step = np.rint(kin.t * HZ).astype(np.int64)
    key = scen.astype(np.int64) * (step.max() + 1) + step
    paths = Paths(scene=scen.astype(np.int64), key=key, track=idx.track,
                  x=np.asarray(checked["x"], float), y=np.asarray(checked["y"], float),
                  heading=np.asarray(checked["heading"], float),
                  speed=np.asarray(checked["speed"], float),
                  start=idx.segment_start[seg_vehicle], stop=idx.segment_stop[seg_vehicle])
    frame = path_frame(paths, (idx.segment >= 0) & vehicle, ahead=60.0, behind=10.0,
                       lateral=6.0)
    return frame, paths


def summarise(name: str, table: pd.DataFrame) -> dict:
    frame, paths = frames(table)
    same = np.abs(frame.heading_rel) <= SAME_DIRECTION
    ahead = same & (frame.s > 0)
    hist, _ = np.histogram(np.abs(frame.d[ahead]), BINS)
    share = hist / max(hist.sum(), 1)
    # the leader's time gap at ego speeds above 5 m/s
    v_e = paths.speed[frame.ego_row][frame.step]
    lead = ahead & (np.abs(frame.d) <= 1.8) & (v_e > 5)
    nearest = pd.DataFrame({"step": frame.step[lead], "s": frame.s[lead],
                            "v": v_e[lead]}).groupby("step").min()
    gap = (nearest["s"] / nearest["v"]).to_numpy()
    passed = same & (np.abs(frame.d) > 1.8) & (np.abs(frame.s) < 1.0)
    v_passed = paths.speed[frame.other[passed]]
    return {
        "source": name,
        "abs_d_share_per_0.5m_bin": {f"{lo:.1f}-{lo + 0.5:.1f}": round(float(x), 3)
                                     for lo, x in zip(BINS[:-1], share, strict=True)},
        "leader_steps": len(gap),
        "leader_time_gap_quantiles_s": {q: round(float(np.quantile(gap, q)), 2)
                                        for q in (0.1, 0.5, 0.9)} if len(gap) else {},
        "share_of_leader_gaps_within_4s": round(float(np.mean(gap <= 4.0)), 3)
        if len(gap) else None,
        "agents_alongside_outside_corridor": int(passed.sum()),
        "share_of_them_below_2_m_s": round(float(np.mean(v_passed < 2.0)), 3)
        if passed.any() else None,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=10)
    args = parser.parse_args()
    out = {}
    if (DATA / FILES[0]).is_file():
        womd = tb.read_womd([DATA / f for f in FILES])
        out["womd"] = summarise("WOMD samples (4 scenes, every vehicle)", womd)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim, _ = tb.rollout("highway", "idm", list(range(args.seeds)), progress=False)
    out["highway"] = summarise(f"highway-env highway, IDM/MOBIL, seeds 0-{args.seeds - 1}",
                               sim)
    report("interaction_parameters", out, seed=0)


if __name__ == "__main__":
    main()

"""Closed loop on recorded WOMD scenes (issue 20 section 5): map build time, simulated steps
per second per core with log and idm traffic, the lane lookup against highway-env's, and,
on every real scenario, each shipped policy's off-road, collision, route progress and label
agreement with the human (log and idm traffic, with idm traffic's own collisions), and the
cost of the RL observation with the route (``KinematicsRoute``).

Each figure is wall time and CPU time (user + sys) of this one process, after one warm-up
episode (numba kernels compiled and cached). The machine is shared: quote both.

Usage: ``python benchmarks/bench_womd_closed_loop.py [FILES ...]`` (default: the four
samples in ../shared/data/womd).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np
from highway_env.road.lane import PolyLaneFixedWidth
from highway_env.road.road import RoadNetwork
from machine import report

from tap_bench.labelling import label
from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_lanes import lane_points
from tap_bench.sim.womd_road import WomdNetwork

DEFAULT = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "womd"
POLICIES = ("log", "idm", "idm-aggressive", "idm-defensive", "lane-keeping", "random",
            "dqn-highway", "ppo-highway")


def _clock() -> tuple[float, float]:
    t = os.times()
    return time.perf_counter(), t.user + t.system


def episode(env, policy: str, seed: int):
    p = load_policy(policy)
    obs, _ = env.reset(seed=seed)
    p.reset(env, seed=seed)
    w0, c0 = _clock()
    done = False
    while not done:
        obs, _, term, trunc, _ = env.step(p.act(obs))
        done = term or trunc
    w1, c1 = _clock()
    steps = env.unwrapped.clock[0] - 10
    return env.trajectories(policy=policy), steps, w1 - w0, c1 - c0


def ego_sdl(table) -> str:
    ego = table[table["is_ego"].to_numpy(bool)].drop(
        columns=[c for c in ("policy", "env", "seed", "source") if c in table.columns])
    labels = label(ego, level="maneuver")
    return " ; ".join(labels["sdl"].astype(str))


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("files", nargs="*")
    args = parser.parse_args()
    files = args.files or [str(DEFAULT / f) for f in (
        "motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord",
        "motion_data_one_example.tfrecord", "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")]
    figures: dict = {"scenes": {}, "policies": {}}
    envs = {traffic: make_womd_env(files, traffic=traffic) for traffic in ("log", "idm")}
    agents: dict = {}  # envs with the observation a trained agent reads
    env = envs["log"]
    for seed in range(len(env.catalog)):
        try:
            episode(env, "idm", seed)  # warm-up: compile, decode, cache the scene
        except Exception as err:
            figures["scenes"][str(env.catalog[seed])] = {"error": str(err)}
            continue
        scene = env.scene
        w0, c0 = _clock()
        network = WomdNetwork(scene.road)
        w1, c1 = _clock()
        row = {"scenario_id": scene.scenario_id, "agents": len(scene.track_ids),
               "lanes": len(network.index), "steps": scene.n_steps,
               "map_build_s": round(w1 - w0, 3), "map_build_cpu_s": round(c1 - c0, 3)}
        for traffic, e in envs.items():
            for policy in ("log", "idm"):
                episode(e, policy, seed)  # warm
                _, steps, wall, cpu = episode(e, policy, seed)
                row[f"{traffic}_traffic_{policy}_steps_per_s"] = round(steps / wall, 1)
                row[f"{traffic}_traffic_{policy}_steps_per_cpu_s"] = round(steps / cpu, 1)
        # the lane lookup: highway-env's against the compiled one
        plain = RoadNetwork()
        for lane in scene.road.lanes.values():
            pts = lane_points(lane.centre)
            if pts is not None:
                plain.add_lane(str(lane.id), f"{lane.id}>", PolyLaneFixedWidth(
                    np.c_[pts[:, 0], -pts[:, 1]].tolist(), width=lane.width))
        p = np.array([scene.x[scene.ego, 10], -scene.y[scene.ego, 10]])
        h = -scene.heading[scene.ego, 10]
        t0 = time.perf_counter()
        for _ in range(5):
            plain.get_closest_lane_index(p, h)
        t1 = time.perf_counter()
        for _ in range(500):
            network.get_closest_lane_index(p, h)
        t2 = time.perf_counter()
        row["lookup_highway_env_ms"] = round((t1 - t0) / 5 * 1e3, 3)
        row["lookup_compiled_ms"] = round((t2 - t1) / 500 * 1e3, 4)
        figures["scenes"][scene.scenario_id] = row
        # the observation of an RL agent: Kinematics alone, and with the route
        env.reset(seed=seed)
        obs_type = env.unwrapped.observation_type
        t0 = time.perf_counter()
        for _ in range(200):
            obs_type.observe()
        t1 = time.perf_counter()
        for _ in range(200):
            obs_type.route_vector()
        t2 = time.perf_counter()
        row["observation_ms"] = round((t1 - t0) / 200 * 1e3, 3)
        row["of_which_route_ms"] = round((t2 - t1) / 200 * 1e3, 3)
        figures["scenes"][scene.scenario_id] = row
        # every shipped policy against the human on this scene, log and idm traffic
        for traffic, e in envs.items():
            human, *_ = episode(e, "log", seed)
            human_sdl = ego_sdl(human)
            for policy in POLICIES:
                observation = load_policy(policy).observation
                if observation is not None:  # the shipped agents read plain Kinematics
                    key = (traffic, repr(sorted(observation.items())))
                    if key not in agents:
                        agents[key] = make_womd_env(files, traffic=traffic,
                                                    config={"observation": observation})
                    run_env = agents[key]
                else:
                    run_env = e
                try:
                    table, *_ = episode(run_env, policy, seed)
                except Exception as err:
                    figures["policies"].setdefault(f"{policy} ({traffic} traffic)", {})[
                        scene.scenario_id] = str(err)
                    continue
                info = run_env.episode_info()
                figures["policies"].setdefault(f"{policy} ({traffic} traffic)", {})[
                    scene.scenario_id] = {
                    "crashed": bool(run_env.unwrapped.vehicle.crashed),
                    "crash_at_fault": info.get("crash_at_fault"),
                    "crash_with": info.get("crash_with"),
                    "crash_fault": info.get("crash_fault"),
                    "off_road": info["off_road"],
                    "max_off_road_distance_m": info.get("max_off_road_distance_m"),
                    "route_progress": None if np.isnan(info["route_progress"])
                    else round(info["route_progress"], 3),
                    "ran_red_light": info["ran_red_light"],
                    "log_ade_m": round(info["log_ade"], 2),
                    "label_equals_human": ego_sdl(table) == human_sdl,
                    "traffic_collisions": info["traffic_collisions"],
                    "traffic_collisions_with_log": info["traffic_collisions_with_log"]}
    report("womd_closed_loop", figures, files=files)


if __name__ == "__main__":
    main()

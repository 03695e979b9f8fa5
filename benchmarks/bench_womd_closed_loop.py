"""Closed loop on recorded WOMD scenes (issue 20 section 5): map build time, simulated steps
per second per core with log and idm traffic, the lane lookup against highway-env's, and,
on every real scenario, each shipped policy's off-road, collision, route progress and label
agreement with the human (log and idm traffic, with idm traffic's own collisions), and the
cost of the RL observation with the route (``KinematicsRoute``).

Each figure is wall time and CPU time (user + sys) of this one process, after one warm-up
episode (numba kernels compiled and cached). The machine is shared: quote both.

Usage: ``python benchmarks/bench_womd_closed_loop.py [FILES ...]`` (default: the four
samples in ../shared/data/womd).

**Speed of the closed loop, trees side by side** (``--speed``): for each checkout given
(``--trees``, default this one), in fresh interpreters with that tree first on the path,
alternating tree by tree ``--repeats`` times:

- *whole file*: ``tap-bench rollout --womd FILES --policy idm --traffic log|idm``, start-up,
  maps and writing included: simulated steps per CPU second (user + sys of the process)
  beside wall time and the load;
- *steps only*: each scene's episode once to warm, then again timed from its first step to
  its last (resets excluded): steps per CPU second by traffic (log, idm) and ego (idm,
  log), as issue 34's speed table counts them.

Each tree's numba kernels are compiled (untimed runs of both traffics) before the timed
ones. Default files for ``--speed``: the four samples and the development file (16 real
scenes)::

    python benchmarks/bench_womd_closed_loop.py --speed --trees /tmp/before . --repeats 3
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
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


_STEPS_CHILD = """
import json, os, sys, warnings
warnings.filterwarnings("ignore")
from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
files = sys.argv[1:]
out = {}
for traffic in ("log", "idm"):
    env = make_womd_env(files, traffic=traffic)
    for seed in range(len(env.catalog)):
        for policy in ("idm", "log"):
            runs = []
            for _ in range(2):  # warm, timed
                p = load_policy(policy)
                obs, _ = env.reset(seed=seed)
                p.reset(env, seed=seed)
                t = os.times()
                done = False
                while not done:
                    obs, _, term, trunc, _ = env.step(p.act(obs))
                    done = term or trunc
                u = os.times()
                runs.append((env.unwrapped.clock[0] - 10, u.user + u.system - t.user - t.system))
            out[f"{traffic}/{policy}/{seed}"] = runs[-1]
print(json.dumps(out))
"""


def _child(tree: Path, args: list[str]) -> tuple[subprocess.CompletedProcess, float, float]:
    """Run ``python args`` with ``tree`` first on the path: (the finished process, its CPU
    s (user + sys, from this process's reaped children's totals), its wall s)."""
    import resource

    env = {**os.environ, "PYTHONPATH": str(tree), "OMP_WAIT_POLICY": "PASSIVE",
           "OMP_NUM_THREADS": "1"}
    r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, *args], env=env, cwd=str(tree),
                          capture_output=True, text=True)
    wall = time.perf_counter() - start
    r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
    return proc, cpu, wall


def whole_file(tree: Path, files: list[str], traffic: str, out: Path) -> dict:
    """``tap-bench rollout --womd`` of ``files`` (idm ego) in a fresh process of ``tree``:
    steps, CPU s (user + sys), wall s, load before and after."""
    import pandas as pd

    load0 = os.getloadavg()[0]
    proc, cpu, wall = _child(tree, ["-m", "tap_bench", "rollout", "--womd", *files,
                                    "--policy", "idm", "--traffic", traffic, "-o", str(out),
                                    "--no-progress"])
    if proc.returncode:
        raise SystemExit(f"{tree}: rollout failed:\n{proc.stderr[-2000:]}")
    episodes = pd.read_parquet(str(out).replace(".parquet", ".episodes.parquet"))
    steps = round(float((episodes["duration_s"].fillna(0) * 10).sum()))
    return {"steps": steps, "cpu_s": round(cpu, 2), "wall_s": round(wall, 2),
            "steps_per_cpu_s": round(steps / cpu, 1),
            "load": [round(load0, 1), round(os.getloadavg()[0], 1)]}


def steps_only(tree: Path, files: list[str]) -> dict:
    """Steps per CPU s of the timed episodes (after a warm one) by traffic/ego, and all."""
    proc, _, _ = _child(tree, ["-c", _STEPS_CHILD, *files])  # CPU: the episodes' own
    if proc.returncode:
        raise SystemExit(f"{tree}: episodes failed:\n{proc.stderr[-2000:]}")
    runs = json.loads(proc.stdout.strip().splitlines()[-1])
    out: dict = {}
    for key, (steps, cpu) in runs.items():
        group = "/".join(key.split("/")[:2])
        s, c = out.get(group, (0, 0.0))
        out[group] = (s + steps, c + cpu)
    return {group: round(s / c, 1) for group, (s, c) in sorted(out.items())}


def speed(trees: list[Path], files: list[str], repeats: int) -> None:
    """The ``--speed`` figures (see the module docstring), printed as they come and
    reported."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for tree in trees:  # compile each tree's numba kernels first (not timed)
            for traffic in ("log", "idm"):
                whole_file(tree, files, traffic, Path(tmp) / "warm.parquet")
        for r in range(repeats):
            for tree in trees:
                row = {"tree": str(tree), "repeat": r}
                for traffic in ("log", "idm"):
                    row[f"whole_file_{traffic}"] = whole_file(
                        tree, files, traffic, Path(tmp) / f"{traffic}.parquet")
                row["steps_only"] = steps_only(tree, files)
                print(json.dumps(row), flush=True)
                rows.append(row)
    report("womd_closed_loop_speed", {"runs": rows}, files=files,
           trees=[str(t) for t in trees])


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("files", nargs="*")
    parser.add_argument("--speed", action="store_true",
                        help="only the speed figures, of each tree in --trees")
    parser.add_argument("--trees", nargs="+", type=Path,
                        default=[Path(__file__).resolve().parents[1]])
    parser.add_argument("--repeats", type=int, default=2)
    args = parser.parse_args()
    if args.speed:
        files = args.files or [str(DEFAULT / f) for f in (
            "motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord",
            "motion_data_one_example.tfrecord", "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl")] + [
            str(p) for p in [DEFAULT.parent / "womd-dev" / "dev.tfrecord"] if p.exists()]
        speed([t.resolve() for t in args.trees], [str(Path(f).resolve()) for f in files],
              args.repeats)
        return
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

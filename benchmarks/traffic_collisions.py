"""Why does idm traffic collide? Every collision of a simulated vehicle, classified.

On every real scene we have (``traffic_realism.real_files``) this runs idm traffic with the
human as the ego (policy ``log``) and with an IDM ego (policy ``idm``), ``--rollouts``
rollouts each, and classifies the first contact of every simulated vehicle that collides
(its box overlaps another valid agent's after the current time, pairs already overlapping
at the current time aside), by

- **partner**: ``ego`` (the replayed human or the IDM ego), ``idm`` (another simulated
  vehicle), ``log vehicle`` (a replayed vehicle: parked, off the map, ...), ``walker`` (a
  pedestrian or cyclist);
- **geometry** at first contact: ``rear-end`` (headings within 30 deg, centres within 1 m
  across the pair's mean heading; ``struck``/``striking`` says whether the simulated
  vehicle is the one in front), ``lateral`` (headings within 30 deg, side by side: a lane
  change, a merge, a lane the map draws across another), ``crossing`` (headings 30-150 deg
  apart: an intersection), ``head-on`` (more than 150 deg);
- **off its path**: the simulated vehicle's centre is more than 2 m from its own logged
  path (the polyline of its logged positions after the current time) at first contact;
- **off the map**: more than half a lane's width + 3 m from the nearest lane centre.

Usage: ``python benchmarks/traffic_collisions.py [--rollouts K] [--name NAME]``
"""

from __future__ import annotations

import argparse
import math
import os
import time
import warnings
from collections import Counter

import numpy as np
from machine import report
from traffic_realism import real_files

from tap_bench.realism.features import overlapping_pairs
from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.sim.womd_road import LogVehicle, path_progress, sim_frame
from tap_bench.sim.womd_scene import CURRENT_STEP

SAME_DIRECTION = math.radians(30.0)  # [rad]
HEAD_ON = math.radians(150.0)  # [rad]
IN_LINE = 1.0  # [m] centres this close across the mean heading: a rear-end
OFF_PATH = 2.0  # [m]
OFF_MAP = 3.0  # [m] beyond half the lane's width


def classify(scene, rec, i: int, j: int, k: int) -> str:
    """Geometry of the first contact of simulated vehicle ``i`` with agent ``j`` at step
    ``k`` (WOMD axes)."""
    hi, hj = float(rec["heading"][i, k]), float(rec["heading"][j, k])
    dh = abs((hi - hj + math.pi) % (2 * math.pi) - math.pi)
    if dh > HEAD_ON:
        return "head-on"
    if dh > SAME_DIRECTION:
        return "crossing"
    mean = math.atan2(math.sin(hi) + math.sin(hj), math.cos(hi) + math.cos(hj))
    dx = float(rec["x"][j, k] - rec["x"][i, k])
    dy = float(rec["y"][j, k] - rec["y"][i, k])
    lon = dx * math.cos(mean) + dy * math.sin(mean)
    lat = -dx * math.sin(mean) + dy * math.cos(mean)
    if abs(lat) > IN_LINE:
        return "lateral"
    return "rear-end striking" if lon > 0 else "rear-end struck"


def partner_kind(env, j: int) -> str:
    scene = env.scene
    if j == scene.ego:
        return "ego"
    if scene.object_types[j] != "vehicle":
        return "walker"
    vehicle = env.unwrapped.simulated.get(j)
    return "log vehicle" if vehicle is None or isinstance(vehicle, LogVehicle) else "idm"


def off_path(scene, rec, i: int, k: int) -> bool:
    steps = np.flatnonzero(scene.valid[i, CURRENT_STEP:]) + CURRENT_STEP
    path = np.c_[scene.x[i, steps], scene.y[i, steps]].astype(float)
    p = np.array([rec["x"][i, k], rec["y"][i, k]], float)
    if len(path) < 2:
        return bool(np.hypot(*(p - path[0])) > OFF_PATH) if len(path) else True
    cum = np.r_[0.0, np.cumsum(np.hypot(*np.diff(path, axis=0).T))]
    return path_progress(path, cum, p)[1] > OFF_PATH


def off_map(env, rec, i: int, k: int) -> bool:
    network = env.unwrapped.road.network
    p = sim_frame(rec["x"][i, k], rec["y"][i, k])
    lane = network.get_lane(network.get_closest_lane_index(p, -float(rec["heading"][i, k])))
    return abs(lane.local_coordinates(p)[1]) > lane.width / 2 + OFF_MAP


def measure(files: list[str], ego: str, rollouts: int) -> dict:
    env = make_womd_env(files, traffic="idm")
    policy = load_policy(ego)
    classes: Counter = Counter()
    per_scene = []
    simulated_total = 0
    cpu = 0.0
    for index in range(len(env.catalog)):
        for k_roll in range(rollouts):
            t0 = os.times()
            try:
                obs, _ = env.reset(seed=index, options={"rollout": k_roll})
            except Exception as err:  # a scene that cannot be driven is reported
                per_scene.append({"scene": str(env.catalog[index]), "error": str(err)})
                break
            policy.reset(env, seed=index)
            done = False
            while not done:
                obs, _, terminated, truncated, _ = env.step(policy.act(obs))
                done = terminated or truncated
            t1 = os.times()
            cpu += t1.user + t1.system - t0.user - t0.system
            scene = env.scene
            rows = set(int(r) for r in env.unwrapped.simulated
                       if not isinstance(env.unwrapped.simulated[r], LogVehicle)
                       and scene.object_types[r] == "vehicle")
            simulated_total += len(rows)
            rec = env.recorded_states()
            length = np.asarray(scene.length, float)
            width = np.asarray(scene.width, float)
            now = slice(CURRENT_STEP, CURRENT_STEP + 1)
            exempt = {(int(a), int(b)) for _, a, b in overlapping_pairs(
                scene.x[:, now], scene.y[:, now], scene.heading[:, now],
                scene.valid[:, now], length, width)}
            w = slice(CURRENT_STEP + 1, scene.n_steps)
            pairs = overlapping_pairs(rec["x"][:, w], rec["y"][:, w], rec["heading"][:, w],
                                      rec["valid"][:, w], length, width)
            first: dict[int, tuple[int, int]] = {}
            for step, a, b in pairs[np.argsort(pairs[:, 0], kind="stable")]:
                a, b = int(a), int(b)
                if (a, b) in exempt:
                    continue
                for i, j in ((a, b), (b, a)):
                    if i in rows and i not in first:
                        first[i] = (j, int(step) + CURRENT_STEP + 1)
            found = []
            for i, (j, k) in sorted(first.items()):
                label = (partner_kind(env, j), classify(scene, rec, i, j, k),
                         "off path" if off_path(scene, rec, i, k) else "on path",
                         "off map" if off_map(env, rec, i, k) else "on map")
                classes[label] += 1
                found.append({"track": str(scene.track_ids[i]),
                              "partner": str(scene.track_ids[j]), "t": k / 10,
                              "class": " / ".join(label)})
            per_scene.append({"scene": scene.scenario_id, "rollout": k_roll,
                              "simulated": len(rows), "collided": len(first),
                              "collisions": found})
    n = sum(classes.values())
    return {"simulated_vehicles": simulated_total, "collided": n,
            "collision_share": n / max(simulated_total, 1),
            "classes": {" / ".join(c): m for c, m in classes.most_common()},
            "by_partner": dict(_sum(classes, 0)),
            "by_geometry": dict(_sum(classes, 1)),
            "off_path": sum(m for c, m in classes.items() if c[2] == "off path"),
            "off_map": sum(m for c, m in classes.items() if c[3] == "off map"),
            "cpu_seconds": cpu, "scenes": per_scene}


def _sum(classes: Counter, part: int) -> Counter:
    out: Counter = Counter()
    for c, m in classes.items():
        out[c[part]] += m
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rollouts", type=int, default=1)
    parser.add_argument("--name", default="traffic_collisions")
    parser.add_argument("--ego", nargs="+", default=["log", "idm"])
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    files = real_files()
    wall = time.perf_counter()
    figures = {"files": files, "rollouts": args.rollouts}
    for ego in args.ego:
        figures[f"ego_{ego}"] = f = measure(files, ego, args.rollouts)
        print(f"ego {ego}: {f['collided']} of {f['simulated_vehicles']} simulated vehicles "
              f"collide ({f['collision_share']:.1%}); {f['cpu_seconds']:.1f} CPU s")
        print(f"  by partner {f['by_partner']}; by geometry {f['by_geometry']}; off their "
              f"path {f['off_path']}, off the map {f['off_map']}")
        for c, m in f["classes"].items():
            print(f"  {m:3d}  {c}")
    figures["wall_seconds"] = time.perf_counter() - wall
    report(args.name, figures, seed=0)


if __name__ == "__main__":
    main()

"""What an agent's at-fault collisions on recorded scenes are: per episode that ended in
one, the other road user's kind of conflict at the collision, and whether the ego's
observation named it as its leader.

Every driver of the scenes given (:func:`tap_bench.rl.heldout.drivers`, log traffic) is
the ego of one episode per policy. For each at-fault collision, the partner (the env's
``crash_with``) at the collision: its speed, its place in the ego's frame (forward, left
[m]) and its heading relative to the ego's, classed as

- ``stopped``: slower than 0.5 m/s;
- ``ahead``: ahead of the ego's centre, heading within 30 degrees of the ego's;
- ``crossing``: heading 30 to 150 degrees off the ego's;
- ``oncoming``: heading more than 150 degrees off;
- ``behind``: behind the ego's centre, heading within 30 degrees;

and ``leader_seen``: whether the leader of the observation (``KinematicsRoute``, the road
user in the path ahead) was that partner (about: its gap within 3 m of the partner's).
Prints the table and the counts per class.

Usage: python benchmarks/agents_collisions.py --womd FILES --scenes 0-5,7,8
       --policies lane-keeping [ppo-womd-seed0 ...]
"""

from __future__ import annotations

import argparse
import math
import time
import warnings

import numpy as np
import pandas as pd
from agents_validation import policy_env
from machine import report

from tap_bench.rl.heldout import drivers
from tap_bench.sim.policies import load_policy
from tap_bench.sim.rollout import run_episode
from tap_bench.sim.womd_env import WomdEnv
from tap_bench.sim.womd_observation import RouteObservation
from tap_bench.sim.womd_scene import WomdScenes

STOPPED = 0.5  # [m/s]
ALONG = math.radians(30.0)  # [rad] headings this close are the same direction


def conflict(env: WomdEnv) -> dict[str, object]:
    """The partner of the ego's collision at the end of an episode, in the ego's frame."""
    inner = env.unwrapped
    ego = inner.vehicle
    partner = [v for v in inner.road.vehicles if v is not ego
               and getattr(v, "row", None) is not None
               and str(inner.scene.track_ids[v.row]) == env.crash_with]
    if not partner:
        return {"kind": "unknown"}
    other = partner[0]
    rel = np.asarray(other.position, float) - np.asarray(ego.position, float)
    c, s = math.cos(ego.heading), math.sin(ego.heading)
    forward, left = float(rel @ (c, s)), float(-(rel @ (-s, c)))
    dh = abs((other.heading - ego.heading + math.pi) % (2 * math.pi) - math.pi)
    if other.speed < STOPPED:
        kind = "stopped"
    elif dh > math.pi - ALONG:
        kind = "oncoming"
    elif dh > ALONG:
        kind = "crossing"
    else:
        kind = "ahead" if forward > 0 else "behind"
    watch = inner.observation_type if isinstance(inner.observation_type, RouteObservation) \
        else inner._lead_watch
    watch.route_vector()
    seen = math.isfinite(watch.lead.gap) and abs(
        watch.lead.gap - (forward - (ego.LENGTH + other.LENGTH) / 2)) < 3.0
    return {"kind": kind, "partner_speed": round(float(other.speed), 2),
            "forward": round(forward, 2), "left": round(left, 2),
            "heading_off_deg": round(math.degrees(dh), 1), "leader_seen": bool(seen)}


def collisions(files: list[str], scenes: list[int], policies: list[str],
               observation: dict | None = None) -> pd.DataFrame:
    """One row per (policy, scene, driver) episode that ended in an at-fault collision;
    ``observation``: the env's observation config (the leader judged by it) for policies
    that read none."""
    scenes_ = WomdScenes(tuple(files))
    rows = []
    for name in policies:
        policy = load_policy(name)
        env = WomdEnv(scenes_.with_overrides({"observation": observation}), record=False) \
            if observation is not None and policy.observation is None \
            else policy_env(scenes_, policy)
        for i in scenes:
            for track in drivers(env.scene_at(i)):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    _, row = run_episode(env, policy, i, record=False,
                                         options={"scene": i, "ego": track})
                if row.get("status") == "ok" and row.get("crash_at_fault"):
                    rows.append({"policy": name, "scene": i, "track": track,
                                 "with": env.crash_with, "length": row.get("length"),
                                 **conflict(env)})
    return pd.DataFrame(rows)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--womd", nargs="+", required=True)
    parser.add_argument("--scenes", required=True, help="scene indexes, 0-5,7,8")
    parser.add_argument("--policies", nargs="+", required=True)
    parser.add_argument("--corners", action="store_true",
                        help="judge leader_seen with leader_corners (policies reading no "
                        "observation only)")
    args = parser.parse_args()
    scenes = list(WomdScenes(tuple(args.womd)).seeds(args.scenes))
    start, cpu = time.perf_counter(), time.process_time()
    table = collisions(args.womd, scenes, args.policies, {
        "type": "KinematicsRoute", "leader": True, "leader_corners": True}
        if args.corners else None)
    with pd.option_context("display.width", 200, "display.max_columns", 20,
                           "display.max_rows", 500):
        print(table.to_string(index=False))
        if len(table):
            print(table.groupby(["policy", "kind"]).agg(
                n=("track", "size"), leader_seen=("leader_seen", "sum")).to_string())
    report("agents_collisions", {
        "scenes": scenes, "at_fault_collisions": len(table),
        "wall_s": round(time.perf_counter() - start, 1),
        "cpu_s": round(time.process_time() - cpu, 1)})


if __name__ == "__main__":
    main()

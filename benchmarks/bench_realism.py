"""Cost and figures of ``tap-bench realism``: CPU seconds per scene for K rollouts (the
issue's target: 8 rollouts of a 9 s scene in at most 5 CPU s on average) and the
meta-metric of the three traffic models (log, idm, constant-velocity) on every real scene
we have (../shared/data/womd/*, ../shared/data/womd-dev/dev.tfrecord; absent ones
skipped), with the human as the ego.

CPU time is user + sys of this process (os.times), split into simulation (the rollouts) and
scoring (features, likelihoods, manoeuvre labels); the machine is shared: quote the load.

Usage: ``python benchmarks/bench_realism.py [--rollouts 8] [--traffic idm ...]``
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np
import pandas as pd
from machine import report
from traffic_realism import real_files

from tap_bench.realism.rollouts import SceneStates, agent_manoeuvres, scene_rollouts, score_scene
from tap_bench.realism.summary import summarise
from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env
from tap_bench.stats.bootstrap import BootstrapConfig


def cpu() -> float:
    t = os.times()
    return t.user + t.system


def run(traffic: str, rollouts: int) -> dict:
    env = make_womd_env(real_files(), traffic=traffic)
    policy = load_policy("log")
    once = traffic in ("log", "constant-velocity")
    tables, per_scene = [], []
    for index in range(len(env.catalog)):
        c0 = cpu()
        states = scene_rollouts(env, index, policy, 1 if once else rollouts)
        if once:
            states = SceneStates(*(np.repeat(a, rollouts, axis=0) for a in
                                   (states.x, states.y, states.heading, states.valid)))
        c1 = cpu()
        scene = env.scene
        table = score_scene(scene, states, manoeuvres=agent_manoeuvres(scene))
        c2 = cpu()
        tables.append(table)
        per_scene.append({"scene": scene.scenario_id, "seconds": float(scene.times[-1]
                                                                       - scene.times[0]),
                          "simulation_cpu": c1 - c0, "scoring_cpu": c2 - c1})
    result = summarise(pd.concat(tables, ignore_index=True), BootstrapConfig(seed=0))
    meta = {r["scenario_id"]: r.get("meta_metric") for r in result["per_scene"]}
    for entry in per_scene:  # each scene's own meta-metric beside its cost
        entry["meta_metric"] = meta.get(entry["scene"])
    frame = pd.DataFrame(per_scene)
    nine = frame[frame["seconds"] < 10.0]  # the 9.1 s WOMD scenes (the pickle is 19.8 s)
    return {"meta_metric": result["overall"]["meta_metric"],
            "features": {k: result["overall"][k] for k in result["weights"]},
            "by_manoeuvre": {k: v["meta_metric"] for k, v in result["by_manoeuvre"].items()},
            "by_object_type": {k: v["meta_metric"] for k, v in
                               result["by_object_type"].items()},
            "scenes": result["scenes"], "agents": result["agents"],
            "cpu_per_9s_scene": float((nine["simulation_cpu"] + nine["scoring_cpu"]).mean()),
            "simulation_cpu_per_9s_scene": float(nine["simulation_cpu"].mean()),
            "scoring_cpu_per_9s_scene": float(nine["scoring_cpu"].mean()),
            "per_scene": per_scene}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rollouts", type=int, default=8)
    parser.add_argument("--traffic", nargs="+", default=["log", "idm", "constant-velocity"])
    parser.add_argument("--name", default="bench_realism")
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    figures = {"rollouts": args.rollouts, "files": real_files()}
    wall = time.perf_counter()
    for traffic in args.traffic:
        f = figures[traffic] = run(traffic, args.rollouts)
        m = f["meta_metric"]
        print(f"{traffic:18s} meta-metric {m['value']:.3f} [{m['low']:.3f}, {m['high']:.3f}] "
              f"over {f['scenes']} scenes, {f['agents']} agents; CPU per 9 s scene "
              f"{f['cpu_per_9s_scene']:.2f} s (simulation {f['simulation_cpu_per_9s_scene']:.2f}"
              f", scoring {f['scoring_cpu_per_9s_scene']:.2f})")
        for name, block in f["by_manoeuvre"].items():
            print(f"    {name:14s} {block['value']:.3f}")
    figures["wall_seconds"] = time.perf_counter() - wall
    report(args.name, figures, seed=0)


if __name__ == "__main__":
    main()

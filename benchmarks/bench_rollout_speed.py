"""Rollout throughput: simulated seconds per wall second for each scenario and built-in
policy, with 1 and 2 worker processes.

Each (scenario, policy, workers) runs the same seeds through ``tap_bench.rollout`` with
recording on, as a user would; wall time includes starting the worker processes. Policies
that read no observation get the cheap one. Run it on an idle machine: with other work on
the cores, a second worker has nothing to gain.

Usage: python benchmarks/bench_rollout_speed.py [--seeds 0-5] [--workers 1,2]
       [--envs highway,merge] [--policies idm,random]
"""

from __future__ import annotations

import argparse
import time
import warnings

from machine import report

from tap_bench.sim import available_policies, rollout, scenario_names
from tap_bench.sim.policies import get_definition

BUILT_INS = ("idm", "idm-aggressive", "idm-defensive", "random", "lane-keeping")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-5")
    parser.add_argument("--workers", default="1,2")
    parser.add_argument("--envs", default=",".join(scenario_names()))
    parser.add_argument("--policies", default=",".join(BUILT_INS))
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    policies = args.policies.split(",")
    # trained models run on the scenario they were trained on
    sb3 = {n: d.params.get("env", "") for n, d in available_policies().items()
           if d.kind == "sb3"}
    figures = {}
    for env in args.envs.split(","):
        names = policies + [n for n, e in sb3.items()
                            if e.removeprefix("tap_bench/").rsplit("-v", 1)[0] == env]
        for policy in names:
            get_definition(policy)
            for workers in map(int, args.workers.split(",")):
                start = time.perf_counter()
                _, episodes = rollout(env, policy, args.seeds, workers=workers,
                                      progress=False)
                wall = time.perf_counter() - start
                simulated = float(episodes["duration_s"].sum())
                key = f"{env}/{policy}/workers={workers}"
                figures[key] = {"simulated_s_per_wall_s": round(simulated / wall, 2),
                                "simulated_s": simulated, "wall_s": round(wall, 2),
                                "episodes": len(episodes)}
                print(key, figures[key], flush=True)
    report("rollout_speed", figures, seeds=args.seeds,
           note="wall time includes starting the worker processes (spawn)")


if __name__ == "__main__":
    main()

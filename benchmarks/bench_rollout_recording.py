"""What recording costs: bare highway-env stepping vs the scenario env with and without its
recorder, and the Kinematics observation vs the cheap one.

For each scenario, the same seeds and actions (IDLE every decision) run in one process:

- ``highway_env``: highway-env's own env with the scenario's config (no tap-bench wrapper);
- ``scenario_env``: tap-bench's scenario env, recording off;
- ``recording``: recording on, and the episode's trajectory table built at its end;

each with the cheap observation (AttributesObservation), plus ``recording_kinematics`` with
highway-env's Kinematics table. Each variant runs ``--repeats`` times, alternating, and the
fastest run counts (the least disturbed by other work on the machine).

Usage: python benchmarks/bench_rollout_recording.py [--seeds 0-3] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time
import warnings

from machine import report

from tap_bench.sim import get_scenario, make_env, scenario_names
from tap_bench.sim.policies import CHEAP_OBSERVATION
from tap_bench.sim.suite import env_class, parse_seeds


def run(make, seeds: list[int], table: bool) -> tuple[float, int]:
    env = make()
    start = time.perf_counter()
    steps = 0
    for seed in seeds:
        env.reset(seed=seed)
        done = False
        while not done:
            _, _, terminated, truncated, _ = env.step(1)
            done = terminated or truncated
            steps += 1
        if table:
            env.trajectories()
    return time.perf_counter() - start, steps


def bare(name: str, observation: dict):
    scenario = get_scenario(name).with_overrides({"observation": observation})
    cls = env_class(scenario.highway_env_id)
    max_steps = scenario.max_steps

    class Bare:
        # highway-env's env, stopped after the scenario's number of decisions
        def __init__(self):
            self.env = cls(config=scenario.config)
            self.n = 0

        def reset(self, seed):
            self.n = 0
            return self.env.reset(seed=seed)

        def step(self, action):
            obs, r, term, trunc, info = self.env.step(action)
            self.n += 1
            return obs, r, term, trunc or self.n >= max_steps, info

    return Bare


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-3")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--envs", default=",".join(scenario_names()))
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    seeds = parse_seeds(args.seeds)
    figures = {}
    for name in args.envs.split(","):
        variants = {
            "highway_env": (bare(name, CHEAP_OBSERVATION), False),
            "scenario_env": (lambda n=name: make_env(
                n, record=False, config={"observation": CHEAP_OBSERVATION}), False),
            "recording": (lambda n=name: make_env(
                n, config={"observation": CHEAP_OBSERVATION}), True),
            "recording_kinematics": (lambda n=name: make_env(n), True),
        }
        best = {k: float("inf") for k in variants}
        steps = {}
        for _ in range(args.repeats):
            for key, (make, table) in variants.items():
                seconds, steps[key] = run(make, seeds, table)
                best[key] = min(best[key], seconds)
        ms = {k: round(1000 * best[k] / steps[k], 2) for k in variants}
        figures[name] = {
            "ms_per_decision": ms,
            "recording_overhead_vs_highway_env_percent": round(
                100 * (best["recording"] / best["highway_env"] - 1), 1),
            "recording_overhead_vs_scenario_env_percent": round(
                100 * (best["recording"] / best["scenario_env"] - 1), 1),
            "kinematics_observation_ms_per_decision": round(
                ms["recording_kinematics"] - ms["recording"], 2),
            "decisions": steps["recording"],
        }
        print(name, figures[name], flush=True)
    report("rollout_recording", figures, seeds=args.seeds, repeats=args.repeats,
           actions="IDLE every decision")


if __name__ == "__main__":
    main()

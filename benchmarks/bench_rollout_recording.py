"""What recording costs, measured inside the run: the CPU time spent in the recorder (every
vehicle at every simulated step, and the episode's table at its end) against the CPU time of
the rest of the stepping, for each scenario. Also what one observation costs: highway-env's
Kinematics table (the scenarios' default) against the cheap AttributesObservation that
rollouts give policies which read none.

Timing the recorder inside the same run, rather than comparing two runs, keeps the figure
free of the run-to-run noise of a shared machine (several per cent, more than the effect).

The episodes are IDM/MOBIL rollouts (policy ``idm``) of the given seeds.

Usage: python benchmarks/bench_rollout_recording.py [--seeds 0-3]
"""

from __future__ import annotations

import argparse
import time
import warnings

from highway_env.envs.common.observation import observation_factory
from machine import report

from tap_bench.sim import get_scenario, load_policy, make_env, scenario_names
from tap_bench.sim.policies import CHEAP_OBSERVATION
from tap_bench.sim.scenario_format import parse_seeds
from tap_bench.sim.schema import env_class


def recording_share(name: str, seeds: list[int]) -> dict:
    env = make_env(name, config={"observation": CHEAP_OBSERVATION})
    recorder = env.recorder
    spent = [0.0]
    frame = recorder.frame

    def timed_frame(*args):
        start = time.process_time()
        try:
            return frame(*args)
        finally:
            spent[0] += time.process_time() - start

    recorder.frame = timed_frame
    policy = load_policy("idm")
    decisions, rows = 0, 0
    start = time.process_time()
    for seed in seeds:
        obs, _ = env.reset(seed=seed)
        policy.reset(env, seed=seed)
        done = False
        while not done:
            obs, _, terminated, truncated, _ = env.step(policy.act(obs))
            done = terminated or truncated
            decisions += 1
        t0 = time.process_time()
        rows += len(env.trajectories())
        spent[0] += time.process_time() - t0
    total = time.process_time() - start
    stepping = total - spent[0]
    return {"recording_percent_of_stepping": round(100 * spent[0] / stepping, 2),
            "stepping_cpu_ms_per_decision": round(1000 * stepping / decisions, 2),
            "recording_cpu_ms_per_decision": round(1000 * spent[0] / decisions, 3),
            "decisions": decisions, "rows": rows}


def observation_cost(name: str, repeats: int = 200) -> dict:
    scenario = get_scenario(name)
    default = scenario.config.get("observation") or \
        env_class(scenario.highway_env_id).default_config()["observation"]
    env = make_env(name, record=False, config={"observation": CHEAP_OBSERVATION})
    env.reset(seed=0)
    for _ in range(3):
        env.step(1)
    out = {}
    for label, config in (("default", default), ("cheap", CHEAP_OBSERVATION)):
        observation = observation_factory(env.unwrapped, dict(config))
        start = time.process_time()
        for _ in range(repeats):
            observation.observe()
        out[f"{label}_observation_cpu_ms"] = round(
            1000 * (time.process_time() - start) / repeats, 3)
    out["default_observation_type"] = default["type"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0-3")
    parser.add_argument("--envs", default=",".join(scenario_names()))
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    seeds = parse_seeds(args.seeds)
    figures = {}
    for name in args.envs.split(","):
        figures[name] = {**recording_share(name, seeds), **observation_cost(name)}
        print(name, figures[name], flush=True)
    report("rollout_recording", figures, seeds=args.seeds, policy="idm",
           timer="time.process_time")


if __name__ == "__main__":
    main()

"""Evaluation of every policy on a scenario: mean return, crash rate, mean ego speed over
fixed seeds (the figures of the policy table in docs/simulation.md).

Usage: python benchmarks/bench_rollout_eval.py [--env highway] [--seeds 1000-1049]
       [--workers 2] [--policies dqn-highway,ppo-highway]
"""

from __future__ import annotations

import argparse
import warnings

from machine import report

from tap_bench.sim import available_policies, rollout
from tap_bench.stats.intervals import wilson_interval


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="highway")
    parser.add_argument("--seeds", default="1000-1049")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--policies", help="comma-separated names (default: every policy)")
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    figures = {}
    for name, definition in available_policies().items():
        if args.policies and name not in args.policies.split(","):
            continue
        trained_on = definition.params.get("env")
        if trained_on and trained_on.removeprefix("tap_bench/").rsplit("-v", 1)[0] != args.env:
            continue
        _, episodes = rollout(args.env, name, args.seeds, workers=args.workers,
                              record=True, progress=False)
        ok = episodes[episodes["status"] == "ok"]
        n = len(ok)
        crash = ok["crashed"].mean()
        figures[name] = {
            "episodes": n, "failed": int(len(episodes) - n),
            "mean_return": round(float(ok["return"].mean()), 2),
            "return_sd": round(float(ok["return"].std()), 2),
            "crash_rate": round(float(crash), 3),
            "crash_rate_wilson95": [round(x, 3) for x in wilson_interval(
                int(ok["crashed"].sum()), n, 0.95)],
            "mean_length": round(float(ok["length"].mean()), 1),
            "mean_ego_speed_m_s": round(float(ok["mean_speed"].mean()), 2),
        }
        print(name, figures[name], flush=True)
    suffix = "" if args.seeds == "1000-1049" else f"_{args.seeds}"
    report(f"rollout_eval_{args.env}{suffix}", figures, env=args.env, seeds=args.seeds,
           policies=args.policies or "all")


if __name__ == "__main__":
    main()

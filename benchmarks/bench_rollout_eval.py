"""Evaluation of every policy on a scenario: mean return, crash rate, mean ego speed over
fixed seeds (the figures of the policy table in docs/simulation.md).

Usage: python benchmarks/bench_rollout_eval.py [--env highway] [--seeds 1000-1049]
       [--workers 2]
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np
from machine import report

from tap_bench.sim import available_policies, rollout


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """Wilson score interval of a proportion k/n (sound at 0 and at n, unlike k/n +- z*se)."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return float(centre - half), float(centre + half)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="highway")
    parser.add_argument("--seeds", default="1000-1049")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    figures = {}
    for name, definition in available_policies().items():
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
            "crash_rate_wilson95": [round(x, 3) for x in wilson(int(ok["crashed"].sum()), n)],
            "mean_length": round(float(ok["length"].mean()), 1),
            "mean_ego_speed_m_s": round(float(ok["mean_speed"].mean()), 2),
        }
        print(name, figures[name], flush=True)
    report(f"rollout_eval_{args.env}", figures, env=args.env, seeds=args.seeds)


if __name__ == "__main__":
    main()

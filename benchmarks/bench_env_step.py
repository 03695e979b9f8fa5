"""CPU per step of one training env (what a worker of `tap-bench train` does), this code
against an older commit, alternating, in fresh processes.

Each run builds the training env exactly as `tap-bench train` does
(``tap_bench.rl.training._make_training_env``: the scenario's fast variant in a Monitor,
recording off), resets it with seed 0 and steps it ``--steps`` times with actions drawn from
a seeded generator, resetting at the end of each episode; it reports the thread CPU time
(user + sys of this thread only, which other jobs on a shared machine move less than wall
time) per env step, resets included, and the sums of every observation and reward, so that
the two versions are seen to simulate the same episodes (within 1e-6). The import and the
first reset are not timed.

Usage: python benchmarks/bench_env_step.py [--before-ref 4e8674d] [--steps 1000]
       [--repeats 3] [--env highway]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from machine import export, report

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import json, sys, time
import numpy as np
from tap_bench.rl.training import _make_training_env
from tap_bench.sim.scenario_env import get_scenario

env = _make_training_env(get_scenario(sys.argv[1]), True)
steps = int(sys.argv[2])
obs, _ = env.reset(seed=0)
rng = np.random.default_rng(0)
obs_sum = reward_sum = 0.0
start = time.thread_time()
for _ in range(steps):
    obs, reward, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
    obs_sum += float(np.abs(obs).sum())
    reward_sum += float(reward)
    if terminated or truncated:
        obs, _ = env.reset()
cpu = time.thread_time() - start
print(json.dumps({"cpu_ms_per_step": 1000 * cpu / steps, "obs_sum": obs_sum,
                  "reward_sum": reward_sum}))
"""


def run(source: Path, env: str, steps: int) -> dict:
    """One fresh process stepping the training env of the code at ``source``."""
    done = subprocess.run([sys.executable, "-c", CHILD, env, str(steps)], cwd=source,
                          env={**os.environ, "PYTHONPATH": str(source),
                               "PYTHONWARNINGS": "ignore"},
                          check=True, capture_output=True, text=True)
    result = json.loads(done.stdout.strip().splitlines()[-1])
    result["load_1m_after"] = round(os.getloadavg()[0], 2)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before-ref", default="4e8674d")
    parser.add_argument("--steps", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--env", default="highway")
    args = parser.parse_args()
    figures: dict[str, list] = {"before": [], "now": []}
    with tempfile.TemporaryDirectory() as tmp:
        before = export(args.before_ref, Path(tmp) / "before")
        for repeat in range(args.repeats):  # alternating, so a change of load hits both
            for name, source in (("before", before), ("now", ROOT)):
                result = run(source, args.env, args.steps)
                figures[name].append(result)
                print(f"run {repeat} {name}: {result}", flush=True)
    medians = {name: statistics.median(r["cpu_ms_per_step"] for r in runs)
               for name, runs in figures.items()}
    sums = [(r["obs_sum"], r["reward_sum"]) for runs in figures.values() for r in runs]
    same = all(abs(a - sums[0][0]) <= 1e-6 * max(1.0, abs(a)) and abs(b - sums[0][1]) <= 1e-6
               for a, b in sums)
    summary = {"median_cpu_ms_per_step": {k: round(v, 3) for k, v in medians.items()},
               "now_vs_before": round(medians["now"] / medians["before"], 3),
               "same_episodes": same}
    print(summary, flush=True)
    figures["summary"] = summary  # type: ignore[assignment]
    report("env_step", figures, env=args.env, steps=args.steps, before_ref=args.before_ref,
           fast_variant=True)


if __name__ == "__main__":
    main()

"""Simulated seconds per CPU second of a scenario with an IDM/MOBIL ego, this code against
an older commit, in one run.

Each version runs ``tap_bench.rollout(env, policy, seeds, workers=1)`` (recording on, as
``bench run`` does) in a fresh process; the figure is the episodes' simulated seconds over
the CPU seconds (user + sys) of the rollouts alone (imports and a warm-up episode not
counted). The versions alternate, so a change of the machine's load hits both; the episode
tables of both must agree (the same seeds, lengths and crashes, returns within 1e-6), else
the script fails.

Usage: python benchmarks/bench_sim_speed.py [--old 4e8674d] [--env highway]
       [--policy idm] [--seeds 0-5] [--repeats 3]
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

DRIVER = """\
import json, os, sys, warnings
warnings.filterwarnings("ignore")
from tap_bench.sim import rollout
env, policy, seeds = sys.argv[1], sys.argv[2], sys.argv[3]
rollout(env, policy, [10_000], workers=1, progress=False)  # warm: imports, first env
t0 = os.times()
_, episodes = rollout(env, policy, seeds, workers=1, progress=False)
t1 = os.times()
cpu = (t1.user - t0.user) + (t1.system - t0.system)
print(json.dumps({"simulated_s": float(episodes["duration_s"].sum()), "cpu_s": cpu,
                  "episodes": episodes[["seed", "length", "crashed", "return"]]
                  .astype(float).values.tolist()}))
"""


def run(tree: Path, env: str, policy: str, seeds: str) -> dict:
    done = subprocess.run([sys.executable, "-c", DRIVER, env, policy, seeds],
                          env={**os.environ, "PYTHONPATH": str(tree),
                               "OMP_WAIT_POLICY": "PASSIVE", "OMP_NUM_THREADS": "1"},
                          cwd=tree, check=True, capture_output=True, text=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", default="4e8674d")
    parser.add_argument("--env", default="highway")
    parser.add_argument("--policy", default="idm")
    parser.add_argument("--seeds", default="0-5")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rates: dict[str, list[float]] = {"old": [], "this": []}
    episodes = {}
    with tempfile.TemporaryDirectory() as tmp:
        old = export(args.old, Path(tmp) / "old")
        for _ in range(args.repeats):
            for name, tree in (("old", old), ("this", ROOT)):
                result = run(tree, args.env, args.policy, args.seeds)
                rates[name].append(result["simulated_s"] / result["cpu_s"])
                episodes[name] = result["episodes"]
                print(name, round(rates[name][-1], 1), "simulated s per CPU s", flush=True)
    if len(episodes["old"]) != len(episodes["this"]) or any(
            a[:3] != b[:3] or abs(a[3] - b[3]) > 1e-6
            for a, b in zip(episodes["old"], episodes["this"], strict=True)):
        raise SystemExit("the two versions simulated different episodes: "
                         f"{episodes['old']} != {episodes['this']}")
    old_rate, this_rate = statistics.median(rates["old"]), statistics.median(rates["this"])
    report("sim_speed", {
        "old_commit": args.old, "env": args.env, "policy": args.policy, "seeds": args.seeds,
        "simulated_s_per_cpu_s": {"old": round(old_rate, 1), "this": round(this_rate, 1)},
        "runs": {k: [round(v, 1) for v in r] for k, r in rates.items()},
        "speedup": round(this_rate / old_rate, 2), "same_episodes": True,
    }, repeats=args.repeats, note="CPU = user + sys of the rollouts, imports excluded")


if __name__ == "__main__":
    main()

"""Where the time of PPO training on recorded scenes goes: a cProfile of ``tap-bench train
--env womd`` in one process (one env, log traffic, no curve), then the functions by own
time and the main parts by cumulative time.

Times are CPU seconds of this process under cProfile (which slows Python-heavy code most, so
shares are indicative; the figures of record are ``benchmarks/bench_train_womd.py``'s).

Usage: python benchmarks/profile_train_womd.py --womd FILES [--timesteps 1024]
       [--egos all] [--top 30]
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import tempfile
import time
import warnings
from pathlib import Path

from machine import report

from tap_bench.rl.training import train
from tap_bench.sim.womd_scene import WomdScenes

# (part, file suffix, function): cumulative CPU time of each, as a share of the training
PARTS = (
    ("env step (all)", "tap_bench/sim/womd_env.py", "step"),
    ("simulation", "highway_env/envs/common/abstract.py", "_simulate"),
    ("road step", "highway_env/road/road.py", "step"),
    ("measure per 10 Hz step", "tap_bench/sim/womd_env.py", "measure_step"),
    ("off-road check", "tap_bench/sim/womd_road.py", "off_road"),
    ("observation", "tap_bench/sim/womd_observation.py", "observe"),
    ("kinematics rows", "tap_bench/sim/observation.py", "observe"),
    ("route vector", "tap_bench/sim/womd_observation.py", "route_vector"),
    ("leader", "tap_bench/sim/womd_observation.py", "leader"),
    ("reward", "tap_bench/sim/womd_env.py", "_reward"),
    ("reset", "tap_bench/sim/womd_env.py", "_reset"),
    ("PPO update", "stable_baselines3/ppo/ppo.py", "train"),
    ("action selection", "stable_baselines3/common/policies.py", "forward"),
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--womd", nargs="+", required=True)
    parser.add_argument("--timesteps", type=int, default=1024)
    parser.add_argument("--egos", default="sdc")
    parser.add_argument("--top", type=int, default=30)
    parser.add_argument("--callers", nargs="*", default=[],
                        help="also print the callers of these functions (by name)")
    args = parser.parse_args()
    scenes = WomdScenes(tuple(args.womd))
    profile = cProfile.Profile(time.process_time)  # CPU time: the machine is shared
    with tempfile.TemporaryDirectory() as out, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        start, cpu = time.perf_counter(), time.process_time()
        profile.enable()
        train("ppo", scenes, timesteps=args.timesteps, seed=0,
              output=Path(out) / "profiled.zip", n_envs=1, egos=args.egos)
        profile.disable()
        wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    stats = pstats.Stats(profile)
    total = max(v[3] for v in stats.stats.values())
    parts = {}
    for name, suffix, function in PARTS:
        parts[name] = round(sum(v[3] for (file, _, func), v in stats.stats.items()
                                if file.endswith(suffix) and func == function), 2)
    text = io.StringIO()
    pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(args.top)
    print(text.getvalue())
    for name in args.callers:
        text = io.StringIO()
        pstats.Stats(profile, stream=text).sort_stats("cumtime").print_callers(name)
        print(text.getvalue())
    for name, seconds in parts.items():
        print(f"{name:26s} {seconds:8.2f} s  {seconds / total:6.1%}")
    report("profile_train_womd", {"timesteps": args.timesteps, "egos": args.egos,
                                  "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
                                  "profiled_total_s": round(total, 1), "parts_s": parts})


if __name__ == "__main__":
    main()

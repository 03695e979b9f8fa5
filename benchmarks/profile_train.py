"""Where the time of `tap-bench train` goes: a cProfile of a short training run in one
process, grouped into env simulation, observation, recording and labelling, reset, gradient
steps, action selection and the rest.

Runs the training code of the checkout it is started from (or of ``--source``, a project
root, to profile another version, e.g. an export of the commit before a change). Times are
CPU seconds of this process (one env, ``n_envs=1``, curve off). cProfile slows
Python-heavy code (highway-env) more than torch's C++ code, so the shares are indicative;
the figures of record are the env steps per second of ``benchmarks/bench_train_speed.py``.

Usage: python benchmarks/profile_train.py [--algo dqn] [--timesteps 1000] [--source DIR]
       [--exact]
"""

from __future__ import annotations

import argparse
import cProfile
import inspect
import os
import pstats
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

# (group, file suffix, function name): cumulative time of these functions; the groups nest
# as listed in NESTING, so each group is reported net of the groups inside it.
PROBES = (
    ("env (step, reset)", "tap_bench/sim/scenario_env.py", "step"),
    ("env (step, reset)", "tap_bench/sim/scenario_env.py", "reset"),
    ("simulation", "highway_env/envs/common/abstract.py", "_simulate"),
    ("observation", "highway_env/envs/common/observation.py", "observe"),
    ("observation", "tap_bench/sim/observation.py", "observe"),
    ("recording", "tap_bench/sim/recorder.py", "frame"),
    # inside the simulation: highway-env's search, or tap-bench's (sim/fast_road.py, which
    # falls back to highway-env's on curved lanes: counted twice there; highway is straight)
    ("neighbour search", "highway_env/road/road.py", "neighbour_vehicles"),
    ("neighbour search", "tap_bench/sim/fast_road.py", "neighbour_vehicles"),
    ("collision checks", "highway_env/vehicle/objects.py", "handle_collisions"),
    ("labelling (coverage)", "tap_bench/sim/wrappers.py", "episode_labels"),
    ("curve evaluations", "tap_bench/rl/callbacks.py", "_evaluate"),
    ("gradient steps", "stable_baselines3/dqn/dqn.py", "train"),
    ("gradient steps", "stable_baselines3/ppo/ppo.py", "train"),
    ("gradient steps", "stable_baselines3/a2c/a2c.py", "train"),
    ("learn", "stable_baselines3/common/base_class.py", "learn"),
    ("learn", "stable_baselines3/common/on_policy_algorithm.py", "learn"),
    ("learn", "stable_baselines3/common/off_policy_algorithm.py", "learn"),
)
NESTING = {  # group: the groups whose time is inside it
    "learn": ("env (step, reset)", "gradient steps", "labelling (coverage)",
              "curve evaluations"),
    # the rest of the env: rewards, scene building at reset, highway-env's bookkeeping
    "env (step, reset)": ("simulation", "observation"),
    # nearly all recording happens inside the simulation
    "simulation": ("recording", "neighbour search", "collision checks"),
}


def group_times(stats: pstats.Stats) -> dict[str, float]:
    """Cumulative seconds per probe group (the outermost call of each function)."""
    out: dict[str, float] = {}
    for (filename, _, name), (_, _, _, cum, _) in stats.stats.items():
        path = filename.replace(os.sep, "/")
        for group, suffix, func in PROBES:
            if name == func and path.endswith(suffix):
                out[group] = out.get(group, 0.0) + cum
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", default="dqn")
    parser.add_argument("--timesteps", type=int, default=1000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--source", help="project root whose tap_bench to profile")
    parser.add_argument("--exact", action="store_true",
                        help="train on the scenario itself (code with the fast option)")
    parser.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if not args.inner:  # re-run in a fresh interpreter with the chosen source first
        env = dict(os.environ)
        root = str(Path(args.source or Path(__file__).parents[1]).resolve())
        env["PYTHONPATH"] = root
        sys.exit(subprocess.call([sys.executable, __file__, *sys.argv[1:], "--inner"],
                                 env=env, cwd=root))
    sys.path.insert(0, str(Path(__file__).parent))
    from machine import report

    import tap_bench
    try:
        from tap_bench.rl.training import train
    except ImportError:  # the code before issue 16 kept it in tap_bench.sim
        from tap_bench.sim.training import train

    warnings.filterwarnings("ignore")
    kwargs = {}
    if "n_envs" in inspect.signature(train).parameters:  # the code after issue 16
        kwargs = {"n_envs": 1, "fast": not args.exact, "curve": None}
    out = Path(tempfile.mkdtemp()) / f"{args.algo}-profile.zip"
    # CPU time, not wall time: on a shared machine waiting for the CPU is not a cost of ours
    profile = cProfile.Profile(time.process_time)
    start = time.perf_counter()
    profile.enable()
    result = train(args.algo, "highway", timesteps=args.timesteps, seed=args.seed,
                   output=out, **kwargs)
    profile.disable()
    wall = time.perf_counter() - start
    stats = pstats.Stats(profile)
    groups = group_times(stats)
    net = {}
    for group, seconds in groups.items():
        inner = sum(groups.get(g, 0.0) for g in NESTING.get(group, ()))
        net[group] = seconds - inner
    learn = groups.get("learn", wall)
    figures = {
        "source": str(Path(tap_bench.__file__).parents[1]),
        "profiled_wall_seconds": round(wall, 1),
        "learn_cpu_seconds": round(learn, 1),
        "episodes": result.episodes,
        "cpu_ms_per_step_under_profiler": round(1000 * learn / args.timesteps, 1),
        "seconds_net": {g: round(s, 2) for g, s in sorted(net.items())},
        "share_of_learn": {g: f"{s / learn:.1%}" for g, s in sorted(net.items())
                           if g != "learn"},
        "rest_of_learn (action selection, buffers, SB3)": f"{net.get('learn', 0) / learn:.1%}",
    }
    report(f"profile_train_{args.algo}_{Path(figures['source']).name}", figures,
           algo=args.algo, timesteps=args.timesteps, seed=args.seed, **kwargs)
    stats.sort_stats("tottime").print_stats(15)


if __name__ == "__main__":
    main()

"""Rollouts and Ray's overhead per task: local processes vs Ray workers on the same seeds.

Rolls out ``--policy`` on ``--env`` for ``--seeds`` episodes (recording every vehicle) with

- ``local-1``: :func:`tap_bench.sim.rollout.rollout` in this process (the baseline);
- ``local-2``: the same with ``workers=2`` (worker processes of :mod:`tap_bench.execution`);
- ``ray-1``, ``ray-2``: the same ``rollout(..., backend=RayBackend(...))`` on a local Ray
  cluster of 1 and 2 CPUs, one episode per task,

and checks that every table equals the baseline's. Throughput is episodes per second of wall
clock; the start of a local Ray cluster (``ray.init`` to the first task done) is timed apart.

Ray's overhead per task is measured on the 2-CPU cluster: the wall time per task of mapping
a function that does nothing over ``--tasks`` items, through :meth:`RayBackend.map` (which
keeps at most 2 x CPUs tasks in flight) and as a plain ``ray.get([f.remote() ...])``.

    nice -n 10 python benchmarks/bench_ray_rollouts.py [--seeds 0-23]
"""

from __future__ import annotations

import argparse
import time
import warnings

import pandas as pd
from machine import report

from tap_bench.execution import RayBackend
from tap_bench.sim.rollout import rollout


def _nothing(item: int) -> int:
    return item


def overhead(backend: RayBackend, tasks: int) -> dict:
    import ray

    backend.map(_nothing, list(range(20)), progress=False)  # workers started and warm
    t0 = time.perf_counter()
    backend.map(_nothing, list(range(tasks)), progress=False)
    mapped = (time.perf_counter() - t0) / tasks
    remote = ray.remote(_nothing)
    t0 = time.perf_counter()
    ray.get([remote.remote(i) for i in range(tasks)])
    plain = (time.perf_counter() - t0) / tasks
    return {"tasks": tasks, "map_ms_per_task": round(1e3 * mapped, 2),
            "plain_ray_ms_per_task": round(1e3 * plain, 2)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="highway")
    parser.add_argument("--policy", default="idm")
    parser.add_argument("--seeds", default="0-23")
    parser.add_argument("--tasks", type=int, default=500)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    figures: dict = {"env": args.env, "policy": args.policy, "seeds": args.seeds}
    runs: dict[str, dict] = {}
    t0 = time.perf_counter()
    base = rollout(args.env, args.policy, args.seeds, progress=False)
    wall = time.perf_counter() - t0
    n = len(base.episodes)
    runs["local-1"] = {"wall_s": round(wall, 2), "episodes_per_s": round(n / wall, 3)}
    t0 = time.perf_counter()
    two = rollout(args.env, args.policy, args.seeds, workers=2, progress=False)
    wall = time.perf_counter() - t0
    pd.testing.assert_frame_equal(two.trajectories, base.trajectories)
    runs["local-2"] = {"wall_s": round(wall, 2), "episodes_per_s": round(n / wall, 3)}
    for cpus in (1, 2):
        start = time.perf_counter()
        backend = RayBackend(num_cpus=cpus, object_store_memory=200 << 20)
        try:
            backend.map(_nothing, [0], progress=False)
            ready = time.perf_counter() - start
            t0 = time.perf_counter()
            got = rollout(args.env, args.policy, args.seeds, backend=backend, progress=False)
            wall = time.perf_counter() - t0
            pd.testing.assert_frame_equal(got.trajectories, base.trajectories)
            pd.testing.assert_frame_equal(got.episodes, base.episodes)
            runs[f"ray-{cpus}"] = {"wall_s": round(wall, 2),
                                   "episodes_per_s": round(n / wall, 3),
                                   "cluster_start_s": round(ready, 2)}
            if cpus == 2:
                figures["overhead"] = overhead(backend, args.tasks)
        finally:
            backend.shutdown()
        print(f"ray-{cpus}", runs[f"ray-{cpus}"], flush=True)
    figures["episodes"] = n
    figures["trajectory_rows"] = len(base.trajectories)
    figures["runs"] = runs
    figures["tables_equal"] = True
    report("ray_rollouts", figures, seed=args.seeds)


if __name__ == "__main__":
    main()

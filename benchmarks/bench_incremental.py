"""Incremental suites: a suite run with an empty episode cache, re-run unchanged, and re-run
with one policy changed (issue 16).

Each run is ``run_suite`` with the same cache folder (a fresh one under a temporary
folder), as ``tap-bench bench run --cache DIR`` does. The changed policy is a copy of a
built-in one with another IDM time gap, found first through ``$TAP_BENCH_PATH``, so only its
episodes miss the cache. The script checks that the re-run's tables equal the first run's.

The whole default suite (750 episodes) takes 20-27 min on 2 cores; ``--seeds 0-2`` runs the
same envs and policies on 3 seeds (75 episodes), and the figures are then extrapolated to
the full suite with a model fitted to the three runs: wall = fixed + per simulated episode x
simulated + per cached episode x cached (the fixed part, worker start-up, scoring and the
report, is a larger share of a small suite, so its re-run ratio is the pessimistic one).

Usage: ``nice -n 10 python benchmarks/bench_incremental.py [--suite default] [--seeds 0-2]
[--workers 2] [--changed idm-defensive]``.
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from machine import report

from tap_bench.bench.cache import EpisodeCache
from tap_bench.bench.runner import run_suite
from tap_bench.bench.suite import load_suite
from tap_bench.sim.policies import get_definition


def timed_run(suite, folder: Path, workers: int, cache: EpisodeCache, seeds: str | None):
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_suite(suite, folder, workers=workers, cache=cache, seeds=seeds,
                           progress=False, announce=lambda line: print("  " + line))
    seconds = time.perf_counter() - start
    counts = result.summary["cache"]
    print(f"  {folder.name}: {seconds:.1f} s, {counts['simulated']} simulated, "
          f"{counts['cached']} cached", flush=True)
    return result, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--suite", default="default")
    parser.add_argument("--seeds", default=None, help="a subset of the suite's seeds")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--changed", default="idm-defensive",
                        help="the policy changed before the third run (an IDM kind)")
    args = parser.parse_args()
    suite = load_suite(args.suite)
    with tempfile.TemporaryDirectory(prefix="bench-incremental-") as tmp:
        root = Path(tmp)
        cache = EpisodeCache(root / "cache")
        print(f"suite {suite.name}, seeds {args.seeds or 'all'}, {args.workers} workers",
              flush=True)
        first, t_first = timed_run(suite, root / "first", args.workers, cache, args.seeds)
        rerun, t_rerun = timed_run(suite, root / "rerun", args.workers, cache, args.seeds)
        for name in ("episodes", "labels", "trajectories"):
            pd.testing.assert_frame_equal(pd.read_parquet(first.folder / f"{name}.parquet"),
                                          pd.read_parquet(rerun.folder / f"{name}.parquet"))
        for name, table in first.scores.tables().items():
            pd.testing.assert_frame_equal(table, rerun.scores.tables()[name], obj=name)

        definition = get_definition(args.changed)
        doc = json.loads(definition.path.read_text())
        doc["params"]["time_wanted"] = round(doc["params"].get("time_wanted", 1.5) * 1.2, 3)
        (root / "catalogue" / "policies").mkdir(parents=True)
        (root / "catalogue" / "policies" / f"{args.changed}.json").write_text(json.dumps(doc))
        os.environ["TAP_BENCH_PATH"] = str(root / "catalogue")
        changed, t_changed = timed_run(suite, root / "changed", args.workers, cache,
                                       args.seeds)
        entries, size = cache.size()

    runs = [(first, t_first), (rerun, t_rerun), (changed, t_changed)]
    design = np.array([[1.0, r.summary["cache"]["simulated"], r.summary["cache"]["cached"]]
                       for r, _ in runs])
    fixed, per_simulated, per_cached = np.linalg.solve(design, [t for _, t in runs])
    n = first.summary["n_episodes"]
    full = len(suite.envs) * len(suite.policies) * len(suite.seeds)
    n_changed = changed.summary["cache"]["simulated"]
    extrapolated = {
        "first_run_s": fixed + per_simulated * full,
        "rerun_unchanged_s": fixed + per_cached * full,
        "one_policy_changed_s": fixed + per_simulated * full * n_changed / n
        + per_cached * full * (1 - n_changed / n),
    }
    figures = {
        "episodes": n,
        "first_run_s": round(t_first, 1),
        "rerun_unchanged_s": round(t_rerun, 1),
        "one_policy_changed_s": round(t_changed, 1),
        "rerun_over_first": round(t_rerun / t_first, 3),
        "changed_over_first": round(t_changed / t_first, 3),
        "simulated_in_changed_run": n_changed,
        "rerun_tables_identical_to_first": True,
        "model_s": {"fixed": round(fixed, 1), "per_simulated_episode": round(per_simulated, 3),
                    "per_cached_episode": round(per_cached, 3)},
        "cache_entries": entries, "cache_mib": round(size / 2**20, 1),
    }
    if n != full:
        figures[f"extrapolated_to_{full}_episodes"] = {
            **{k: round(v, 1) for k, v in extrapolated.items()},
            "rerun_over_first": round(extrapolated["rerun_unchanged_s"]
                                      / extrapolated["first_run_s"], 3),
            "changed_over_first": round(extrapolated["one_policy_changed_s"]
                                        / extrapolated["first_run_s"], 3)}
    report("bench_incremental", figures, suite=suite.name, seeds=args.seeds or "suite's",
           workers=args.workers, changed_policy=args.changed)


if __name__ == "__main__":
    main()

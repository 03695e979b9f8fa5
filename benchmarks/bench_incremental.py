"""Incremental suites: a suite run with an empty episode cache, re-run unchanged, and re-run
with one policy changed (issue 16).

Each run is ``run_suite`` with the same cache folder (a fresh one under a temporary
folder), as ``tap-bench bench run --cache DIR`` does. The changed policy is a copy of a
built-in one with another IDM time gap, found first through ``$TAP_BENCH_PATH``, so only its
episodes miss the cache. The script checks that the re-run's tables equal the first run's.

The whole default suite (750 episodes) takes 20-27 min on 2 cores; ``--seeds 0-2`` runs the
same envs and policies on 3 seeds (75 episodes), and the figures are then extrapolated to
the full suite: each run's worker start-up (the part of the episodes' wall time the
workers did not spend on episodes) and what lies outside ``run_suite`` stay as measured,
and the rest (episodes, scoring, writing and the report) grows in proportion to the
episodes. Start-up is a larger share of a small suite, so the subset's re-run ratio is the
pessimistic one.

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

    n = first.summary["n_episodes"]
    full = len(suite.envs) * len(suite.policies) * len(suite.seeds)
    scale = full / n

    def parts(result, wall: float) -> dict:
        """Where a run's wall time went [s]; start-up is the part of the episodes' wall
        time the workers did not spend on episodes (start, imports, messages)."""
        t = result.summary["timings"]
        work = sum(t.get(f"{k}_cpu_in_workers", 0.0) for k in ("rollout", "labelling",
                                                                 "measures"))
        episodes = t["rollouts_wall"]
        startup = max(0.0, episodes - work / args.workers)
        return {"wall": wall, "episodes": episodes, "worker_startup": startup,
                "scoring": t["scoring"], "writing_and_report": t["writing_and_report"],
                "outside_run_suite": max(0.0, wall - t["total"])}

    def extrapolate(p: dict) -> float:
        """The run at full size: start-up and what lies outside run_suite stay, the rest
        grows with the episodes."""
        return (p["worker_startup"] + p["outside_run_suite"] + scale * (
            p["episodes"] - p["worker_startup"] + p["scoring"] + p["writing_and_report"]))

    split = {name: parts(r, t) for name, r, t in (("first", first, t_first),
                                                  ("rerun", rerun, t_rerun),
                                                  ("changed", changed, t_changed))}
    figures = {
        "episodes": n,
        "first_run_s": round(t_first, 1),
        "rerun_unchanged_s": round(t_rerun, 1),
        "one_policy_changed_s": round(t_changed, 1),
        "rerun_over_first": round(t_rerun / t_first, 3),
        "changed_over_first": round(t_changed / t_first, 3),
        "simulated_in_changed_run": changed.summary["cache"]["simulated"],
        "rerun_tables_identical_to_first": True,
        "split_s": {name: {k: round(v, 1) for k, v in p.items()} for name, p in split.items()},
        "cache_entries": entries, "cache_mib": round(size / 2**20, 1),
    }
    if n != full:
        ext = {name: extrapolate(p) for name, p in split.items()}
        figures[f"extrapolated_to_{full}_episodes"] = {
            "first_run_s": round(ext["first"], 1),
            "rerun_unchanged_s": round(ext["rerun"], 1),
            "one_policy_changed_s": round(ext["changed"], 1),
            "rerun_over_first": round(ext["rerun"] / ext["first"], 3),
            "changed_over_first": round(ext["changed"] / ext["first"], 3)}
    report("bench_incremental", figures, suite=suite.name, seeds=args.seeds or "suite's",
           workers=args.workers, changed_policy=args.changed)


if __name__ == "__main__":
    main()

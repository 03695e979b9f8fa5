"""Incremental suites: a suite run with an empty episode cache, re-run unchanged, and re-run
with one policy changed (issue 16).

Each run is ``run_suite`` with the same cache folder (a fresh one under a temporary
folder), as ``tap-bench bench run --cache DIR`` does. The changed policy is a copy of a
built-in one with another IDM time gap, found first through ``$TAP_BENCH_PATH``, so only its
episodes miss the cache. The script checks that the re-run's tables equal the first run's.

The whole default suite (750 episodes) takes 20-27 min on 2 cores. ``--seeds 0-2`` runs the
same envs and policies on 3 seeds (75 episodes), and the figures are extrapolated to the
full suite from the parts of each run: the episodes' work (simulation, or reading cached
episodes, labelling and measures) grows with the episodes, at the rate of the largest
subset given (``--seeds 0-2 --seeds 0-5`` measures two); worker start-up, scoring, and the
writing and the report (18 plots, whatever the number of episodes) are taken at their
largest measured value, and, as an upper bound, with the writing also growing with the
episodes. On a loaded machine one subset's parts vary by a factor of two between runs:
read the extrapolation as a range.

Usage: ``nice -n 10 python benchmarks/bench_incremental.py [--suite default] [--seeds 0-2
[--seeds 0-5]] [--workers 2] [--changed idm-defensive]``.
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
from tap_bench.bench.run.runner import run_suite
from tap_bench.bench.suite import load_suite
from tap_bench.sim.policies import get_definition

RUNS = ("first", "rerun", "changed")
PARTS = ("worker_startup", "episode_work", "scoring", "writing_and_report", "outside")


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


def parts(result, wall: float, workers: int) -> dict[str, float]:
    """Where a run's wall time went [s]. Worker start-up is the part of the episodes' wall
    time the workers did not spend on episodes (start, imports, messages)."""
    t = result.summary["timings"]
    work = sum(t.get(f"{k}_cpu_in_workers", 0.0) for k in ("rollout", "labelling", "measures"))
    startup = max(0.0, t["rollouts_wall"] - work / workers)
    return {"worker_startup": startup, "episode_work": t["rollouts_wall"] - startup,
            "scoring": t["scoring"], "writing_and_report": t["writing_and_report"],
            "outside": max(0.0, wall - t["total"]), "wall": wall}


def experiment(suite, seeds: str | None, workers: int, changed_policy: str) -> dict:
    """The three runs on ``seeds``: their parts and checks."""
    with tempfile.TemporaryDirectory(prefix="bench-incremental-") as tmp:
        root = Path(tmp)
        cache = EpisodeCache(root / "cache")
        print(f"suite {suite.name}, seeds {seeds or 'all'}, {workers} workers", flush=True)
        first, t_first = timed_run(suite, root / "first", workers, cache, seeds)
        rerun, t_rerun = timed_run(suite, root / "rerun", workers, cache, seeds)
        for name in ("episodes", "labels", "trajectories"):
            pd.testing.assert_frame_equal(pd.read_parquet(first.folder / f"{name}.parquet"),
                                          pd.read_parquet(rerun.folder / f"{name}.parquet"))
        for name, table in first.scores.tables().items():
            pd.testing.assert_frame_equal(table, rerun.scores.tables()[name], obj=name)

        definition = get_definition(changed_policy)
        doc = json.loads(definition.path.read_text())
        doc["params"]["time_wanted"] = round(doc["params"].get("time_wanted", 1.5) * 1.2, 3)
        catalogue = root / "catalogue" / "policies"
        catalogue.mkdir(parents=True)
        (catalogue / f"{changed_policy}.json").write_text(json.dumps(doc))
        os.environ["TAP_BENCH_PATH"] = str(catalogue.parent)
        try:
            changed, t_changed = timed_run(suite, root / "changed", workers, cache, seeds)
        finally:
            del os.environ["TAP_BENCH_PATH"]
        entries, size = cache.size()
    return {"episodes": first.summary["n_episodes"],
            "simulated_in_changed_run": changed.summary["cache"]["simulated"],
            "rerun_tables_identical_to_first": True,
            "cache_entries": entries, "cache_mib": round(size / 2**20, 1),
            "parts_s": {name: parts(r, t, workers) for name, r, t in (
                ("first", first, t_first), ("rerun", rerun, t_rerun),
                ("changed", changed, t_changed))}}


def extrapolate(subsets: list[dict], full: int) -> dict[str, float]:
    """Each run's wall time at ``full`` episodes (module docstring): the episodes' work at
    the per-episode rate of the largest subset; worker start-up, scoring, the writing and
    the report at their largest measured value (``*_s``), or with the writing and the report
    also growing with the episodes (``*_upper_s``)."""
    largest = max(subsets, key=lambda s: s["episodes"])
    scale = full / largest["episodes"]
    out = {}
    for run in RUNS:
        fixed = sum(max(s["parts_s"][run][part] for s in subsets)
                    for part in ("worker_startup", "scoring", "writing_and_report", "outside"))
        work = largest["parts_s"][run]["episode_work"] * scale
        writing = largest["parts_s"][run]["writing_and_report"]
        out[f"{run}_s"] = round(fixed + work, 1)
        out[f"{run}_upper_s"] = round(fixed + work + writing * (scale - 1), 1)
    for run in ("rerun", "changed"):
        out[f"{run}_over_first"] = round(out[f"{run}_s"] / out["first_s"], 3)
        out[f"{run}_over_first_upper"] = round(out[f"{run}_upper_s"] / out["first_s"], 3)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--suite", default="default")
    parser.add_argument("--seeds", action="append", default=None,
                        help="a subset of the suite's seeds (repeat for a second size)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--changed", default="idm-defensive",
                        help="the policy changed before the third run (an IDM kind)")
    args = parser.parse_args()
    suite = load_suite(args.suite)
    subsets = [experiment(suite, seeds, args.workers, args.changed)
               for seeds in (args.seeds or [None])]
    for subset in subsets:
        walls = {run: subset["parts_s"][run]["wall"] for run in RUNS}
        subset["rerun_over_first"] = round(walls["rerun"] / walls["first"], 3)
        subset["changed_over_first"] = round(walls["changed"] / walls["first"], 3)
        subset["parts_s"] = {run: {k: round(v, 1) for k, v in p.items()}
                             for run, p in subset["parts_s"].items()}
    full = len(suite.envs) * len(suite.policies) * len(suite.seeds)
    figures: dict = {"subsets": {seeds or "all": s for seeds, s in
                                 zip(args.seeds or [None], subsets, strict=True)}}
    if subsets[-1]["episodes"] != full:
        figures[f"extrapolated_to_{full}_episodes"] = extrapolate(subsets, full)
    report("bench_incremental", figures, suite=suite.name, seeds=args.seeds or "suite's",
           workers=args.workers, changed_policy=args.changed)


if __name__ == "__main__":
    main()

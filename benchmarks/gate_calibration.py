"""The regression gate's false-alarm rate and power on real rollouts.

    PYTHONPATH=$PWD python benchmarks/gate_calibration.py [--workers 2] [--rerun]

**False alarms.** An unchanged policy (IDM/MOBIL, highway-env defaults) checked against a
baseline of itself on *other* seeds: seed blocks of 10, 30 and 100 cut from a pool of 300
seeds, every pair of disjoint blocks one check (unpaired tests: the seeds differ). The gate
should fire in at most alpha = 5 % of the checks. (On the baseline's own seeds a re-run is
the same episodes, the paired differences are all 0 and p = 1: it cannot fire.)

**Power.** IDM with changed parameters on the baseline's seeds (paired tests): desired
speed 90 % of the default (``target_speed_factor`` 0.9), and a 2.5 s desired time gap
(``time_wanted``, default 1.5 s). Each block of 10, 30 or 100 seeds is one check; the table
gives the share of checks that fire, and on which metrics.

Cost and what is cached: one env (highway, 10 vehicles, **shortened to 12 s** so the study
runs in minutes; the gate's tests do not depend on the episode length) and the suite's
default gate (alpha 0.05, 9999 permutations, the default margins), 1 env x 1 policy = 6
tests per check. The rollouts' episode table is cached in
``benchmarks/out/gate_calibration_episodes.parquet`` (``--rerun`` redoes it): the
statistics are recomputed from it on every run, which is valid because the gate reads only
the episode table.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
import warnings
from pathlib import Path

import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from machine import report

from tap_bench.bench.episodes import episode_table
from tap_bench.bench.gate import check
from tap_bench.bench.intervals import wilson_interval
from tap_bench.bench.suite import GateConfig

OUT = Path(__file__).resolve().parent / "out"
CACHE = OUT / "gate_calibration_episodes.parquet"
ENV = "highway"
DURATION = 12.0  # [s]
CONFIG = {"vehicles_count": 10}
POOL = 300  # seeds of the unchanged policy
CHANGED_SEEDS = 100
BLOCKS = (10, 30, 100)
MAX_PAIRS = 1000  # false-alarm checks per block size (every ordered pair of blocks)
IDM = {"time_wanted": 1.5, "distance_wanted": 10.0, "comfort_acc_max": 3.0,
       "comfort_acc_min": -5.0, "delta": 4.0, "politeness": 0.0,
       "lane_change_min_acc_gain": 0.2, "lane_change_max_braking_imposed": 2.0,
       "lane_change_delay": 1.0, "target_speed_factor": 1.0}
CHANGES = {"idm": {}, "idm-speed-0.9": {"target_speed_factor": 0.9},
           "idm-gap-2.5s": {"time_wanted": 2.5}}
SUMMARY = {"suite": {"name": "gate-calibration", "version": 0}, "level": "maneuver",
           "thresholds": "paper"}
BASELINE = {"suite": "gate-calibration", "suite_version": 0, "level": "maneuver",
            "thresholds": "paper"}


def _episodes(name: str, seeds: list[int], workers: int) -> pd.DataFrame:
    from tap_bench.labelling import tap
    from tap_bench.sim.policies import PolicyDefinition
    from tap_bench.sim.rollout import rollout

    policy = PolicyDefinition(name=name, kind="idm", params={**IDM, **CHANGES[name]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = rollout(ENV, policy, seeds, workers=workers, config=CONFIG,
                         duration=DURATION, progress=False)
        labels = tap(result.trajectories, "paper").labels("all")
    return episode_table(labels=labels, trajectories=result.trajectories,
                         episodes=result.episodes, level="maneuver", policy=name)


def rollouts(workers: int, rerun: bool) -> tuple[pd.DataFrame, float]:
    if CACHE.is_file() and not rerun:
        return pd.read_parquet(CACHE), 0.0
    start = time.perf_counter()
    frames = [_episodes("idm", list(range(POOL)), workers)]
    for name in CHANGES:
        if name != "idm":
            frames.append(_episodes(name, list(range(CHANGED_SEEDS)), workers))
    table = pd.concat(frames, ignore_index=True)
    OUT.mkdir(exist_ok=True)
    table.to_parquet(CACHE, index=False)
    return table, time.perf_counter() - start


def _as_idm(block: pd.DataFrame) -> pd.DataFrame:
    return block.assign(policy="idm", env=ENV)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--rerun", action="store_true", help="redo the cached rollouts")
    args = parser.parse_args()
    episodes, rollout_seconds = rollouts(args.workers, args.rerun)
    gate = GateConfig()
    start = time.perf_counter()
    idm = episodes[episodes["policy"] == "idm"].sort_values("seed")
    rows = []
    for n in BLOCKS:
        blocks = [idm[(idm["seed"] >= k * n) & (idm["seed"] < (k + 1) * n)]
                  for k in range(POOL // n)]
        pairs = list(itertools.permutations(range(len(blocks)), 2))[:MAX_PAIRS]
        fired, metrics = 0, {}
        for i, j in pairs:
            result = check(SUMMARY, _as_idm(blocks[j]), BASELINE, _as_idm(blocks[i]), gate)
            fired += result.moved
            for m in result.moved_rows()["metric"]:
                metrics[m] = metrics.get(m, 0) + 1
        lo, hi = wilson_interval(fired, len(pairs), 0.95)
        rows.append({"check": "unchanged idm, other seeds (unpaired)", "seeds": n,
                     "checks": len(pairs), "fired": fired, "rate": fired / len(pairs),
                     "rate_low": lo, "rate_high": hi, "moved metrics": metrics})
        print(rows[-1], flush=True)
        for name in CHANGES:
            if name == "idm":
                continue
            changed = episodes[episodes["policy"] == name]
            k_blocks = CHANGED_SEEDS // n
            fired, metrics = 0, {}
            for k in range(k_blocks):
                seeds = range(k * n, (k + 1) * n)
                base = _as_idm(idm[idm["seed"].isin(seeds)])
                run = _as_idm(changed[changed["seed"].isin(seeds)])
                result = check(SUMMARY, run, BASELINE, base, gate)
                fired += result.moved
                for m in result.moved_rows()["metric"]:
                    metrics[m] = metrics.get(m, 0) + 1
            lo, hi = wilson_interval(fired, k_blocks, 0.95)
            change = ", ".join(f"{k} {v:g}" for k, v in CHANGES[name].items())
            rows.append({"check": f"IDM with {change}, same seeds (paired)", "seeds": n,
                         "checks": k_blocks, "fired": fired, "rate": fired / k_blocks,
                         "rate_low": lo, "rate_high": hi, "moved metrics": metrics})
            print(rows[-1], flush=True)
    print()
    print("| check | seeds | checks | fired | rate [95 % Wilson] | metrics that moved |")
    print("|---|---|---|---|---|---|")
    for r in rows:
        moved = ", ".join(f"{k} ({v})" for k, v in sorted(r["moved metrics"].items())) or "–"
        print(f"| {r['check']} | {r['seeds']} | {r['checks']} | {r['fired']} | "
              f"{r['rate']:.2f} [{r['rate_low']:.2f}, {r['rate_high']:.2f}] | {moved} |")
    report("gate_calibration", {"rows": rows, "rollout_seconds": rollout_seconds,
                                "check_seconds": time.perf_counter() - start,
                                "env": ENV, "duration_s": DURATION, "config": CONFIG,
                                "gate": gate.to_dict()}, seed=0)


if __name__ == "__main__":
    main()

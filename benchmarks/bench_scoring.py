"""Scoring speed: everything after the rollouts of a suite of 10 policies x 5 envs x 100 seeds.

Times :func:`tap_bench.bench.scores.scoring.score` (paired comparisons of 9 policies with the
reference, SDL-matched groups, per-policy measures, coverage and novelty with their
intervals, 2000 bootstrap resamples) on a synthetic episode table whose ego labels follow
policy-specific Zipf distributions over 60 maneuver-level labels; then the ego measures
(:func:`tap_bench.bench.measures.ego_measures`) and the labelling of the trajectory tables
those 5000 episodes would have, built by replicating recorded rollouts of each env.

Usage: ``nice -n 10 python benchmarks/bench_scoring.py [--seeds 100] [--repeats 3]``.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import pandas as pd
from machine import report

from tap_bench.bench.episodes import EPISODE_COLUMNS
from tap_bench.bench.measures import ego_measures
from tap_bench.bench.scores.scoring import score
from tap_bench.stats.bootstrap import BootstrapConfig

ENVS = ("highway", "merge", "roundabout", "exit", "intersection")
POLICIES = tuple(f"policy-{i}" for i in range(10))


def synthetic_episodes(n_seeds: int, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    labels = np.array([f"Straight > Left Merge x{i} | Maintain Speed" for i in range(60)])
    rows = []
    for env in ENVS:
        for k, policy in enumerate(POLICIES):
            p = 1 / np.arange(1, 61) ** (1.0 + 0.1 * k)
            p = rng.permutation(p / p.sum())
            n = n_seeds
            rows.append(pd.DataFrame({
                "env": env, "policy": policy, "seed": np.arange(n),
                "scenario_id": [f"{env}/{policy}/s{s}" for s in range(n)],
                "status": "ok", "error": "", "sdl": labels[rng.choice(60, n, p=p)],
                "return": rng.normal(10, 2, n), "crashed": rng.random(n) < 0.05 * (1 + k / 3),
                "mean_speed": rng.normal(20 + k / 5, 2, n),
                "min_headway_s": rng.normal(1.5, 0.4, n), "min_ttc_s": rng.uniform(1, 10, n),
                "rms_jerk": rng.gamma(3, 1, n), "duration_s": 30.0}))
    table = pd.concat(rows, ignore_index=True)
    for col in EPISODE_COLUMNS:
        if col not in table:
            table[col] = pd.NA
    table["sdl"] = table["sdl"].astype("string")
    return table


def replicated_trajectories(n_seeds: int) -> pd.DataFrame:
    """Trajectory tables of 10 policies x 5 envs x n_seeds episodes, made by copying one
    recorded IDM episode per env under new scenario ids (timing only: the content repeats)."""
    import tap_bench

    frames = []
    for env in ENVS:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            one, _ = tap_bench.rollout(env, "idm", [0], progress=False)
        n_copies = len(POLICIES) * n_seeds
        rows = len(one)
        big = one.loc[np.tile(np.arange(rows), n_copies)].reset_index(drop=True)
        copy = np.repeat(np.arange(n_copies), rows)
        big["scenario_id"] = [f"{env}/c{c}" for c in range(n_copies)][0:0] or \
            pd.Series(copy).map(lambda c, e=env: f"{e}/c{c}").to_numpy()
        big["seed"] = copy
        frames.append(big)
    return pd.concat(frames, ignore_index=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seeds", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--no-trajectories", action="store_true",
                        help="time the scoring only (no measures, no labelling)")
    args = parser.parse_args()
    episodes = synthetic_episodes(args.seeds)
    config = BootstrapConfig(n_resamples=2000, level=0.95, seed=0)
    score(episodes.head(400), reference_policy="policy-0", level="maneuver", config=config)
    runs = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        scores = score(episodes, reference_policy="policy-0", level="maneuver", config=config)
        runs.append(time.perf_counter() - t0)
    figures = {"episodes": len(episodes), "policies": len(POLICIES), "envs": len(ENVS),
               "seeds": args.seeds, "bootstrap_resamples": config.n_resamples,
               "scoring_seconds_runs": [round(r, 3) for r in runs],
               "scoring_seconds_median": round(float(np.median(runs)), 3),
               "table_rows": {k: len(v) for k, v in scores.tables().items()}}
    if not args.no_trajectories:
        traj = replicated_trajectories(args.seeds)
        t0 = time.perf_counter()
        measures = ego_measures(traj)
        t1 = time.perf_counter()
        from tap_bench.labelling import tap

        tap(traj, "paper").labels("maneuver")
        t2 = time.perf_counter()
        figures.update({"trajectory_rows": len(traj), "measured_episodes": len(measures),
                        "ego_measures_seconds": round(t1 - t0, 3),
                        "labelling_seconds_all_vehicles": round(t2 - t1, 3)})
    report("bench_scoring", figures, seed=0)


if __name__ == "__main__":
    main()

"""Per real scene: the human's (policy ``log``) and IDM's off-road, crash, crash partner,
at-fault and episode length, in log and idm traffic (issue 32: the figures a reviewer reads
first, before and after off-road from road edges and collisions with their cause).

Runs every scene of the files found (the four samples in ../shared/data/womd and the
twelve development scenes in ../shared/data/womd-dev; files that are absent are skipped),
prints one line per (scene, traffic, policy) and writes the rows as JSON under
``benchmarks/out/womd_measures_table.json`` with the machine (``machine.report``).

Columns the code of the day does not have are printed as ``-`` (the script runs on main
before the change and after it, unchanged).

Usage: ``python benchmarks/womd_measures_table.py [FILES ...]``
"""

from __future__ import annotations

import argparse
import math
import os
import time
import warnings
from pathlib import Path

from machine import report

from tap_bench.sim.policies import load_policy
from tap_bench.sim.womd_env import make_womd_env

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"
FILES = (DATA / "womd" / "motion_data_one_scenario.tfrecord",
         DATA / "womd" / "womd_scenario_input.tfrecord",
         DATA / "womd" / "motion_data_one_example.tfrecord",
         DATA / "womd" / "sd_waymo_v1.2_eb4b91b10ca94ff2.pkl",
         DATA / "womd-dev" / "dev.tfrecord")
POLICIES = ("log", "idm")
TRAFFIC = ("log", "idm")


def run_episode(env, policy: str, seed: int) -> dict:
    """One episode of ``policy`` on scene ``seed``: its measures (what the env reports)."""
    p = load_policy(policy)
    obs, _ = env.reset(seed=seed)
    p.reset(env, seed=seed)
    done = False
    steps = 0
    while not done:
        obs, _, term, trunc, _ = env.step(p.act(obs))
        done = term or trunc
        steps += 1
    info = env.episode_info()
    inner = env.unwrapped
    row = {"scenario_id": env.scene.scenario_id,
           "crashed": bool(inner.vehicle.crashed),
           "off_road": bool(info.get("off_road")),
           "crash_with": info.get("crash_with", ""),
           "crash_at_fault": info.get("crash_at_fault"),
           "from_behind_by_log": info.get("crash_from_behind_by_log"),
           "off_road_rule": info.get("off_road_rule"),
           "max_off_road_m": info.get("max_off_road_distance_m"),
           "route_progress": info.get("route_progress"),
           "skipped": info.get("skipped"),
           "decisions": steps,
           "length_s": round((inner.clock[0] - 10) / 10.0, 1)}
    return row


def _fmt(value) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.2f}"
    return str(value)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("files", nargs="*")
    args = parser.parse_args()
    files = [str(f) for f in (args.files or FILES) if Path(f).exists()]
    rows = []
    t0 = time.perf_counter()
    c0 = sum(os.times()[:2])
    warnings.simplefilter("ignore")
    envs = {traffic: make_womd_env(files, traffic=traffic) for traffic in TRAFFIC}
    n = len(envs["log"].catalog)
    cols = ("scenario_id", "traffic", "policy", "off_road", "off_road_rule", "max_off_road_m",
            "crashed", "crash_with", "crash_at_fault", "length_s", "route_progress", "error")
    print(" | ".join(cols))
    for seed in range(n):
        for traffic, env in envs.items():
            for policy in POLICIES:
                try:
                    row = run_episode(env, policy, seed)
                except Exception as err:  # a scene that cannot be built: say why
                    row = {"scenario_id": str(env.catalog[seed]),
                           "error": f"{type(err).__name__}: {str(err)[:90]}"}
                row.update(traffic=traffic, policy=policy, seed=seed)
                rows.append(row)
                print(" | ".join(_fmt(row.get(c)) for c in cols), flush=True)
    wall = time.perf_counter() - t0
    cpu = sum(os.times()[:2]) - c0
    for traffic in TRAFFIC:
        for policy in POLICIES:
            done = [r for r in rows if r["traffic"] == traffic and r["policy"] == policy
                    and "error" not in r]
            known = done and done[0].get("crash_at_fault") is not None
            fault = sum(bool(r.get("crash_at_fault")) for r in done) if known else "-"
            print(f"{policy} in {traffic} traffic: {len(done)} of {n} scenes ran; off-road "
                  f"{sum(r['off_road'] for r in done)}, crashed "
                  f"{sum(r['crashed'] for r in done)}, at fault {fault}")
    print(f"wall {wall:.1f} s, cpu {cpu:.1f} s")
    report("womd_measures_table", {"rows": rows, "wall_s": round(wall, 1),
                                   "cpu_s": round(cpu, 1)}, files=files)


if __name__ == "__main__":
    main()

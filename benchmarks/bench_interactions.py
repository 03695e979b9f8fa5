"""Speed of the interaction axis (SPEC 7) on WOMD-sized scenes: scenarios per second per core.

The scenes are the real WOMD samples of ``../shared/data/womd`` with 91 steps (83, 128 and
257 agents), copied under new scenario ids until ``--scenarios`` are reached, so the
geometry (parked cars, crossings, pedestrians) is real. The interaction axis (the path
frame, relations and runs: :func:`tap_bench.interactions.interaction_steps`) is timed in
CPU seconds of this one process, so other load on the machine slows it less than a
wall-clock figure (the load is printed beside it).

Usage: ``python benchmarks/bench_interactions.py [--scenarios 300] [--mode ego]``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import pandas as pd
from machine import report

import tap_bench as tb
import tap_bench.labelling as labelling
from tap_bench.interactions import interaction_steps

CPU: list[float] = []


def timed_interaction_steps(*args, **kwargs):
    """interaction_steps, recording its CPU time."""
    start = time.process_time()
    out = interaction_steps(*args, **kwargs)
    CPU.append(time.process_time() - start)
    return out

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "womd"
FILES = ("motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord",
         "motion_data_one_example.tfrecord")


def scenes(n: int) -> pd.DataFrame:
    base = tb.read_womd([DATA / f for f in FILES])
    ids = base["scenario_id"].unique()
    copies = []
    for k in range(n):
        sid = ids[k % len(ids)]
        copies.append(base[base["scenario_id"] == sid].assign(scenario_id=f"{sid}/{k}"))
    return pd.concat(copies, ignore_index=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--scenarios", type=int, default=300)
    parser.add_argument("--mode", choices=("ego", "all"), default="ego")
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    table = scenes(args.scenarios)
    agents = table.groupby("scenario_id")["track_id"].nunique().mean()
    tb.tap(table.head(1000), interactions="all")  # warm imports
    labelling.interaction_steps = timed_interaction_steps
    runs = []
    for _ in range(args.repeats):
        c0 = time.process_time()
        result = tb.tap(table, interactions=args.mode)
        runs.append({"interactions_s": CPU[-1], "wall_s": result.timings["interactions"],
                     "tap_total_cpu_s": time.process_time() - c0})
    best = min(runs, key=lambda r: r["interactions_s"])
    labelled = len(result.interaction_segments)
    report(f"interactions_{args.mode}", {
        "scenarios": args.scenarios, "mean_agents": round(float(agents), 1), "steps": 91,
        "mode": args.mode, "tracks_labelled": labelled,
        "interaction_axis_cpu_s": round(best["interactions_s"], 3),
        "interaction_axis_wall_s": round(best["wall_s"], 3),
        "scenarios_per_s_per_core": round(args.scenarios / best["interactions_s"], 1),
        "whole_tap_scenarios_per_s": round(args.scenarios / best["tap_total_cpu_s"], 1),
        "repeats": args.repeats})


if __name__ == "__main__":
    main()

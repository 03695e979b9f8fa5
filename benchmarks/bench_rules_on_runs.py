"""Issue 21's labels and measures on a benchmark run's own trajectories, by env and policy.

Reads a run folder's ``trajectories.parquet`` (``tap-bench bench run ... -o RUN``; nothing
is simulated again) and labels and measures the egos with the code on ``PYTHONPATH``, so
one run scored by two versions gives the figures before and after a change of the rules:
per env and policy, the episodes, those with no leader after the burn-in (no minimum
headway or TTC), the mean minimum headway and TTC over the episodes that have one (the
10 s "no leader" values counted in, as the old code did, beside them), the mean RMS jerk,
and the share of episodes whose maneuver-level label has a Turn.

Usage: ``python benchmarks/bench_rules_on_runs.py RUN [RUN ...]``.
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
from machine import report

import tap_bench as tb
from tap_bench.bench.measures import ego_measures


def figures(run: Path) -> dict:
    table = pd.read_parquet(run / "trajectories.parquet")
    egos = table[table["is_ego"].fillna(False).astype(bool)]
    labels = tb.tap(egos, "paper").labels("maneuver")
    longest = labels.assign(d=labels["t_end"] - labels["t_start"]).sort_values(
        "d", ascending=False).drop_duplicates("scenario_id")
    turn = longest.set_index("scenario_id")["lateral"].str.contains("Turn")
    m = ego_measures(table).set_index("scenario_id")
    m["turn"] = turn.reindex(m.index).fillna(False).astype(bool)
    out = {}
    for (env, policy), sub in m.groupby(["env", "policy"]):
        hw, ttc = sub["min_headway_s"].to_numpy(float), sub["min_ttc_s"].to_numpy(float)
        out[f"{env} {policy}"] = {
            "episodes": len(sub),
            "no_min_headway": int(np.isnan(hw).sum()), "no_min_ttc": int(np.isnan(ttc).sum()),
            "min_headway_mean": _r(np.nanmean(hw)),
            "min_headway_mean_no_leader_as_10": _r(np.mean(np.where(np.isnan(hw), 10, hw))),
            "min_ttc_mean": _r(np.nanmean(ttc)),
            "min_ttc_mean_no_leader_as_10": _r(np.mean(np.where(np.isnan(ttc), 10, ttc))),
            "rms_jerk_mean": _r(sub["rms_jerk"].mean()),
            "turn_label_share": _r(sub["turn"].mean())}
    return out


def _r(x) -> float | None:
    return None if not np.isfinite(x) else round(float(x), 3)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path)
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    cpu, wall = time.process_time(), time.perf_counter()
    out = {str(run): figures(run) for run in args.runs}
    out["cpu_s"] = round(time.process_time() - cpu, 1)
    out["wall_s"] = round(time.perf_counter() - wall, 1)
    report("rules_on_runs", out, runs=[str(r) for r in args.runs], thresholds="paper",
           level="maneuver")


if __name__ == "__main__":
    main()

"""How far the paper's finite-difference step moves the thresholds on real WOMD data.

The four real files of ../shared/data/womd (three scenarios at 10 Hz, one tf.Example;
vehicles only; the 20 s ScenarioNet pickle too when its loader is available) give the
one-second samples. For each distribution and each of the paper's starts this prints how
far 100 epochs of the paper's step (theta <- theta - eta grad, Table 1) and of the scaled
step move the thresholds, and J before and after, beside the grid optimum.

Usage: ``python benchmarks/paper_step_on_womd.py [--data ../shared/data/womd]``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pandas as pd
from machine import report

import tap_bench as tb
from tap_bench.fitting import (
    PAPER_HYPERPARAMETERS,
    PAPER_STARTS,
    V_STOP,
    descent,
    feasible_starts,
    grid_search,
)
from tap_bench.objective import SortedSamples


def load(data: Path) -> pd.DataFrame:
    from tap_bench.sources.ingest import read_womd

    frames = [read_womd(sorted(data.glob("*.tfrecord")), object_types="vehicle")]
    try:
        from tap_bench.sources.scenarionet import decode_scenarionet, load_scenarionet

        for pkl in sorted(data.glob("*.pkl")):
            frames.append(decode_scenarionet(load_scenarionet(pkl), path=str(pkl)).to_pandas())
    except (ImportError, TypeError):
        pass
    table = pd.concat(frames, ignore_index=True)
    return table[table["object_type"] == "vehicle"].reset_index(drop=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    root = Path(__file__).resolve().parents[1]
    parser.add_argument("--data", type=Path, default=root / ".." / "shared" / "data" / "womd")
    args = parser.parse_args()
    table = load(args.data)
    samples = tb.one_second_samples(table)
    samples["v"] = samples["v"][samples["v"] > V_STOP]
    rows = []
    for dist in ("w", "a", "v"):
        s = SortedSamples(samples[dist])
        eps, eta = PAPER_HYPERPARAMETERS[dist]
        starts = feasible_starts(s, np.array(PAPER_STARTS[dist]))
        theta_grid, j_grid = grid_search(s, starts.shape[1])
        j0 = s.objective(starts)
        paper = descent(s, starts, eps, eta, step="paper")
        scaled = descent(s, starts, eps, eta, step="scaled")
        for k, start in enumerate(starts):
            rows.append({
                "dist": dist, "n": len(s), "start": np.round(start, 4).tolist(),
                "J_start": float(j0[k]),
                "paper_theta": np.round(paper[k][0], 4).tolist(), "paper_J": paper[k][1],
                "paper_moved": float(np.max(np.abs(paper[k][0] - start))),
                "scaled_theta": np.round(scaled[k][0], 4).tolist(), "scaled_J": scaled[k][1],
                "scaled_moved": float(np.max(np.abs(scaled[k][0] - start))),
                "grid_theta": np.round(theta_grid, 4).tolist(), "grid_J": j_grid,
            })
    frame = pd.DataFrame(rows)
    with pd.option_context("display.width", 250, "display.max_columns", 20):
        print(frame.to_string(index=False))
    report("paper_step_on_womd", {"rows": rows, "vehicles": int(
        table.groupby(["scenario_id", "track_id"]).ngroups)}, data=str(args.data))


if __name__ == "__main__":
    main()

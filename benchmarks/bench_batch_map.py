"""CPU of labelling and measuring one batch of episodes along the road's lanes, as ``bench
run``'s workers do it (:func:`tap_bench.bench.run.tasks._label_together`): ``tap()`` with
the interaction axis, then the ego's steps (the measures' and the contexts' leaders), each
env's 20-episode batch as one table.

Three ways per env:

- ``arc``: no map (the path beyond the record along an arc of the ego's last curvature);
- ``map table``: the road's map table given to both calls (each builds its own lane map
  and extends every path end along it);
- ``shared``: one :class:`~tap_bench.pathframe.LaneMap` built once for the batch
  (``LaneMap.of_maps``) and given to both calls, which then share its lane matches and
  chains (what the runner does).

The outputs of ``map table`` and ``shared`` are compared cell for cell.

    python benchmarks/bench_batch_map.py --rollouts ROLLOUTS.parquet [--repeat 5]

``--rollouts``: highway-env rollouts with an ``env`` column (every vehicle recorded, the ego
marked ``is_ego``), e.g. ``rollout(env, "idm", range(20))`` of intersection, roundabout and
highway; each env is one batch.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
import pandas as pd
from machine import report

from tap_bench.bench.measures import ego_steps
from tap_bench.labelling import tap
from tap_bench.sim.roads import road_table
from tap_bench.sim.scenario_env import get_scenario


def batch(table: pd.DataFrame, lanes) -> tuple[pd.DataFrame, object]:
    result = tap(table, "paper", interactions="ego", map_table=lanes)
    return result.labels("all"), ego_steps(table, lanes)


def cpu(fn, repeat: int) -> float:
    """Median CPU seconds (user + sys of this process) of ``fn()`` over ``repeat`` calls."""
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rollouts", required=True)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    rollouts = pd.read_parquet(args.rollouts)
    try:
        from tap_bench.pathframe import LaneMap
        shared = getattr(LaneMap, "of_maps", None)
    except ImportError:
        shared = None
    figures = {}
    for env, table in rollouts.groupby("env", sort=False):
        table = table.reset_index(drop=True)
        road = road_table(get_scenario(str(env))).assign(map_id=str(env))
        batch(table, road)  # warm (numba, imports)
        row = {"episodes": int(table["scenario_id"].nunique()),
               "arc_s": cpu(lambda t=table: batch(t, None), args.repeat),
               "map_table_s": cpu(lambda t=table, r=road: batch(t, r), args.repeat)}
        if shared is not None:
            row["shared_s"] = cpu(lambda t=table, r=road: batch(t, shared(r)), args.repeat)
            labels_a, steps_a = batch(table, road)
            labels_b, steps_b = batch(table, shared(road))
            pd.testing.assert_frame_equal(labels_a, labels_b)
            for name in ("leader_row", "gap", "closing", "headway", "ttc"):
                a, b = getattr(steps_a, name, None), getattr(steps_b, name, None)
                if a is not None:
                    np.testing.assert_array_equal(a, b)
            row["identical"] = True
        figures[str(env)] = row
        print(f"{env}: {row}")
    report("batch_map", figures, repeat=args.repeat)


if __name__ == "__main__":
    main()

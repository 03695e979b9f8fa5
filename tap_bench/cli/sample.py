"""``tap-bench sample``: write the built-in synthetic sample of trajectories."""

from __future__ import annotations

import argparse

from tap_bench.synthetic import BEHAVIOURS, sample_table
from tap_bench.tableio import write_table


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sample", help="write a built-in synthetic trajectory table (no data needed)",
        description="Write the hand-shaped behaviours (cruise, turns, lane changes, stop and "
        "go ...) plus random WOMD-like trajectories as a trajectory table.")
    p.add_argument("-o", "--output", required=True, help="table to write (.parquet or .csv)")
    p.add_argument("--random", type=int, default=200,
                   help="random trajectories to add (default 200)")
    p.add_argument("--seed", type=int, default=0, help="seed of the random trajectories")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    table = sample_table(n_random=args.random, seed=args.seed)
    write_table(table, args.output)
    n = table[["scenario_id", "track_id"]].drop_duplicates().shape[0]
    print(f"wrote {args.output}: {n} trajectories ({len(BEHAVIOURS)} named behaviours, "
          f"{args.random} random, seed {args.seed}), {len(table)} rows at 10 Hz")
    return 0

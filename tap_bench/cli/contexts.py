"""``tap-bench contexts``: two policies compared inside each interaction context."""

from __future__ import annotations

import argparse

import pandas as pd

from tap_bench.bench.scores.contexts import compare_contexts, context_occurrences, context_scores
from tap_bench.stats.bootstrap import add_bootstrap_arguments, bootstrap_from_args
from tap_bench.tableio import beside, check_outputs, read_table, write_tables


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "contexts", help="compare two policies inside interaction contexts (cut-in, ...)",
        description="Label the egos' interactions (Following, Cut-in, Lead Braking, ...; "
        "docs/interactions.md) in rollouts of two policies, take the measures inside each "
        "context (smallest TTC and headway, hardest braking, jerk, reaction time from a "
        "cut-in to the first braking) and compare policy A with policy B (the reference) "
        "per env and context: paired by seed where both meet the context on the same seed, "
        "with bootstrap intervals. Input: trajectory tables with is_ego, env, policy and "
        "seed (a run's trajectories.parquet, or rollout outputs).")
    p.add_argument("trajectories", nargs="+", help="trajectory tables (.parquet/.csv)")
    p.add_argument("--a", required=True, help="policy A")
    p.add_argument("--b", required=True, help="policy B, the reference (differences A - B)")
    p.add_argument("--thresholds", default="paper",
                   help="TAP thresholds (preset or JSON; default paper)")
    p.add_argument("--min-pairs", type=int, default=5,
                   help="fewest seeds for a paired interval (default 5)")
    add_bootstrap_arguments(p)
    p.add_argument("-o", "--output", help="write the comparison table (.csv/.parquet); the "
                   "occurrences go beside it as <name>.occurrences.<suffix>")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    occ_path = beside(args.output, "occurrences") if args.output else None
    check_outputs([args.output, occ_path], args.trajectories)  # before any work
    table = pd.concat([read_table(p) for p in args.trajectories], ignore_index=True)
    if "policy" in table.columns:
        table = table[table["policy"].isin([args.a, args.b])]
    occ = context_occurrences(table, args.thresholds, source=", ".join(args.trajectories))
    config = bootstrap_from_args(args)
    if not (occ["policy"] == args.b).any() or not (occ["policy"] == args.a).any():
        compare_contexts(occ, args.a, args.b)  # names the policy without occurrences
    out = context_scores(occ, [args.a], args.b, config=config, min_pairs=args.min_pairs)
    out = out.drop(columns=["policy_a", "policy_b"])  # this command's table, as before
    print(f"{args.a} against {args.b} (the reference) inside interaction contexts; "
          f"differences {args.a} - {args.b}, {config.describe('seeds (pairs of episodes)')}")
    for (env, context), group in out.groupby(["env", "context"], sort=True):
        first = group.iloc[0]
        print(f"{env} / {context}: {first['n_pairs']} seed(s) where both meet it "
              f"({args.a} {first['n_a']}, {args.b} {first['n_b']} episodes)")
        for r in group.itertuples():
            interval = (f"[{r.diff_low:+.2f}, {r.diff_high:+.2f}]" if pd.notna(r.diff_low)
                        else "(no interval)")
            print(f"  {r.measure:16s} {args.a} {r.mean_a:8.2f}  {args.b} {r.mean_b:8.2f}  "
                  f"diff {r.diff:+8.2f} {interval} {r.unit}  {r.method}")
    if args.output:
        write_tables({args.output: out, occ_path: occ})
        print(f"wrote {args.output} and {occ_path}")
    return 0

"""``tap-bench gap``: the sim-to-real behaviour gap of policies from real driving."""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from tap_bench.bench.scores.gap import behaviour_gap, labelled_with_speed
from tap_bench.bench.scores.windows import window_seconds, windows
from tap_bench.errors import LabelTableError
from tap_bench.sdl import LEVELS
from tap_bench.stats.bootstrap import add_bootstrap_arguments, bootstrap_from_args
from tap_bench.tableio import beside, check_outputs, read_table, write_tables


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "gap", help="how far policies drive from real driving (per label and one number)",
        description="Compare each policy's ego behaviour (the shares of its single labels: "
        "manoeuvres and interactions) with a reference corpus of real driving (WOMD "
        "vehicles) in comparable situations (the reference's vehicles in the policy's speed "
        "range): a per-label table of what the policy does more or less often than people, "
        "and one number, the total variation distance of the label shares, with bootstrap "
        "intervals and the floor two samples of the reference alone would show "
        "(docs/interactions.md).")
    p.add_argument("policy_table", help="the policies' trajectory table (rollouts; one "
                   "policy, or a policy column) or label table with interactions")
    p.add_argument("--reference", required=True,
                   help="real driving: a trajectory table (WOMD, ingested; labelled here "
                   "with every vehicle's interactions) or such a label table")
    p.add_argument("--level", default="maneuver", choices=LEVELS,
                   help="SDL level (default maneuver)")
    p.add_argument("--axes", default="lateral,longitudinal,interaction",
                   help="axes whose labels are compared (default all three)")
    p.add_argument("--min-speed", type=float, help="reference vehicles slower than this "
                   "[m/s] are left out (default: the policy's 5 %% mean-speed quantile)")
    p.add_argument("--max-speed", type=float, help="... and faster than this (default: its "
                   "95 %% quantile)")
    p.add_argument("--thresholds", default="paper", help="TAP thresholds (default paper)")
    p.add_argument("--window", default="auto",
                   help="cut the policy's episodes into windows of this many seconds before "
                   "labelling: 'auto' (default) the reference's median track length (WOMD: "
                   "9.1 s), so 30 s episodes meet 9 s tracks on equal terms; 'none' whole "
                   "episodes")
    p.add_argument("--top", type=int, default=8, help="labels printed per policy (8)")
    add_bootstrap_arguments(p)
    p.add_argument("-o", "--output", help="write one row per policy (.csv/.parquet); the "
                   "per-label table goes beside it as <name>.labels.<suffix>")
    p.set_defaults(func=run)


def _crash_rate(table: pd.DataFrame) -> float:
    """Share of the policy's episodes whose ego crashed (NaN without the columns)."""
    if "crashed" not in table.columns or "scenario_id" not in table.columns:
        return float("nan")
    ego = (table[table["is_ego"].fillna(False).astype(bool)] if "is_ego" in table.columns
        else table)
    return (float(ego.groupby("scenario_id")["crashed"].any().mean()) if len(ego) else
        float("nan"))


def _pct(x: float) -> str:
    return "unknown" if x != x else f"{x:.0%}"


def run(args: argparse.Namespace) -> int:
    labels_path = beside(args.output, "labels") if args.output else None
    check_outputs([args.output, labels_path], [args.policy_table, args.reference])
    config = bootstrap_from_args(args)
    table = read_table(args.policy_table)
    if not len(table):
        raise LabelTableError(f"{args.policy_table}: the table is empty; gap compares a "
                              "policy's episodes with the reference. Give a trajectory or "
                              "label table with rows (a run's trajectories.parquet, a "
                              "rollout output).")
    ref_table = read_table(args.reference)
    reference = labelled_with_speed(ref_table, args.level, interactions="all",
                                    thresholds=args.thresholds, source=str(args.reference))
    window = window_seconds(args.window, ref_table, table)
    policies = (sorted(table["policy"].dropna().unique()) if "policy" in table.columns
                else [Path(args.policy_table).name.split(".")[0]])
    if not policies:
        raise LabelTableError(f"{args.policy_table}: no row names a policy (the 'policy' "
                              "column is empty); name the policy of each row.")
    rows, per_label = [], []
    for name in policies:
        mine = table[table["policy"] == name] if "policy" in table.columns else table
        crash = _crash_rate(mine)
        if window is not None:
            mine = windows(mine, window)
        labels = labelled_with_speed(mine, args.level, interactions="auto",
                                     thresholds=args.thresholds, source=str(args.policy_table))
        if "is_ego" in labels.columns:
            labels = labels[labels["is_ego"].fillna(False).astype(bool)]
        # the bootstrap draws whole episodes (a window's episode) and whole scenes
        result = behaviour_gap(labels, reference, name=str(name), axes=args.axes,
                               min_speed=args.min_speed, max_speed=args.max_speed,
                               config=config, reference_name=Path(args.reference).name)
        rows.append({**result.row(), "crash_rate": crash, "window_s": window})
        per_label.append(result.labels.assign(policy=name))
        unit = (f"{window:.1f} s windows of {result.n_policy_units} episodes"
                if window is not None else f"trajectories of {result.n_policy_units} "
                "episodes")
        print(f"{name}: gap {result.gap_debiased:.3f} [{result.debiased_low:.3f}, "
              f"{result.debiased_high:.3f}] (debiased; plug-in {result.gap:.3f}, floor "
              f"{result.floor:.3f}); crash rate {_pct(crash)}; {result.n_policy} {unit} "
              f"against {result.n_reference} trajectories of {result.n_reference_units} "
              f"scenes; {result.reference}")
        for r in result.labels.head(args.top).itertuples():
            print(f"  {r.axis:12s} {r.label:28s} policy {r.share_policy:6.1%}  reference "
                  f"{r.share_reference:6.1%}  diff {r.diff:+6.1%} [{r.diff_low:+.1%}, "
                  f"{r.diff_high:+.1%}]")
    drawn = ("whole scenes of the reference and whole episodes of each policy (windows "
             "with their episode), each side on its own")
    print(f"({config.describe(drawn)}; the debiased gap "
          "is the bootstrap bias-corrected total variation distance, its interval the basic "
          "bootstrap one starting at 0 when two samples of one behaviour could differ as "
          "much; a low gap from a policy that crashes is no praise: read the crash rate "
          "beside it)")
    if args.output:
        write_tables({args.output: pd.DataFrame(rows),
                      labels_path: pd.concat(per_label, ignore_index=True)})
        print(f"wrote {args.output} and {labels_path}")
    return 0

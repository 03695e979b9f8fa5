"""``tap-bench unique``: trajectories whose SDL label no other has (TAP paper section 6.4)."""

from __future__ import annotations

import argparse

from tap_bench.sdl import LEVELS, check_axes
from tap_bench.similarity.unique import label_counts, unique_labels
from tap_bench.tableio import check_outputs, read_table, write_tables


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "unique", help="list the unique behaviours of a label table",
        description="A trajectory is unique at a level when no other trajectory of the table "
        "has its SDL label. Prints the counts and the examples with the most actions.")
    p.add_argument("labels", help="label table from 'tap-bench label' (.parquet or .csv)")
    p.add_argument("--level", choices=[*LEVELS, "all"], default=None,
                   help="SDL level, or 'all' for each level (needed when the table holds "
                   "several)")
    p.add_argument("--axes", default=None, metavar="AXES",
                   help="comma-separated axes a label is made of: lateral, longitudinal, "
                   "interaction (default lateral,longitudinal; interaction needs a table "
                   "labelled with --interactions)")
    p.add_argument("-o", "--output", help="write the unique trajectories (.parquet or .csv)")
    p.add_argument("--counts", help="also write every distinct label with its count")
    p.add_argument("--top", type=int, default=10, help="examples to print per level (10)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_outputs([args.output, args.counts], [args.labels])
    table = read_table(args.labels)
    counts = label_counts(table, args.level, axes=args.axes)
    unique = unique_labels(table, args.level, axes=args.axes)
    for level, group in counts.groupby("level", sort=False):
        n = int(group["count"].sum())
        mine = unique[unique["level"] == level] if "level" in unique.columns else unique
        print(f"{level}: {len(mine):,} of {n:,} trajectories ({100 * len(mine) / n:.2f} %) "
              f"have a unique label; {len(group):,} distinct labels")
        for _, row in mine.head(args.top).iterrows():
            text = " | ".join(str(row[a]) for a in check_axes(args.axes))
            print(f"  {row['scenario_id']}:{row['track_id']}  {row['n_actions']} actions  "
                  f"{text}")
    outputs = {path: t for path, t in ((args.output, unique), (args.counts, counts)) if path}
    write_tables(outputs)
    written = [w for w in (args.output, args.counts) if w]
    if written:
        print("wrote " + ", ".join(written))
    return 0

"""``tap-bench export``: labels in exchange formats (ASAM OpenLABEL JSON)."""

from __future__ import annotations

import argparse

from tap_bench.labelling import tap
from tap_bench.openlabel import write_openlabel
from tap_bench.sdl import LEVELS
from tap_bench.tableio import check_folder_output, check_outputs, check_replace, read_table

FORMATS = ("openlabel",)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "export", help="export labels (every axis, with times and track ids) as OpenLABEL",
        description="Write labels as ASAM OpenLABEL 1.0.0 JSON, one document per scenario: "
        "each track an object, each run of a label (lateral, longitudinal and interaction "
        "axes) an action with its frame interval and exact times, linked to its track "
        "(isSubjectOfAction) and, on the interaction axis, to the other agent "
        "(isObjectOfAction). Input: a segment table ('tap-bench label --segments', with "
        "--interactions for that axis) or a trajectory table, labelled here with its egos' "
        "interactions.")
    p.add_argument("input", help="segment table or trajectory table (.parquet/.csv)")
    p.add_argument("--format", choices=FORMATS, default="openlabel", help="(openlabel)")
    p.add_argument("-o", "--output", required=True,
                   help="a .json file (one scenario) or a directory (one file per scenario)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace the .json file, or the folder an earlier export wrote (a "
                   "folder holding files tap-bench did not write is never replaced)")
    p.add_argument("--level", default=None, choices=LEVELS,
                   help="SDL level exported (default: the segment table's level when it "
                   "holds one, as 'tap-bench label --segments' writes; else maneuver)")
    p.add_argument("--thresholds", default="paper",
                   help="TAP thresholds for a trajectory table (default paper)")
    p.add_argument("--interactions", default="auto", choices=("auto", "ego", "all"),
                   help="whose interactions a trajectory table gets (default: the egos when "
                   "is_ego is given, else every track)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.output.endswith(".json"):  # before any work
        check_outputs([args.output], [args.input])
        check_replace([args.output], args.overwrite)
    else:
        check_folder_output(args.output, args.overwrite)
    table = read_table(args.input)
    if args.level is None:  # the level 'label' wrote, so label then export agree
        held = table["level"].dropna().unique() if "level" in table.columns else []
        args.level = str(held[0]) if len(held) == 1 else "maneuver"
    if "axis" not in table.columns:  # a trajectory table: label it
        table = tap(table, args.thresholds, source=str(args.input),
                    interactions=args.interactions).segments(args.level)
    written = write_openlabel(table, args.output, level=args.level, source=str(args.input),
                              overwrite=args.overwrite)
    print(f"wrote {len(written)} OpenLABEL document(s) "
          f"({len(table[table['level'] == args.level]) if 'level' in table else len(table)} "
          f"label runs at level {args.level}) to {args.output}")
    return 0

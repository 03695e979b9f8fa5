"""``tap-bench validate``: TAP labels of WOMD tracks against Waymo's own classifier."""

from __future__ import annotations

import argparse
from pathlib import Path

import pandas as pd

from tap_bench.sdl import LEVELS
from tap_bench.sources.ingest import read_womd
from tap_bench.tableio import read_table
from tap_bench.womd.validation import markdown, validate_womd, write_validation

_TABLE_SUFFIXES = (".parquet", ".csv")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "validate", help="compare TAP labels of WOMD tracks with Waymo's trajectory types",
        description="Label WOMD tracks with TAP and compare them with Waymo's trajectory-type "
        "classifier (ClassifyTrack of its motion metrics) on the classifier's window, from "
        "1 s to the last valid step: the strict one-category agreement on the lateral axis, "
        "the direction alone, the longitudinal side, the full confusion table, and whether a "
        "track that travels less than 1 m carries a turn or merge. Writes validation.md, "
        "validation.json, agreement.csv, confusion.csv and per_track.parquet.",
        epilog="example: tap-bench validate 'data/validation/*.tfrecord*' -o validation/")
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="WOMD files, directories or quoted glob patterns (Scenario or "
                   "tf.Example TFRecords, ScenarioNet pickles), or an ingested trajectory "
                   "table (.parquet or .csv) that keeps the invalid rows")
    p.add_argument("-o", "--output", required=True, help="folder to write the results to")
    p.add_argument("--thresholds", default="paper",
                   help="a preset ('paper', the default) or a thresholds JSON")
    p.add_argument("--level", default="maneuver", choices=LEVELS,
                   help="TAP level compared (maneuver: turns and merges)")
    p.add_argument("--object-types", default="vehicle",
                   help="comma-separated object types to compare, or 'all' (vehicle)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    types = None if args.object_types == "all" else tuple(
        t.strip().lower() for t in args.object_types.split(",") if t.strip())
    if all(Path(i).suffix.lower() in _TABLE_SUFFIXES for i in args.inputs):
        table = pd.concat([read_table(i) for i in args.inputs], ignore_index=True)
    else:
        table = read_womd(args.inputs, object_types=types)
    source = ", ".join(args.inputs)
    result = validate_womd(table, args.thresholds, object_types=types, level=args.level,
                           source=source)
    written = write_validation(result, args.output)
    print(markdown(result))
    print("wrote " + ", ".join(str(w) for w in written))
    return 0

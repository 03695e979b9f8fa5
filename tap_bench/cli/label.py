"""``tap-bench label``: SDL labels (and segments, per-step labels) of a trajectory file."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from tap_bench.errors import FileFormatError, TrajectoryTableError
from tap_bench.execution import add_backend_arguments
from tap_bench.labelling import INTERACTION_TRACKS, PART_ROWS, tap_in_parts
from tap_bench.sdl import LEVELS
from tap_bench.stages import StageConfig
from tap_bench.tableio import (
    EncodedTable,
    check_outputs,
    read_table,
    read_table_encoded,
    write_tables,
)


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "label", help="label trajectories with SDL labels (TAP)",
        description="Run the Trajectory-to-Action Pipeline on a trajectory table (Parquet or "
        "CSV, SPEC section 1) and write the label table: one row per trajectory segment and "
        "level.")
    p.add_argument("input", help="trajectory table (.parquet or .csv), or a directory of "
                   "Parquet shards (an ingest's output)")
    p.add_argument("-o", "--output", required=True,
                   help="label table to write (.parquet/.csv); a directory of label parts, "
                   "one per shard, for a directory input or --backend ray")
    p.add_argument("--thresholds", default="paper",
                   help="a preset ('paper', the default) or a thresholds JSON from "
                   "'tap-bench fit'")
    p.add_argument("--level", default="action", choices=[*LEVELS, "all"],
                   help="SDL level (default: action); 'all' gives one row per level")
    p.add_argument("--segments", help="also write the segment table (one row per label run)")
    p.add_argument("--steps", help="also write per-step labels of every level")
    p.add_argument("--report", help="write one row per track here: its valid segments, those "
                   "too short to label (< 1 s), its glitches (heading flips and jumps, speed "
                   "spikes), reversing steps and how far it travels")
    p.add_argument("--min-run", type=float, default=1.0, help="shortest label run [s] (1)")
    p.add_argument("--merge-gap", type=float, default=4.0,
                   help="longest straight stretch inside a merge [s] (4)")
    p.add_argument("--merge-heading", type=float, default=0.2,
                   help="largest net heading change over a merge [rad] (0.2)")
    p.add_argument("--merge-offset", type=float, default=1.5,
                   help="smallest sideways move of a merge [m] (1.5)")
    p.add_argument("--interactions", nargs="?", const="auto", default=None,
                   choices=INTERACTION_TRACKS,
                   help="also label the interaction axis (Following, Cut-in, Overtaking ...; "
                   "SPEC 7, docs/interactions.md): of the egos when the table has is_ego, "
                   "else of every track; '--interactions all' labels every vehicle and "
                   "cyclist track. Adds the 'interaction' column and, with --segments, "
                   "axis='interaction' rows naming the other agent (other_track_id)")
    p.add_argument("--map", nargs="+", metavar="FILE",
                   help="with --interactions: lane centre lines along which each ego's path "
                   "goes on beyond the end of its record (SPEC 7), else along an arc of its "
                   "last curvature: a map table (.parquet/.csv, tap_bench.maps; a run's "
                   "roads.parquet) or the WOMD/ScenarioNet files the trajectories came from "
                   "(a scene's map is the one whose map_id is its scenario_id, else its env)")
    add_backend_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.map and not args.interactions:
        print("tap-bench label: error: --map extends the egos' paths for the interaction "
              "axis; add --interactions (or leave --map out).", file=sys.stderr)
        return 2
    if args.backend != "local" or Path(args.input).is_dir():
        if args.map:
            print("tap-bench label: error: --map labels one trajectory file; with a directory "
                  "input or --backend ray, label without it.", file=sys.stderr)
            return 2
        return _run_sharded(args)
    # before any work: no output replaces the input, every output can be written
    check_outputs([args.output, args.segments, args.steps, args.report], [args.input])
    t0 = time.perf_counter()
    # a large Parquet file's strings read as codes: cheaper to read and to label
    table = read_table_encoded(args.input, PART_ROWS)
    lanes = _lanes(args.map) if args.map else None
    t1 = time.perf_counter()
    config = _config(args)
    # a large table scenario by scenario (the same tables, a fraction of the memory)
    # (the per-step times and rows only for the tables that read them)
    result = tap_in_parts(table, args.thresholds, config, source=str(args.input),
                          interactions=args.interactions, map_table=lanes,
                          per_step=bool(args.segments or args.steps or args.interactions))
    labels = result.labels(args.level)
    short = result.short_segments
    if len(result.segments_info) == 0:
        frame = table.frame() if isinstance(table, EncodedTable) else table
        raise TrajectoryTableError(_nothing_to_label(frame, short, args.input, config),
                                   column="valid")
    glitches = result.glitches()
    outputs = {args.output: labels}
    if args.segments:
        outputs[args.segments] = result.segments(args.level)
    if args.steps:
        outputs[args.steps] = result.steps()
    if args.report:
        outputs[args.report] = glitches
    write_tables(outputs)  # together or not at all
    t2 = time.perf_counter()

    info = result.segments_info
    n_tracks = info[["scenario_id", "track_id"]].drop_duplicates().shape[0]
    print(f"labelled {len(info)} segment(s) of {n_tracks} track(s) from {args.input} "
          f"in {t2 - t1:.2f} s (read {t1 - t0:.2f} s; "
          + ", ".join(f"{k} {v:.2f} s" for k, v in result.timings.items()) + ")")
    if len(short):
        where = f"; listed in {args.report}" if args.report else "; --report FILE lists them"
        print(f"warning: {len(short)} valid segment(s) shorter than {config.min_run:g} s "
              f"carry no label{where}", file=sys.stderr)
    print(_glitch_summary(glitches, args.report))
    shown = labels if args.level != "all" else labels[labels["level"] == "action"]
    counts = shown["sdl"].value_counts()
    print(f"{counts.size} distinct {'action' if args.level == 'all' else args.level}-level "
          f"labels; most common:")
    for text, n in counts.head(5).items():
        print(f"  {n:6d}  {text}")
    if result.interactions is not None:
        relations = result.segments("trend")
        relations = relations[relations["axis"] == "interaction"]
        per = relations["label"].value_counts()
        print(f"interaction axis of {len(result.interaction_segments)} segment(s): "
              + ", ".join(f"{name} {n}" for name, n in per.items()) + " run(s)")
    if lanes is not None:
        keys = _strings(table, "scenario_id") | _strings(table, "env")
        if not keys & set(lanes.map_ids):
            print(f"warning: no scene of {args.input} has a map in --map (a map's map_id is "
                  "a scene's scenario_id or env): every path went on along an arc",
                  file=sys.stderr)
    written = [args.output, args.segments, args.steps, args.report]
    print("wrote " + ", ".join(w for w in written if w))
    return 0


def _strings(table, name: str) -> set:
    """The distinct values of column ``name`` of the input as strings (none: no column)."""
    if isinstance(table, EncodedTable) and name in table.values:  # (no reading again)
        return {v for v in table.values[name].to_pylist() if v is not None}
    frame = table.frame() if isinstance(table, EncodedTable) else table
    return set(frame[name].astype(str)) if name in frame.columns else set()


def _lanes(paths: list[str]):
    """The lane map of ``--map``: map tables (Parquet/CSV, checked) or driving-data files
    whose maps are read (:func:`tap_bench.sources.maps.read_maps`)."""
    import pandas as pd

    from tap_bench.maps import check_map_table
    from tap_bench.pathframe import LaneMap
    from tap_bench.sources.maps import read_maps

    tables = []
    for path in paths:
        name = str(path).lower()
        if name.endswith((".parquet", ".csv", ".csv.gz")):
            tables.append(check_map_table(read_table(path), source=str(path)))
        else:
            tables.append(read_maps(path))
    maps = pd.concat(tables, ignore_index=True)
    if not (maps["kind"] == "lane").any():
        raise FileFormatError(f"--map {' '.join(paths)}: no lane centre lines (kind 'lane') "
                              "in the map; give a map table with lanes or the WOMD files the "
                              "trajectories came from.")
    return LaneMap.of_maps(maps)


def _nothing_to_label(table, short, source: str, config: StageConfig) -> str:
    """Why a table gave no label, for the error: no rows, no valid state, or only short
    stretches."""
    n_tracks = (table[["scenario_id", "track_id"]].drop_duplicates().shape[0] if len(table)
        else 0)
    valid = int(table["valid"].sum()) if "valid" in table.columns else len(table)
    what = (f"{source}: nothing to label: {len(table)} row(s) of {n_tracks} track(s)")
    if len(table) == 0:
        return f"{what}. Give a table with trajectories."
    if valid == 0:
        return (f"{what}, and 'valid' is False on every row. Check the column (it marks the "
                "states that were observed) or the source the table came from.")
    return (f"{what}, {valid} valid, but every valid stretch ({len(short)}) is shorter than "
            f"{config.min_run:g} s (--min-run).")


def _config(args: argparse.Namespace) -> StageConfig:
    return StageConfig(min_run=args.min_run, merge_gap=args.merge_gap,
                       merge_heading=args.merge_heading, merge_offset=args.merge_offset)


def _glitch_summary(glitches, report: str | None) -> str:
    """One line: how many tracks carry which glitches (SPEC section 2)."""
    parts = []
    for col, what in (("heading_glitches", "heading flips or jumps"),
                      ("speed_glitches", "speed spikes"), ("reversing_steps", "reversing steps")):
        hit = glitches[col] > 0
        parts.append(f"{int(glitches[col].sum())} {what} in {int(hit.sum())} track(s)")
    still = int(glitches["still"].sum())
    where = f" (per track in {report})" if report else " (--report FILE lists them per track)"
    return (f"glitches repaired: {', '.join(parts)}; {still} of {len(glitches)} track(s) "
            f"travel less than 1 m (no turn, no merge){where}")


def _run_sharded(args: argparse.Namespace) -> int:
    """Label each Parquet shard of ``input`` as a task; one label part per shard."""
    from tap_bench.distributed.shards import label_shards
    from tap_bench.execution import backend_from_args, close_backend

    extra = [flag for flag, value in (("--segments", args.segments), ("--steps", args.steps),
                                      ("--report", args.report)) if value]
    if extra:
        print(f"tap-bench label: error: {', '.join(extra)} label one file; with a directory "
              "input or --backend ray, the output directory's _report.json counts the short "
              "segments of every shard.", file=sys.stderr)
        return 2
    config = _config(args)
    backend = backend_from_args(args)
    try:
        report = label_shards(args.input, args.output, backend, thresholds=args.thresholds,
                              level=args.level, config=config, retries=args.retries,
                              resume=args.resume, interactions=args.interactions)
    finally:
        close_backend(backend)
    short = sum(s.get("short_segments", 0) for s in report.shards)
    print(f"labelled {len(report.shards) - len(report.failed)} of {len(report.shards)} "
          f"shard(s) on {report.backend} ({report.workers} worker(s)) in "
          f"{report.seconds:.1f} s: {report.rows} label rows, {short} segment(s) too short "
          f"to label; wrote {args.output}/")
    for note in report.notes:
        print(f"tap-bench label: {note}", file=sys.stderr)
    for failed in report.failed:
        print(f"warning: {failed['input']} failed after {failed['attempts']} attempt(s): "
              f"{failed['error']}", file=sys.stderr)
    return 1 if report.shards and len(report.failed) == len(report.shards) else 0

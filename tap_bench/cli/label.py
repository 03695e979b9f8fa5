"""``tap-bench label``: SDL labels (and segments, per-step labels) of a trajectory file."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from tap_bench.execution import add_backend_arguments
from tap_bench.labelling import tap
from tap_bench.sdl import LEVELS
from tap_bench.stages import StageConfig
from tap_bench.tableio import read_table, write_table


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
    p.add_argument("--report", help="write the segments too short to label (< 1 s) here")
    p.add_argument("--min-run", type=float, default=1.0, help="shortest label run [s] (1)")
    p.add_argument("--merge-gap", type=float, default=4.0,
                   help="longest straight stretch inside a merge [s] (4)")
    add_backend_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.backend != "local" or Path(args.input).is_dir():
        return _run_sharded(args)
    t0 = time.perf_counter()
    table = read_table(args.input)
    t1 = time.perf_counter()
    config = StageConfig(min_run=args.min_run, merge_gap=args.merge_gap)
    result = tap(table, args.thresholds, config, source=str(args.input))
    labels = result.labels(args.level)
    write_table(labels, args.output)
    if args.segments:
        write_table(result.segments(args.level), args.segments)
    if args.steps:
        write_table(result.steps(), args.steps)
    short = result.short_segments
    if args.report:
        write_table(short, args.report)
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
    shown = labels if args.level != "all" else labels[labels["level"] == "action"]
    counts = shown["sdl"].value_counts()
    print(f"{counts.size} distinct {'action' if args.level == 'all' else args.level}-level "
          f"labels; most common:")
    for text, n in counts.head(5).items():
        print(f"  {n:6d}  {text}")
    written = [args.output, args.segments, args.steps, args.report]
    print("wrote " + ", ".join(w for w in written if w))
    return 0


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
    config = StageConfig(min_run=args.min_run, merge_gap=args.merge_gap)
    backend = backend_from_args(args)
    try:
        report = label_shards(args.input, args.output, backend, thresholds=args.thresholds,
                              level=args.level, config=config, retries=args.retries,
                              resume=args.resume)
    finally:
        close_backend(backend)
    short = sum(s.get("short_segments", 0) for s in report.shards)
    print(f"labelled {len(report.shards) - len(report.failed)} of {len(report.shards)} "
          f"shard(s) on {report.backend} ({report.workers} worker(s)) in "
          f"{report.seconds:.1f} s: {report.rows} label rows, {short} segment(s) too short "
          f"to label; wrote {args.output}/")
    for failed in report.failed:
        print(f"warning: {failed['input']} failed after {failed['attempts']} attempt(s): "
              f"{failed['error']}", file=sys.stderr)
    return 1 if report.shards and len(report.failed) == len(report.shards) else 0

"""``tap-bench ingest``: driving data sets to a trajectory table (Parquet)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tap_bench.execution import add_backend_arguments
from tap_bench.progress import add_progress_arguments, progress_choice
from tap_bench.sources.ingest import ON_ERROR, formats, ingest_womd, report_path
from tap_bench.womd.tfrecord import MAX_RECORD_BYTES


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "ingest", help="convert a data set to a trajectory table",
        description="Convert a driving data set into a trajectory table (SPEC section 1).")
    sources = p.add_subparsers(dest="dataset", metavar="DATASET", required=True)
    w = sources.add_parser(
        "womd", help="Waymo Open Motion Dataset (Scenario or tf.Example TFRecords, "
        "ScenarioNet pickles)",
        description="Read WOMD files without TensorFlow: TFRecords (plain or GZIP) of "
        "Scenario or tf.Example protos, or ScenarioNet *.pkl scenarios. Writes one Parquet "
        "trajectory table atomically, and a report (<output>.report.json) listing every "
        "skipped record.",
        epilog="example: tap-bench ingest womd 'data/training/*.tfrecord*' -o womd.parquet "
        "--object-types vehicle --workers 2")
    w.add_argument("inputs", nargs="+", metavar="PATTERN",
                   help="files, directories or quoted glob patterns ('**' is recursive)")
    w.add_argument("-o", "--output", required=True,
                   help="trajectory table to write (.parquet), or a directory of Parquet "
                   "parts, one per input file (a name without suffix, or --backend ray)")
    w.add_argument("--object-types", default=None,
                   help="comma-separated types to keep: vehicle, pedestrian, cyclist, other "
                   "(default: all)")
    w.add_argument("--workers", type=int, default=None,
                   help="decoding processes (default 1); with --backend ray and no "
                   "--address, the CPUs of the local Ray cluster (default: all)")
    w.add_argument("--on-error", default="stop", choices=ON_ERROR,
                   help="at a bad record: stop (default, nothing is written) or skip it and "
                   "list it in the report")
    w.add_argument("--format", default="auto", choices=formats(),
                   help="input format (default: auto, per file)")
    w.add_argument("--no-crc", action="store_true",
                   help="do not check the CRC-32C of records (trusted local copies only)")
    w.add_argument("--max-record-mb", type=float, default=MAX_RECORD_BYTES / (1 << 20),
                   help="longest record read, in MiB (default %(default)g; a WOMD record is "
                   "about 1 MB); a longer one is a bad record, never loaded")
    add_progress_arguments(w)
    add_backend_arguments(w)
    w.set_defaults(func=run)


def _log(line: str) -> None:
    from tqdm import tqdm

    tqdm.write(f"tap-bench ingest: {line}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    if args.workers is not None and args.workers < 1:
        print(f"tap-bench ingest: error: --workers must be 1 or more, not {args.workers}",
              file=sys.stderr)
        return 2
    if not args.max_record_mb > 0:
        print(f"tap-bench ingest: error: --max-record-mb must be > 0, not {args.max_record_mb}",
              file=sys.stderr)
        return 2
    args.max_record_bytes = int(args.max_record_mb * (1 << 20))
    types = ([t.strip() for t in args.object_types.split(",") if t.strip()]
             if args.object_types else None)
    if args.backend != "local" or Path(args.output).is_dir() or not Path(args.output).suffix:
        return _run_sharded(args, types)
    report = ingest_womd(args.inputs, args.output, format=args.format, object_types=types,
                         on_error=args.on_error, check_crc=not args.no_crc,
                         workers=args.workers or 1, progress=progress_choice(args), log=_log,
                         max_record_bytes=args.max_record_bytes)
    print(f"read {report.records} record(s) from {report.files} file(s) "
          f"({report.bytes_read / 1e6:.1f} MB in {report.seconds:.1f} s, "
          f"{report.mb_per_s:.1f} MB/s): {report.scenarios} scenario(s), {report.rows} rows")
    if report.skipped:
        print(f"warning: skipped {len(report.skipped)} record(s); listed in "
              f"{report_path(args.output)}", file=sys.stderr)
    print(f"wrote {args.output} and {report_path(args.output)}")
    return 0


def _run_sharded(args: argparse.Namespace, types: list[str] | None) -> int:
    """One task per input file, each writing its Parquet part of the output directory."""
    from tap_bench.distributed.shards import ingest_shards
    from tap_bench.execution import backend_from_args, close_backend

    backend = backend_from_args(args, workers=args.workers)
    try:
        report = ingest_shards(args.inputs, args.output, backend, format=args.format,
                               object_types=types, on_error=args.on_error,
                               check_crc=not args.no_crc, retries=args.retries,
                               resume=args.resume, progress=progress_choice(args),
                               max_record_bytes=args.max_record_bytes, log=_log)
    finally:
        close_backend(backend)
    scenarios = sum(s.get("scenarios", 0) for s in report.shards)
    skipped = sum(len(s.get("skipped", [])) for s in report.shards)
    mb = report.bytes_read / 1e6
    print(f"ingested {len(report.shards) - len(report.failed)} of {len(report.shards)} "
          f"file(s) on {report.backend} ({report.workers} worker(s)): {mb:.1f} MB in "
          f"{report.seconds:.1f} s ({mb / max(report.seconds, 1e-9):.1f} MB/s), "
          f"{scenarios} scenario(s), {report.rows} rows")
    for note in report.notes:
        _log(note)
    if skipped:
        _log(f"skipped {skipped} record(s); listed in {args.output}/_report.json")
    for failed in report.failed:
        _log(f"{failed['input']} failed after {failed['attempts']} attempt(s): "
             f"{failed['error']}")
    print(f"wrote {args.output}/ (one part per file) and {args.output}/_report.json")
    return 1 if report.shards and len(report.failed) == len(report.shards) else 0

"""``tap-bench fit``: learn thresholds from a trajectory file and save them as JSON."""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import pandas as pd

from tap_bench.errors import FitWarning
from tap_bench.execution import add_backend_arguments
from tap_bench.fitting import METHODS, fit_report
from tap_bench.kinematics import one_second_samples
from tap_bench.tableio import check_outputs, read_table
from tap_bench.thresholds import save_thresholds


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "fit", help="learn TAP thresholds from trajectories",
        description="Fit the yaw-rate, acceleration and speed thresholds to the one-second "
        "distributions of a trajectory table (SPEC section 3) with every method and start, "
        "print how each fared against the grid optimum, and save the chosen thresholds as "
        "versioned JSON.")
    p.add_argument("input", help="trajectory table (.parquet or .csv), or a directory of "
                   "Parquet shards")
    p.add_argument("-o", "--output", required=True, help="thresholds JSON to write")
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS,
                   help="methods to run (default: all)")
    p.add_argument("--select", default=None, choices=["best", *METHODS],
                   help="which run gives the thresholds: 'best' (default), the lowest J of "
                   "every method, start and the grid, passing over degenerate bands; or one "
                   "method's lowest J")
    p.add_argument("--epochs", type=int, default=100, help="descent epochs per start (100)")
    p.add_argument("--seed", type=int, default=0, help="seed of the cross-entropy method")
    add_backend_arguments(p, shards=False)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    check_outputs([args.output], [args.input])
    t0 = time.perf_counter()
    options = {"methods": tuple(args.methods), "select": args.select,
               "dataset": str(args.input), "epochs": args.epochs, "seed": args.seed}
    if args.backend != "local" or Path(args.input).is_dir():
        samples, options["dataset"] = _sharded_samples(args)
    else:
        table = read_table(args.input)
        samples = one_second_samples(table, source=str(args.input))
    t1 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", FitWarning)  # printed below, after the tables
        report = fit_report(samples, **options)
    t2 = time.perf_counter()
    save_thresholds(report.thresholds, args.output)
    frame = report.table()
    with pd.option_context("display.width", 200, "display.max_columns", 20,
                           "display.float_format", "{:.3e}".format):
        for dist, fit in report.fits.items():
            print(f"\n{dist}: {fit.n_samples} one-second samples "
                  f"[{frame.loc[frame['dist'] == dist, 'unit'].iloc[0]}]")
            part = frame[frame["dist"] == dist].drop(columns=["dist", "unit"])
            print(part.to_string(index=False))
    th = report.thresholds
    print(f"\nchosen: w {th.of('w')}  a {th.of('a')}  v {th.of('v')}")
    print(f"samples {t1 - t0:.2f} s, fitting {t2 - t1:.2f} s; wrote {args.output}")
    for note in report.warnings:
        print(f"warning: {note}", file=sys.stderr)
    return 0


def _sharded_samples(args: argparse.Namespace) -> tuple[dict, str]:
    """One-second samples per Parquet shard as tasks, merged exactly (sorted), and the data
    set's name for the provenance."""
    from tap_bench.distributed.fitting import dataset_name, shard_samples
    from tap_bench.execution import backend_from_args, close_backend

    backend = backend_from_args(args)
    try:
        merged = shard_samples(args.input, backend, retries=args.retries)
    finally:
        close_backend(backend)
    for shard, error in merged.failed:
        print(f"warning: {shard} left out of the fit: {error}", file=sys.stderr)
    print(f"one-second samples of {len(merged.shards) - len(merged.failed)} of "
          f"{len(merged.shards)} shard(s) on {backend.name}")
    return merged.samples, dataset_name(str(args.input), merged)

"""``tap-bench evaluate``: the TAP paper's sections 6.3 and 6.4 on the user's data."""

from __future__ import annotations

import argparse

from tap_bench.sdl import LEVELS
from tap_bench.similarity.evaluate import SEGMENTS, evaluate
from tap_bench.similarity.figures import write_evaluation
from tap_bench.tableio import read_table


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "evaluate", help="SDL search against ADE and DTW nearest neighbours, unique labels",
        description="For every trajectory (or --queries N of them) find its nearest other "
        "trajectory by ADE and by DTW on normalised shapes, count how often it has a "
        "different SDL label, count unique labels and time 1,000 comparisons of TAP, ADE and "
        "DTW. Writes evaluation.json, evaluation.md, neighbours.parquet, unique.parquet and "
        "figures like the paper's Figures 5 and 6.")
    p.add_argument("trajectories", help="trajectory table (.parquet or .csv)")
    p.add_argument("--labels", help="its label table (default: label it here with "
                   "--thresholds)")
    p.add_argument("-o", "--output", required=True, help="folder to write the results to")
    p.add_argument("--level", choices=LEVELS, default="action", help="SDL level (action)")
    p.add_argument("--thresholds", default="paper",
                   help="preset or thresholds JSON, to label and to time TAP (paper)")
    p.add_argument("--queries", type=int, help="answer a random sample of N trajectories")
    p.add_argument("--seed", type=int, default=0, help="seed of the sample (0)")
    p.add_argument("--object-types", nargs="+", default=["vehicle"],
                   help="trajectories to compare (default: vehicle; 'all' for every type)")
    p.add_argument("--ade-length", default="equal",
                   help="'equal': ADE compares equal lengths only (default); N: every "
                   "trajectory cut to its first N points, shorter ones left out")
    p.add_argument("--segments", choices=SEGMENTS, default="full",
                   help="'full' (default): trajectories valid over their whole scenario, the "
                   "paper's 9 s WOMD tracks; 'all': every labelled valid segment")
    p.add_argument("--workers", type=int, help="threads (default: the usable cores)")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    trajectories = read_table(args.trajectories)
    labels = read_table(args.labels) if args.labels else None
    types = (None if [t.lower() for t in args.object_types] == ["all"] else
        tuple(t.lower() for t in args.object_types))
    length = args.ade_length if args.ade_length == "equal" else int(args.ade_length)
    ev = evaluate(trajectories, labels, level=args.level, thresholds=args.thresholds,
                  queries=args.queries, seed=args.seed, object_types=types, ade_length=length,
                  segments=args.segments, workers=args.workers, source=str(args.trajectories))
    written = write_evaluation(ev, args.output, figures=not args.no_figures)
    s = ev.summary
    d = s["data"]
    scope = ("full-length" if d["segments"] == "full" else "all") + " trajectories"
    print(f"{d['queries']:,} queries among {d['trajectories']:,} {scope} "
          f"({d['level']} level; {d['stationary_queries']:,} queries stationary):")
    for m in ("ade", "dtw"):
        f = s[m]
        share = "n/a" if f["share_different"] is None else f"{100 * f['share_different']:.2f} %"
        print(f"  nearest by {m.upper()}: {f['different_label']:,} of "
              f"{f['queries_with_neighbour']:,} have a different SDL label ({share}); search "
              f"{f['search_seconds']:.2f} s")
        for part in ("moving", "stationary"):
            g = f[part]
            share = "n/a" if g["share_different"] is None else f"{100 * g['share_different']:.2f} %"
            print(f"    {part}: {g['different_label']:,} of {g['queries_with_neighbour']:,} "
                  f"({share})")
    u = s["sdl_exact"]
    print(f"  unique labels: {u['unique_labels']:,} ({100 * u['share_unique']:.2f} %)")
    t = s["timing"]
    print(f"  per 1,000 comparisons: TAP {t['tap_ms_per_1000']:.1f} ms (labels), ADE "
          f"{t['ade_ms_per_1000']:.3f} ms, DTW {t['dtw_ms_per_1000']:.3f} ms")
    print("wrote " + ", ".join(str(w) for w in written))
    return 0

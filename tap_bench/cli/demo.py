"""``tap-bench demo``: run the demo benchmark and print where its report is."""

from __future__ import annotations

import argparse
import os
import time

from tap_bench.progress import add_progress_arguments, progress_choice


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "demo", help="run the demo benchmark (no download) and write its HTML report",
        description="Roll out four driving policies (IDM/MOBIL default, aggressive, defensive; "
        "random) in three highway-env scenarios over 12 seeds, label every vehicle with TAP, "
        "compare the policies with IDM/MOBIL (paired by seed and matched by SDL label), score "
        "behaviour coverage and unique manoeuvres, and write tables, plots and a static HTML "
        "report. Under a minute on 2 quiet cores.")
    p.add_argument("-o", "--output", default="results/demo",
                   help="run folder (default results/demo; an earlier demo there is replaced)")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="rollout processes (default 2)")
    add_progress_arguments(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import pandas as pd

    from tap_bench.bench.run.demo import run_demo, timing_split

    start = time.perf_counter()
    result = run_demo(args.output, workers=args.workers,
                      progress=progress_choice(args),
                      announce=lambda line: print(line, flush=True))
    split = timing_split(result)
    summary = result.summary
    print(f"{summary['n_episodes']} episodes ({summary['n_failed']} failed) of "
          f"{len(summary['suite']['policies'])} policies in {len(summary['suite']['envs'])} "
          f"envs; {time.perf_counter() - start:.0f} s (rollouts {split['rollout']:.0f} s, "
          f"labelling {split['labelling']:.0f} s, scoring {split['scoring']:.1f} s, "
          f"report {split['report']:.1f} s)")
    nan = float("nan")

    def with_interval(row: dict, key: str, fmt: str) -> str:
        lo, hi = row.get(f"{key}_low"), row.get(f"{key}_high")
        text = format(row.get(key, nan) if row.get(key) is not None else nan, fmt)
        if lo is not None and hi is not None:
            text += f" [{format(lo, fmt)}, {format(hi, fmt)}]"
        return text

    level = summary.get("suite", {}).get("bootstrap", {}).get("level", 0.95)
    print(f"per policy, pooled over the envs ({level:.0%} intervals):")
    for policy, row in summary["headline"].items():
        bits = [f"crash rate {with_interval(row, 'crashed', '.0%')}",
                f"mean speed {with_interval(row, 'mean_speed', '.1f')} m/s"]
        for k, v in row.items():  # coverage beside the same-policy figure (halves)
            if k.startswith("coverage of") and ":" not in k and v is not None:
                bits.append(f"{k} {v:.0%}" + _halves(row, k))
        print(f"  {policy:16s} " + ", ".join(bits))
    if summary.get("verdict"):
        from tap_bench.bench.scores.verdict import verdict_lines

        print("against the reference (paired by seed; safety first):")
        for line in verdict_lines(pd.DataFrame(summary["verdict"])):
            print(f"  {line}")
    print(f"report: {result.report.resolve()}")
    return 0


def _halves(row: dict, key: str) -> str:
    """`` (halves: policy 28% vs same policy 50%: -22 pts [-35, -9])``: the policy and the
    same-policy figure at the half sizes the difference is taken at, and the difference
    with its interval (:func:`tap_bench.bench.scores.null.halves_text`); "" without them."""
    half, null = row.get(f"{key}: policy at halves"), row.get(f"{key}: same-policy figure")
    diff = row.get(f"{key}: difference")
    low, high = row.get(f"{key}: difference_low"), row.get(f"{key}: difference_high")
    if None in (half, null, diff, low, high):
        return ""
    from tap_bench.bench.scores.null import halves_text

    return f" ({halves_text(half, null, diff, low, high)})"

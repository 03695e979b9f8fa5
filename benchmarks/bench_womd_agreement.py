"""TAP labels of WOMD vehicles against Waymo's own trajectory-type classifier.

Ingests the given files (default: the real samples in ../shared/data/womd), labels the
vehicles with the paper thresholds at the maneuver level, classifies them as WOMD's motion
metrics do, and prints the agreement table (markdown, as in docs/womd.md) and every track
that disagrees.

    python benchmarks/bench_womd_agreement.py ['data/*.tfrecord' ...]
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

from machine import report

import tap_bench
from tap_bench.womd.trajectory_types import (
    agreement_table,
    classify_trajectories,
    label_agreement,
)

SAMPLES = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "womd"


def main(patterns: list[str]) -> None:
    patterns = patterns or [str(SAMPLES / "*.tfrecord"), str(SAMPLES / "*.pkl")]
    table = tap_bench.read_womd(patterns, object_types="vehicle")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", tap_bench.ShortSegmentWarning)
        labels = tap_bench.label(table, level="maneuver")
    per_track = label_agreement(classify_trajectories(table), labels)
    summary = agreement_table(per_track)
    text = summary.astype(str)
    print("| " + " | ".join(text.columns) + " |")
    print("|" + "---|" * len(text.columns))
    for row in text.itertuples(index=False):
        print("| " + " | ".join(row) + " |")
    print()
    wrong = per_track[per_track["labelled"] & ~per_track["agrees"]]
    print(wrong[["scenario_id", "track_id", "trajectory_type", "dy", "heading_change",
                 "max_speed", "lateral", "longitudinal"]].to_string(index=False))
    report("womd_agreement", {"table": summary.to_dict(orient="records")},
           inputs=patterns, thresholds="paper", level="maneuver")


if __name__ == "__main__":
    main(sys.argv[1:])

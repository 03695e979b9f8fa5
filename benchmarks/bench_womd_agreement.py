"""TAP labels of WOMD vehicles against Waymo's own trajectory-type classifier.

Reads the given files (default: the real samples in ../shared/data/womd), labels the
vehicles with the paper thresholds, classifies them as WOMD's motion metrics do, and prints
the strict agreement, the direction-only and longitudinal figures, the confusion table (as
in docs/womd.md; the same as ``tap-bench validate``) and every labelled track that
disagrees.

    python benchmarks/bench_womd_agreement.py ['data/*.tfrecord' ...]
"""

from __future__ import annotations

import sys
from pathlib import Path

from machine import report

import tap_bench
from tap_bench.womd.validation import markdown, validate_womd

SAMPLES = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "womd"


def main(patterns: list[str]) -> None:
    patterns = patterns or [str(SAMPLES / "*.tfrecord"), str(SAMPLES / "*.pkl")]
    table = tap_bench.read_womd(patterns, object_types="vehicle")
    result = validate_womd(table, source=", ".join(patterns))
    print(markdown(result))
    per_track = result.per_track
    wrong = per_track[per_track["labelled"] & ~per_track["strict"]]
    print(wrong[["scenario_id", "track_id", "trajectory_type", "dy", "heading_change",
                 "max_speed", "lateral", "longitudinal"]].to_string(index=False))
    report("womd_agreement", {"summary": result.summary,
                              "table": result.agreement.to_dict(orient="records"),
                              "confusion": result.confusion.to_dict(orient="index")},
           inputs=patterns, thresholds="paper", level="maneuver")


if __name__ == "__main__":
    main(sys.argv[1:])

"""Per-core cost of ingest plus labelling on the real WOMD samples (for the 100-node estimate).

Writer-made shards hold tracks only; real WOMD ``Scenario`` records also carry the map
(lanes, road lines, signals), which the decoder reads past. This script times what one task
of ``tap-bench ingest ... --backend ray`` and ``tap-bench label ... --backend ray`` does per
file, on the real samples in ``../shared/data/womd/`` (read in place, never copied): ingest
to Parquet in one process, then TAP at the action level on all vehicles. Each file is run
``--repeat`` times; the median CPU time (this process) is the per-core cost.

    nice -n 10 python benchmarks/bench_ray_real_rate.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from machine import report

from tap_bench.labelling import tap
from tap_bench.sources import ingest_womd
from tap_bench.tableio import read_table

WOMD_DIR = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "womd"
FILES = ("motion_data_one_scenario.tfrecord", "womd_scenario_input.tfrecord")


def one(path: Path, scratch: Path) -> tuple[float, float, dict]:
    part = scratch / "part.parquet"
    wall, cpu = time.perf_counter(), time.process_time()
    ingested = ingest_womd([path], part)
    result = tap(read_table(part), "paper", source=str(part))
    labels = result.labels("action")
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return wall, cpu, {"scenarios": ingested.scenarios, "rows": ingested.rows,
                       "label_rows": len(labels)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    figures: dict = {}
    with tempfile.TemporaryDirectory() as scratch:
        for name in FILES:
            path = (WOMD_DIR / name).resolve()
            if not path.is_file():
                print(f"skipped {name}: not found in {WOMD_DIR}")
                continue
            one(path, Path(scratch))  # imports and caches warm
            runs = [one(path, Path(scratch)) for _ in range(args.repeat)]
            cpu = statistics.median(r[1] for r in runs)
            wall = statistics.median(r[0] for r in runs)
            counts = runs[0][2]
            mb = path.stat().st_size / 1e6
            figures[name] = {
                "MB": round(mb, 3), **counts,
                "median_wall_s": round(wall, 4), "median_cpu_s": round(cpu, 4),
                "MB_per_cpu_s": round(mb / cpu, 2),
                "cpu_s_per_scenario": round(cpu / counts["scenarios"], 4),
                "rows_per_cpu_s": round(counts["rows"] / cpu),
            }
            print(name, figures[name], flush=True)
    report("ray_real_rate", figures, repeat=args.repeat)


if __name__ == "__main__":
    main()
